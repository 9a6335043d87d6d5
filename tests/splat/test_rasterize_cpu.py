"""The C++ ``cpu`` backend against the PyTorch reference: values and every gradient, float32."""

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
from panorecon.splat.rasterize import cpu_backend, rasterize

pytestmark = pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")

# float32 on both sides; the reference composites with cumprod, the kernel with a running product
ATOL_VALUE, ATOL_GRAD, RTOL = 2e-5, 2e-4, 1e-3


def cameras(width, height):
    Ks = torch.tensor(intrinsics_from_fov(width, height, 70.0), dtype=torch.float32)[None].repeat(2, 1, 1)
    Vs = torch.stack(
        [
            torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32),
            torch.tensor(look_at_viewmat([0.2, -0.3, 0.1], [1, 0.4, -0.2]), dtype=torch.float32),
        ]
    )
    return Vs, Ks


def random_scene(n, seed, extremes=True):
    g = torch.Generator().manual_seed(seed)
    means = torch.stack(
        [
            torch.rand(n, generator=g) * 4 + 0.5,
            torch.rand(n, generator=g) * 3 - 1.5,
            torch.rand(n, generator=g) * 2 - 1,
        ],
        -1,
    )
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.2 + 0.02
    opac = torch.rand(n, generator=g) * 0.9 + 0.05
    sh = torch.randn(n, 16, 3, generator=g) * 0.3
    if extremes:
        means[0] = torch.tensor([-1.0, 0.0, 0.0])  # behind the camera
        means[1] = torch.tensor([0.011, 0.0, 0.0])  # at the near plane
        scales[2] = torch.tensor([1e-6, 1e-6, 1e-6])  # extremely thin
        scales[3] = torch.tensor([1e3, 1e3, 1e3])  # huge
        quats[4] = 0.0  # zero-norm quaternion
        scales[5] = torch.tensor([1e-6, 0.3, 0.3])  # a flat disc
        opac[6] = 1.0  # alpha clamped at 0.999 near its centre
    return means, quats, scales, opac, sh


def run(backend, scene, sh_degree, width=40, height=28):
    Vs, Ks = cameras(width, height)
    leaves = [t.clone().requires_grad_(True) for t in scene]
    m, q, s, o, sh = leaves
    colors = sh if sh_degree is not None else torch.sigmoid(sh[:, 0])
    img, alpha, depth, meta = rasterize(
        m,
        q,
        s,
        o,
        colors,
        Vs,
        Ks,
        width,
        height,
        sh_degree=sh_degree,
        backend=backend,
        backgrounds=torch.tensor([[0.1, 0.2, 0.3], [0.0, 0.0, 0.0]]),
    )
    meta["means2d"].retain_grad()
    g = torch.Generator().manual_seed(99)
    loss = (
        (img * torch.rand(img.shape, generator=g)).sum()
        + (alpha * torch.rand(alpha.shape, generator=g)).sum()
        + 0.1 * (depth * torch.rand(depth.shape, generator=g)).sum()
    )
    loss.backward()
    return (img.detach(), alpha.detach(), depth.detach(), meta["means2d"].grad), [t.grad for t in leaves]


@pytest.mark.parametrize("sh_degree", [None, 3])
@pytest.mark.parametrize("seed", [0, 1])
def test_cpu_matches_torch_values_and_gradients(sh_degree, seed):
    scene = random_scene(120, seed)
    (i_t, a_t, d_t, m2_t), g_t = run("torch", scene, sh_degree)
    (i_c, a_c, d_c, m2_c), g_c = run("cpu", scene, sh_degree)
    torch.testing.assert_close(i_c, i_t, atol=ATOL_VALUE, rtol=RTOL)
    torch.testing.assert_close(a_c, a_t, atol=ATOL_VALUE, rtol=RTOL)
    torch.testing.assert_close(d_c, d_t, atol=ATOL_VALUE * 10, rtol=RTOL)
    torch.testing.assert_close(m2_c, m2_t, atol=ATOL_GRAD, rtol=RTOL)
    for name, a, b in zip(("means", "quats", "scales", "opacities", "sh/colours"), g_c, g_t):
        assert b.abs().max() > 0, f"the reference gives no gradient for {name}: the comparison would be empty"
        scale = b.abs().max().clamp_min(1.0)
        torch.testing.assert_close(a / scale, b / scale, atol=ATOL_GRAD, rtol=RTOL, msg=f"gradient of {name}")
        assert torch.isfinite(a).all()


