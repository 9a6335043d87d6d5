"""The cpu backend's training-step kernels beside the compositor against their PyTorch references, measured in the
same run, as speed ratios: SSIM of a render against a target (``losses.ssim``, fused in C++, against
``losses.ssim_separable``), forward + backward; the SH colours at degree 0, the trainer's
(``cpu_backend.sh_colors`` against ``sh_colors_reference`` masked to the visible pairs), forward + backward, with a
tenth of the Gaussians visible; and the loss's L1 and Pearson depth terms (``loss_rows``). Median ms over repeats
(the two called alternately, after warm-up calls), the ratio reference / fused, and the largest |difference| of
values and gradients.

    python -m panorecon.bench.fused [--quick] [--repeats N] [--out result.json]

``--quick``: 128² x 3 and 20k Gaussians (CI); else 256² x 3 and 200k.
"""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass

import torch

from .. import checks as C
from ..checks import opt
from ..evaluation.environment import emit, environment
from ..io import peak_rss_mb


def _paired_ms(fused, reference, repeats: int) -> tuple[float, float]:
    """Median ms of each callable, after two warm-up calls each, called alternately (fused, reference, reference,
    fused, ...) so that the machine's drift falls on both alike."""
    for fn in (fused, reference, fused, reference):
        fn()
    times = {fused: [], reference: []}
    for r in range(repeats):
        for fn in (fused, reference) if r % 2 == 0 else (reference, fused):
            t = time.perf_counter()
            fn()
            times[fn].append(1000 * (time.perf_counter() - t))
    return statistics.median(times[fused]), statistics.median(times[reference])


def _rows(kernel: str, run, repeats: int) -> dict:
    """``run("fused")`` against ``run("reference")`` (each -> its values and gradients) by ``_paired_ms``: the
    ``{kernel}_ms``, ``{kernel}_reference_ms``, ``{kernel}_speedup_vs_torch`` and ``{kernel}_max_abs_difference``
    (over every value and gradient, from the last calls) rows."""
    out = {}

    def call(key):
        out[key] = run(key)

    fused_ms, reference_ms = _paired_ms(lambda: call("fused"), lambda: call("reference"), repeats)
    return {
        f"{kernel}_ms": fused_ms,
        f"{kernel}_reference_ms": reference_ms,
        f"{kernel}_speedup_vs_torch": reference_ms / fused_ms,
        f"{kernel}_max_abs_difference": max(float((a - b).abs().max()) for a, b in zip(out["fused"], out["reference"])),
    }


def ssim_rows(size: int, repeats: int) -> dict:
    """SSIM forward + backward of a [1, size, size, 3] render against a target: fused and separable PyTorch."""
    from panorecon.splat.losses import ssim, ssim_separable

    g = torch.Generator().manual_seed(0)
    target = torch.rand(1, size, size, 3, generator=g)
    render = (target + 0.1 * torch.randn(1, size, size, 3, generator=g)).clamp(0, 1)

    def run(key):
        leaf = render.clone().requires_grad_(True)
        value = (ssim if key == "fused" else ssim_separable)(leaf, target)
        value.backward()
        return value.detach(), leaf.grad

    return _rows("ssim", run, repeats)


def sh_rows(n: int, repeats: int) -> dict:
    """SH colours at degree 0 of n Gaussians (a tenth visible) from one camera, forward + backward: the C++ kernel
    and the reference on every Gaussian, masked."""
    from panorecon.splat.rasterize import cpu_backend
    from panorecon.splat.rasterize.sh import sh_colors_reference

    g = torch.Generator().manual_seed(1)
    sh0, shN = torch.randn(n, 1, 3, generator=g), torch.zeros(n, 15, 3)
    means, campos = torch.randn(n, 3, generator=g), torch.zeros(1, 3)
    radii = ((torch.rand(1, n, generator=g) < 0.1) * 3).to(torch.int32)
    upstream = torch.randn(1, n, 3, generator=g)

    def run(key):
        dc = sh0.clone().requires_grad_(True)
        if key == "fused":
            colors = cpu_backend.sh_colors(0, (dc, shN), means, campos, radii)
        else:
            colors = sh_colors_reference(0, torch.cat([dc, shN], 1), means, campos) * (radii[..., None] > 0)
        (colors * upstream).sum().backward()
        return colors.detach(), dc.grad

    return _rows("sh", run, repeats)


def loss_rows(size: int, repeats: int) -> dict:
    """The loss's L1 of a [1, size, size, 3] render against a target plus its Pearson depth term over a [size, size]
    depth with a third of the pixels masked out, forward + backward: ``losses.l1`` and ``losses.pearson_depth_loss``
    (fused in C++) against the PyTorch formulas (``(a - b).abs().mean()``, ``pearson_depth_loss_torch``)."""
    from panorecon.splat.losses import l1, pearson_depth_loss, pearson_depth_loss_torch

    g = torch.Generator().manual_seed(2)
    target, render = torch.rand(1, size, size, 3, generator=g), torch.rand(1, size, size, 3, generator=g)
    depth = torch.rand(size, size, generator=g) * 4 + 1
    teacher, valid = 2 * depth + torch.rand(size, size, generator=g), torch.rand(size, size, generator=g) > 0.3

    def run(key):
        image, z = render.clone().requires_grad_(True), depth.clone().requires_grad_(True)
        if key == "fused":
            value = 0.8 * l1(image, target) + 0.05 * pearson_depth_loss(z, teacher, valid)
        else:
            value = 0.8 * (image - target).abs().mean() + 0.05 * pearson_depth_loss_torch(z, teacher, valid)
        value.backward()
        return value.detach(), image.grad, z.grad

    return _rows("loss", run, repeats)


def measure(quick: bool = True, repeats: int = 20) -> dict:
    """The rows above at CI's sizes (``quick``) or the trainer's (256², 200k Gaussians)."""
    from panorecon.splat.rasterize import cpu_backend

    if not cpu_backend.available():
        return {"status": "n/a: the C++ cpu backend could not be built here"}
    size, n = (128, 20_000) if quick else (256, 200_000)
    rows = {**ssim_rows(size, repeats), **sh_rows(n, repeats), **loss_rows(size, repeats)}
    return {"size": size, "gaussians": n, "repeats": repeats, **rows}


@dataclass(frozen=True)
class BenchFusedConfig:
    quick: bool = opt(False, "128² and 20k Gaussians (CI)")
    repeats: int = opt(20, "timed runs per kernel", check=C.int_in(1, None, "repeat count"))
    out: str | None = opt(None, "also write the result JSON here", role="out-file")


def main(argv=None) -> dict:
    from ..cli_types import parse_config

    cfg = parse_config(BenchFusedConfig, argv, __doc__.splitlines()[0])
    result = measure(cfg.quick, cfg.repeats)
    return emit(
        {
            "benchmark": "fused SSIM, SH and loss terms against their PyTorch references",
            **environment(),
            "threads": torch.get_num_threads(),
            **result,
            "peak_rss_mb": peak_rss_mb(),
        },
        cfg.out,
    )


if __name__ == "__main__":
    main()
