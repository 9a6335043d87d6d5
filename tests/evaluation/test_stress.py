"""eval/stress.py in its quick mode: every case and source gives a row (numbers or a reason), the error columns
agree with a direct computation, the per-row peak memory is a window of its own, and a case builder's scene is
what its name says."""

import importlib.util
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.io import reset_peak_rss, window_peak_rss_mb

spec = importlib.util.spec_from_file_location("stress", Path(__file__).parents[2] / "eval" / "stress.py")
script = importlib.util.module_from_spec(spec)
sys.modules["stress"] = script  # its dataclass looks its module up there
spec.loader.exec_module(script)


def test_quick_mode_gives_every_row_and_its_table(tmp_path):
    out = script.main(["--quick", "--out", str(tmp_path / "s.json"), "--table", str(tmp_path / "t.md")])
    assert json.loads((tmp_path / "s.json").read_text())["rows"] == out["rows"]
    assert {"machine", "versions", "commit"} <= set(out) and out["quick"] and out["complete"] and out["width"] == 64
    assert [r["case"] for r in out["rows"]] == list(script.QUICK_CASES)
    rows = {r["case"]: r for r in out["rows"]}
    for case in ("textureless", "cliff-100", "seam-jump"):
        for source, p in rows[case]["points"].items():
            assert 0 <= p["abs_rel"] < 5 and 0 <= p["flying"] <= 1 and 0 <= p["ws_flying"] <= 1, (case, source)
            assert p["points"] > 0 and p["seconds"] > 0 and p["peak_mb"] > 0
        t = rows[case]["train"]
        assert math.isfinite(t["psnr"]) and t["gaussians"] > 0 and t["peak_mb"] > 0
    # the cliff's background flies off the near wall's scale somewhere; one sphere never does
    assert rows["textureless"]["points"]["fibonacci"]["flying"] == 0
    assert all("gave no point" in p["unavailable"] for p in rows["all-sky"]["points"].values())
    assert "unavailable" in rows["all-sky"]["train"]
    table = (tmp_path / "t.md").read_text()
    assert table == out["table"] and table.count("\n") == 2 + sum(len(r["points"]) for r in out["rows"])
    lines = out["summary"].splitlines()  # one line per case: the method's columns and the worst over sources
    assert len(lines) == 2 + len(out["rows"]) and "gave no point" in next(x for x in lines if x.startswith("| all-sky"))
    cells = [c.strip() for c in next(x for x in lines if x.startswith("| cliff-100")).strip("|").split("|")]
    cliff = rows["cliff-100"]["points"]
    assert cells[3] == f"{100 * cliff['fibonacci']['flying']:.3f}" and cells[6] == cells[3]  # one layout ran
    assert cells[7] == f"{100 * cliff['erp-direct']['flying']:.3f} / n/a"  # moge-merge did not run
    low, high = sorted(p["abs_rel"] for p in cliff.values())
    assert cells[5] == f"{low:.3f}–{high:.3f}"


EVERY_CASE = [c.name for c in script.CASES if c.name not in (*script.QUICK_CASES, "8k")]


def test_every_other_case_runs_in_quick_mode_with_finite_rows():
    """The cases the quick mode leaves out, by name, at 64 px (8K: its chunked stages' own tests): a row per source,
    finite errors where the scene has truth, a finite training row, a reason where no teacher runs; at the cliffs
    the fused layouts fly far less than the teacher on the whole panorama (erp-direct), and the same room at 1e-3
    and 1e3 trains to the same picture."""
    out = script.main(["--quick", "--cases", ",".join(EVERY_CASE)])
    rows = {r["case"]: r for r in out["rows"]}
    assert list(rows) == EVERY_CASE
    for name, r in rows.items():
        if name == "real-py360":
            assert all("no teacher runs offline" in p["unavailable"] for p in r["points"].values())
            continue
        assert set(r["points"]) == {"fibonacci", "erp-direct"} and math.isfinite(r["train"]["psnr"]), name
        for p in r["points"].values():
            assert p["points"] > 0 and p["seconds"] > 0, name
            if name != "real-hohonet":
                assert all(math.isfinite(p[k]) for k in ("abs_rel", "flying", "ws_flying", "median_rel")), name
    assert rows["real-hohonet"]["points"]["fibonacci"]["depth"].startswith("n/a")
    for cliff in ("cliff-10", "cliff-1e4"):
        points = rows[cliff]["points"]
        assert points["fibonacci"]["flying"] < 0.1 * points["erp-direct"]["flying"], points
    small, large = rows["scale-1e-3"]["train"]["psnr"], rows["scale-1e3"]["train"]["psnr"]
    assert abs(small - large) < 0.3, (small, large)


