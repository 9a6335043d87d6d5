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


@pytest.fixture(scope="module")
def space(tmp_path_factory):
    """bedroom's panoramas at the origin and at OFFSET, written as two Stanford2D3D panoramas (world frame
    shifted by ORIGIN), and the dataset scene of the first."""
    root, origin = tmp_path_factory.mktemp("s2d3d"), np.array([4.0, -2.0, 1.0])
    world = load_scene("bedroom", 256).world
    for i, off in enumerate((np.zeros(3), OFFSET)):
        r = world.render_erp(128, off)
        base, pano = root / "area_1" / "pano", f"camera_{i:032x}_room_1_{i}_frame_equirectangular_domain"
        write_image(base / "rgb" / f"{pano}_rgb.png", r.rgb)
        (base / "depth").mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(base / "depth" / f"{pano}_depth.png"), np.round(r.distance * 512).astype(np.uint16))
        (base / "pose").mkdir(parents=True, exist_ok=True)
        (base / "pose" / f"{pano}_pose.json").write_text(json.dumps({"camera_location": (origin + off).tolist()}))
    return world, load_scene(f"stanford2d3d:{root}/area_1/camera_{0:032x}_room_1_0")


def test_views_match_the_world_where_the_mask_says_covisible(space):
    world, scene = space
    pans = heldout_panoramas(scene)
    assert len(pans) == 1 and np.allclose(pans[0][0], OFFSET, atol=1e-9)
    views = make_panorama_heldout_views(scene, pans, 6, 48, 60.0, seed=1)
    fractions = []
    for v in views:
        truth = world.render_view(v.camera)
        np.testing.assert_allclose(v.camera.position, OFFSET, atol=1e-9)
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
