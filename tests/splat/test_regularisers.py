"""splat/regularisers.py: the depth spread from three renders against the pairwise double sum over each pixel's
blending weights (values and gradients), the surface anchor against a per-Gaussian loop over the points
(values and gradients), and both unchanged at any scene scale; flattening (the C++ kernel and the torch formula)
against its per-axis loop and against each other."""

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
from panorecon.splat.model import GaussianModel, covariances
from panorecon.splat.rasterize import cpu_backend, project_gaussians, rasterize
from panorecon.splat.rasterize.torch_backend import ALPHA_MAX, ALPHA_MIN
from panorecon.splat.regularisers import (
    ANCHOR_BAND,
    FLAT_MIN_COS,
    anchor_height,
    depth_spread,
    depth_spread_reference,
    flatten_frames,
    flatten_onto_surface,
    flatten_onto_surface_reference,
    flatten_onto_surface_torch,
    normal_coherence,
    render_depth_sq,
    surface_anchor,
    surface_anchor_reference,
    surface_distances,
    surface_normals,
)

W, H = 10, 8


def _model(scale: float = 1.0, seed: int = 0) -> GaussianModel:
    """Six overlapping Gaussians 2-4 units ahead of the camera (times ``scale``), opacities 0.2-0.6: no pixel's
    transmittance reaches gsplat's stop, so every pair is blended."""
    g = torch.Generator().manual_seed(seed)
    n = 6
    means = torch.stack(
        [
            2 + 2 * torch.rand(n, generator=g),
            0.4 * torch.rand(n, generator=g) - 0.2,
            0.3 * torch.rand(n, generator=g) - 0.15,
        ],
        -1,
    )
    m = GaussianModel(
        means * scale,
        torch.randn(n, 4, generator=g),
        torch.log(scale * (0.2 + 0.2 * torch.rand(n, 3, generator=g))),
        torch.logit(0.2 + 0.4 * torch.rand(n, generator=g)),
        torch.rand(n, 1, 3, generator=g),
        torch.zeros(n, 0, 3),
    )
    m.near_plane = 0.01 * scale
    return m


def _camera():
    K = torch.tensor(intrinsics_from_fov(W, H, 40.0), dtype=torch.float32)[None]
    V = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None]
    return V, K


def _fast(model, backend="torch"):
    V, K = _camera()
    scales, opacities = model.rendered()
    _, alpha, depth, _ = rasterize(
        model.means,
        model.quats,
        scales,
        opacities,
        model.sh0[:, 0],
        V,
        K,
        W,
        H,
        near_plane=model.near_plane,
        backend=backend,
    )
    return depth_spread(alpha[..., 0], depth[..., 0], render_depth_sq(model, V, K, W, H, backend, False))


def _slow(model):
    """Each pixel's blending weights by a loop over its depth-sorted Gaussians (gsplat's rules), then the double sum."""
    V, K = _camera()
    scales, opacities = model.rendered()
    means2d, conics, depths, _ = project_gaussians(model.means, model.quats, scales, V, K, W, H, model.near_plane)
    order = torch.argsort(depths[0].detach())
    rows = []
    for y in range(H):
        for x in range(W):
            T, w = 1.0, [torch.zeros(())] * len(order)
            for i in order.tolist():
                d = torch.tensor([x + 0.5, y + 0.5]) - means2d[0, i]
                a, b, c = conics[0, i]
                sigma = 0.5 * (a * d[0] ** 2 + c * d[1] ** 2) + b * d[0] * d[1]
                al = torch.clamp(opacities[i] * torch.exp(-sigma), max=ALPHA_MAX)
                if float(al.detach()) < ALPHA_MIN:
                    continue
                w[i] = al * T
                T = T * (1 - al)
            rows.append(torch.stack(w))
    return depth_spread_reference(torch.stack(rows), depths[0])


@pytest.mark.parametrize("backend", ["torch", "cpu"])
def test_depth_spread_from_renders_is_the_pairwise_double_sum_values_and_gradients(backend):
    from panorecon.splat.rasterize import cpu_backend

    if backend == "cpu" and not cpu_backend.available():
        pytest.skip("the C++ rasterizer could not be built here")
    grads = []
    for fn in (lambda m: _fast(m, backend), _slow):
        model = _model()
        value = fn(model)
        value.backward()
        grads.append((value.item(), model.means.grad.clone(), model.logit_opacities.grad.clone()))
    (fast, gm_f, go_f), (slow, gm_s, go_s) = grads
    assert slow > 1e-4  # the layers overlap: a spread to measure
    assert fast == pytest.approx(slow, rel=1e-4)
    torch.testing.assert_close(gm_f, gm_s, rtol=2e-3, atol=1e-6)
    torch.testing.assert_close(go_f, go_s, rtol=2e-3, atol=1e-6)


