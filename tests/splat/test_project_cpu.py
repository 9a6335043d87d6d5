"""The C++ projection (``cpu_backend.project``) against the PyTorch reference ``project_gaussians``: every output
and the gradients of means, quats and scales, in float64 (to rounding) and float32 (to a stated tolerance)."""

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
from panorecon.splat.rasterize import cpu_backend, project_gaussians, rasterize

pytestmark = pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")


def cameras(width, height, dtype):
    Ks = torch.tensor(intrinsics_from_fov(width, height, 70.0), dtype=dtype)[None].repeat(3, 1, 1)
    Ks[2, 0, 0] *= 40.0  # a telephoto camera (about 2° across): most Gaussians fall outside its image
    Ks[2, 1, 1] *= 40.0
    Vs = torch.stack(
        [
            torch.tensor(look_at_viewmat(o, t), dtype=dtype)
            for o, t in (([0, 0, 0], [1, 0, 0]), ([0.2, -0.3, 0.1], [1, 0.4, -0.2]), ([0, 0, 0], [1, 0.1, 0]))
        ]
    )
    return Vs, Ks


def scene(n, seed, dtype):
    """n Gaussians whose first seven (as far as n reaches) are the extreme cases named below."""
    n_all, n = max(n, 7), n
    g = torch.Generator().manual_seed(seed)
    means = torch.stack(
        [
            torch.rand(n_all, generator=g) * 4 - 0.5,
            torch.rand(n_all, generator=g) * 3 - 1.5,
            torch.rand(n_all, generator=g) * 2 - 1,
        ],
        -1,
    ).to(dtype)
    quats = torch.randn(n_all, 4, generator=g).to(dtype)
    scales = (torch.rand(n_all, 3, generator=g) * 0.3 + 1e-3).to(dtype)
    means[0] = torch.tensor([0.011, 0.0, 0.0])  # at the near plane
    means[1] = torch.tensor([-1.0, 0.0, 0.0])  # behind every camera
    means[2] = torch.tensor([2.0, 9.0, 0.0])  # far off-axis: the clamped Jacobian
    quats[3] = 0.0  # zero-norm quaternion: the identity
    scales[4] = torch.tensor([1e-7, 1e-7, 1e-7])  # near-singular: the 2D covariance is eps2d I
    scales[5] = torch.tensor([1e3, 1e3, 1e3])  # huge
    scales[6] = torch.tensor([1e-7, 0.5, 0.5])  # a flat disc
    return means[:n], quats[:n], scales[:n]


def project_both(dtype, n=400, seed=0, width=48, height=32):
    Vs, Ks = cameras(width, height, dtype)
    leaves = {k: [t.clone().requires_grad_(True) for t in scene(n, seed, dtype)] for k in ("torch", "cpu")}
    out_t = project_gaussians(*leaves["torch"], Vs, Ks, width, height)
    out_c = cpu_backend.project(*leaves["cpu"], Vs, Ks, width, height)
    kept = out_t[3] > 0
    g = torch.Generator().manual_seed(seed + 1)
    # the compositor never reads culled pairs, so their upstream gradients are zero in training as well
    ups = [
        torch.randn(t.shape, generator=g, dtype=dtype) * (kept[..., None] if t.dim() == 3 else kept) for t in out_t[:3]
    ]
    for out in (out_t, out_c):
        sum((o * u).sum() for o, u in zip(out[:3], ups)).backward()
    return out_t, out_c, [t.grad for t in leaves["torch"]], [t.grad for t in leaves["cpu"]], kept


def test_float64_matches_the_reference_to_rounding():
    out_t, out_c, g_t, g_c, kept = project_both(torch.float64)
    assert 50 < kept.sum() < kept.numel(), "the scene should have both kept and culled pairs"
    assert not kept[:, 1].any() and kept[2].sum() < kept[0].sum()
    assert torch.equal(out_c[3], out_t[3]), "radii"
    for name, a, b in zip(("means2d", "conics", "depths"), out_c[:3], out_t[:3]):
        torch.testing.assert_close(a, b, rtol=1e-12, atol=1e-9, msg=name)
    for name, a, b in zip(("means", "quats", "scales"), g_c, g_t):
        assert b.abs().max() > 0
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-9 * float(b.abs().max()), msg=f"gradient of {name}")
    assert (g_c[1][3] == 0).all(), "the identity stand-in of a zero quaternion has no gradient"


