"""The fusion's resolution choice and its guided upsampling (fusion/upsample.py) against their references."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.fusion import FusionConfig, fuse_views, pyramid_heights
from panorecon.fusion.lsq import view_supported_height
from panorecon.fusion.upsample import (
    bilinear_upsample_reference,
    guided_upsample,
    guided_upsample_reference,
    snap_to_side,
)
from panorecon.geometry import Layout, centred_camera
from panorecon.metrics import depth_metrics

from .conftest import make_views


@pytest.mark.parametrize("edge_log", [None, np.log(1.5)])
@pytest.mark.parametrize("with_guide", [False, True])
@pytest.mark.parametrize("rows", [1, 5, 256])
def test_banded_guided_upsampling_equals_the_reference(with_guide, rows, edge_log):
    rng = np.random.default_rng(0)
    coarse = (0.3 * rng.standard_normal((8, 16))).astype(np.float32)
    coarse[3, 4] = coarse[0, 0] = np.nan  # unseen pixels, one at the pole row and the seam
    coarse[:, 9:] += 0.8  # a depth edge across the map
    guide = rng.integers(0, 256, (32, 64, 3)).astype(np.uint8) if with_guide else None
    fast = guided_upsample(coarse, guide, 32, 64, edge_log=edge_log, rows=rows)
    ref = guided_upsample_reference(coarse, guide, 32, 64, edge_log=edge_log)
    assert np.array_equal(np.isnan(fast), np.isnan(ref))
    assert np.isnan(fast).any()
    np.testing.assert_allclose(fast[np.isfinite(ref)], ref[np.isfinite(ref)], rtol=2e-6)


def test_bilinear_reference_wraps_at_the_seam_and_keeps_constants():
    coarse = np.zeros((4, 8))
    coarse[:, 0] = 1.0
    up = bilinear_upsample_reference(coarse, 8, 16)
    # the first and the last fine columns lie a quarter coarse pixel from coarse column 0, across the seam
    np.testing.assert_allclose(up[:, 0], 0.75)
    np.testing.assert_allclose(up[:, -1], 0.25)
    np.testing.assert_allclose(bilinear_upsample_reference(np.full((4, 8), 2.5), 16, 32), 2.5)


def test_depth_steps_where_the_colour_steps_at_full_resolution():
    """A wall edge inside a solve-level pixel: bilinear upsampling blends across it, the guided one puts the step
    on the fine colour edge (the fine pixels left of it near, right of it far)."""
    H, W, h, w = 64, 128, 16, 32
    edge = 50  # fine column of the edge, inside coarse column 12 (fine 48..51)
    guide = np.zeros((H, W, 3), np.uint8)
    guide[:, edge:] = 200
    truth = np.where(np.arange(W) < edge, np.log(1.0), np.log(3.0))[None].repeat(H, 0)
    coarse = np.log(np.where(np.arange(w) < edge // 4, 1.0, 3.0))[None].repeat(h, 0)
    coarse[:, edge // 4] = np.log(2.0)  # the mixed coarse pixel: a blend of both sides
    guided = np.log(guided_upsample(coarse, guide, H, W))
    bilinear = np.log(guided_upsample(coarse, None, H, W, edge_log=None))
    band = slice(edge - 6, edge + 6)
    assert np.abs(guided[:, band] - truth[:, band]).mean() < 0.5 * np.abs(bilinear[:, band] - truth[:, band]).mean()


@settings(max_examples=40, deadline=None)
@given(st.floats(-2, 2), st.floats(0.2, 3), st.integers(0, 2**31 - 1))
def test_snapped_values_lie_on_one_side_of_an_edge(q0, jump, seed):
    """Property: where the taps span an edge, the result is within edge_log of a tap (never floating in the
    gap); elsewhere it lies within the taps' range."""
    rng = np.random.default_rng(seed)
    values = rng.normal(0, 0.02, (4, 50))
    values[rng.random((4, 50)) < 0.5] += jump
    weights = rng.random((4, 50))
    weights /= weights.sum(0)
    q = q0 + rng.normal(0, 1, 50)
    out = snap_to_side(q, values, weights, 0.1)
    assert (out >= values.min(0) - 1e-12).all() and (out <= values.max(0) + 1e-12).all()
    spans = values.max(0) - values.min(0) > 0.1
    gap = np.abs(values - out).min(0)
    assert (gap[spans] <= 0.1 + 1e-12).all()


