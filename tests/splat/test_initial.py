import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from panorecon.geometry import PointCloud, erp_directions
from panorecon.scenes import load_scene
from panorecon.splat.initial import (
    disocclusion_fill,
    disocclusion_fill_reference,
    points_for_resolution,
    sky_environment,
    thin_cloud,
    view_background,
)
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


def erp_cloud(distance: np.ndarray, seed: int = 0) -> tuple[PointCloud, np.ndarray]:
    """One point per finite pixel of an ERP distance map [H, W], random colours -> (cloud, colours [H, W, 3])."""
    H, W = distance.shape
    rgb = np.random.default_rng(seed).random((H, W, 3)).astype(np.float32)
    ok = np.isfinite(distance)
    return PointCloud((erp_directions(H, W)[ok] * distance[ok][:, None]).astype(np.float32), rgb[ok]), rgb


def as_layer(fill: PointCloud, H: int, W: int) -> dict:
    """{(row, col): (distance, rgb)} of the fill's points, for comparing with the reference."""
    from panorecon.geometry.sphere import direction_to_erp_pixel

    d = np.linalg.norm(fill.xyz.astype(np.float64), axis=1)
    rows, cols = direction_to_erp_pixel(fill.xyz.astype(np.float64), H, W)
    return {(int(round(r)), int(round(c)) % W): (float(x), tuple(col)) for r, c, x, col in zip(rows, cols, d, fill.rgb)}


def test_a_box_in_front_of_a_wall_gets_the_wall_behind_its_edge():
    """A 4 x 4 box at 1 m in front of a wall at 3 m (ERP 12 x 24: 15 degrees a pixel): with 15 degrees of fill
    the box's outer ring of pixels gets a point at 3 m coloured like the wall pixel next to it; its inner
    2 x 2 pixels and the wall get nothing."""
    H, W = 12, 24
    dist = np.full((H, W), 3.0)
    dist[3:7, 5:9] = 1.0
    pc, rgb = erp_cloud(dist)
    layer = as_layer(disocclusion_fill(pc, H, W, fill_deg=15.0), H, W)
    ring = {(r, c) for r in range(3, 7) for c in range(5, 9)} - {(r, c) for r in range(4, 6) for c in range(6, 8)}
    assert set(layer) == ring
    for (r, c), (d, col) in layer.items():
        assert d == pytest.approx(3.0, rel=1e-6)
        wall = [(rr, cc) for rr, cc in ((r - 1, c), (r + 1, c), (r, c - 1), (r, c + 1)) if dist[rr, cc] == 3.0]
        assert any(np.allclose(col, rgb[w]) for w in wall)
    # with 30 degrees the layer reaches the box's centre: every box pixel has the wall behind it
    assert len(disocclusion_fill(pc, H, W, fill_deg=30.0)) == 16


def test_no_edge_no_fill_and_sky_gives_nothing():
    H, W = 8, 16
    pc, _ = erp_cloud(np.full((H, W), 2.0))
    assert len(disocclusion_fill(pc, H, W)) == 0
    dist = np.full((H, W), 2.0)
    dist[:3] = np.inf  # sky: no point, no distance to extend
    pc, _ = erp_cloud(dist)
    assert len(disocclusion_fill(pc, H, W, fill_deg=90.0)) == 0


def test_fill_wraps_across_the_seam():
    H, W = 8, 16
    dist = np.full((H, W), 4.0)
    dist[3:5, 0] = 1.0  # a post on column 0: its left neighbour is column 15
    pc, _ = erp_cloud(dist)
    layer = as_layer(disocclusion_fill(pc, H, W, fill_deg=22.5), H, W)
    assert set(layer) == {(3, 0), (4, 0)}


def test_bad_fill_arguments_are_one_clear_error():
    pc, _ = erp_cloud(np.full((4, 8), 1.0))
    with pytest.raises(ValueError, match="fill_deg=-1"):
        disocclusion_fill(pc, 4, 8, fill_deg=-1)
    with pytest.raises(ValueError, match="jump=0"):
        disocclusion_fill(pc, 4, 8, jump=0)


@given(seed=st.integers(0, 10_000), fill_deg=st.floats(0, 60), sky=st.booleans())
def test_fill_matches_its_pixel_by_pixel_reference(seed, fill_deg, sky):
    """Random nested boxes at random distances (and a sky band) on a 10 x 20 ERP: the vectorised fill and the
    loop reference give the same layer pixels, distances and colours."""
    H, W = 10, 20
    rng = np.random.default_rng(seed)
    dist = np.full((H, W), rng.uniform(2, 10))
    for _ in range(4):
        r, c = rng.integers(0, H - 2), rng.integers(0, W)
        h, w = rng.integers(1, 5), rng.integers(1, 8)
        dist[r : r + h, (c + np.arange(w)) % W] = rng.uniform(0.5, 10)
    if sky:
        dist[:2] = np.inf
    pc, _ = erp_cloud(dist, seed)
    got = as_layer(disocclusion_fill(pc, H, W, fill_deg), H, W)
    want = disocclusion_fill_reference(pc, H, W, fill_deg)
    assert set(got) == set(want)
    for k, (d, col) in want.items():
        assert got[k][0] == pytest.approx(d, rel=1e-6)
        np.testing.assert_allclose(got[k][1], col, atol=1e-6)