def test_float32_matches_the_reference():
    out_t, out_c, g_t, g_c, kept = project_both(torch.float32)
    assert torch.equal(out_c[3], out_t[3]), "radii"
    for name, a, b in zip(("means2d", "conics", "depths"), out_c[:3], out_t[:3]):
        torch.testing.assert_close(a, b, rtol=1e-4, atol=1e-4, msg=name)
        culled = ~kept[..., None] if a.dim() == 3 else ~kept
        assert (a * culled == 0).all() and (b * culled == 0).all(), f"{name} of culled pairs is 0"
        assert (a.abs() * culled).sum() == 0
    for name, a, b in zip(("means", "quats", "scales"), g_c, g_t):
        scale = float(b.abs().max())
        torch.testing.assert_close(a / scale, b / scale, rtol=1e-3, atol=2e-5, msg=f"gradient of {name}")
        assert torch.isfinite(a).all()


@settings(max_examples=15, deadline=None)
@given(st.integers(1, 80), st.integers(0, 10_000), st.integers(4, 64), st.integers(4, 64))
def test_random_scenes_and_image_sizes_agree(n, seed, width, height):
    out_t, out_c, g_t, g_c, _ = project_both(torch.float64, n, seed, width, height)
    assert torch.equal(out_c[3], out_t[3])
    for a, b in zip((*out_c[:3], *g_c), (*out_t[:3], *g_t)):
        assert torch.isfinite(a).all()
        torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-9 * max(1.0, float(b.detach().abs().max())))


def test_rasterize_uses_the_reference_projection_when_cameras_need_gradients():
    """The C++ projection does not differentiate w.r.t. the cameras; with a camera that requires grad the
    reference runs and the pose gradient arrives."""
    Vs, Ks = cameras(24, 16, torch.float32)
    means, quats, scales = scene(50, 3, torch.float32)
    V = Vs[:1].clone().requires_grad_(True)
    img, *_ = rasterize(
        means, quats, scales, torch.full((50,), 0.8), torch.rand(50, 3), V, Ks[:1], 24, 16, backend="cpu"
    )
    img.sum().backward()
    assert V.grad is not None and V.grad.abs().max() > 0


