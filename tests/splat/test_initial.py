import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from panorecon.geometry import PointCloud, erp_directions
from panorecon.scenes import load_scene
from panorecon.splat.initial import points_for_resolution, sky_environment, thin_cloud, view_background
from panorecon.splat.labels import make_heldout_views


@pytest.fixture(scope="module")
def beach():
    return load_scene("beach", 128)


def test_sky_environment_keeps_the_sky_and_fills_the_rest_with_the_nearest_sky(beach):
    env = sky_environment(beach)
    rgb = beach.rgb.astype(np.float32) / 255
    assert env.shape == rgb.shape and env.dtype == np.float32 and beach.sky.any() and not beach.sky.all()
    np.testing.assert_array_equal(env[beach.sky], rgb[beach.sky])
    # the first ground pixel under a sky column takes the colour of the sky pixel just above it
    r, c = next(
        (r, c)
        for c in range(beach.width)
        for r in range(1, beach.height)
        if beach.sky[r - 1, c] and not beach.sky[r, c] and beach.sky[r - 1, max(c - 1, 0) : c + 2].all()
    )
    np.testing.assert_allclose(env[r, c], rgb[r - 1, c])
    assert sky_environment(load_scene("bedroom", 64)) is None  # indoors: nothing behind the Gaussians


def test_the_sky_background_matches_the_true_sky_seen_from_off_centre(beach):
    """The sky is at infinity: from a held-out position the environment (sampled by direction only) is the
    true sky colour wherever the true view sees sky."""
    env = sky_environment(beach)
    views = make_heldout_views(beach, 8, 48, seed=0)
    sky_px = [(view_background(env, v.camera), v.rgb, ~np.isfinite(v.depth)) for v in views]
    err = np.concatenate([np.abs(bg - rgb)[sky] for bg, rgb, sky in sky_px])
    assert len(err) > 1000 and err.mean() < 0.03
    # a grey background (what the sky looked like before) is far off
    grey = np.concatenate([np.abs(0.5 - rgb)[sky] for bg, rgb, sky in sky_px])
    assert grey.mean() > 4 * err.mean()
    assert view_background(None, views[0].camera) is None


def test_points_for_resolution():
    assert points_for_resolution(128, 60.0, 4.0) == round(4 * math.pi / (math.pi / 3 / 128) ** 2 / 4)
    assert points_for_resolution(256, 60.0, 4.0) == pytest.approx(4 * points_for_resolution(128, 60.0, 4.0), rel=1e-5)


def test_thinning_an_erp_cloud_spreads_points_evenly_over_the_sphere():
    h = 256
    d = erp_directions(h, 2 * h).reshape(-1, 3) * 3.0  # an ERP cloud on a sphere: crowded at the poles
    pc = PointCloud(d, np.full(d.shape, 0.5))
    out = thin_cloud(pc, 20_000, seed=1)
    assert len(out) == 20_000 and len(np.unique(out.xyz, axis=0)) == 20_000
    z = out.xyz[:, 2] / 3.0
    # equal-area bands (uniform in z): each should hold ~1/8 of the points; the raw ERP cloud does not
    counts = np.histogram(z, bins=8, range=(-1, 1))[0] / len(out)
    assert np.abs(counts - 1 / 8).max() < 0.01
    raw = np.histogram(pc.xyz[:, 2] / 3.0, bins=8, range=(-1, 1))[0] / len(pc)
    assert np.abs(raw - 1 / 8).max() > 0.03
    assert thin_cloud(pc, len(pc) + 1) is pc
    with pytest.raises(ValueError, match="n_points"):
        thin_cloud(pc, 0)


@given(st.integers(1, 60), st.integers(0, 3), st.booleans())
def test_thin_cloud_returns_distinct_points_of_the_cloud(n, seed, with_origin):
    xyz = np.random.default_rng(seed).normal(size=(40, 3))
    if with_origin:
        xyz[0] = 0  # a point at the centre has no direction: it is still drawable
        xyz[1] = [0, 0, 2]  # a pole
    pc = PointCloud(xyz, np.zeros((40, 3)), view_id=np.arange(40))
    out = thin_cloud(pc, n, seed)
    assert len(out) == min(n, 40) and len(set(out.view_id)) == len(out)
    np.testing.assert_array_equal(out.xyz, pc.xyz[out.view_id])
