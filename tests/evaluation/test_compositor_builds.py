"""eval/compositor_builds.py on a tiny scene: it times, saves, and compares a build's outputs with saved ones."""

import importlib.util
from pathlib import Path

import pytest

from panorecon.splat.rasterize import cpu_backend

spec = importlib.util.spec_from_file_location(
    "compositor_builds", Path(__file__).parents[2] / "eval" / "compositor_builds.py"
)
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
def test_same_build_against_itself_differs_nowhere(tmp_path):
    tiny = ["--size", "32", "--gaussians", "300", "--repeats", "1"]
    first = script.main([*tiny, "--save", str(tmp_path / "a.pt")])
    assert first["forward_cpu_ms"] > 0 and first["backward_cpu_ms"] > 0
    again = script.main([*tiny, "--against", str(tmp_path / "a.pt")])
    assert len(again["max_abs_difference_forward"]) == 6 and len(again["max_rel_difference_backward"]) == 5
    assert max(again["max_abs_difference_forward"]) == 0 and max(again["max_rel_difference_backward"]) == 0
