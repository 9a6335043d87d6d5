"""gsplat (CUDA) against the torch reference: values, gradients, radii and means2d, per-Gaussian contributions,
``auto`` choosing it. The ``cuda`` tests run only where CUDA and gsplat exist."""

import pytest
import torch

from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
from panorecon.splat.rasterize import cpu_backend, gsplat_backend, rasterize, resolve_backend

from .test_rasterize import camera, opaque_pair

needs_gsplat = pytest.mark.skipif(not gsplat_backend.available(), reason="needs CUDA and the gsplat package")
W, H = 64, 48


def random_scene(n=300, seed=0):
    g = torch.Generator().manual_seed(seed)
    means = torch.stack(
        [
            torch.rand(n, generator=g) * 4 + 0.5,
            torch.rand(n, generator=g) * 3 - 1.5,
            torch.rand(n, generator=g) * 2 - 1,
        ],
        -1,
    )
    opac = torch.rand(n, generator=g) * 0.98 + 0.01
    opac[:5] = 0.002  # below 1/255: gsplat culls them, the reference keeps them (they blend nothing)
    scene = [
        means,
        torch.randn(n, 4, generator=g),
        torch.rand(n, 3, generator=g) * 0.2 + 0.02,
        opac,
        torch.randn(n, 16, 3, generator=g) * 0.3,
    ]
    Ks = torch.tensor(intrinsics_from_fov(W, H, 70.0), dtype=torch.float32)[None].repeat(2, 1, 1)
    Vs = torch.stack(
        [
            torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32),
            torch.tensor(look_at_viewmat([0.2, -0.3, 0.1], [1, 0.4, -0.2]), dtype=torch.float32),
        ]
    )
    return scene, Vs, Ks


def test_gsplat_is_refused_clearly_where_it_cannot_run():
    if gsplat_backend.available():
        pytest.skip("gsplat is available here")
    with pytest.raises(RuntimeError, match="gsplat"):
        resolve_backend("gsplat")
    assert resolve_backend("auto", cuda_tensors=False) in ("cpu", "torch")


@pytest.mark.cuda
@needs_gsplat
@pytest.mark.parametrize("antialiased", [False, True])
def test_gsplat_matches_torch_values_and_gradients(antialiased):
    g = torch.Generator().manual_seed(0)
    n = 200
    means = torch.stack(
        [
            torch.rand(n, generator=g) * 4 + 0.5,
            torch.rand(n, generator=g) * 3 - 1.5,
            torch.rand(n, generator=g) * 2 - 1,
        ],
        -1,
    )
    scene = [
        means,
        torch.randn(n, 4, generator=g),
        torch.rand(n, 3, generator=g) * 0.2 + 0.02,
        torch.rand(n, generator=g) * 0.9 + 0.05,
        torch.randn(n, 16, 3, generator=g) * 0.3,
    ]
    scene[1][0] = 0.0  # a zero-norm quaternion: the identity in panorecon's convention
    Ks = torch.tensor(intrinsics_from_fov(64, 48, 70.0), dtype=torch.float32)[None]
    Vs = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None]
    out = {}
    for backend, dev in (("torch", "cpu"), ("gsplat", "cuda")):
        leaves = [t.clone().to(dev).requires_grad_(True) for t in scene]
        m, q, s, o, sh = leaves
        img, alpha, depth, _ = rasterize(
            m, q, s, o, sh, Vs.to(dev), Ks.to(dev), 64, 48, sh_degree=3, backend=backend, antialiased=antialiased
        )
        (img.sum() + alpha.sum() + 0.1 * depth.sum()).backward()
        out[backend] = [img.detach().cpu(), alpha.detach().cpu()] + [t.grad.cpu() for t in leaves]
    for a, b in zip(out["gsplat"], out["torch"]):
        scale = b.abs().max().clamp_min(1.0)
        torch.testing.assert_close(a / scale, b / scale, atol=1e-3, rtol=1e-3)


@pytest.mark.cuda
@needs_gsplat
def test_gsplat_caps_an_opaque_gaussians_alpha_as_the_reference_does():
    """Opaque Gaussians (o = 1, o exp(-sigma) > 0.9996 at the centre pixels): gsplat's alpha there is its cap,
    0.999, and the reference's is the same (the random scenes above keep o < 0.99, below either cap)."""
    V, K = camera(64, 64, torch.float32)
    out = {
        backend: rasterize(
            *(t.to(dev) for t in opaque_pair(torch.float32)), V.to(dev), K.to(dev), 64, 64, backend=backend
        )
        for backend, dev in (("torch", "cpu"), ("gsplat", "cuda"))
    }
    centre = (0, slice(31, 33), slice(31, 33))
    for k in (0, 1):  # image, alpha
        gs, ref = out["gsplat"][k].cpu(), out["torch"][k]
        torch.testing.assert_close(gs[centre], ref[centre], atol=1e-6, rtol=0)
    assert torch.allclose(out["gsplat"][1].cpu()[centre], torch.tensor(0.999), atol=1e-6, rtol=0)


