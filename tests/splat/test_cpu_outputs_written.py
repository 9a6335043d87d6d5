"""Every entry of the C++ kernels' outputs is written, whatever the memory held before: the projection, the SH
backward and the compositor's backward allocate theirs uninitialised (no zero-fill pass), and the compositor's forward
must stay so if it ever does. The heap is poisoned with NaN, then with zeros, in blocks of the outputs' sizes (the
allocator hands freed blocks back), and the two calls compared; dropping any one write from the kernels fails here."""

import pytest
import torch

from panorecon.splat.rasterize import cpu_backend

from .test_rasterize_cpu import cameras, random_scene

pytestmark = pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")

W, H = 40, 28


def poisoned(value: float, like: list[torch.Tensor], fn):
    """fn() after the heap got and freed blocks of each of ``like``'s sizes, filled with ``value`` (integer
    blocks: -7 for NaN)."""
    fill = lambda t: value if t.is_floating_point() or value == value else -7  # noqa: E731
    blocks = [torch.full((t.numel(),), fill(t), dtype=t.dtype) for t in like for _ in range(4)]
    del blocks
    return fn()


def same_after_poison(fn):
    """fn()'s tensors after NaN and after zero poisoning: equal, NaN-free."""
    shapes = fn()
    after_nan = poisoned(float("nan"), shapes, fn)
    after_zero = poisoned(0.0, shapes, fn)
    for k, (a, b) in enumerate(zip(after_nan, after_zero)):
        assert not a.float().isnan().any(), f"output {k}: an entry was not written (NaN from the poisoned heap)"
        assert torch.equal(a, b), f"output {k} depends on the memory it was allocated in"


def projected(n=64, seed=0):
    means, quats, scales, opac, sh = random_scene(n, seed)
    Vs, Ks = cameras(W, H)
    ext = cpu_backend.load()
    return ext, (means, quats / quats.norm(dim=-1, keepdim=True).clamp_min(1e-12), scales, Vs, Ks), opac, sh


def test_projection_writes_every_entry():
    ext, args, _, _ = projected()
    same_after_poison(lambda: ext.project_forward(*args, W, H, 0.01, 1e10, 0.3))
    radii = ext.project_forward(*args, W, H, 0.01, 1e10, 0.3)[3]
    assert (radii == 0).any() and (radii > 0).any(), "the case must have culled and kept pairs"
    g = torch.Generator().manual_seed(1)
    grads = [torch.randn(*radii.shape, k, generator=g) for k in (2, 3)] + [torch.randn(radii.shape, generator=g)]
    same_after_poison(lambda: ext.project_backward(*args, radii, *grads, W, H, 0.01, 1e10, 0.3))


@pytest.mark.parametrize("degree", [0, 3])
def test_sh_backward_writes_every_entry(degree):
    ext, args, _, sh = projected()
    radii = ext.project_forward(*args, W, H, 0.01, 1e10, 0.3)[3]
    campos = torch.randn(radii.shape[0], 3)
    g = torch.randn(*radii.shape, 3, generator=torch.Generator().manual_seed(2))
    dc, rest = sh[:, :1].contiguous(), sh[:, 1:].contiguous()
    same_after_poison(lambda: ext.sh_backward(dc, rest, args[0], campos, radii, g, degree))
    g_dc, g_rest, g_means = ext.sh_backward(dc, rest, args[0], campos, radii, g, degree)
    assert g_rest.shape == ((len(sh), 15, 3) if degree else (len(sh), 0, 3))
    assert g_means.shape == ((len(sh), 3) if degree else (0, 3)), "degree 0 does not read the view direction"


def test_compositor_writes_every_entry():
    ext, args, opac, sh = projected(n=200, seed=3)
    m2d, con, dep, radii = ext.project_forward(*args, W, H, 0.01, 1e10, 0.3)
    cols = torch.sigmoid(sh[:, 0])[None].expand(radii.shape[0], -1, -1).contiguous()
    inputs = (m2d, con, cols, opac, dep, radii)
    same_after_poison(lambda: ext.forward(*inputs, W, H, 16, True)[9:])  # the contributions [C, N]
    f = ext.forward(*inputs, W, H, 16, True)
    g = torch.Generator().manual_seed(4)
    grads = [torch.randn(radii.shape[0], H, W, k, generator=g) for k in (3, 1, 1)]
    same_after_poison(lambda: ext.backward(*inputs, f[3], f[4], *f[5:9], *grads, W, H, 16))
