"""The roofline benchmark: its work counts, a tiny run's shape and sanity, and the bench guard on its ratio."""

import math

import pytest
import torch

from panorecon.bench.command import compare
from panorecon.bench.roofline import lane_work, roofline, step_stages, trainer_sh_degree
from panorecon.splat.rasterize import cpu_backend


def test_lane_work_counts_the_longest_lane_of_each_block():
    last = torch.zeros(1, 4, 8, dtype=torch.int32)
    last[0, 1, 2] = 5  # block (0, 0): its longest lane composited 5 entries
    last[0, 0, 4] = 2
    last[0, 3, 7] = 3  # block (0, 1): 3
    lanes, blends = lane_work(last)
    assert (lanes, blends) == (16 * (5 + 3), 10)
    partial = torch.ones(1, 5, 5, dtype=torch.int32)  # 4 blocks, 3 of them partial, all run with 16 lanes
    assert lane_work(partial) == (4 * 16, 25)


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
@pytest.mark.parametrize("sh_degree", [None, 3])
def test_tiny_roofline_reports_every_stage_with_finite_rates(sh_degree):
    r = roofline(64, 2_000, 1, sh_degree=sh_degree)
    assert r["sh_degree"] == (trainer_sh_degree() if sh_degree is None else sh_degree)
    assert r["peak_gflops"] > 0 and r["peak_gbs"] > 0
    if torch.backends.cpu.get_cpu_capability() == "AVX512":
        assert isinstance(r["peak_gflops_16_lanes"], float) and r["peak_gflops_16_lanes"] > 0
    else:
        assert str(r["peak_gflops_16_lanes"]).startswith("n/a:")
    stages = {s["stage"]: s for s in r["stages"]}
    assert set(stages) == {
        "projection_forward",
        "sh_forward",
        "composite_forward",
        "loss_forward",
        "loss_backward",
        "composite_backward",
        "sh_backward",
        "projection_backward",
        "adam",
        "densify",
    }
    for s in stages.values():
        assert s["ms"] > 0 and math.isfinite(s["distance"]) and s["distance"] > 0, s
    assert 0 < r["blends"] <= r["lane_evaluations"] and 0 < r["simd_efficiency"] <= 1
    assert r["step_ms"] == pytest.approx(sum(s["ms"] for s in stages.values()))


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
def test_roofline_steps_the_trainers_default_degree_and_its_parameters():
    """The default step is the trainer's: SH degree 0 (its bands are not switched on), and Adam over the parameters
    that get a gradient there (not shN); degree 3 steps all 59 floats a Gaussian."""
    assert trainer_sh_degree() == 0
    n = 2_000
    adam_floats = {d: step_stages(64, n, 1, sh_degree=d)["work"]["adam"]["flops"] / 12 for d in (0, 3)}
    assert adam_floats == {0: n * 14, 3: n * 59}
    with pytest.raises(ValueError, match="sh_degree=2"):
        step_stages(64, n, 1, sh_degree=2)


def test_bench_warns_when_the_compositing_moves_away_from_the_peak():
    base = {
        "suite": {},
        "fusion": {"abs_rel": 0.01, "speedup_vs_reference": 3.0},
        "rasterizer": {"speedup_cpu_vs_torch": 10.0, "max_abs_difference": {"image": 0, "grad_means": 0}},
        "roofline": {"composite_distance": 10.0},
    }
    assert compare({**base, "roofline": {"composite_distance": 14.0}}, base) == ([], [])
    fails, warns = compare({**base, "roofline": {"composite_distance": 16.0}}, base)
    assert fails == [] and len(warns) == 1 and "FMA peak" in warns[0]