def _zbuffer_one_piece(pc, height, width):
    """``erp_zbuffer`` as a whole-cloud float64 copy, one argsort and one fancy assignment (the reference)."""
    from panorecon.geometry.sphere import direction_to_erp_pixel

    r = np.linalg.norm(pc.xyz.astype(np.float64), axis=1)
    ok = r > 0
    rows, cols = direction_to_erp_pixel(pc.xyz[ok].astype(np.float64), height, width)
    ri = np.clip(np.rint(rows).astype(np.int64), 0, height - 1)
    ci = np.rint(cols).astype(np.int64) % width
    far_first = np.argsort(-r[ok], kind="stable")
    dist = np.full((height, width), np.inf)
    rgb = np.zeros((height, width, 3), np.float32)
    dist[ri[far_first], ci[far_first]] = r[ok][far_first]
    rgb[ri[far_first], ci[far_first]] = pc.rgb[ok][far_first]
    return dist, rgb


@pytest.mark.parametrize("chunk", [1 << 21, 997])
def test_zbuffer_in_chunks_equals_one_piece(monkeypatch, chunk):
    import panorecon.splat.initial as initial

    monkeypatch.setattr(initial, "SPREAD_CHUNK", chunk)
    rng = np.random.default_rng(2)
    d = erp_directions(32, 64).reshape(-1, 3)
    xyz = d * rng.uniform(1, 4, (len(d), 1))
    # several points per pixel, some equally near (the later one wins), and two at the origin
    more = xyz[rng.integers(0, len(d), 3000)] * rng.choice([0.5, 1.0, 2.0], (3000, 1))
    pc = PointCloud(np.concatenate([xyz, more, xyz[:50], np.zeros((2, 3))]), rng.random((len(d) + 3052, 3)))
    got, want = initial.erp_zbuffer(pc, 32, 64), _zbuffer_one_piece(pc, 32, 64)
    np.testing.assert_array_equal(got[0], want[0])
    np.testing.assert_array_equal(got[1], want[1])


def test_fill_points_lie_on_their_erp_pixels_rays():
    from panorecon.splat.initial import erp_zbuffer

    H, W = 16, 32
    dist = np.full((H, W), 6.0)
    dist[5:10, 8:14] = 2.0
    pc, _ = erp_cloud(dist, 0)
    fill = disocclusion_fill(pc, H, W, 30.0)
    layer, _ = erp_zbuffer(fill, H, W)
    at = np.isfinite(layer)
    assert at.sum() == len(fill) > 0
    # each fill point is on erp_directions' ray of its pixel (row-major, as the fill lists them)
    np.testing.assert_allclose(fill.xyz, (erp_directions(H, W)[at] * layer[at][:, None]).astype(np.float32), rtol=1e-6)


def test_directions_of_some_pixels_are_erp_directions_values_to_the_bit():
    """The fill's directions are made for its pixels only (rows and columns from the flat index), not picked from
    the whole grid: the same float64 values."""
    from panorecon.geometry.sphere import erp_pixel_to_lonlat, lonlat_to_direction

    H, W = 48, 96
    at = np.sort(np.random.default_rng(0).choice(H * W, 500, replace=False))
    rows, cols = np.divmod(at, W)
    some = lonlat_to_direction(*erp_pixel_to_lonlat(rows.astype(np.float64), cols.astype(np.float64), H, W))
    np.testing.assert_array_equal(some, erp_directions(H, W).reshape(-1, 3)[at])


def test_fill_in_chunks_of_sources_equals_one_piece(monkeypatch):
    import panorecon.splat.initial as initial

    H, W = 24, 48
    rng = np.random.default_rng(5)
    dist = np.full((H, W), 8.0)
    for _ in range(6):  # nested boxes: ties between neighbours, layers over several steps
        r, c = rng.integers(0, H - 4), rng.integers(0, W)
        dist[r : r + rng.integers(2, 8), (c + np.arange(rng.integers(2, 12))) % W] = rng.choice([1.0, 2.0, 4.0])
    dist[:2] = np.inf
    pc, _ = erp_cloud(dist, 5)
    whole = initial.disocclusion_fill(pc, H, W, 40.0)
    monkeypatch.setattr(initial, "SPREAD_CHUNK", 37)
    chunked = initial.disocclusion_fill(pc, H, W, 40.0)
    assert len(whole) > 50
    np.testing.assert_array_equal(chunked.xyz, whole.xyz)
    np.testing.assert_array_equal(chunked.rgb, whole.rgb)
