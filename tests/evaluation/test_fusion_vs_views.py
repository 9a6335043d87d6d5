import importlib.util
import json
from pathlib import Path

spec = importlib.util.spec_from_file_location("fusion_vs_views", Path(__file__).parents[2] / "eval" / "fusion_vs_views.py")
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)


def test_ratio_is_fused_over_per_view_and_written_as_json(tmp_path):
    out = tmp_path / "ratios.json"
    result = script.main(["--teachers", "sim:affine-disparity", "--scenes", "bedroom", "--width", "128", "--out", str(out)])
    saved = json.loads(out.read_text())
    assert saved["results"] == json.loads(json.dumps(result["results"]))
    row = result["results"]["sim:affine-disparity"]["scenes"][0]
    assert row["scene"] == "bedroom" and row["ratio"] == row["fused_abs_rel"] / row["per_view_abs_rel"]
    assert 0 < row["fused_abs_rel"] < 1 and "ratio_inverse_affine" in row
    assert result["results"]["sim:affine-disparity"]["mean_ratio"] == row["ratio"]
