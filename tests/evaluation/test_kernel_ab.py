"""eval/kernel_ab.py: a checkout against itself times every stage on both sides and finds the outputs equal."""

import importlib.util
from pathlib import Path

import pytest

from panorecon.splat.rasterize import cpu_backend

ROOT = Path(__file__).parents[2]
spec = importlib.util.spec_from_file_location("kernel_ab", ROOT / "eval" / "kernel_ab.py")
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
def test_this_checkout_against_itself_is_equal_in_every_stage():
    out = script.main([str(ROOT), "--gaussians", "300", "--repeats", "2", "--threads", "1"])
    assert set(out["stages"]) == {
        f"{stage}_{direction}"
        for stage in ("projection", "sh", "composite", "ssim")
        for direction in ("forward", "backward")
    } | {"densify_statistic"}
    assert all(s["new_ms"] > 0 and s["old_ms"] > 0 for s in out["stages"].values())
    assert out["outputs_equal"] is True


def test_a_folder_without_the_sources_is_one_clear_error(tmp_path):
    with pytest.raises(SystemExit, match="no panorecon/splat/rasterize/csrc"):
        script.main([str(tmp_path)])
