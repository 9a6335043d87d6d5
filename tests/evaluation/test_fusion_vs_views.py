import importlib.util
import json
import math
from pathlib import Path

import pytest

spec = importlib.util.spec_from_file_location(
    "fusion_vs_views", Path(__file__).parents[2] / "eval" / "fusion_vs_views.py"
)
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    out = tmp_path_factory.mktemp("ratios") / "ratios.json"
    teachers = "sim:clean,sim:relative,sim:affine-disparity"
    res = script.main(["--teachers", teachers, "--scenes", "bedroom", "--width", "128", "--out", str(out)])
    return res, out


def test_ratio_is_fused_over_per_view_and_written_as_json(result):
    res, out = result
    assert json.loads(out.read_text())["results"] == json.loads(json.dumps(res["results"]))
    for summary in res["results"].values():
        (row,) = summary["scenes"]
        assert row["scene"] == "bedroom" and row["ratio"] == row["fused_abs_rel"] / row["per_view_abs_rel"]
        assert summary["mean_ratio"] == row["ratio"]
    assert "ratio_inverse_affine" in res["results"]["sim:affine-disparity"]["scenes"][0]


def test_per_view_error_of_the_clean_profile_is_its_declared_noise(result):
    # sim:clean is the truth times a per-view scale times (1 + 0.005 N(0, 1)); once median-aligned, a view's
    # AbsRel is E|0.005 N| = 0.005 sqrt(2 / pi) = 0.00399
    row = result[0]["results"]["sim:clean"]["scenes"][0]
    assert row["per_view_abs_rel"] == pytest.approx(0.005 * math.sqrt(2 / math.pi), rel=0.1)


def test_fusion_beats_the_views_of_a_noisy_teacher(result):
    # sim:relative (2 % noise, +-8 % smooth warp): each pixel is seen by several views whose warps differ, so the
    # fused map must be clearly better than the median view
    row = result[0]["results"]["sim:relative"]["scenes"][0]
    assert row["ratio"] < 0.9, row