@pytest.mark.cuda
@needs_gsplat
def test_gsplat_radii_and_means2d_follow_the_documented_conventions():
    """means2d (and its gradient, which densification accumulates) equal the reference where both see a
    Gaussian; visibility (radius > 0, all that densification reads of radii) differs only for Gaussians that blend
    nothing (opacity < 1/255) or whose reference 3-sigma square reaches the image but whose gsplat box does not;
    the gsplat radius (larger axis) is within its opacity-aware bound of the reference's."""
    (m, q, s, o, sh), Vs, Ks = random_scene()
    ref = {}
    for backend, dev in (("torch", "cpu"), ("gsplat", "cuda")):
        leaves = [t.clone().to(dev).requires_grad_(True) for t in (m, q, s, o, sh)]
        img, _, _, meta = rasterize(*leaves, Vs.to(dev), Ks.to(dev), W, H, sh_degree=3, backend=backend)
        meta["means2d"].retain_grad()
        img.sum().backward()
        ref[backend] = {k: meta[k].detach().cpu() for k in ("means2d", "radii")} | {"g": meta["means2d"].grad.cpu()}
    r, g = ref["torch"], ref["gsplat"]
    both = (r["radii"] > 0) & (g["radii"] > 0)
    assert both.sum() > 100
    torch.testing.assert_close(g["means2d"][both], r["means2d"][both], atol=1e-3, rtol=1e-5)
    # gsplat's boxes add or drop pairs at the 3-sigma edge (alpha near 1/255): small against the largest gradient
    scale = r["g"].abs().max()
    torch.testing.assert_close(g["g"][both] / scale, r["g"][both] / scale, atol=2e-3, rtol=1e-2)
    only_ref = (r["radii"] > 0) & ~(g["radii"] > 0)
    near_border = (
        (r["means2d"][..., 0] < r["radii"])
        | (r["means2d"][..., 0] > W - r["radii"])
        | (r["means2d"][..., 1] < r["radii"])
        | (r["means2d"][..., 1] > H - r["radii"])
    )
    faint = (o < 1 / 255)[None].expand_as(only_ref)
    assert (only_ref <= (near_border | faint)).all()
    assert not (g["radii"] > 0)[:, :5].any()  # opacity 0.002 < 1/255
    # gsplat: ceil(e sqrt(cov_axis)), e <= 3.33, cov_axis <= largest eigenvalue -> at most ceil(3.33/3 x ref) + 1
    assert (g["radii"][both] <= torch.ceil(r["radii"][both] * 3.33 / 3) + 1).all()


@pytest.mark.cuda
@needs_gsplat
@pytest.mark.skipif(not cpu_backend.available(), reason="needs the cpu backend")
def test_gsplat_contributions_equal_the_cpu_backends():
    """From the pairs gsplat blended (and, independently, by the ones-channel gradient through gsplat)."""
    from panorecon.splat.rasterize.contrib import weight_sum_by_gradient

    (m, q, s, o, sh), Vs, Ks = random_scene(seed=1)
    o[:5] = 0.5  # every Gaussian visible to both
    rgb = torch.sigmoid(sh[:, 0])
    *_, ref = rasterize(m, q, s, o, rgb, Vs, Ks, W, H, backend="cpu", return_contrib=True)
    cuda = [t.cuda() for t in (m, q, s, o, rgb, Vs, Ks)]
    *_, got = rasterize(*cuda, W, H, backend="gsplat", return_contrib=True)
    # gsplat's tile lists (per-axis, opacity-aware boxes) differ from the reference's squares at the 3-sigma edge,
    # where alpha is near 1/255: contributions agree to a small absolute amount (pixels)
    for k in ("weight_sum", "weight_max", "trans_max"):
        torch.testing.assert_close(got[k].cpu(), ref[k], atol=0.05 if k == "weight_sum" else 0.01, rtol=1e-3)
    by_grad = weight_sum_by_gradient(
        lambda ones: rasterize(*cuda[:4], ones, *cuda[5:], W, H, backend="gsplat")[0], 2, len(m), device="cuda"
    )
    torch.testing.assert_close(by_grad, got["weight_sum"], atol=1e-3, rtol=1e-4)


@pytest.mark.cuda
@needs_gsplat
def test_auto_chooses_gsplat_for_cuda_tensors():
    assert resolve_backend("auto", cuda_tensors=True) == "gsplat"
    (m, q, s, o, sh), Vs, Ks = random_scene(50)
    *_, meta = rasterize(*(t.cuda() for t in (m, q, s, o, sh)), Vs.cuda(), Ks.cuda(), W, H, sh_degree=3)
    assert meta["backend"] == "gsplat"
    with pytest.raises(RuntimeError, match="CUDA tensors"):
        resolve_backend("cpu", cuda_tensors=True)
    assert gsplat_backend.build_seconds() is not None