def test_an_unknown_case_is_one_argparse_error(capsys):
    with pytest.raises(SystemExit):
        script.main(["--quick", "--cases", "nosuch"])
    assert "nosuch" in capsys.readouterr().err


def test_the_cases_build_what_they_say():
    cliff = script.cliff(1e4)(64)
    assert set(np.unique(cliff.distance)) == {1.0, 1e4} and cliff.has_ground_truth
    seam = {c.name: c for c in script.CASES}["seam-jump"].build(64)
    assert seam.distance[:, -1].min() / seam.distance[:, 0].max() > 9  # the jump is at the seam
    ramp = script.ramp(4)(64)
    assert ramp.distance.max() / ramp.distance.min() > 1e3
    assert script.all_sky(64).sky.all() and not script.textureless(64).sky.any()
    assert len(np.unique(script.textureless(64).rgb)) == 1


def _reference_shares(pred, truth, scale, mask):
    """error_shares by plain loops over the valid pixels."""
    from panorecon.metrics.panorama import erp_row_weights

    w_row = erp_row_weights(truth.shape[0])
    errs = []
    for r in range(truth.shape[0]):
        for c in range(truth.shape[1]):
            p, t = float(pred[r, c]), float(truth[r, c])
            if mask[r, c] and np.isfinite(p) and np.isfinite(t) and p > 0 and t > 0:
                errs.append((abs(p * scale - t) / t, w_row[r]))
    errs.sort()
    total = sum(w for _, w in errs)
    acc, ws_median = 0.0, None
    for e, w in errs:
        acc += w
        if acc >= 0.5 * total:
            ws_median = e
            break
    return {
        "median_rel": float(np.median([e for e, _ in errs])),
        "flying": sum(e > 0.5 for e, _ in errs) / len(errs),
        "ws_median_rel": ws_median,
        "ws_flying": sum(w for e, w in errs if e > 0.5) / total,
    }


@settings(max_examples=25, deadline=None)
@given(log_scale=st.floats(-3, 3), noise=st.floats(0, 2), holes=st.floats(0, 0.9), seed=st.integers(0, 2**16))
def test_error_shares_equal_the_loop_and_stay_finite_on_extreme_maps(log_scale, noise, holes, seed):
    rng = np.random.default_rng(seed)
    truth = (10.0**log_scale * rng.uniform(0.5, 2.0, (8, 16))).astype(np.float32)
    pred = (truth * np.exp(noise * rng.standard_normal(truth.shape)) / 3.0).astype(np.float32)
    pred[rng.random(truth.shape) < holes] = np.nan
    mask = np.ones(truth.shape, bool)
    mask[0, 0] = False
    if not np.isfinite(pred[mask]).any():
        assert all(math.isnan(v) for v in script.error_shares(pred, truth, 3.0, mask).values())
        return
    fast, ref = script.error_shares(pred, truth, 3.0, mask), _reference_shares(pred, truth, 3.0, mask)
    for k in ref:
        assert fast[k] == pytest.approx(ref[k], rel=1e-9, abs=1e-12) and math.isfinite(fast[k]), k


def test_the_peak_memory_window_restarts():
    reset_peak_rss()
    big = np.ones(50_000_000)  # 400 MB
    high = window_peak_rss_mb()
    del big
    if not reset_peak_rss():
        pytest.skip("this system does not let a process reset its peak RSS")
    assert window_peak_rss_mb() < high - 300
