"""eval/train_levers.py's ``--teacher-views erp``: the simulated teacher's view distance comes from the ERP (as
for a render folder), while held-out views are still rendered by the world; ``--heldout-seed``: the held-out views
of one seed whatever the training's."""

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


def test_heldout_seed_fixes_the_views_whatever_the_runs_seed():
    from panorecon.splat import trainer
    from panorecon.splat.labels import make_heldout_views

    scene = load_scene("bedroom", 128)
    ref = make_heldout_views(scene, 2, 16, 60.0, 0)
    with script.heldout_views_seeded(0):
        fixed = trainer.make_heldout_views(scene, 2, 16, 60.0, 5)
    own = trainer.make_heldout_views(scene, 2, 16, 60.0, 5)  # restored on exit
    for a, b in zip(ref, fixed):
        np.testing.assert_array_equal(a.camera.viewmat, b.camera.viewmat)
        np.testing.assert_array_equal(a.rgb, b.rgb)
    assert not np.array_equal(own[0].camera.viewmat, ref[0].camera.viewmat)
