"""Training losses (paper eq. 8-12): L1, SSIM and a Pearson-correlation depth term; on the CPU in C++
(csrc/ssim_cpu.cpp, csrc/loss_cpu.cpp), with the PyTorch formulas as the reference and the fallback.

SSIM: 11x11 Gaussian window, sigma 1.5, C1 = 0.01^2, C2 = 0.03^2 on [0, 1] images, computed on the
'valid' region (no padding) and averaged over pixels and channels.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .rasterize import cpu_backend


def gaussian_kernel_1d(size: int = 11, sigma: float = 1.5, dtype=torch.float32) -> torch.Tensor:
    """[size] normalised Gaussian taps."""
    x = torch.arange(size, dtype=dtype) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    return g / g.sum()


def gaussian_window(size: int = 11, sigma: float = 1.5, dtype=torch.float32) -> torch.Tensor:
    """[size, size] separable Gaussian window (outer product of ``gaussian_kernel_1d``)."""
    g = gaussian_kernel_1d(size, sigma, dtype)
    return g[:, None] * g[None, :]


def _ssim_map(mx, my, exx, eyy, exy):
    sxx, syy, sxy = exx - mx**2, eyy - my**2, exy - mx * my
    c1, c2 = 0.01**2, 0.03**2
    return ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx**2 + my**2 + c1) * (sxx + syy + c2))


class _FusedSsim(torch.autograd.Function):
    """SSIM of planar float32 images [P, H, W] against a constant target in C++ (csrc/ssim_cpu.cpp): one pass for
    the statistics, the map and its partials, one for the gradient, where the grouped convolutions and a dozen
    elementwise tensors of ``ssim_separable`` took ~6.5 ms of a training step at 256² (docs/benchmarks.md)."""

    @staticmethod
    def forward(ctx, x, y, taps):
        value, partials = cpu_backend.load().ssim_forward(x, y, taps)
        ctx.save_for_backward(x, y, taps, partials)
        return value

    @staticmethod
    def backward(ctx, g):
        x, y, taps, partials = ctx.saved_tensors
        return cpu_backend.load().ssim_backward(x, y, taps, partials, g.float().contiguous()), None, None


def ssim(a: torch.Tensor, b: torch.Tensor, size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM of images [..., H, W, C] in [0, 1] (H, W >= ``size``), differentiable w.r.t. ``a``: fused in C++
    for float32 CPU images when the cpu backend is built and ``b`` needs no gradient (a target), else
    ``ssim_separable``; ``ssim_reference`` is the same quantity with the 2-D window."""
    fused = a.device.type == "cpu" and a.dtype == b.dtype == torch.float32 and not b.requires_grad
    if not (fused and cpu_backend.available()):
        return ssim_separable(a, b, size, sigma)
    H, W, C = a.shape[-3:]
    planar = lambda t: t.reshape(-1, H, W, C).permute(0, 3, 1, 2).reshape(-1, H, W).contiguous()  # noqa: E731
    return _FusedSsim.apply(planar(a), planar(b), gaussian_kernel_1d(size, sigma))