@settings(max_examples=8, deadline=None)
@given(st.integers(1, 60), st.integers(0, 10_000))
def test_random_small_scenes_agree(n, seed):
    scene = random_scene(n, seed, extremes=False)
    (i_t, a_t, _, _), _ = run("torch", scene, None, 24, 20)
    (i_c, a_c, _, _), _ = run("cpu", scene, None, 24, 20)
    assert torch.isfinite(i_c).all() and (a_c >= 0).all() and (a_c <= 1).all()
    torch.testing.assert_close(i_c, i_t, atol=ATOL_VALUE, rtol=RTOL)


def test_auto_picks_cpu():
    from panorecon.splat.rasterize import resolve_backend

    assert resolve_backend("auto") == "cpu"


@pytest.mark.parametrize("seed,width,height", [(0, 40, 28), (3, 40, 28), (5, 37, 23)])
def test_cpu_contributions_match_torch(seed, width, height):
    """weight_sum / weight_max / trans_max per Gaussian and camera, reduced from the kernel's per-thread buffers;
    37x23 leaves block lanes outside the image, which must not count."""
    m, q, s, o, sh = random_scene(150, seed)
    Vs, Ks = cameras(width, height)
    out = {}
    for backend in ("torch", "cpu"):
        *_, meta = rasterize(
            m, q, s, o, torch.sigmoid(sh[:, 0]), Vs, Ks, width, height, backend=backend, return_contrib=True
        )
        out[backend] = meta
    for key in ("weight_sum", "weight_max", "trans_max"):
        ref, got = out["torch"][key], out["cpu"][key]
        assert ref.shape == got.shape == (2, 150)
        assert (ref > 0).sum() > 20, f"{key}: too few contributing Gaussians for a meaningful comparison"
        torch.testing.assert_close(got, ref, atol=ATOL_VALUE * 5, rtol=RTOL)


def test_partial_blocks_and_saturated_pixels_agree():
    """An image size that is not a multiple of the 4x4 blocks or the 16x16 tiles (lanes outside the image), and
    a scene dense enough that most pixels stop at T <= 1e-4 before their list ends."""
    scene = list(random_scene(1500, 7, extremes=False))
    scene[3] = torch.full_like(scene[3], 0.95)  # opaque: transmittance collapses within a few layers
    (i_t, a_t, d_t, m2_t), g_t = run("torch", scene, None, 37, 23)
    (i_c, a_c, d_c, m2_c), g_c = run("cpu", scene, None, 37, 23)
    assert (a_t > 1 - 2e-4).float().mean() > 0.5, "the scene should saturate most pixels"
    torch.testing.assert_close(i_c, i_t, atol=ATOL_VALUE, rtol=RTOL)
    torch.testing.assert_close(a_c, a_t, atol=ATOL_VALUE, rtol=RTOL)
    torch.testing.assert_close(m2_c, m2_t, atol=ATOL_GRAD, rtol=RTOL)
    for name, a, b in zip(("means", "quats", "scales", "opacities", "colours"), g_c, g_t):
        scale = b.abs().max().clamp_min(1.0)
        torch.testing.assert_close(a / scale, b / scale, atol=ATOL_GRAD, rtol=RTOL, msg=f"gradient of {name}")


def composite_both(gaussians, radii, width, height, loss):
    """The torch reference (``rasterize_tiles``) and ``cpu_backend.composite`` on the same 2D Gaussians (means2d,
    conics, colors, opacities, depths) -> {"torch" | "cpu": (image, alpha, gradients of loss(image, alpha, depth)
    w.r.t. the five)}."""
    from panorecon.splat.rasterize.torch_backend import rasterize_tiles

    out = {}
    for name, fn in (("torch", rasterize_tiles), ("cpu", cpu_backend.composite)):
        leaves = [t.clone().requires_grad_(True) for t in gaussians]
        img, alpha, depth, _ = fn(*leaves, radii, width, height)
        loss(img, alpha, depth).backward()
        out[name] = (img.detach(), alpha.detach(), [t.grad for t in leaves])
    return out


