"""bench/fused.py and its guard in ``panorecon bench``: the fused SSIM, SH and loss-term kernels against
their PyTorch references, as ratios measured in one run; a drift from the reference fails, a slowdown warns."""

import pytest

from panorecon.bench import fused as bench_fused
from panorecon.bench.command import compare
from panorecon.splat.rasterize import cpu_backend


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
def test_quick_run_reports_agreement_and_every_ratio(tmp_path):
    out = bench_fused.main(["--quick", "--repeats", "1", "--out", str(tmp_path / "r.json")])
    assert out["size"] == 128 and out["gaussians"] == 20_000 and "machine" in out and "commit" in out
    for kernel in ("ssim", "sh", "loss"):
        assert out[f"{kernel}_ms"] > 0 and out[f"{kernel}_reference_ms"] > 0
        assert out[f"{kernel}_speedup_vs_torch"] == pytest.approx(out[f"{kernel}_reference_ms"] / out[f"{kernel}_ms"])
        assert out[f"{kernel}_max_abs_difference"] < 1e-6
    assert (tmp_path / "r.json").is_file()


BASE = {
    "suite": {},
    "fusion": {"abs_rel": 0.01, "speedup_vs_reference": 3.0},
    "rasterizer": {"speedup_cpu_vs_torch": 10.0, "max_abs_difference": {"image": 0, "grad_means": 0}},
    "fused": {
        "ssim_speedup_vs_torch": 5.0,
        "sh_speedup_vs_torch": 6.0,
        "loss_speedup_vs_torch": 4.0,
        "ssim_max_abs_difference": 0.0,
        "sh_max_abs_difference": 0.0,
        "loss_max_abs_difference": 0.0,
    },
}


def test_bench_warns_when_a_fused_kernel_loses_its_speedup():
    assert compare({**BASE, "fused": {**BASE["fused"], "sh_speedup_vs_torch": 4.5}}, BASE) == ([], [])
    fails, warns = compare({**BASE, "fused": {**BASE["fused"], "sh_speedup_vs_torch": 3.5}}, BASE)
    assert fails == [] and len(warns) == 1 and "fused sh" in warns[0]


@pytest.mark.parametrize("kernel", ["ssim", "loss"])
def test_bench_fails_when_a_fused_kernel_drifts_from_its_reference(kernel):
    fails, _ = compare({**BASE, "fused": {**BASE["fused"], f"{kernel}_max_abs_difference": 1e-3}}, BASE)
    assert len(fails) == 1 and f"fused {kernel}" in fails[0]


def test_a_baseline_without_fused_ratios_warns_once_per_kernel():
    fails, warns = compare(BASE, {k: v for k, v in BASE.items() if k != "fused"})
    assert fails == [] and sorted(warns) == sorted(
        f"fused {k} speedup has no baseline (run with --update-baseline)" for k in ("ssim", "sh", "loss")
    )
