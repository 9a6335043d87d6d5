import numpy as np
import pytest

from panorecon.scenes import load_scene
from panorecon.splat.labels import make_heldout_views, make_pseudo_labels
from panorecon.teachers import get_teacher


@pytest.fixture(scope="module")
def bedroom():
    return load_scene("bedroom", 256)


def test_pseudo_labels_are_views_of_the_panorama_with_teacher_depth(bedroom):
    teacher = get_teacher("sim:relative")
    labels = make_pseudo_labels(
        bedroom, 120, 32, 60.0, depth_fn=lambda cams: [v.depth for v in teacher.predict_views(bedroom, cams)]
    )
    assert len(labels) == 120
    fw = np.stack([lv.camera.forward for lv in labels])
    assert np.allclose(np.linalg.norm(fw, axis=1), 1) and np.abs(fw.mean(0)).max() < 0.05  # spread over the sphere
    lv = labels[7]
    assert lv.rgb.shape == (32, 32, 3) and 0 <= lv.rgb.min() and lv.rgb.max() <= 1
    # the label's colour is the true view's colour up to ERP resampling
    true = bedroom.world.render_view(lv.camera).rgb / 255.0
    assert np.abs(lv.rgb - true).mean() < 0.08
    assert lv.depth.shape == (32, 32) and np.isfinite(lv.depth).mean() > 0.9


def test_heldout_views_are_off_centre_true_renders(bedroom):
    views = make_heldout_views(bedroom, 4, 24, seed=3)
    r = bedroom.world.free_space_radius()
    for v in views:
        d = np.linalg.norm(v.camera.position)
        assert 0.3 * r - 1e-9 <= d <= 0.7 * r + 1e-9
        assert np.isfinite(v.depth).all() and v.rgb.shape == (24, 24, 3)
    a, b = make_heldout_views(bedroom, 2, 24, seed=3), make_heldout_views(bedroom, 2, 24, seed=3)
    np.testing.assert_array_equal(a[1].rgb, b[1].rgb)


def test_heldout_views_at_a_chosen_distance_keep_their_directions(bedroom):
    r = bedroom.world.free_space_radius()
    far = make_heldout_views(bedroom, 3, 16, seed=3)
    centre = make_heldout_views(bedroom, 3, 16, seed=3, radius=(0.0, 0.0))
    near = make_heldout_views(bedroom, 3, 16, seed=3, radius=(0.1, 0.2))
    for f, c, n in zip(far, centre, near):
        assert np.linalg.norm(c.camera.position) == 0.0
        assert 0.1 * r - 1e-9 <= np.linalg.norm(n.camera.position) <= 0.2 * r + 1e-9
        unit = [v.camera.position / np.linalg.norm(v.camera.position) for v in (f, n)]
        np.testing.assert_allclose(unit[0], unit[1], atol=1e-12)  # same draw, another distance
        np.testing.assert_allclose(c.camera.viewmat[:3, :3], f.camera.viewmat[:3, :3], atol=1e-12)
        assert c.covisible.mean() > 0.95  # from the centre the panorama sees every point but at its depth steps
    with pytest.raises(ValueError, match="radius"):
        make_heldout_views(bedroom, 1, 16, radius=(0.5, 0.2))


def test_errors(real_data, bedroom):
    with pytest.raises(ValueError, match="ground-truth world"):
        make_heldout_views(load_scene("py360-demo", 64), 2, 16)
    with pytest.raises(ValueError, match="n_views"):
        make_pseudo_labels(bedroom, 0, 32)