def loss_of_every_output(img, alpha, depth):
    """A scalar that every output reaches, the colour channels weighted apart (for ``composite_both``)."""
    return (img * torch.linspace(0.5, 1.5, 3)).sum() + alpha.sum() + 0.1 * depth.sum()


def assert_cpu_matches_torch(out):
    """Image, alpha and every gradient of ``composite_both``'s two sides agree (gradients relative to the largest)."""
    torch.testing.assert_close(out["cpu"][0], out["torch"][0], atol=ATOL_VALUE, rtol=RTOL)
    torch.testing.assert_close(out["cpu"][1], out["torch"][1], atol=ATOL_VALUE, rtol=RTOL)
    for name, a, b in zip(("means2d", "conics", "colors", "opacities", "depths"), out["cpu"][2], out["torch"][2]):
        scale = b.abs().max().clamp_min(1.0)
        torch.testing.assert_close(a / scale, b / scale, atol=ATOL_GRAD, rtol=RTOL, msg=f"gradient of {name}")


@pytest.mark.parametrize("opacity", [0.1, 0.3])
def test_long_lists_stop_inside_a_later_batch(opacity):
    """The kernels walk a block's list in batches of entries (alphas first, then the blend; the backward batch by
    batch from the back). 300 wide, translucent splats over every pixel: with opacity 0.1 a pixel's T reaches 1e-4
    only after ~90 entries, with 0.3 after ~26 (random alphas put the stops at every offset within a batch), so
    lists run over many batches and stop inside one. Values and gradients against the reference."""
    g = torch.Generator().manual_seed(11)
    n, width, height = 300, 29, 19
    means2d = (torch.rand(1, n, 2, generator=g) * torch.tensor([width, height])).contiguous()
    conics = (torch.rand(1, n, 1, generator=g) * 0.004 + 0.001) * torch.tensor([1.0, 0.0, 1.0])  # sigma 16-32 px
    radii = torch.full((1, n), 60, dtype=torch.int32)
    opac = torch.full((n,), opacity)
    colors = torch.rand(1, n, 3, generator=g)
    depths = torch.rand(1, n, generator=g) + 1
    out = composite_both(
        (means2d, conics, colors, opac, depths),
        radii,
        width,
        height,
        loss_of_every_output,
    )
    assert (out["torch"][1] > 1 - 2e-4).float().mean() > 0.9, "most pixels should stop before their list ends"
    assert_cpu_matches_torch(out)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_needles_at_every_angle_keep_every_pixel_they_reach(seed):
    """The kernel's 4x4-block lists keep a Gaussian only where its ellipse sigma <= ln(255 o) reaches a pixel centre
    of the block (tighter than the disc of its smallest eigenvalue). Needles, 2D Gaussians with axis ratios up to
    60 at every angle and sub-pixel offsets, few overlapping, over a black background: a pixel that a list dropped
    loses at least alpha >= 1/255 of its value, 200x the tolerance. Values and gradients against the reference."""
    g = torch.Generator().manual_seed(seed)
    n, width, height = 80, 61, 45
    theta = torch.rand(n, generator=g) * torch.pi
    major = torch.rand(n, generator=g) * 18 + 2
    minor = torch.rand(n, generator=g) * 0.7 + 0.3
    rot = torch.stack([torch.cos(theta), -torch.sin(theta), torch.sin(theta), torch.cos(theta)], -1).view(n, 2, 2)
    cov = rot @ torch.diag_embed(torch.stack([major, minor], -1) ** 2) @ rot.transpose(1, 2)
    inv = torch.linalg.inv(cov)
    conics = torch.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], -1)[None]
    means2d = (torch.rand(n, 2, generator=g) * torch.tensor([width, height]))[None]
    radii = torch.ceil(3 * major)[None].to(torch.int32)
    opac = torch.rand(n, generator=g) * 0.9 + 0.1
    colors = torch.rand(1, n, 3, generator=g)
    depths = torch.rand(1, n, generator=g) + 1
    out = composite_both(
        (means2d, conics, colors, opac, depths),
        radii,
        width,
        height,
        loss_of_every_output,
    )
    assert (out["torch"][1] > 0).float().mean() > 0.4, "the needles should cover a good part of the image"
    assert_cpu_matches_torch(out)


