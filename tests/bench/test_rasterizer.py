import json
import math

import pytest

from panorecon.bench import rasterizer as bench_rasterizer
from panorecon.splat.rasterize import cpu_backend

needs_cpu = pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")


@needs_cpu
def test_quick_run_reports_agreement_ratio_and_environment(tmp_path):
    out = tmp_path / "bench.json"
    res = bench_rasterizer.main(["--quick", "--repeats", "1", "--out", str(out)])
    assert json.loads(out.read_text()) == json.loads(json.dumps(res))
    (row,) = res["results"]
    assert (row["size"], row["gaussians"]) == (128, 10_000)
    cpu, ref = row["cpu"]["median_seconds"], row["torch"]["median_seconds"]
    assert row["speedup_cpu_vs_torch"] == pytest.approx(ref / cpu)
    # the benchmark's correctness check: both backends render the same image and gradient (float32 rounding)
    assert res["max_abs_difference"]["image"] < 1e-5 and res["max_abs_difference"]["grad_means"] < 1e-3
    assert {"versions", "commit", "machine"} <= set(res) and res["peak_rss_mb"] > 0


@needs_cpu
def test_max_difference_detects_a_wrong_backend(monkeypatch):
    # the check above must be able to fail: a compositor that drops a tenth of the light is caught
    from panorecon.splat import rasterize as rz

    real = rz.rasterize

    def dimmed(*args, backend="auto", **kw):
        img, alpha, depth, meta = real(*args, backend=backend, **kw)
        return (img * 0.9 if backend == "cpu" else img), alpha, depth, meta

    monkeypatch.setattr(rz, "rasterize", dimmed)
    assert bench_rasterizer.max_difference(64, 500)["image"] > 1e-2


@needs_cpu
def test_cpu_stages_times_every_stage():
    out = bench_rasterizer.cpu_stages(size=32, n=300, repeats=2)
    stages = (
        "projection_forward",
        "composite_forward",
        "composite_backward",
        "projection_backward",
        "reference_projection_forward",
        "reference_projection_backward",
        "sh_forward_backward",
        "reference_sh_forward_backward",
    )
    assert out["size"] == 32 and out["gaussians"] == 300
    assert all(math.isfinite(out[s + "_ms"]) and 0 < out[s + "_ms"] < 10_000 for s in stages)
    # the ratio is the two medians, and half the Gaussians (mirrored behind the camera) are never visible
    assert out["sh_speedup_cpu_vs_reference"] == out["reference_sh_forward_backward_ms"] / out["sh_forward_backward_ms"]
    assert 0 < out["sh_visible_fraction"] <= 0.5
