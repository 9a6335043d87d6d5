"""Off-centre pseudo-labels (splat/offcentre.py): the depth splat against its per-point reference, the warp against
the held-out views' reprojection oracle when given the true geometry, the cameras' placement, and the trainer's
masked loss (no gradient from a masked pixel)."""

import numpy as np
import pytest
import torch

from panorecon.geometry import PointCloud, centred_camera
from panorecon.geometry.sphere import erp_directions
from panorecon.scenes import load_scene
from panorecon.splat import offcentre as oc
from panorecon.splat import trainer as trainer_mod
from panorecon.splat.labels import make_heldout_views
from panorecon.splat.losses import l1
from panorecon.splat.model import nearest_neighbour_scale
from panorecon.splat.trainer import TrainConfig, train


@pytest.fixture(scope="module")
def bedroom():
    return load_scene("bedroom", 128)


def _true_cloud(scene) -> PointCloud:
    """The panorama lifted with its true distance (no sky in the bedroom)."""
    d = scene.distance
    xyz = erp_directions(*d.shape) * d[..., None]
    return PointCloud(xyz.reshape(-1, 3), scene.rgb.reshape(-1, 3) / 255.0)


def test_the_depth_splat_is_its_per_point_reference(bedroom, monkeypatch):
    cloud = _true_cloud(bedroom)
    spacing = nearest_neighbour_scale(cloud.xyz)
    for cam in oc.offcentre_cameras(cloud.xyz, 3, 24, 60.0, 0.7, seed=4):
        fast = oc.splat_depth(cloud.xyz, spacing, cam)
        np.testing.assert_array_equal(fast, oc.splat_depth_reference(cloud.xyz, spacing, cam))
        assert np.isfinite(fast).mean() > 0.95  # footprints close the gaps between the points
    # a point's square grows with its footprint: one point 1 m ahead, spacing of 3 pixels there -> 3 x 3 pixels
    cam = centred_camera(np.array([0.0, 1.0, 0.0]), 16, 60.0)
    forward = cam.rotation_c2w[:, 2]
    f = cam.K[0, 0]
    z = oc.splat_depth(forward[None], np.array([3 / f]), cam)
    assert np.isfinite(z).sum() == 9 and np.nanmin(z) == pytest.approx(1.0)


def test_with_the_true_geometry_the_warp_is_the_held_out_oracle(bedroom):
    """The warp is the held-out views' reprojection oracle with the cloud in place of the truth: with the
    truth's cloud, on the held-out cameras, it gives the oracle's colours on (almost) the oracle's pixels."""
    cloud = _true_cloud(bedroom)
    spacing = nearest_neighbour_scale(cloud.xyz)
    distance = oc.erp_distance(cloud, *bedroom.rgb.shape[:2])
    np.testing.assert_allclose(distance, bedroom.distance, rtol=1e-5)  # one point per ERP pixel, its own
    for v in make_heldout_views(bedroom, 3, 32, 60.0, seed=0):
        rgb, mask = oc.warp_panorama(bedroom.rgb, distance, cloud.xyz, spacing, v.camera)
        both = mask & v.covisible
        assert both.sum() >= 0.9 * v.covisible.sum() and both.sum() >= 0.9 * mask.sum()
        # the same colours where both use the same 3D point (depth from the splat against the true ray's)
        err = np.abs(rgb - v.oracle)[both].max(-1)
        assert np.median(err) < 0.01 and np.mean(err < 0.05) > 0.9


def test_the_cameras_stand_inside_the_free_space_and_follow_the_seed(bedroom):
    cloud = _true_cloud(bedroom)
    r_free = oc.free_space_radius(cloud.xyz)
    assert 0 < r_free < np.nanmin(bedroom.distance) * 1.5
    cams = oc.offcentre_cameras(cloud.xyz, 50, 16, 60.0, 0.7, seed=1)
    positions = np.array([c.position for c in cams])
    assert np.linalg.norm(positions, axis=1).max() <= 0.7 * r_free + 1e-9
    assert np.linalg.norm(positions, axis=1).max() > 0.5 * r_free  # the ball, not its centre alone
    again = oc.offcentre_cameras(cloud.xyz, 50, 16, 60.0, 0.7, seed=1)
    assert all(np.array_equal(a.viewmat, b.viewmat) for a, b in zip(cams, again))
    other = oc.offcentre_cameras(cloud.xyz, 50, 16, 60.0, 0.7, seed=2)
    assert not np.array_equal(cams[0].viewmat, other[0].viewmat)
    # scale-free: the same cloud 1000x larger gives the same cameras 1000x further out
    big = oc.offcentre_cameras(cloud.xyz * 1000, 50, 16, 60.0, 0.7, seed=1)
    np.testing.assert_allclose(np.array([c.position for c in big]), positions * 1000, rtol=1e-6)


def test_an_off_centre_labels_masked_pixels_take_the_render_as_target_and_give_no_l1_gradient(
    bedroom, tmp_path, monkeypatch
):
    cloud = _true_cloud(bedroom)
    seen = []
    real = trainer_mod.total_loss

    def spy(render, target, *a, **k):
        seen.append((render.detach().clone(), target.detach().clone()))
        return real(render, target, *a, **k)

    monkeypatch.setattr(trainer_mod, "total_loss", spy)
    cfg = TrainConfig(iters=30, res=24, labels=6, heldout=0, offcentre_labels=30, checkpoint_every=0, history_every=10)
    metrics = train(bedroom, cloud, cfg, tmp_path / "run", progress=False)
    assert np.isfinite(metrics["pseudo-label"]["psnr"])
    offcentre_steps = [(r, t) for r, t in seen if bool((r == t).all(-1).any())]
    assert offcentre_steps  # an off-centre view was drawn, and its masked pixels carry the render itself
    for r, t in offcentre_steps:
        equal = (r == t).all(-1)
        assert 0 < equal.float().mean() < 0.5  # some pixels masked, most not
        x = r.clone().requires_grad_()
        (g,) = torch.autograd.grad(l1(x, t), x)
        assert (g[equal] == 0).all() and (g[~equal] != 0).any()
