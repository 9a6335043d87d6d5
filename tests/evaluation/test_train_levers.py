"""eval/train_levers.py's ``--teacher-views erp``: the simulated teacher's view distance comes from the ERP (as
for a render folder), while held-out views are still rendered by the world."""

import dataclasses
import importlib.util
from pathlib import Path

import numpy as np

from panorecon.geometry import erp_to_perspective, intrinsics_from_fov, look_at_viewmat
from panorecon.geometry.camera import PinholeCamera
from panorecon.scenes import load_scene
from panorecon.teachers.base import true_view_distance

spec = importlib.util.spec_from_file_location("train_levers", Path(__file__).parents[2] / "eval" / "train_levers.py")
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)


def test_erp_teacher_views_are_sampled_from_the_erp_and_heldout_views_still_render():
    scene = load_scene("bedroom", 128)
    cam = PinholeCamera(intrinsics_from_fov(48, 48, 60.0), look_at_viewmat([0, 0, 0], [1, 0.2, 0]), 48, 48)
    erp_scene = dataclasses.replace(scene, world=script.ErpTeacherWorld(scene.world))
    rendered, _ = true_view_distance(scene, cam)
    sampled, _ = true_view_distance(erp_scene, cam)
    np.testing.assert_array_equal(sampled, erp_to_perspective(scene.distance, cam, "nearest").astype(np.float32))
    assert not np.array_equal(sampled, rendered)  # the world's render is finer than the 128-wide ERP
    np.testing.assert_array_equal(erp_scene.world.render_view(cam).rgb, scene.world.render_view(cam).rgb)
    assert erp_scene.world.free_space_radius() == scene.world.free_space_radius()
