"""Held-out views from a dataset space's other panoramas, checked against the synthetic world they came from."""

import json

import cv2
import numpy as np
import pytest

from panorecon.io import write_image
from panorecon.scenes import load_scene
from panorecon.scenes.datasets import heldout_panoramas
from panorecon.splat.labels import make_panorama_heldout_views

OFFSET = np.array([0.5, 0.3, 0.0])


ROLL = 77  # columns: the held-out panorama is turned against the training one (its own orientation)


@pytest.fixture(scope="module")
def space(tmp_path_factory):
    """bedroom's panoramas at the origin and at OFFSET, written as two Stanford2D3D panoramas (world frame
    shifted by ORIGIN; the second one's image turned by ROLL columns, its global_xyz saying so), and the dataset
    scene of the first."""
    from panorecon.geometry import erp_directions

    from ..scenes.conftest import write_exr_xyz

    root, origin = tmp_path_factory.mktemp("s2d3d"), np.array([4.0, -2.0, 1.0])
    world = load_scene("bedroom", 256).world
    for i, off in enumerate((np.zeros(3), OFFSET)):
        r = world.render_erp(128, off)
        xyz = origin + off + r.distance[..., None] * erp_directions(128, 256)
        roll = ROLL * i
        base, pano = root / "area_1" / "pano", f"camera_{i:032x}_room_1_{i}_frame_equirectangular_domain"
        write_image(base / "rgb" / f"{pano}_rgb.png", np.roll(r.rgb, roll, 1))
        (base / "depth").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(
            str(base / "depth" / f"{pano}_depth.png"), np.roll(np.round(r.distance * 512), roll, 1).astype(np.uint16)
        )
        (base / "pose").mkdir(parents=True, exist_ok=True)
        (base / "pose" / f"{pano}_pose.json").write_text(json.dumps({"camera_location": (origin + off).tolist()}))
        write_exr_xyz(base / "global_xyz" / f"{pano}_global_xyz.exr", np.roll(xyz, roll, 1))
    return world, load_scene(f"stanford2d3d:{root}/area_1/camera_{0:032x}_room_1_0")


def test_views_match_the_world_where_the_mask_says_covisible(space):
    world, scene = space
    pans = heldout_panoramas(scene)
    assert len(pans) == 1 and np.allclose(pans[0][0], OFFSET, atol=2e-3)
    turn = 2 * np.pi * ROLL / 256  # the held-out panorama's frame is turned by ROLL columns about +z
    np.testing.assert_allclose(
        pans[0][1], [[np.cos(turn), np.sin(turn), 0], [-np.sin(turn), np.cos(turn), 0], [0, 0, 1]], atol=2e-3
    )
    views = make_panorama_heldout_views(scene, pans, 6, 48, 60.0, seed=1)
    fractions = []
    for v in views:
        truth = world.render_view(v.camera)
        np.testing.assert_allclose(v.camera.position, OFFSET, atol=2e-3)
        m = v.mask
        fractions.append(m.mean())
        assert m.any() and np.isfinite(v.depth[m]).all() and np.isnan(v.depth[~m]).all()
        assert np.median(np.abs(v.depth[m] / truth.depth_z[m] - 1)) < 0.01
        mse = np.mean((v.rgb[m] - truth.rgb[m] / 255.0) ** 2)
        assert 10 * np.log10(1 / mse) > 18
        # a masked-in pixel's true point is what the training panorama sees along its direction
        x = OFFSET + v.camera.world_rays()[m] * truth.distance[m][:, None]
        from panorecon.geometry import sample_erp

        seen = sample_erp(scene.distance, (x / np.linalg.norm(x, axis=1, keepdims=True))[None], "nearest")[0]
        assert np.median(np.abs(seen / np.linalg.norm(x, axis=1) - 1)) < 0.02
    assert 0.3 < np.mean(fractions) < 1.0  # a room seen from 0.6 m away: most but not all of it


