"""What a scene does not need, the trainer leaves out and says so: metrics.json's 'skipped' (stage -> why)."""

import json

import numpy as np

from panorecon.geometry import PointCloud, erp_directions
from panorecon.scenes import load_scene
from panorecon.scenes.base import Scene
from panorecon.sources import run_source
from panorecon.splat.trainer import METRICS_MEANING, TrainConfig, train


def _cfg(**kw):
    return TrainConfig(**{**dict(iters=2, res=16, labels=4, heldout=2, checkpoint_every=0, history_every=0), **kw})


def _grey_sphere(truth: bool) -> Scene:
    h = 32
    return Scene(
        "grey",
        "synthetic" if truth else "real",
        "one grey on a sphere",
        np.full((h, 2 * h, 3), 128, np.uint8),
        np.full((h, 2 * h), 3.0, np.float32) if truth else None,
        np.zeros((h, 2 * h), bool),
        "truth" if truth else "none",
    )


def _sphere_cloud() -> PointCloud:
    d = erp_directions(32, 64).reshape(-1, 3)
    return PointCloud(d * 3.0, np.full((len(d), 3), 0.5))


def _skipped(out):
    m = json.loads((out / "metrics.json").read_text())
    assert m["meaning"] == METRICS_MEANING and "skipped" in m["meaning"]
    return m["skipped"]


def test_a_scene_without_sky_edges_truth_or_teacher_skips_those_stages(tmp_path):
    skipped = _skipped_run(_grey_sphere(truth=False), _sphere_cloud(), tmp_path / "a", depth_fn=None)
    assert skipped == {
        "sky": "the panorama has no sky pixel",
        "disocclusion_fill": "the cloud has no depth edge as seen from the centre",
        "depth_loss": "no teacher depth for the labels",
        "held-out": "scene has no ground-truth world",
        "depth_metrics": "scene 'grey' has no true depth",
    }


def _skipped_run(scene, cloud, out, depth_fn=None, **kw):
    train(scene, cloud, _cfg(**kw), out, depth_fn, progress=False)
    return _skipped(out)


def test_settings_that_turn_a_stage_off_say_so(tmp_path):
    scene = _grey_sphere(truth=True)
    ones = lambda cams: [np.ones((c.height, c.width), np.float32) for c in cams]  # noqa: E731
    skipped = _skipped_run(
        scene, _sphere_cloud(), tmp_path / "a", ones, sky="none", disocclusion_fill_deg=0.0, w_depth=0.0, heldout=0
    )
    assert skipped == {
        "sky": "sky = none",
        "disocclusion_fill": "disocclusion_fill_deg = 0",
        "depth_loss": "w_depth = 0",
        "held-out": "heldout = 0",
    }


def test_a_scene_that_needs_every_stage_skips_none(tmp_path):
    beach = load_scene("beach", 64)  # sky, depth edges, truth, a world for held-out views
    pc, _ = run_source(beach, "fibonacci", "sim:clean")
    ones = lambda cams: [np.ones((c.height, c.width), np.float32) for c in cams]  # noqa: E731
    assert _skipped_run(beach, pc, tmp_path / "b", ones) == {}
