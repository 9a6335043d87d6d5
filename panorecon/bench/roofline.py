"""Per-stage roofline of one cpu training step: each stage's time, the work it did (counted from the run), its
achieved rate, and its distance from the machine's limits measured in the same run.

    python -m panorecon.bench.roofline [--size 256] [--gaussians 200000] [--repeats 5]
        [--sh-degree 0|3] [--threads N] [--clock wall|cpu] [--out r.json]

``--clock cpu`` times every stage and both peaks by this process's CPU seconds divided by the thread count: with
``--threads 1`` on a machine shared with other work, that is the work's own time, where wall seconds count the
time slices others took (a shared machine's wall seconds are inflated unevenly, most for multi-threaded stages).

The limits: ``peak_gflops`` from an FMA loop on every thread (csrc/peak_cpu.cpp: 12 independent 8-lane
accumulators, AVX2+FMA where the CPU has it; an FMA counts as 2 flops), the width of the kernels' vectors, so the
compute floors are those of the code as written; ``peak_gflops_16_lanes``, the same loop on 16 lanes where the CPU
has AVX-512 (what 16-lane code could reach: the compute floors at that peak are ``peak_gflops`` /
``peak_gflops_16_lanes`` of those below); and ``peak_gbs`` from a STREAM-like copy
of two 64 MiB float32 arrays (read + write bytes; the copies' time alone, without the arrays' allocation and
first touch, whose page faults cost several times the copies). A stage's floor is max(flops / peak_gflops, bytes /
peak_gbs); ``distance`` = its time / that floor (1 = at the machine's limit), ``bound`` says which roof is nearer.

The step: the bench rasterizer's scene (bench/rasterizer.scene) with half the Gaussians mirrored behind
the one 60° camera (as a panorama's label view sees a part of the sphere), the colours at the trainer's active SH
degree (``--sh-degree``; default the trainer's defaults' active degree, 0: ``TrainConfig.sh_increase_every`` is 0),
the trainer's loss (L1 + SSIM + Pearson depth against a noisy copy of the rendered depth) and fused Adam over the
``GaussianModel``'s parameters that get a gradient at that degree (at 0, not shN: the trainer's shN.grad stays None),
and one densification (``DefaultStrategy`` refine: 5 % of the Gaussians cloned) amortised over its 100-step period.
Each stage's backward runs alone (``torch.autograd.grad``).

Work per unit, counted from the sources (floating-point operations on lanes, an FMA-able multiply-add as 2;
compares and selects as 1), so that the counts are stated rather than measured by hardware counters:
- compositing: ``lane_evaluations`` = 16 lanes x the longest list entry any lane of a 4x4 block composited,
  summed over blocks (the work both passes do; the forward also walks the entries after that one until every
  lane has stopped, so its count is a lower bound); ``blends`` = pixel-Gaussian pairs composited (sum of each
  pixel's list end) and ``simd_efficiency`` = blends / lane_evaluations.
- projection, SH, losses, Adam: per (camera, Gaussian) pair, per visible pair, per pixel-channel, per parameter.
"""

from __future__ import annotations

import math
import statistics
import time
from dataclasses import dataclass

import torch

from .. import checks as C
from ..checks import opt
from ..evaluation.environment import emit, environment
from ..io import peak_rss_mb

# flops per unit (module docstring): forward, backward
FLOPS = {
    "composite": (67, 122),  # per lane evaluation: sigma 9, exp 27, alpha/T/weight 13, rgb+z 8, masks 10 | backward
    "projection": (190, 420),  # per (camera, Gaussian) pair: rotation, 3-D covariance, EWA Jacobian, 2x2 inverse
    "sh": {3: (130, 260), 0: (9, 9)},  # per visible pair | degree 3: 16 basis values, 16 x 3 multiply-adds, clamp;
    # degree 0: 3 multiply-adds and a clamp | 3 tests and 3 multiply-adds
    "loss": (250, 520),  # per pixel-channel: 5 statistics x 2 separable passes x 11 taps, SSIM map, L1, Pearson
    "adam": 12,  # per parameter: two moments, bias correction, sqrt, update
}
# bytes per unit moved to or from memory
BYTES = {
    "projection": (68, 112),  # means, quats, scales in; means2d, conics, depth, radius out | + gradients
    "sh": {3: (212, 400), 0: (24, 36)},  # 16 x 3 coefficients + mean in, colour out | coefficient gradients out;
    # degree 0: 3 coefficients in, colour out | colour gradient in, 3 coefficient gradients out
    "loss": (120, 240),  # the 5 statistic planes written and read by each pass
    "adam": 28,  # param, grad, m, v read; param, m, v written
    "densify": 59 * 3 * 4 * 2,  # 59 parameters + 2 Adam moments per Gaussian, read and written once
}


