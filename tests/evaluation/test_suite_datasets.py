"""Suites on real panoramas with true depth: depth keys, {root} and dataset scene patterns, a row end to end."""

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from panorecon.evaluation.suite import load_suite
from panorecon.io import PanoreconInputError, write_image
from panorecon.pipeline import Row, StageCache, run_points
from panorecon.pipeline.cache import stage_key
from panorecon.pipeline.stages import POINTS_CODE
from panorecon.scenes import load_scene
from panorecon.teachers import teacher_fingerprint

REAL_GT = Path(__file__).parents[2] / "eval" / "suites" / "real_gt.toml"


@pytest.fixture(scope="module")
def root(tmp_path_factory):
    """Two Stanford2D3D panoramas of bedroom (area_3) in the dataset's layout, and a capture (pano.png, depth.png)."""
    root = tmp_path_factory.mktemp("s2d3d")
    world = load_scene("bedroom", 32).world
    for i, pos in enumerate(([0.0, 0, 0], [0.3, 0, 0])):
        r = world.render_erp(16, np.array(pos))
        base, pano = root / "area_3" / "pano", f"camera_{i:032x}_office_1_{i}_frame_equirectangular_domain"
        write_image(base / "rgb" / f"{pano}_rgb.png", r.rgb)
        (base / "depth").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(base / "depth" / f"{pano}_depth.png"), np.round(r.distance * 512).astype(np.uint16))
        (base / "pose").mkdir(parents=True, exist_ok=True)
        (base / "pose" / f"{pano}_pose.json").write_text(json.dumps({"camera_location": pos}))
    write_image(root / "pano.png", r.rgb)
    cv2.imwrite(str(root / "depth.png"), np.round(r.distance * 1000).astype(np.uint16))
    return root


def test_real_gt_suite_expands_the_root(root, monkeypatch):
    monkeypatch.delenv("PANORECON_DATASET_ROOT", raising=False)
    with pytest.raises(PanoreconInputError, match="needs the dataset root: give --root DIR or set"):
        load_suite(REAL_GT)
    suite = load_suite(REAL_GT, str(root))
    scenes = sorted({r.scene for r in suite.rows})
    assert len(scenes) == 2 and all(s.startswith(f"stanford2d3d:{root}/area_3/camera_") for s in scenes)
    assert {r.source for r in suite.rows} >= {"fibonacci", "cube", "erp-direct", "random", "colmap-sfm"}
    assert {r.teacher for r in suite.rows} == {"sim:clean", "sim:relative", "sim:affine-disparity"}
    monkeypatch.setenv("PANORECON_DATASET_ROOT", str(root))
    assert len(load_suite(REAL_GT).rows) == len(suite.rows)


def test_depth_keys_and_a_row_end_to_end(root, tmp_path):
    (tmp_path / "s.toml").write_text(
        "[defaults]\nwidth = 32\nsource = 'fibonacci'\nteacher = 'sim:relative'\nviews = 12\ntrain = false\n"
        "depth = '{root}/depth.png'\ndepth_scale = 0.001\n[grid]\nscene = ['{root}/pano.png']\n"
    )
    (row,) = load_suite(tmp_path / "s.toml", str(root)).rows
    assert row.depth == (f"{root}/depth.png", 0.001, "distance") and row.scene == f"{root}/pano.png"
    rec = run_points(StageCache(tmp_path / "cache"), row)
    assert rec["report"]["depth"]["abs_rel"] < 0.1 and isinstance(rec["report"]["points"]["fscore"], float)
    # depth enters the key; a row without depth keeps the key it always had (the simulated teacher is seeded, so
    # its seed is in the key; a seed-independent stage's key has no seed)
    plain = Row(row.scene, row.width, row.source, row.teacher, row.views)
    assert plain.points_key() != row.points_key()
    params = {"scene": row.scene, "width": 32, "source": "fibonacci", "teacher": "sim:relative", "views": 12}
    # today's fusion defaults are not the values that behave as before they existed, so they are in the key
    params["fusion"] = {"edge_jump": math.log(1.5), "edge_reach": 3, "affine_gauge": "reference"}
    assert plain.points_key() == stage_key("points", {**params, "seed": 0}, code=POINTS_CODE)
    unseeded = Row(row.scene, row.width, "fibonacci", "oracle", row.views)
    assert unseeded.points_key() == stage_key(
        "points", {**params, "teacher": teacher_fingerprint("oracle")}, code=POINTS_CODE
    )
    # a multi-view baseline needs a world to render panoramas around the centre: the row reads n/a
    colmap = Row(f"stanford2d3d:{root}/area_3/camera_{0:032x}_office_1_0", 32, "colmap-sfm", None, train=None)
    assert run_points(StageCache(tmp_path / "cache"), colmap)["unavailable"].startswith("n/a: scene")


@pytest.mark.parametrize(
    "text,match",
    [
        ("[grid]\nscene = ['p.png']\nsource = ['random']\n[defaults]\ndepth_scale = 2.0", "without a depth file"),
        ("[grid]\nscene = ['stanford2d3d:{root}/area_9/*']\nsource = ['random']", "no stanford2d3d panorama"),
    ],
)
def test_bad_dataset_suites(root, tmp_path, text, match):
    (tmp_path / "s.toml").write_text(text)
    with pytest.raises(PanoreconInputError, match=match):
        load_suite(tmp_path / "s.toml", str(root))