def test_radius_is_capped_for_enormous_gaussians():
    """A Gaussian of 1e8 m two metres away is kept with radius 2^30 px by both projections (not an undefined
    int32 conversion), and both backends render the image it fills alike."""
    Vs, Ks = cameras(24, 16, torch.float32)
    means = torch.tensor([[2.0, 0.0, 0.0], [3.0, 0.1, 0.0]])
    quats = torch.tensor([[1.0, 0.0, 0.0, 0.0]] * 2)
    scales = torch.tensor([[1e8, 1e8, 1e8], [0.05, 0.05, 0.05]])  # 3 sigma: about 2.5e9 px
    for project in (project_gaussians, cpu_backend.project):
        radii = project(means, quats, scales, Vs[:1], Ks[:1], 24, 16)[3]
        assert radii[0, 0] == 2**30 and 0 < radii[0, 1] < 100
    opac, cols = torch.tensor([0.5, 0.9]), torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    img_t = rasterize(means, quats, scales, opac, cols, Vs[:1], Ks[:1], 24, 16, backend="torch")[0]
    img_c = rasterize(means, quats, scales, opac, cols, Vs[:1], Ks[:1], 24, 16, backend="cpu")[0]
    assert torch.isfinite(img_c).all() and img_c[..., 0].min() > 0.4
    torch.testing.assert_close(img_c, img_t, atol=2e-5, rtol=1e-3)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_the_early_cull_keeps_every_gaussian_that_reaches_the_image(dtype):
    """The C++ forward skips the covariance of pairs whose centre lies far enough off the image (a bound on the
    radius from the largest scale); Gaussians of every size and shape around the image's edges, many of them
    reaching in by a pixel or two, get the reference's radii exactly, and a culled pair's outputs are 0. float64
    takes scales from 1e-4 to 20 m; float32 up to 3 m, since beyond that near-singular needles round differently in
    the two implementations whether or not the cull is there (2 of these 20,000 radii differ without it)."""
    W, H = 40, 30
    Ks = torch.tensor(intrinsics_from_fov(W, H, 60.0), dtype=dtype)[None]
    Vs = torch.tensor(look_at_viewmat([0, 0, 0], [0, 0, 1]), dtype=dtype)[None]
    g = torch.Generator().manual_seed(7)
    n = 20_000
    z = torch.rand(n, generator=g, dtype=dtype) * 5 + 0.05
    u = torch.rand(n, generator=g, dtype=dtype) * 3 * W - W  # centres from one image width left to one right
    v = torch.rand(n, generator=g, dtype=dtype) * 3 * H - H
    K = Ks[0]
    means = torch.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z], -1)
    means = (torch.linalg.inv(Vs[0]) @ torch.cat([means, torch.ones(n, 1, dtype=dtype)], 1).T).T[:, :3]
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    top = 3.0 if dtype == torch.float64 else 1.1  # ln of the largest scale: 20 m or 3 m; needles throughout
    scales = torch.exp(torch.rand(n, 3, generator=g, dtype=dtype) * (top + 9) - 9)
    out_t = project_gaussians(means, quats, scales, Vs, Ks, W, H)
    out_c = cpu_backend.project(means, quats, scales, Vs, Ks, W, H)
    kept = out_t[3] > 0
    assert 1000 < kept.sum() < n - 1000, "both kept and culled pairs"
    off = (out_t[0][..., 0] < 0) | (out_t[0][..., 0] > W) | (out_t[0][..., 1] < 0) | (out_t[0][..., 1] > H)
    assert (kept & off).sum() > 500, "many kept Gaussians are centred off the image"
    assert torch.equal(out_c[3], out_t[3]), "radii"
    # means2d and depths; conics too in float64 (a needle's conic is ill-conditioned in float32, cull or not)
    for a, b in zip(
        out_c[:3] if dtype == torch.float64 else out_c[:3:2], out_t[:3] if dtype == torch.float64 else out_t[:3:2]
    ):
        torch.testing.assert_close(a, b, rtol=1e-4 if dtype == torch.float32 else 1e-12, atol=1e-4)
    assert (out_c[1][~kept] == 0).all() and (out_c[0][~kept] == 0).all() and (out_c[2][~kept] == 0).all()


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_culled_pairs_pass_no_gradient_whatever_arrives_for_them(dtype):
    """The backward runs its Gaussians in vector lanes, a Gaussian kept by one camera beside others that camera culls:
    the upstream gradients of culled pairs (here random, with NaN and inf among them) must not reach any Gaussian,
    and a Gaussian culled by every camera gets exact zeros. Same gradients as with the culled pairs' upstream zeroed,
    bit for bit."""
    Vs, Ks = cameras(48, 32, dtype)
    means, quats, scales = scene(403, 5, dtype)  # 403: the last vector of lanes is partial
    ext = cpu_backend.load()
    args = (means, quats / 1.0, scales, Vs, Ks)
    radii = ext.project_forward(*args, 48, 32, 0.01, 1e10, 0.3)[3]
    kept = radii > 0
    assert kept.any(0).any() and (~kept.any(0)).any() and (kept[0] != kept[1]).any(), "mixed cases needed"
    g = torch.Generator().manual_seed(6)
    ups = [torch.randn(*radii.shape, k, generator=g, dtype=dtype) for k in (2, 3)] + [
        torch.randn(radii.shape, generator=g, dtype=dtype)
    ]
    for u in ups:  # junk where culled
        u.view(radii.numel(), -1)[(~kept).flatten().nonzero()[::3, 0]] = float("nan")
        u.view(radii.numel(), -1)[(~kept).flatten().nonzero()[1::3, 0]] = float("inf")
    clean = [torch.where(kept[..., None] if u.dim() == 3 else kept, u, torch.zeros_like(u)) for u in ups]
    got = ext.project_backward(*args, radii, *ups, 48, 32, 0.01, 1e10, 0.3)
    want = ext.project_backward(*args, radii, *clean, 48, 32, 0.01, 1e10, 0.3)
    for name, a, b in zip(("means", "quats", "scales"), got, want):
        assert torch.isfinite(a).all(), f"a culled pair's upstream gradient reached the {name}"
        assert torch.equal(a, b), name
        assert (a[~kept.any(0)] == 0).all(), f"a Gaussian no camera kept got a {name} gradient"


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_mean_between_the_cull_margin_and_the_near_plane_is_culled(dtype):
    """The vectorised bound lets through z down to 0.999 near (its rounding margin); the exact path must then cull
    what lies at or before the near plane, as the reference does, while its lane neighbours stay kept."""
    Vs, Ks = cameras(48, 32, dtype)
    near = 0.01
    means = torch.tensor([[near * 0.9995, 0.0, 0.0], [near, 0.0, 0.0], [0.5, 0.0, 0.0], [near * 1.001, 0.0, 0.0]])
    means = means.to(dtype).repeat(3, 1)  # twelve: a full vector of floats and a partial one
    quats = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=dtype).repeat(len(means), 1)
    scales = torch.full((len(means), 3), 1e-3, dtype=dtype)
    radii_c = cpu_backend.project(means, quats, scales, Vs[:1], Ks[:1], 48, 32, near_plane=near)[3]
    radii_t = project_gaussians(means, quats, scales, Vs[:1], Ks[:1], 48, 32, near_plane=near)[3]
    assert (radii_t[0, 0::4] == 0).all() and (radii_t[0, 1::4] == 0).all() and (radii_t[0, 2::4] > 0).all()
    assert torch.equal(radii_c, radii_t.to(radii_c.dtype))