def _room_with_a_pillar(h=128, w=256):
    """A hand-built panorama: a wall 4 m away in every direction, an occluder 1 m away within 25 degrees of +x,
    sky (inf) above 60 degrees of latitude; each pixel's colour is its direction, (d + 1) / 2 (so a colour says
    which direction it was sampled along)."""
    from panorecon.geometry import erp_directions
    from panorecon.scenes.base import Scene

    dirs = erp_directions(h, w)
    distance = np.full((h, w), 4.0, np.float32)
    distance[dirs @ np.array([1.0, 0.0, 0.0]) > np.cos(np.radians(25))] = 1.0
    sky = dirs[..., 2] > np.sin(np.radians(60))
    distance[sky] = np.inf
    rgb = np.round((dirs + 1) / 2 * 255).astype(np.uint8)
    return Scene("pillar", "synthetic", "hand-built", rgb, distance, sky, "truth")


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def test_reprojection_oracle_sees_what_the_panorama_sees_from_its_centre():
    """Each case's co-visibility is known by construction; the oracle's colour must be the panorama's along the
    point's direction from the panorama centre (not along the held-out camera's ray)."""
    from panorecon.splat.labels import COVISIBLE_REL_TOL, reprojection_oracle

    scene = _room_with_a_pillar()
    origin = np.array([0.0, 1.5, 0.0])  # the held-out camera, 1.5 m off the centre
    wall = _unit([-1.0, 1.0, 0.2])
    points = {  # name: (true 3D point, co-visible?)
        "wall": (4.0 * wall, True),
        "behind the pillar": (4.0 * np.array([1.0, 0.0, 0.0]), False),
        "on the pillar": (1.0 * _unit([1.0, 0.1, 0.0]), True),
        "within the tolerance, beyond": (4.19 * wall, True),
        "outside the tolerance, beyond": (4.25 * wall, False),
        "within the tolerance, nearer": (3.82 * wall, True),
        "outside the tolerance, nearer": (3.78 * wall, False),
    }
    assert abs(4.0 - 4.19) <= COVISIBLE_REL_TOL * 4.19 and abs(4.0 - 4.25) > COVISIBLE_REL_TOL * 4.25
    rays = [_unit(x - origin) for x, _ in points.values()]
    dist = [np.linalg.norm(x - origin) for x, _ in points.values()]
    expected = [c for _, c in points.values()]
    up = _unit([0.2, 0.1, 1.0])
    # sky: a ray at infinity is co-visible where the panorama sees sky along the same ray, and only there
    rays += [up, wall, wall]
    dist += [np.inf, np.inf, np.nan]  # sky; "sky" where the panorama sees the wall; unknown depth
    expected += [True, False, False]
    covisible, oracle = reprojection_oracle(scene, origin, np.array(rays)[None], np.array(dist)[None])
    names = [*points, "sky", "sky behind the wall", "unknown"]
    assert dict(zip(names, covisible[0].tolist())) == dict(zip(names, expected))
    assert np.isnan(oracle[0][~covisible[0]]).all() and np.isfinite(oracle[0][covisible[0]]).all()
    for k, (x, seen) in enumerate(points.values()):
        if seen:  # the colour along X / |X| from the centre, one 8-bit step and the bilinear sample off at most
            np.testing.assert_allclose(oracle[0, k], (_unit(x) + 1) / 2, atol=0.02)
            # ... which the held-out camera's own ray would not give (the direction convention matters here)
            assert np.abs((rays[k] + 1) / 2 - (_unit(x) + 1) / 2).max() > 0.1
    np.testing.assert_allclose(oracle[0, len(points)], (up + 1) / 2, atol=0.02)


def test_heldout_views_carry_their_covisible_pixels_and_oracle(bedroom):
    """On a synthetic room the oracle is the truth up to resampling where the panorama sees the point, and
    sampling the panorama along the held-out camera's own rays instead (the wrong direction) is far worse."""
    from panorecon.geometry import sample_erp
    from panorecon.metrics.aligned import masked_psnr

    views = make_heldout_views(bedroom, 4, 48, seed=3)
    fractions = []
    for v in views:
        m = v.covisible
        assert m.shape == (48, 48) and v.mask is None  # the all-pixel score stays the headline
        assert np.isnan(v.oracle[~m]).all() and np.isfinite(v.oracle[m]).all()
        fractions.append(m.mean())
        if m.sum() >= 256:
            wrong = sample_erp(bedroom.rgb, v.camera.world_rays(), "linear").astype(np.float32) / 255.0
            good = masked_psnr(v.oracle, v.rgb, m)
            assert good > 20 and good > masked_psnr(wrong, v.rgb, m) + 5
    # off the centre some of what a view sees is hidden from the panorama (furniture, corners), most is not
    assert 0.3 < np.mean(fractions) < 1 and min(fractions) < 1
