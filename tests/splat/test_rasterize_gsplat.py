"""gsplat (CUDA) against the torch reference: values and gradients. Runs only where CUDA and gsplat exist."""
import pytest
import torch

from panorecon.splat.rasterize import gsplat_backend, rasterize, resolve_backend

needs_gsplat = pytest.mark.skipif(not gsplat_backend.available(), reason="needs CUDA and the gsplat package")


def test_gsplat_is_refused_clearly_where_it_cannot_run():
    if gsplat_backend.available():
        pytest.skip("gsplat is available here")
    with pytest.raises(RuntimeError, match="gsplat"):
        resolve_backend("gsplat")
    assert resolve_backend("auto", cuda_tensors=False) in ("cpu", "torch")


@needs_gsplat
def test_gsplat_matches_torch_values_and_gradients():
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat

    g = torch.Generator().manual_seed(0)
    n = 200
    means = torch.stack([torch.rand(n, generator=g) * 4 + 0.5, torch.rand(n, generator=g) * 3 - 1.5,
                         torch.rand(n, generator=g) * 2 - 1], -1)
    scene = [means, torch.randn(n, 4, generator=g), torch.rand(n, 3, generator=g) * 0.2 + 0.02,
             torch.rand(n, generator=g) * 0.9 + 0.05, torch.randn(n, 16, 3, generator=g) * 0.3]
    scene[1][0] = 0.0  # a zero-norm quaternion: the identity in panorecon's convention
    Ks = torch.tensor(intrinsics_from_fov(64, 48, 70.0), dtype=torch.float32)[None]
    Vs = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None]
    out = {}
    for backend, dev in (("torch", "cpu"), ("gsplat", "cuda")):
        leaves = [t.clone().to(dev).requires_grad_(True) for t in scene]
        m, q, s, o, sh = leaves
        img, alpha, depth, _ = rasterize(m, q, s, o, sh, Vs.to(dev), Ks.to(dev), 64, 48, sh_degree=3, backend=backend)
        (img.sum() + alpha.sum() + 0.1 * depth.sum()).backward()
        out[backend] = [img.detach().cpu(), alpha.detach().cpu()] + [t.grad.cpu() for t in leaves]
    for a, b in zip(out["gsplat"], out["torch"]):
        scale = b.abs().max().clamp_min(1.0)
        torch.testing.assert_close(a / scale, b / scale, atol=1e-3, rtol=1e-3)