@settings(max_examples=40, deadline=None)
@given(st.floats(-2, 2), st.floats(0.45, 9), st.integers(0, 2**31 - 1))
def test_snapped_values_take_nothing_of_an_unseen_tap(q0, jump, seed):
    """Property: with some taps unseen (their fill value far off), the result is a blend of seen taps on one side
    of any edge: inside the seen taps' range and within edge_log of one of them."""
    rng = np.random.default_rng(seed)
    values = rng.normal(0, 0.02, (4, 50))
    values[rng.random((4, 50)) < 0.5] += jump
    seen = rng.random((4, 50)) < 0.7
    seen[0] = True  # at least one seen tap per pixel
    values[~seen] = 1e3  # an unseen pixel's fill value: nothing of it may leak
    weights = rng.random((4, 50))
    weights /= weights.sum(0)
    out = snap_to_side(q0 + rng.normal(0, 1, 50), values, weights, np.log(1.5), seen)
    lo, hi = np.where(seen, values, np.inf).min(0), np.where(seen, values, -np.inf).max(0)
    assert (out >= lo - 1e-12).all() and (out <= hi + 1e-12).all()
    assert (np.where(seen, np.abs(values - out), np.inf).min(0) <= np.log(1.5) + 1e-12).all()


def test_supported_height_follows_the_views_focal_length(fib20):
    heights = pyramid_heights(2048, None)  # 256 .. 2048 rows (a 4096 px wide panorama)
    two = Layout(fib20.name, fib20.directions[:2], fib20.fov_deg)
    cams = [centred_camera(d, 512, fib20.fov_deg) for d in two.directions]
    views = make_views(two, 512, np.random.default_rng(0))
    assert views[0].camera.K[0, 0] == pytest.approx(cams[0].K[0, 0])
    h, why = view_supported_height(views, heights)
    assert h == 1024 and why["max_height"] == pytest.approx(np.sqrt(2) * np.pi * cams[0].K[0, 0])
    big = make_views(two, 2048, np.random.default_rng(0))
    assert view_supported_height(big, heights)[0] == 2048  # views at full resolution: the finest level runs
    tiny = make_views(two, 16, np.random.default_rng(0))
    assert view_supported_height(tiny, heights)[0] == 256  # never coarser than the coarsest level


def test_views_resolution_skips_unobserved_levels_and_matches_the_full_solve(fib20, box_truth):
    """Views of 24 px on a 128-row panorama resolve ~32 rows: the solve stops there, the upsampled map is as close
    to the truth as the full solve's (the reference) and to it."""
    views = make_views(fib20, 24, np.random.default_rng(1), noise=0.01)
    H = 128
    guide = np.full((H, 2 * H, 3), 128, np.uint8)
    fast = fuse_views(views, H, 2 * H, FusionConfig(tol=1e-6, levels=3), guide=guide)
    full = fuse_views(views, H, 2 * H, FusionConfig(tol=1e-6, levels=3, resolution="full"), guide=guide)
    assert fast.report["resolution"]["solved"] == [32] and fast.report["resolution"]["skipped"] == [64, 128]
    assert [lv["height"] for lv in full.report["levels"]] == [32, 64, 128]
    assert fast.distance.shape == (H, 2 * H) and fast.seen.all()
    truth = box_truth(H)
    e_fast = depth_metrics(fast.distance, truth)["abs_rel"]
    e_full = depth_metrics(full.distance, truth)["abs_rel"]
    assert e_fast < 1.1 * e_full + 1e-3
    assert depth_metrics(fast.distance, full.distance)["abs_rel"] < 0.01


def test_guide_of_the_wrong_size_is_refused(fib20):
    views = make_views(fib20, 24, np.random.default_rng(1))
    with pytest.raises(ValueError, match="guide"):
        fuse_views(views, 64, 128, guide=np.zeros((10, 20, 3), np.uint8))


def test_upsampled_distances_are_finite_where_seen():
    coarse = np.log(np.linspace(0.5, 50, 8 * 16)).reshape(8, 16)
    out = guided_upsample(coarse, None, 64, 128)
    assert np.isfinite(out).all() and (out > 0).all()