def test_training_scores_held_out_panoramas(space, tmp_path):
    from panorecon.splat.trainer import TrainConfig, train

    _, scene = space
    m = train(scene, scene.point_cloud(), TrainConfig(iters=10, labels=6, res=32, heldout=3), tmp_path, progress=False)
    held = m["held-out"]
    assert isinstance(held["psnr"], float) and held["ssim"].startswith("n/a") and 0 < held["covisible_fraction"] < 1
    # beside the raw number: the colour-aligned render and the reprojection oracle, raw and aligned, labelled
    for key in ("aligned_psnr", "oracle_psnr", "oracle_aligned_psnr"):
        assert isinstance(held[key], float) and held[f"{key}_views"] == held["views"] and key in held["meaning"]
    assert held["oracle_psnr"] <= held["oracle_aligned_psnr"]
    # the gaps to the oracle, on the same pixels as the raw (and the aligned) score
    assert held["covisible_psnr"] == pytest.approx(held["psnr"], abs=1e-3)  # float64 sums against float32
    assert held["oracle_gap"] == pytest.approx(held["oracle_psnr"] - held["covisible_psnr"])
    assert held["oracle_aligned_gap"] == pytest.approx(held["oracle_aligned_psnr"] - held["aligned_psnr"])
    # 32 px views: 22 x 22 SSIM windows at most, n/a below 256 of them wholly co-visible
    assert isinstance(held["aligned_ssim"], float) or "SSIM windows" in held["aligned_ssim"]
    # LPIPS only over the views whose every pixel is co-visible (n/a when none is)
    if isinstance(held["aligned_lpips"], float):
        assert 0 <= held["aligned_lpips"] <= 1 and 1 <= held["aligned_lpips_views"] <= held["views"]
    else:
        assert held["aligned_lpips"].startswith("n/a: ") and held["aligned_lpips_views"] == 0
    saved = json.loads((tmp_path / "metrics.json").read_text())["held-out"]
    assert saved["aligned_psnr"] == held["aligned_psnr"] and saved["meaning"]["psnr"].startswith("raw")

    import pandas as pd

    from panorecon.evaluation.ablate import result_row
    from panorecon.evaluation.report import average_table, markdown_table
    from panorecon.pipeline import Row

    row = Row(scene.name, 128, "fibonacci", "sim:relative", label="s2d3d")
    pts = {"report": {"depth": {}, "points": {}, "seconds": {}}, "seconds": 1.0, "peak_rss_mb": 1.0}
    rec = result_row(row, pts, {"metrics": m, "seconds": 1.0, "peak_rss_mb": 1.0}, {"versions": {}}, False, False)
    assert rec["psnr_ho"] == held["psnr"] and rec["heldout_aligned_psnr"] == held["aligned_psnr"]
    assert rec["heldout_oracle_psnr"] == held["oracle_psnr"]
    for key in ("covisible_psnr", "oracle_gap", "covisible_fraction", "oracle_aligned_gap"):
        assert rec[f"heldout_{key}"] == held[key]
    for key in ("aligned_ssim", "aligned_lpips"):  # a number, or NaN with the reason in its note column
        if isinstance(held[key], float):
            assert rec[f"heldout_{key}"] == held[key]
        else:
            assert np.isnan(rec[f"heldout_{key}"]) and rec[f"heldout_{key}_note"] == held[key]
    table = markdown_table(average_table(pd.DataFrame([rec])), "label")
    assert "held-out PSNR, colour-aligned" in table and "oracle PSNR (ceiling)" in table
    assert f"{held['aligned_psnr']:.2f}" in table and f"{held['oracle_psnr']:.2f}" in table
    assert "gap to oracle (dB)" in table and f"{held['oracle_gap']:.2f}" in table


def test_min_covisible_pixels_is_the_line():
    from panorecon.geometry import centred_camera
    from panorecon.splat.labels import MIN_COVISIBLE_PIXELS, LabelView, covisible_shortfall

    def view(n):
        m = np.zeros((32, 32), bool)
        m.flat[:n] = True
        return LabelView(centred_camera(np.array([1.0, 0, 0]), 32, 60.0), np.zeros((32, 32, 3), np.float32), None, m)

    assert covisible_shortfall([view(MIN_COVISIBLE_PIXELS - 1), view(3)]).startswith(
        f"n/a: no held-out view has {MIN_COVISIBLE_PIXELS}"
    )
    assert covisible_shortfall([view(MIN_COVISIBLE_PIXELS - 1), view(MIN_COVISIBLE_PIXELS)]) is None
    assert covisible_shortfall([]) is None


def test_no_covisible_pixel_reads_na_everywhere(tmp_path):
    """Two Structured3D rooms that see nothing of each other: metrics.json's held-out, heldout_best and
    heldout_plateau, the history and the results.csv row all say the same n/a, and no number computed on nothing
    appears anywhere."""
    from panorecon.evaluation.ablate import result_row
    from panorecon.pipeline import Row
    from panorecon.splat.trainer import TrainConfig, train

    from ..scenes.conftest import FAR_ROOM, write_structured3d_room

    c = np.array([1.2, 1.0, 1.5])
    write_structured3d_room(tmp_path, "scene_00000", 1, c, 64)
    write_structured3d_room(tmp_path, "scene_00000", 2, c + [9.0, 0, 0], 64, room_box=FAR_ROOM)
    scene = load_scene(f"structured3d:{tmp_path}/scene_00000/1")
    assert len(heldout_panoramas(scene)) == 1
    cfg = TrainConfig(iters=10, labels=6, res=32, heldout=3, history_every=5)
    m = train(scene, scene.point_cloud(), cfg, tmp_path / "run", progress=False)
    na = m["held-out"]["psnr"]
    assert na.startswith("n/a: no held-out view has") and m["held-out"]["pixels"] == 0
    assert m["heldout_best"] == m["heldout_plateau"] == na
    assert len(m["history"]) == 2 and all("heldout_psnr" not in h for h in m["history"])
    saved = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert saved["heldout_best"] == saved["held-out"]["psnr"] == na
    row = Row(scene.name, 128, "fibonacci", "sim:relative", label="s3d")
    pts = {"report": {"depth": {}, "points": {}, "seconds": {}}, "seconds": 1.0, "peak_rss_mb": 1.0}
    rec = result_row(row, pts, {"metrics": m, "seconds": 1.0, "peak_rss_mb": 1.0}, {"versions": {}}, False, False)
    assert np.isnan(rec["psnr_ho"]) and rec["psnr_ho_note"] == na and rec["history_heldout"] is None
    assert np.isnan(rec["heldout_aligned_psnr"]) and rec["heldout_aligned_psnr_note"] == na
    for key in ("oracle_psnr", "covisible_psnr", "oracle_gap", "oracle_aligned_gap"):
        assert np.isnan(rec[f"heldout_{key}"]) and rec[f"heldout_{key}_note"] == na
