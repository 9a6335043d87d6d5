"""``panorecon bench``: the benchmark CI job.

Runs the tiny ablation suite (fresh cache, so everything is computed), the fusion and the rasterizer
micro-benchmarks, the fused SSIM and SH kernels against their references (``bench.fused``) and the training step's
roofline (``bench.roofline``; small: 128², 20k Gaussians), and compares them with a stored baseline
(``benchmarks/baseline.json``):
- correctness regressions fail (exit 1): an error metric worse than baseline x ``ERROR_SLACK`` (+ a floor), a
  PSNR more than ``PSNR_SLACK_DB`` below it, the cpu rasterizer or the fused kernels drifting from the torch
  references, a NaN;
- slowdowns warn: a speed ratio measured in the same run (method / reference) below baseline / ``SLOWDOWN_RATIO``,
  or the compositing's distance from the machine's FMA peak (both measured in the same run) above baseline x
  ``SLOWDOWN_RATIO``.
Ratios, not seconds, are compared, so a slower or busier machine does not raise false alarms.
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from pathlib import Path

from ..io import write_json

ERROR_SLACK, ERROR_FLOOR = 1.5, 0.005
PSNR_SLACK_DB = 1.5
RASTER_MAX_DIFF = {"image": 1e-4, "grad_means": 1e-2}
FUSED_MAX_DIFF = {"ssim": 1e-6, "sh": 1e-6, "loss": 1e-6}  # values and gradients, fused against the PyTorch reference
SLOWDOWN_RATIO = 1.5


def measure(suite_path, quick: bool = True, device: str = "auto") -> dict:
    """Run the suite (its stages on ``device``) and both micro-benchmarks (CPU) -> the numbers the baseline
    stores."""
    from ..evaluation.ablate import run_suite
    from ..evaluation.suite import load_suite
    from . import fused as bench_fused
    from . import fusion as bench_fusion
    from . import rasterizer as bench_rasterizer
    from . import roofline as bench_roofline

    t = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="panorecon-bench-") as tmp:
        frame = run_suite(load_suite(suite_path), tmp, jobs=1, progress=False, device=device)
    suite_seconds = time.perf_counter() - t
    flag = ["--quick"] if quick else []
    fusion = bench_fusion.main(flag)["results"][0]
    raster = bench_rasterizer.main(flag)
    fused = bench_fused.measure(quick)
    roof = bench_roofline.roofline(128, 20_000, 3) if quick else bench_roofline.roofline()
    stage = {r["stage"]: r for r in roof["stages"]}
    trained = frame[frame["device"].notna()] if "device" in frame else frame.iloc[:0]
    out = {
        "suite": {},
        "suite_seconds": suite_seconds,
        "device": {
            "device": ",".join(sorted(set(trained["device"]))) or "n/a: no row trains",
            "device_name": ",".join(sorted(set(trained["device_name"]))) or "n/a: no row trains",
            "peak_gpu_mb": float(trained["peak_gpu_mb"].max())
            if len(trained) and trained["peak_gpu_mb"].notna().any()
            else "n/a: CPU run",
            "train_seconds": float(trained["sec_train"].sum()) if len(trained) else 0.0,
        },
        "fusion": {
            "abs_rel": fusion["fibonacci-lsq"]["median_abs_rel"],
            "reference_abs_rel": fusion["moge-reference"]["median_abs_rel"],
            "speedup_vs_reference": fusion["speedup_vs_reference"],
        },
        "rasterizer": {
            "max_abs_difference": raster["max_abs_difference"],
            "speedup_cpu_vs_torch": raster["results"][0]["speedup_cpu_vs_torch"],
        },
        "fused": {k: v for k, v in fused.items() if k == "status" or "speedup" in k or "difference" in k},
        "roofline": {
            "size": roof["size"],
            "gaussians": roof["gaussians"],
            "peak_gflops": roof["peak_gflops"],
            "step_ms": roof["step_ms"],
            "composite_distance": sum(stage[k]["ms"] for k in ("composite_forward", "composite_backward"))
            / sum(stage[k]["floor_ms"] for k in ("composite_forward", "composite_backward")),
        },
    }
    for label, g in frame.groupby("label", sort=False):  # metrics a row does not define (NaN) are left out
        out["suite"][label] = {
            k: float(g[k].mean()) for k in ("abs_rel", "chamfer", "psnr_pl", "psnr_ho") if k in g and g[k].notna().all()
        }
    return out


def compare(current: dict, baseline: dict) -> tuple[list[str], list[str]]:
    """-> (failures, warnings), each a list of one-line messages."""
    fails, warns = [], []
    for label, metrics in current["suite"].items():
        base = baseline["suite"].get(label)
        if base is None:
            warns.append(f"suite row {label!r} has no baseline (run with --update-baseline)")
            continue
        for k in set(base) - set(metrics):
            fails.append(f"{label}: {k} is no longer measured (NaN or missing; baseline {base[k]:.4g})")
        for k, v in metrics.items():
            if k not in base:
                continue
            if not math.isfinite(v):
                fails.append(f"{label}: {k} is {v}")
            elif k.startswith("psnr") and v < base[k] - PSNR_SLACK_DB:
                fails.append(f"{label}: {k} {v:.2f} dB < baseline {base[k]:.2f} - {PSNR_SLACK_DB} dB")
            elif not k.startswith("psnr") and v > base[k] * ERROR_SLACK + ERROR_FLOOR:
                fails.append(f"{label}: {k} {v:.4f} > baseline {base[k]:.4f} x {ERROR_SLACK} + {ERROR_FLOOR}")
    f, bf = current["fusion"], baseline["fusion"]
    if not f["abs_rel"] <= bf["abs_rel"] * ERROR_SLACK + ERROR_FLOOR:
        fails.append(f"fusion AbsRel {f['abs_rel']:.4f} > baseline {bf['abs_rel']:.4f} x {ERROR_SLACK} + {ERROR_FLOOR}")
    for k, tol in RASTER_MAX_DIFF.items():
        d = current["rasterizer"]["max_abs_difference"][k]
        if not d <= tol:
            fails.append(f"rasterizer cpu vs torch: max |difference| of {k} {d:.2e} > {tol:.0e}")
    ratios = [
        ("fusion speedup vs the MoGe-style reference", f["speedup_vs_reference"], bf["speedup_vs_reference"]),
        (
            "rasterizer cpu vs torch speedup",
            current["rasterizer"]["speedup_cpu_vs_torch"],
            baseline["rasterizer"]["speedup_cpu_vs_torch"],
        ),
    ]
    fused, base_fused = current.get("fused", {}), baseline.get("fused", {})
    for kernel, tol in FUSED_MAX_DIFF.items():
        d = fused.get(f"{kernel}_max_abs_difference")
        if d is not None and not d <= tol:
            fails.append(f"fused {kernel} vs its PyTorch reference: max |difference| {d:.2e} > {tol:.0e}")
        key = f"{kernel}_speedup_vs_torch"
        if key in fused and key in base_fused:
            ratios.append((f"fused {kernel} vs torch speedup", fused[key], base_fused[key]))
        elif key in fused:
            warns.append(f"fused {kernel} speedup has no baseline (run with --update-baseline)")
    for name, cur, base in ratios:
        if cur < base / SLOWDOWN_RATIO:
            warns.append(f"{name}: {cur:.2f}x < baseline {base:.2f}x / {SLOWDOWN_RATIO}")
    if "roofline" in baseline:
        cur, base = current["roofline"]["composite_distance"], baseline["roofline"]["composite_distance"]
        if cur > base * SLOWDOWN_RATIO:
            warns.append(
                f"compositing distance from the FMA peak: {cur:.1f}x > baseline {base:.1f}x x {SLOWDOWN_RATIO}"
            )
    return fails, warns


def run_bench(
    suite_path, baseline_path, out_path=None, quick: bool = True, update_baseline: bool = False, device: str = "auto"
) -> int:
    """Measure, compare, print JSON; exit status 1 on a correctness regression."""
    from ..device import resolve_device
    from ..evaluation.environment import environment

    resolve_device(device)  # a CUDA request without CUDA is refused before anything runs
    baseline_path = Path(baseline_path)
    current = measure(suite_path, quick, device)
    if update_baseline:
        write_json(baseline_path, {**current, "measured_with": environment()})
        print(f"baseline written to {baseline_path}")
        return 0
    if not baseline_path.is_file():
        from ..io import PanoreconInputError

        raise PanoreconInputError(f"baseline {baseline_path}: no such file (make one with --update-baseline)")
    fails, warns = compare(current, json.loads(baseline_path.read_text()))
    result = {
        **environment(),
        "current": current,
        "baseline": str(baseline_path),
        "failures": fails,
        "warnings": warns,
        "status": "fail" if fails else "ok",
    }
    print(json.dumps(result, indent=2))
    if out_path:
        write_json(out_path, result)
    for w in warns:
        print(f"warning: {w}")
    for f in fails:
        print(f"FAIL: {f}")
    return 1 if fails else 0