def test_one_layer_has_no_spread_and_two_layers_their_variance():
    alpha = torch.tensor([[0.5, 0.75]])
    z = torch.tensor([2.0, 4.0])
    # pixel 0: one Gaussian (w 0.5 at z 2): none; pixel 1: w 0.5 at 2 and 0.25 at 4
    w = torch.tensor([[0.5, 0.0], [0.5, 0.25]])
    s1, s2 = (w @ z)[None], (w @ z.square())[None]
    got = depth_spread(alpha, s1, s2)
    # A sum_ij w_i w_j (z_i - z_j)^2 / 2 / S1^2 = 0.75 * (0.5 * 0.25 * 2^2) / 2^2, over two pixels
    assert float(got) == pytest.approx(0.75 * 0.5 / 4 / 2, rel=1e-6)
    assert float(depth_spread_reference(w, z)) == pytest.approx(float(got), rel=1e-6)
    empty = depth_spread(torch.zeros(1, 2), torch.zeros(1, 2), torch.zeros(1, 2))
    assert float(empty) == 0.0


@settings(max_examples=12, deadline=None)
@given(st.floats(-3.0, 3.0))
def test_depth_spread_is_the_same_at_any_scene_scale(log10_scale):
    """A room in millimetres or a valley in kilometres: the same Gaussians scaled give the same spread."""
    ref = _fast(_model()).item()
    got = _fast(_model(10.0**log10_scale)).item()
    assert np.isfinite(got) and got == pytest.approx(ref, rel=1e-3)


def _cloud(seed=0, n=4000):
    """Points on a sphere of radius 3 with a bump, and a second layer 30 % behind in one octant."""
    g = np.random.default_rng(seed)
    u = g.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    r = 3 + 0.3 * (u[:, 0] > 0.5)
    pts = u * r[:, None]
    back = u[:500] * (1.3 * r[:500, None])
    return np.concatenate([pts, back])


def test_surface_distances_keep_the_nearest_point_per_bin_and_nan_where_none():
    pts = np.array([[1.0, 0, 0], [2.0, 0, 0], [0, 0, 5.0]])
    grid = surface_distances(pts, 8)
    assert grid.shape == (8, 16) and np.nanmin(grid) == 1.0
    assert np.isnan(grid).sum() == grid.size - 2  # two bins have points; the farther point along +x is hidden
    assert anchor_height(64, 60.0) == 192


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_surface_anchor_is_the_per_gaussian_loop_values_and_gradients(scale):
    pts = _cloud() * scale
    g = np.random.default_rng(1)
    idx = g.choice(len(pts), 300, replace=False)
    off = np.exp(g.uniform(-0.2, 0.2, size=(300, 1)))  # some inside the band, some beyond it
    means = torch.tensor(pts[idx] * off, dtype=torch.float64, requires_grad=True)
    height = 24
    slow = surface_anchor_reference(means, pts, height)
    slow.backward()
    g_slow = means.grad.clone()
    means.grad = None
    fast = surface_anchor(means, torch.from_numpy(surface_distances(pts, height)).double())
    fast.backward()
    assert fast.item() == pytest.approx(slow.item(), rel=1e-5)
    torch.testing.assert_close(means.grad, g_slow, rtol=1e-4, atol=1e-12)