@pytest.mark.parametrize("seed", [0, 1])
def test_equal_depths_composite_in_id_order(seed):
    """Ties in depth keep the Gaussians' id order (the reference's stable argsort), -0 and +0 tie, and negative
    depths sort before them: opaque, overlapping splats of distinct colours at five depths, so that any other order
    changes the image by far more than the tolerance. Values and gradients against the reference."""
    from panorecon.splat.rasterize.torch_backend import rasterize_tiles

    g = torch.Generator().manual_seed(seed)
    n, width, height = 60, 33, 21
    means2d = (torch.rand(1, n, 2, generator=g) * torch.tensor([width, height])).contiguous()
    conics = torch.tensor([0.02, 0.0, 0.02]).repeat(1, n, 1)  # sigma 7 px: every splat covers much of the image
    radii = torch.full((1, n), 21, dtype=torch.int32)
    opac = torch.full((n,), 0.9)
    colors = torch.rand(1, n, 3, generator=g)
    levels = torch.tensor([-1.0, -0.0, 0.0, 2.0, 2.0])
    depths = levels[torch.randint(0, 5, (1, n), generator=g)]
    out = composite_both(
        (means2d, conics, colors, opac, depths),
        radii,
        width,
        height,
        lambda img, alpha, depth: (img * torch.linspace(0.5, 1.5, 3)).sum() + 0.1 * depth.sum(),
    )
    reversed_ties = rasterize_tiles(means2d.flip(1), conics, colors.flip(1), opac, depths.flip(1), radii, width, height)
    assert (reversed_ties[0] - out["torch"][0]).abs().max() > 0.1, "the scene should depend on the order of ties"
    assert_cpu_matches_torch(out)


@pytest.mark.parametrize("seed", [0, 1])
def test_tile_lists_are_front_to_back_with_ties_in_id_order_at_scale(seed):
    """The depth sort that orders every tile's list runs in parallel chunks once a camera has 8,192 visible pairs or
    more: each tile's ids, from the kernel, are its Gaussians sorted by depth with ties in id order (-0 ties +0),
    for two cameras of 30,000 pairs whose depths differ in every byte, many of them tied."""
    g = torch.Generator().manual_seed(seed)
    C, n, width, height = 2, 30_000, 48, 40
    means2d = (torch.rand(C, n, 2, generator=g) * torch.tensor([width, height])).contiguous()
    conics = torch.tensor([1.0, 0.0, 1.0]).repeat(C, n, 1)
    radii = torch.randint(0, 4, (C, n), generator=g, dtype=torch.int32)  # radius 0: culled, in no list
    spread = torch.exp(torch.randn(C, n, generator=g) * 8) * torch.where(torch.rand(C, n, generator=g) < 0.1, -1, 1)
    ties = torch.tensor([-2.5, -0.0, 0.0, 1.0, 3.0e5])[torch.randint(0, 5, (C, n), generator=g)]
    depths = torch.where(torch.rand(C, n, generator=g) < 0.5, ties, spread).contiguous()
    colors, opac = torch.rand(C, n, 3, generator=g), torch.full((n,), 0.5)
    out = cpu_backend.load().forward(means2d, conics, colors, opac, depths, radii, width, height, 16, False)
    offsets, ids = out[5], out[6].long()
    tiles = (offsets.numel() - 1) // C
    assert ids.numel() > C * n, "most Gaussians should reach a tile"
    for t in range(offsets.numel() - 1):
        got = ids[offsets[t] : offsets[t + 1]]
        z = depths[t // tiles, got] + 0.0  # -0 -> +0
        expected = got.sort().values  # id order, then a stable sort by depth
        expected = expected[torch.sort(z[torch.argsort(got)], stable=True).indices]
        assert torch.equal(got, expected), f"tile {t}: not front to back with ties in id order"
