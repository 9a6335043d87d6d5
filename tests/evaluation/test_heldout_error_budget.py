"""eval/heldout_error_budget.py on a short run: its mean PSNR is the trainer's held-out PSNR (same views, same
frame), shares are fractions, and removing a share's error can only raise the PSNR."""

import importlib.util
from pathlib import Path

import pytest

from panorecon.scenes import load_scene
from panorecon.sources import cloud_scale, run_source
from panorecon.splat.trainer import TrainConfig, train

spec = importlib.util.spec_from_file_location(
    "heldout_error_budget", Path(__file__).parents[2] / "eval" / "heldout_error_budget.py"
)
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("budget")
    scene = load_scene("bedroom", 128)
    pc, report = run_source(scene, "fibonacci", "sim:relative")
    cfg = TrainConfig(iters=30, res=32, labels=16, heldout=4, checkpoint_every=0, history_every=0, backend="cpu")
    metrics = train(scene, pc, cfg, out, progress=False, device="cpu", heldout_scale=cloud_scale(report))
    return out, metrics


def test_budget_reads_the_trainers_heldout_views(run):
    out, metrics = run
    budget = script.main([str(out), "--scene", "bedroom", "--width", "128"])
    assert len(budget["views"]) == 4
    assert budget["psnr"] == pytest.approx(metrics["held-out"]["psnr"], abs=1e-3)
    for key in ("hole_error_share", "depth_off_error_share"):
        assert 0 <= budget[key] <= 1
    assert budget["psnr_without_hole_error"] >= budget["psnr"]
    assert budget["psnr_without_depth_off_error"] >= budget["psnr"]
    assert any(v["depth_off_pixels"] > 0 for v in budget["views"])  # 30 steps at 32² leave geometry to fix