def test_the_anchor_pulls_within_its_band_towards_the_surface_and_leaves_the_rest():
    """On a sphere of radius 3: Gaussians 5 % in front or behind are pulled onto it (descent moves them towards
    r = 3); those 15 % away, a fill behind a depth edge or another layer, get no gradient at all."""
    g = np.random.default_rng(2)
    u = g.normal(size=(20000, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    dirs = torch.tensor(u[:8], dtype=torch.float64)
    factor = torch.tensor([0.95, 1.05, 0.86, 1.16, 0.95, 1.05, 0.86, 1.16], dtype=torch.float64)
    means = (3 * dirs * factor[:, None]).requires_grad_(True)
    surface_anchor(means, torch.from_numpy(surface_distances(3 * u, 24)).double()).backward()
    radial = (means.grad * dirs).sum(1)  # d loss / d r
    inside = torch.tensor([True, True, False, False] * 2)
    assert (factor.log().abs()[~inside] > ANCHOR_BAND).all() and (factor.log().abs()[inside] < ANCHOR_BAND).all()
    assert (radial[inside] * (factor[inside] - 1) > 0).all()  # descent moves them towards the surface
    assert (means.grad[~inside] == 0).all()


def test_surface_anchor_without_a_surface_bin_is_zero_and_finite():
    surface = torch.full((4, 8), float("nan"))
    means = torch.randn(5, 3, requires_grad=True)
    loss = surface_anchor(means, surface)
    loss.backward()
    assert loss.item() == 0.0 and torch.isfinite(means.grad).all()


def _box(scale: float, n: int = 200_000) -> np.ndarray:
    """[n, 3] points on the six faces of a box around the centre, [-2, 2] x [-3, 3] x [-1.5, 2.5] times scale."""
    g = np.random.default_rng(7)
    lo, hi = np.array([-2.0, -3.0, -1.5]), np.array([2.0, 3.0, 2.5])
    pts = g.uniform(lo, hi, size=(n, 3))
    axis, side = g.integers(0, 3, n), g.integers(0, 2, n)
    pts[np.arange(n), axis] = np.where(side == 1, hi[axis], lo[axis])
    return pts * scale


def _gaussians_on(pts: np.ndarray, k: int, extreme: bool = False) -> GaussianModel:
    """k random Gaussians at points of ``pts`` (random rotations; scales 1-5 % of their distance, or with
    ``extreme`` one axis a millionth of that: near-singular)."""
    from scipy.spatial.transform import Rotation

    g = np.random.default_rng(8)
    means = pts[g.choice(len(pts), k, replace=False)]
    r = np.linalg.norm(means, axis=1, keepdims=True)
    scales = r * g.uniform(0.01, 0.05, size=(k, 3))
    if extreme:
        scales[:, 0] *= 1e-6
    quats = Rotation.random(k, random_state=9).as_quat()[:, [3, 0, 1, 2]]
    return GaussianModel(
        torch.tensor(means, dtype=torch.float32),
        torch.tensor(quats, dtype=torch.float32),
        torch.tensor(np.log(scales), dtype=torch.float32),
        torch.zeros(k),
        torch.rand(k, 1, 3),
        torch.zeros(k, 15, 3),
    )


FLATTENS = {"dispatch": flatten_onto_surface, "torch": flatten_onto_surface_torch}  # C++ on the CPU where built


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
@pytest.mark.parametrize("extreme", [False, True])
@pytest.mark.parametrize("kernel", list(FLATTENS))
def test_flatten_is_the_per_axis_reference_and_the_centre_sees_it_as_before(scale, extreme, kernel):
    pts = _box(scale)
    normals = surface_normals(pts, 24)
    normals[:, :6] = np.nan  # a sector without a surface: its Gaussians stay as they are
    model = _gaussians_on(pts, 300, extreme)
    before = covariances(model)
    ref, ref_flat = flatten_onto_surface_reference(
        *(t.detach().numpy() for t in (model.means, model.quats, model.log_scales)), normals
    )
    means, sh0 = model.means.detach().clone(), model.sh0.detach().clone()
    flat = FLATTENS[kernel](model, flatten_frames(normals)).numpy()
    after = covariances(model)
    np.testing.assert_array_equal(flat, ref_flat)
    assert 0.6 < flat.mean() < 0.95
    tol = 1e-4 * np.abs(ref).max(axis=(1, 2))[:, None, None]  # the float32 parameters' round trip
    assert (np.abs(after - ref) <= tol).all()
    np.testing.assert_allclose(after[~flat], before[~flat], rtol=1e-5, atol=0)
    m = model.means.detach().double().numpy()
    u = m / np.linalg.norm(m, axis=1, keepdims=True)
    P = np.eye(3) - np.einsum("ni,nj->nij", u, u)  # across the centre's ray: what the centre sees
    seen_before, seen_after = P @ before @ P, P @ after @ P
    big = np.abs(seen_before).max(axis=(1, 2))[:, None, None]
    assert (np.abs(seen_after - seen_before)[flat] <= 0.01 * big[flat]).all()  # the thickness term's share only
    torch.testing.assert_close(model.means, means, rtol=0, atol=0)
    torch.testing.assert_close(model.sh0, sh0, rtol=0, atol=0)
    assert torch.isfinite(model.quats).all() and torch.isfinite(model.log_scales).all()


def test_a_flattened_gaussian_lies_on_its_wall():
    """A blob on the wall x = 2 of the box, seen from the centre along a ray 30 degrees off the wall's normal: after
    flattening its covariance along the wall's normal (x) is the thickness term only, and it spans the wall."""
    pts = _box(1.0)
    u = np.array([np.cos(np.radians(30)), np.sin(np.radians(30)), 0.0])
    model = _gaussians_on(pts, 1)
    with torch.no_grad():
        model.means[:] = torch.tensor(u * 2 / u[0], dtype=torch.float32)
        model.quats[:] = torch.tensor([1.0, 0, 0, 0])
        model.log_scales[:] = float(np.log(0.05))
    (flat,) = flatten_onto_surface(model, flatten_frames(surface_normals(pts, 48)), thickness=0.05)
    cov = covariances(model)[0]
    assert flat and abs(u[0]) > FLAT_MIN_COS
    lam = np.linalg.eigvalsh(cov)
    assert cov[0, 0] == pytest.approx(0.05**2 * (lam[1] + lam[2]) / 2, rel=1e-3)  # along x: the thickness only
    assert lam[-1] > 0.05**2  # the blob's depth along the ray now lies along the wall


@pytest.mark.parametrize("kernel", list(FLATTENS))
def test_flatten_leaves_a_gaussian_without_a_finite_covariance_as_it_is(kernel):
    pts = _box(1.0)
    model = _gaussians_on(pts, 4)
    with torch.no_grad():
        model.log_scales[1, 0] = float("inf")
    before = model.log_scales.detach().clone(), model.quats.detach().clone()
    flat = FLATTENS[kernel](model, flatten_frames(surface_normals(pts, 24)))
    assert not flat[1] and flat[[0, 2, 3]].all()
    torch.testing.assert_close(model.log_scales[1], before[0][1], rtol=0, atol=0)
    torch.testing.assert_close(model.quats[1], before[1][1], rtol=0, atol=0)
    assert torch.isfinite(model.log_scales[[0, 2, 3]]).all() and torch.isfinite(model.quats).all()


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ cpu backend could not be built here")
def test_the_flatten_kernel_is_the_torch_formula_to_a_float32_rounding():
    """csrc/flatten_cpu.cpp against flatten_onto_surface_torch on 20,000 Gaussians of the box, among them a zero and
    a NaN quaternion, infinite, NaN and huge scales (one whose variances are finite and whose sheared ones are not),
    a Gaussian at the centre and one with a NaN mean: the same
    Gaussians flattened, the same parameters to a float32 rounding (both float64 inside; libm's and torch's
    transcendentals may round differently), the others untouched."""
    pts = _box(1.0)
    normals = surface_normals(pts, 24)
    normals[:, :6] = np.nan
    frames = flatten_frames(normals)
    a, b = _gaussians_on(pts, 20_000), _gaussians_on(pts, 20_000)
    e = torch.nonzero(flatten_onto_surface_torch(b, frames)).flatten()[:8]  # Gaussians that flatten, to edit
    with torch.no_grad():
        a.quats[e[0]], a.quats[e[1], 0] = 0.0, float("nan")
        a.log_scales[e[2], 0], a.log_scales[e[3], 1], a.log_scales[e[4], 2] = float("inf"), float("nan"), 400.0
        a.means[e[5]], a.means[e[6], 0] = 0.0, float("nan")
        a.log_scales[e[7]] = 354.8  # s^2 = 1.5e308: finite, but the sheared variances' sum is not
    b.load_state_dict(a.state_dict())
    before = a.quats.detach().clone(), a.log_scales.detach().clone()
    fa = cpu_backend.flatten_surface(a.means, a.quats.data, a.log_scales.data, frames, 0.05, FLAT_MIN_COS)
    fb = flatten_onto_surface_torch(b, frames, 0.05)
    torch.testing.assert_close(fa, fb, rtol=0, atol=0)
    assert 0.6 < fa.float().mean() < 0.95 and fa[e[:2]].all() and not fa[e[2:]].any()  # NaN quaternion: identity
    torch.testing.assert_close(a.quats, b.quats, rtol=0, atol=2e-7)
    torch.testing.assert_close(a.log_scales, b.log_scales, rtol=2e-7, atol=2e-7, equal_nan=True)
    torch.testing.assert_close(a.quats[~fa], before[0][~fa], rtol=0, atol=0, equal_nan=True)
    torch.testing.assert_close(a.log_scales[~fa], before[1][~fa], rtol=0, atol=0, equal_nan=True)
    assert torch.isfinite(a.quats[fa]).all() and torch.isfinite(a.log_scales[fa]).all()


def test_normal_coherence_tells_a_surface_from_random_points():
    g = np.random.default_rng(3)
    box = surface_normals(_box(1.0), 24)
    scattered = surface_normals(g.uniform(-3, 3, size=(200_000, 3)), 24)
    assert normal_coherence(box) > 0.8  # the box's faces; its edges disagree
    assert normal_coherence(scattered) < 0.35
    assert normal_coherence(np.full((4, 8, 3), np.nan)) == 0.0
