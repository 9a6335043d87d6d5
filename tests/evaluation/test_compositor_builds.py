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
    assert first["forward_ms"] > 0 and first["backward_ms"] > 0
    again = script.main([*tiny, "--against", str(tmp_path / "a.pt")])
    assert len(again["max_abs_difference_forward"]) == 6 and len(again["max_rel_difference_backward"]) == 5
    assert max(again["max_abs_difference_forward"]) == 0 and max(again["max_rel_difference_backward"]) == 0


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
def test_a_trained_runs_label_views(tmp_path):
    """--run reads a train output's model and cameras.json: each view's image, alpha and depth are compared
    (no contributions with --no-contrib)."""
    import torch

    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
    from panorecon.io import write_json
    from panorecon.splat.model import GaussianModel
    from panorecon.splat.ply import save_ply

    g = torch.Generator().manual_seed(0)
    n = 400
    model = GaussianModel(
        torch.randn(n, 3, generator=g) * 0.5 + torch.tensor([3.0, 0.0, 0.0]),
        torch.randn(n, 4, generator=g),
        torch.full((n, 3), -3.0),
        torch.zeros(n),
        torch.randn(n, 1, 3, generator=g),
        torch.zeros(n, 15, 3),
    )
    save_ply(model, tmp_path / "point_cloud.ply")
    camera = {
        "viewmat": look_at_viewmat([0, 0, 0], [1, 0, 0]).tolist(),
        "K": intrinsics_from_fov(32, 32, 60.0).tolist(),
        "width": 32,
        "height": 32,
    }
    write_json(tmp_path / "cameras.json", {"pseudo-label": [camera] * 4, "held-out": []})
    run = ["--run", str(tmp_path), "--views", "2", "--repeats", "1", "--no-contrib"]
    first = script.main([*run, "--save", str(tmp_path / "a.pt")])
    assert first["gaussians"] == n and first["views"] == 2 and first["size"] == 32 and not first["contributions"]
    again = script.main([*run, "--against", str(tmp_path / "a.pt")])
    assert len(again["max_abs_difference_forward"]) == 2 * 3 and max(again["max_abs_difference_forward"]) == 0
