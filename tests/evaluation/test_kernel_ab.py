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


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
def test_a_runs_views_at_another_size_scale_their_intrinsics(tmp_path):
    """--run with --size: the run's label views rendered at that size, K's focal lengths and centre scaled with it
    (the trainer's coarse steps), the last row of K kept."""
    import json

    import numpy as np
    import torch

    from panorecon.geometry import PointCloud, intrinsics_from_fov, look_at_viewmat
    from panorecon.splat.model import GaussianModel
    from panorecon.splat.ply import save_ply

    rng = np.random.default_rng(0)
    pc = PointCloud(rng.normal(size=(200, 3)) * 0.3 + [3, 0, 0], rng.uniform(size=(200, 3)))
    save_ply(GaussianModel.from_point_cloud(pc), tmp_path / "point_cloud.ply")
    K = intrinsics_from_fov(64, 64, 60.0)
    camera = {"viewmat": look_at_viewmat([0, 0, 0], [1, 0, 0]).tolist(), "K": K.tolist(), "width": 64, "height": 64}
    (tmp_path / "cameras.json").write_text(json.dumps({"pseudo-label": [camera], "held-out": []}))
    *_, cams, size = script.inputs(str(tmp_path), 1, 0, 32)
    assert size == 32
    torch.testing.assert_close(
        cams[0][1][0], torch.tensor(K, dtype=torch.float32) * torch.tensor([[0.5], [0.5], [1.0]])
    )
    assert script.inputs(str(tmp_path), 1, 0)[-1] == 64
    out = script.main(
        [str(ROOT), "--run", str(tmp_path), "--views", "1", "--size", "32", "--repeats", "1", "--threads", "1"]
    )
    assert out["size"] == 32 and out["outputs_equal"] is True