def _clock(kind: str):
    """() -> seconds: wall (perf_counter) or this process's CPU seconds / threads (module docstring)."""
    if kind == "wall":
        return time.perf_counter
    threads = torch.get_num_threads()
    return lambda: time.process_time() / threads


def machine_peaks(
    fma_iters: int = 20_000_000, copy_floats: int = 16 << 20, repeats: int = 5, clock: str = "wall"
) -> dict:
    """Best of ``repeats`` runs of the FMA loop and the copy (the best is the nearest to the machine's limit; a
    shared machine only lowers it)."""
    from panorecon.splat.rasterize import cpu_backend

    ext, now = cpu_backend.load(), _clock(clock)
    rates = {"fma": [], "fma16": [], "copy": []}
    for _ in range(repeats):
        t = now()
        work = ext.peak_fma(fma_iters, 8)[1]
        rates["fma"].append(work / (now() - t))
        t = now()
        work = ext.peak_fma(fma_iters // 2, 16)[1]  # [0, 0] without AVX-512
        rates["fma16"].append(work / (now() - t) if work else 0.0)
        # the copies' own time: a call of 17 copies minus a call of 1, so that the allocation and first touch of
        # the two arrays inside each call (page faults: ~3 copies' time, and uneven) cancel
        t = now()
        ext.stream_copy(copy_floats, 1)
        t1 = now()
        work = ext.stream_copy(copy_floats, 17)[1] * 16 / 17
        rates["copy"].append(work / max((now() - t1) - (t1 - t), 1e-9))
    return {
        "peak_gflops": max(rates["fma"]) / 1e9,
        "peak_gflops_16_lanes": max(rates["fma16"]) / 1e9 or "n/a: this CPU has no AVX-512",
        "peak_gbs": max(rates["copy"]) / 1e9,
        "threads": torch.get_num_threads(),
        "clock": clock,
    }


def _camera(size: int):
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat

    K = torch.tensor(intrinsics_from_fov(size, size, 60.0), dtype=torch.float32)[None]
    V = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None]
    return V, K