def ssim_separable(a: torch.Tensor, b: torch.Tensor, size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """``ssim`` in PyTorch on any device and dtype: the five local statistics are blurred in one grouped
    convolution, separably (a row pass, then a column pass): 2 x 11 taps per pixel instead of 121."""
    C = a.shape[-1]
    x = a.reshape(-1, *a.shape[-3:]).permute(0, 3, 1, 2)
    y = b.reshape(-1, *b.shape[-3:]).permute(0, 3, 1, 2)
    stats = torch.cat([x, y, x * x, y * y, x * y], 1)
    k = stats.shape[1]
    g = gaussian_kernel_1d(size, sigma, a.dtype).to(a.device)
    stats = F.conv2d(stats, g.view(1, 1, 1, size).expand(k, 1, 1, size), groups=k)
    stats = F.conv2d(stats, g.view(1, 1, size, 1).expand(k, 1, size, 1), groups=k)
    return _ssim_map(*stats.split(C, 1)).mean()


def ssim_reference(a: torch.Tensor, b: torch.Tensor, size: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """``ssim`` with the 2-D window, one convolution per statistic: the reference the tests compare with."""
    C = a.shape[-1]
    x = a.reshape(-1, *a.shape[-3:]).permute(0, 3, 1, 2)
    y = b.reshape(-1, *b.shape[-3:]).permute(0, 3, 1, 2)
    w = gaussian_window(size, sigma, a.dtype).to(a.device)[None, None].repeat(C, 1, 1, 1)
    conv = lambda t: F.conv2d(t, w, groups=C)  # noqa: E731
    return _ssim_map(conv(x), conv(y), conv(x * x), conv(y * y), conv(x * y)).mean()


class _FusedL1(torch.autograd.Function):
    """mean |x - y| of float32 CPU tensors in C++ (csrc/loss_cpu.cpp), a pass each way; the gradient has the bits of
    PyTorch's backward of ``(x - y).abs().mean()``, the value is summed in double."""

    @staticmethod
    def forward(ctx, x, y):
        ctx.save_for_backward(x, y)
        return cpu_backend.load().l1_forward(x, y)

    @staticmethod
    def backward(ctx, g):
        x, y = ctx.saved_tensors
        return cpu_backend.load().l1_backward(x, y, g.float()), None


def l1(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """mean |a - b|, differentiable w.r.t. ``a``: fused in C++ for float32 CPU tensors of one shape when the cpu
    backend is built and ``b`` needs no gradient (a target), else in PyTorch."""
    fused = a.device.type == "cpu" and a.dtype == b.dtype == torch.float32 and a.shape == b.shape
    if fused and not b.requires_grad and cpu_backend.available():
        return _FusedL1.apply(a.contiguous(), b.contiguous())
    return (a - b).abs().mean()


class _FusedPearson(torch.autograd.Function):
    """``pearson_depth_loss`` of float32 CPU depths in C++ (csrc/loss_cpu.cpp): two passes with double sums for the
    value, one for the gradient w.r.t. the rendered depth."""

    @staticmethod
    def forward(ctx, rendered, teacher, valid):
        loss, stats = cpu_backend.load().pearson_forward(rendered, teacher, valid)
        ctx.save_for_backward(rendered, teacher, valid, stats)
        return loss

    @staticmethod
    def backward(ctx, g):
        rendered, teacher, valid, stats = ctx.saved_tensors
        return cpu_backend.load().pearson_backward(rendered, teacher, valid, stats, g), None, None


def pearson_depth_loss(
    rendered: torch.Tensor, teacher: torch.Tensor, valid: torch.Tensor | None = None
) -> torch.Tensor:
    """1 - Pearson correlation between rendered and teacher depth over valid pixels (eq. 10-11): invariant to
    the teacher's scale and shift. Fewer than 2 valid pixels or a constant map give 0 loss. Fused in C++ (sums in
    double) for float32 CPU depths of one shape when the cpu backend is built and the teacher needs no gradient;
    else masked sums in PyTorch, no boolean indexing or branch on a value: nothing is read back to the host.
    ``pearson_depth_loss_reference`` is the same quantity, written directly."""
    fused = rendered.device.type == "cpu" and rendered.dtype == teacher.dtype == torch.float32
    fused = fused and rendered.shape == teacher.shape and (valid is None or valid.shape == rendered.shape)
    if fused and not teacher.requires_grad and cpu_backend.available():
        mask = torch.empty(0, dtype=torch.bool) if valid is None else valid.to(torch.bool).contiguous()
        return _FusedPearson.apply(rendered.contiguous(), teacher.contiguous(), mask)
    return pearson_depth_loss_torch(rendered, teacher, valid)


def pearson_depth_loss_torch(
    rendered: torch.Tensor, teacher: torch.Tensor, valid: torch.Tensor | None = None
) -> torch.Tensor:
    """``pearson_depth_loss`` in PyTorch on any device and dtype, by masked sums in the inputs' dtype."""
    ok = torch.isfinite(teacher) & torch.isfinite(rendered)
    if valid is not None:
        ok = ok & valid
    w = ok.to(rendered.dtype)
    n = w.sum()
    x0 = torch.where(ok, rendered, torch.zeros_like(rendered))
    y0 = torch.where(ok, teacher.to(rendered.dtype), torch.zeros_like(rendered))
    x = (x0 - x0.sum() / n.clamp_min(1)) * w
    y = (y0 - y0.sum() / n.clamp_min(1)) * w
    prod = (x * x).sum() * (y * y).sum()
    use = (n >= 2) & (prod > 1e-24)  # denominator > 1e-12; sqrt taken only where used (finite gradient)
    corr = (x * y).sum() / torch.sqrt(torch.where(use, prod, torch.ones_like(prod)))
    return torch.where(use, 1 - corr, x0.sum() * 0)


def pearson_depth_loss_reference(
    rendered: torch.Tensor, teacher: torch.Tensor, valid: torch.Tensor | None = None
) -> torch.Tensor:
    """``pearson_depth_loss`` by boolean indexing and host-side branches: the reference the tests compare with."""
    ok = torch.isfinite(teacher) & torch.isfinite(rendered)
    if valid is not None:
        ok = ok & valid
    if ok.sum() < 2:
        return rendered[ok].sum() * 0  # over the valid pixels only: a NaN elsewhere would make it NaN
    x, y = rendered[ok], teacher[ok]
    x, y = x - x.mean(), y - y.mean()
    denom = torch.sqrt((x * x).sum() * (y * y).sum())
    if denom <= 1e-12:
        return rendered[ok].sum() * 0
    return 1 - (x * y).sum() / denom


def total_loss(render, target, depth=None, teacher_depth=None, valid=None, w_l1=0.8, w_ssim=0.2, w_depth=0.05):
    """w_l1 L1 + w_ssim (1 - SSIM) + w_depth (1 - Pearson) (eq. 8); the 3DGS default 0.8 / 0.2, depth 0.05."""
    loss = w_l1 * l1(render, target) + w_ssim * (1 - ssim(render, target))
    if w_depth and depth is not None and teacher_depth is not None:
        loss = loss + w_depth * pearson_depth_loss(depth, teacher_depth, valid)
    return loss