def _model(n: int):
    from panorecon.splat.model import GaussianModel

    from .rasterizer import scene

    means, quats, scales, opac, colors = scene(n)
    means[: n // 2, 0] *= -1  # behind the camera
    g = torch.Generator().manual_seed(1)
    return GaussianModel(
        means,
        quats,
        scales.log(),
        torch.logit(opac),
        ((colors - 0.5) / 0.28209479177387814)[:, None],
        torch.randn(n, 15, 3, generator=g) * 0.05,
    )


def lane_work(last: torch.Tensor, block: int = 4) -> tuple[int, int]:
    """-> (lane evaluations, blends) of the compositing, from the per-pixel list ends ``last`` [C,H,W] (module
    docstring); a partial block at the border counts its 16 lanes, as the kernel runs them."""
    C, H, W = last.shape
    pad = torch.nn.functional.pad(last.float(), (0, -W % block, 0, -H % block))
    per_block = torch.nn.functional.max_pool2d(pad[:, None], block)[:, 0]
    return int(per_block.sum()) * block * block, int(last.sum())


def trainer_sh_degree() -> int:
    """The SH degree the trainer's default configuration renders at: 0 unless its bands are switched on over time."""
    from panorecon.splat.trainer import TrainConfig

    cfg = TrainConfig()
    return cfg.sh_degree if cfg.sh_increase_every else 0


def step_stages(size: int, n: int, repeats: int, clock: str = "wall", sh_degree: int | None = None) -> dict:
    """Median seconds of each stage of one training step, and the counted work (module docstring)."""
    deg = trainer_sh_degree() if sh_degree is None else sh_degree
    if deg not in FLOPS["sh"]:
        raise ValueError(f"sh_degree={deg}: the roofline counts the work of degrees {sorted(FLOPS['sh'])}")
    from panorecon.splat.losses import total_loss
    from panorecon.splat.rasterize import cpu_backend
    from panorecon.splat.strategy import DefaultStrategy, edit_parameters
    from panorecon.splat.trainer import _adam

    V, K = _camera(size)
    campos = torch.zeros(1, 3)
    ext = cpu_backend.load()
    model = _model(n)
    opt = _adam(model, [(name, 1e-3) for name, _ in model.named_parameters()])
    times: dict[str, list[float]] = {}
    clock = _clock(clock)

    def tick(key, t0):
        times.setdefault(key, []).append(clock() - t0)
        return clock()

    teacher = None
    g_adam = torch.Generator().manual_seed(3)
    # the parameters with a gradient at this degree (at 0 shN gets none, and fused Adam skips it, as in the trainer)
    stepped = [p for name, p in model.named_parameters() if deg > 0 or name != "shN"]
    adam_grads = [torch.randn(p.shape, generator=g_adam) * 1e-3 for p in stepped]
    for _ in range(repeats + 1):  # the first is a warm-up
        t = clock()
        m2d, con, dep, radii = cpu_backend.project(model.means, model.quats, model.scales(), V, K, size, size)
        t = tick("projection_forward", t)
        cols = cpu_backend.sh_colors(deg, (model.sh0, model.shN), model.means, campos, radii)
        t = tick("sh_forward", t)
        leaves = [x.detach().requires_grad_(True) for x in (m2d, con, cols, dep)]
        op = model.opacities()
        op_leaf = op.detach().requires_grad_(True)
        img, alpha, depth, _ = cpu_backend.composite(*leaves[:3], op_leaf, leaves[3], radii, size, size)
        t = tick("composite_forward", t)
        img_l, alpha_l, depth_l = (x.detach().requires_grad_(True) for x in (img, alpha, depth))
        z = (depth_l / alpha_l.clamp_min(1e-6))[0, ..., 0]
        if teacher is None:
            g = torch.Generator().manual_seed(2)
            teacher = z.detach() * (1 + 0.05 * torch.randn(z.shape, generator=g))
            target = (img.detach() + 0.05 * torch.randn(img.shape, generator=g)).clamp(0, 1)
        loss = total_loss(img_l, target, z, teacher, alpha_l[0, ..., 0].detach() > 0.5, 0.8, 0.2, 0.05)
        t = tick("loss_forward", t)
        g_img, g_alpha, g_depth = torch.autograd.grad(loss, [img_l, alpha_l, depth_l])
        t = tick("loss_backward", t)
        grads = torch.autograd.grad([img, alpha, depth], [*leaves, op_leaf], [g_img, g_alpha, g_depth])
        t = tick("composite_backward", t)
        torch.autograd.grad(cols, [model.shN, model.sh0, model.means] if deg > 0 else [model.sh0], grads[2])
        t = tick("sh_backward", t)
        torch.autograd.grad(
            [m2d, con, dep], [model.means, model.quats, model.log_scales], [grads[0], grads[1], grads[3]]
        )
        t = tick("projection_backward", t)
        for p, grad in zip(stepped, adam_grads):  # outside the clock: randn costs ~10x the step
            p.grad = grad
        t = clock()
        opt.step()
        t = tick("adam", t)
        opt.zero_grad(set_to_none=True)
    # densification: one refine cloning 5 % of the Gaussians, then pruning them again so the size stays n
    strategy = DefaultStrategy(refine_start=0, refine_every=1, dense_fraction=1e9, grad_threshold=0.5)
    refine = []
    for _ in range(repeats):
        strategy.grad_sum = (torch.arange(n) % 20 == 0).float()
        strategy.count = torch.ones(n)
        t = clock()
        out = strategy.step(model, opt, 1, 1.0)
        refine.append(clock() - t)
        keep = torch.ones(len(model), dtype=torch.bool)
        keep[n:] = False
        edit_parameters(model, opt, keep)
    med = {k: statistics.median(v[1:]) for k, v in times.items()}
    med["densify"] = statistics.median(refine) / 100  # amortised over the trainer's 100-step refine period
    # work, counted from this run's outputs
    fwd = ext.forward(
        *(x.detach().contiguous() for x in (m2d, con, cols)), op.detach(), dep.detach(), radii, size, size, 16, False
    )
    lanes, blends = lane_work(fwd[4])
    pairs, visible = radii.numel(), int((radii > 0).sum())
    pixel_channels = size * size * 3
    params = sum(p.numel() for p in stepped)
    work = {
        "projection_forward": (pairs * FLOPS["projection"][0], pairs * BYTES["projection"][0]),
        "projection_backward": (pairs * FLOPS["projection"][1], pairs * BYTES["projection"][1]),
        "sh_forward": (visible * FLOPS["sh"][deg][0], visible * BYTES["sh"][deg][0]),
        "sh_backward": (visible * FLOPS["sh"][deg][1], visible * BYTES["sh"][deg][1]),
        "composite_forward": (lanes * FLOPS["composite"][0], size * size * 36),
        "composite_backward": (lanes * FLOPS["composite"][1], size * size * 64),
        "loss_forward": (pixel_channels * FLOPS["loss"][0], pixel_channels * BYTES["loss"][0]),
        "loss_backward": (pixel_channels * FLOPS["loss"][1], pixel_channels * BYTES["loss"][1]),
        "adam": (params * FLOPS["adam"], params * BYTES["adam"]),
        "densify": (0, len(model) * BYTES["densify"] / 100),
    }
    return {
        "size": size,
        "gaussians": n,
        "visible_pairs": visible,
        "sh_degree": deg,
        "lane_evaluations": lanes,
        "blends": blends,
        "simd_efficiency": blends / max(lanes, 1),
        "refine_cloned": out["cloned"],
        "seconds": med,
        "work": {k: {"flops": f, "bytes": b} for k, (f, b) in work.items()},
    }


def roofline(
    size: int = 256, n: int = 200_000, repeats: int = 5, clock: str = "wall", sh_degree: int | None = None
) -> dict:
    """Peaks, stages, and each stage's achieved rate and distance from its floor (module docstring)."""
    peaks = machine_peaks(clock=clock)
    st = step_stages(size, n, repeats, clock, sh_degree)
    rows = []
    for k, s in st["seconds"].items():
        f, b = st["work"][k]["flops"], st["work"][k]["bytes"]
        floor_c, floor_m = f / (peaks["peak_gflops"] * 1e9), b / (peaks["peak_gbs"] * 1e9)
        rows.append(
            {
                "stage": k,
                "ms": 1000 * s,
                "gflop": f / 1e9,
                "mbytes": b / 1e6,
                "achieved_gflops": f / s / 1e9,
                "achieved_gbs": b / s / 1e9,
                "floor_ms": 1000 * max(floor_c, floor_m),
                "bound": "compute" if floor_c >= floor_m else "memory",
                "distance": s / max(floor_c, floor_m) if max(floor_c, floor_m) > 0 else math.inf,
            }
        )
    total = sum(st["seconds"].values())
    return {
        **peaks,
        **{k: v for k, v in st.items() if k not in ("seconds", "work")},
        "step_ms": 1000 * total,
        "floor_step_ms": sum(r["floor_ms"] for r in rows),
        "stages": rows,
    }


@dataclass(frozen=True)
class BenchRooflineConfig:
    size: int = opt(256, "view size in pixels", check=C.LABEL_RES)
    gaussians: int = opt(200_000, "Gaussians in the model", check=C.int_in(1, None, "Gaussian count"))
    repeats: int = opt(5, "timed steps", check=C.int_in(1, None, "repeat count"))
    threads: int | None = opt(None, "torch threads (default: torch's own)", check=C.int_in(1, 1024, "thread count"))
    clock: str = opt("wall", "wall-clock or process CPU time", choices=("wall", "cpu"))
    sh_degree: int | None = opt(
        None, "SH degree (default: the trainer's; module doc)", choices=tuple(sorted(FLOPS["sh"]))
    )
    out: str | None = opt(None, "also write the result JSON here", role="out-file")


def main(argv=None) -> dict:
    from ..cli_types import parse_config

    cfg = parse_config(BenchRooflineConfig, argv, __doc__.splitlines()[0])
    if cfg.threads:
        torch.set_num_threads(cfg.threads)
    r = roofline(cfg.size, cfg.gaussians, cfg.repeats, cfg.clock, cfg.sh_degree)
    return emit(
        {"benchmark": "cpu training step roofline", **environment(), **r, "peak_rss_mb": peak_rss_mb()}, cfg.out
    )


if __name__ == "__main__":
    main()
