"""Content-adaptive thinning of the initial cloud (splat/initial.thin_by_detail): fewer, larger Gaussians where
colour and geometry are smooth, the label resolution elsewhere."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial import cKDTree

from panorecon.geometry import PointCloud, erp_directions
from panorecon.splat.initial import site_spread, thin_by_detail, thin_cloud


def _sphere(h: int, radius=3.0, rgb=None) -> PointCloud:
    d = erp_directions(h, 2 * h).reshape(-1, 3)
    return PointCloud(d * radius, np.full((len(d), 3), 0.5) if rgb is None else rgb)


def site_spread_reference(site, n_sites, xyz, rgb) -> dict:
    """``site_spread`` site by site: NumPy's std, and the plane through the site's points as a least-squares fit
    of 1/z to (1, u/z, v/z) in a frame whose z is the mean direction (np.linalg.lstsq)."""
    out = {k: np.full(n_sites, np.nan) for k in ("colour_sd", "depth_sd")}
    out["count"] = np.zeros(n_sites, np.int64)
    for s in range(n_sites):
        m = site == s
        if not m.any():
            continue
        x = xyz[m].astype(np.float64)
        out["count"][s] = len(x)
        out["colour_sd"][s] = rgb[m].astype(np.float64).std(0).max()
        axis = (x / np.linalg.norm(x, axis=1, keepdims=True)).mean(0)
        axis /= np.linalg.norm(axis)
        a = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        e1 = np.cross(axis, a) / np.linalg.norm(np.cross(axis, a))
        e2 = np.cross(axis, e1)
        z = x @ axis
        if (z <= 0).any():
            continue
        A = np.stack([np.ones(len(x)), x @ e1 / z, x @ e2 / z], 1)
        fit = A @ np.linalg.lstsq(A, 1 / z, rcond=None)[0]
        dof = len(x) - 3
        out["depth_sd"][s] = np.sqrt(((1 / z - fit) ** 2).sum() / dof) / (1 / z).mean() if dof > 0 else np.inf
    return out


def test_site_spread_equals_the_per_site_reference():
    rng = np.random.default_rng(0)
    site = rng.integers(0, 40, 2000)
    site[site == 7] = 8  # an empty site: NaN spreads, count 0
    xyz = rng.normal(size=(2000, 3)) * [1.0, 2.0, 0.01] + [100.0, 20.0, 5.0]
    xyz[site == 3] = rng.normal(size=(int((site == 3).sum()), 3))  # around the origin: some behind its mean ray
    rgb = rng.random((2000, 3))
    fast, ref = site_spread(site, 40, xyz, rgb), site_spread_reference(site, 40, xyz, rgb)
    assert fast["count"][7] == 0 and np.isnan(fast["depth_sd"][7]) and np.isnan(fast["depth_sd"][3])
    # points on a plane: no spread, whatever its tilt
    plane = np.concatenate([rng.random((50, 2)) * 4 - 2, np.zeros((50, 1))], 1) @ [[1, 0, 0.3], [0, 1, -0.5], [0, 0, 1]]
    flat = site_spread(np.zeros(50, np.int64), 1, plane + [0.5, 0.2, 7.0], np.zeros((50, 3)))
    assert flat["depth_sd"][0] < 1e-7 and flat["colour_sd"][0] == 0
    normal = np.cross([1, 0, 0.3], [0, 1, -0.5])
    assert abs(flat["normal"][0] @ normal / np.linalg.norm(normal)) == pytest.approx(1, abs=1e-9)
    for k in ref:
        np.testing.assert_allclose(fast[k], ref[k], rtol=1e-7, atol=1e-9, equal_nan=True, err_msg=k)
    assert np.isnan(fast["normal"][[3, 7]]).all() and np.allclose(np.linalg.norm(fast["normal"][:3], axis=1), 1)


def test_without_a_tolerance_it_is_thin_cloud():
    rng = np.random.default_rng(1)
    pc = _sphere(64, rgb=rng.random((64 * 128, 3)))
    out, info = thin_by_detail(pc, 3000, 0.0, 0.01, seed=3)
    np.testing.assert_array_equal(out.xyz, thin_cloud(pc, 3000, seed=3).xyz)
    assert info == {"points": 3000, "points_per_level": {0: 3000}}
    # textured everywhere: no level is smooth, so a tolerance changes nothing either
    np.testing.assert_array_equal(thin_by_detail(pc, 3000, 0.01, 0.01, seed=3)[0].xyz, out.xyz)


def test_a_textureless_sphere_keeps_few_points_that_still_cover_every_direction():
    pc = _sphere(128)
    n = 20_000
    out, info = thin_by_detail(pc, n, 0.005, 0.01)
    assert len(out) * 50 < n and info["points"] == len(out) and info["points_per_level"][0] == 0
    # each coarse point carries its region's plane: on a sphere, about the tangent plane (its normal within the
    # site's angular radius of the kept point's ray)
    u_out = out.xyz / np.linalg.norm(out.xyz, axis=1, keepdims=True)
    assert np.abs(np.einsum("nk,nk->n", out.normals, u_out)).min() > 0.95
    # every direction is within the coarsest spacing (16 x that of n sites) of a kept point
    spacing = np.sqrt(4 * np.pi / n) * 16
    u = out.xyz / np.linalg.norm(out.xyz, axis=1, keepdims=True)
    probe = erp_directions(64, 128).reshape(-1, 3)
    assert cKDTree(u).query(probe)[0].max() < spacing


def test_texture_keeps_its_density_and_smooth_colour_or_geometry_alone_does_not_thin():
    h = 128
    rng = np.random.default_rng(2)
    pc = _sphere(h)
    upper = pc.xyz[:, 2] > 0
    pc.rgb[upper] = rng.random((int(upper.sum()), 3))  # textured above the horizon, one grey below
    n = 20_000
    out, info = thin_by_detail(pc, n, 0.005, 0.01)
    base = thin_cloud(pc, n)
    up_new, up_old = (out.xyz[:, 2] > 0.05).sum(), (base.xyz[:, 2] > 0.05).sum()
    assert abs(up_new - up_old) < 0.05 * up_old  # the textured half as dense as before
    assert (out.xyz[:, 2] < -0.05).sum() * 20 < (base.xyz[:, 2] < -0.05).sum()  # the grey half 20x sparser
    # one grey, but a rough surface (5 % relative bumps): the geometry needs the points
    bumpy = PointCloud(pc.xyz * (1 + 0.05 * rng.standard_normal(len(pc)))[:, None], np.full((len(pc), 3), 0.5))
    assert len(thin_by_detail(bumpy, n, 0.005, 0.01)[0]) > 0.95 * len(thin_cloud(bumpy, n))


def test_bad_tolerances_are_refused():
    with pytest.raises(ValueError, match="colour_tol"):
        thin_by_detail(_sphere(8), 10, -0.1, 0.01)
    with pytest.raises(ValueError, match="n_points"):
        thin_by_detail(_sphere(8), 0, 0.1, 0.01)


@settings(max_examples=30, deadline=None)
@given(
    n=st.integers(1, 400),
    log_scale=st.floats(-3, 3),
    spread=st.floats(0, 1),
    grey=st.booleans(),
    want=st.integers(1, 500),
    seed=st.integers(0, 2**16),
)
def test_any_cloud_thins_to_a_finite_subset(n, log_scale, spread, grey, want, seed):
    """Random clouds from 1e-3 to 1e3 m, near-planar to scattered, one grey or random colours: a finite subset,
    never more points than the cloud."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    r = 10.0**log_scale * (1 + spread * rng.random(n))
    rgb = np.full((n, 3), 0.3) if grey else rng.random((n, 3))
    pc = PointCloud(d * r[:, None], rgb)
    out, info = thin_by_detail(pc, want, 0.01, 0.01, seed=seed)
    assert np.isfinite(out.xyz).all() and len(out) <= len(pc) and info["points"] == len(out)
    if len(pc) <= want:
        assert len(out) == len(pc) or not grey or spread < 1  # coarse levels may merge a smooth cloud
    assert {tuple(p) for p in out.xyz} <= {tuple(p) for p in pc.xyz}
    if out.normals is not None:  # a disc's plane, or 0: never NaN into the model
        norm = np.linalg.norm(out.normals, axis=1)
        assert np.isfinite(out.normals).all() and np.all((np.abs(norm - 1) < 1e-5) | (norm == 0))


def test_site_spread_and_thinning_in_chunks_equal_one_piece(monkeypatch):
    import panorecon.splat.initial as initial

    rng = np.random.default_rng(4)
    pc = _sphere(48)  # grey: smooth but for some depth detail near the north pole
    pc.xyz[:600] *= rng.uniform(0.5, 2.0, (600, 1)).astype(np.float32)
    site = rng.integers(0, 60, len(pc))
    whole = site_spread(site, 60, pc.xyz, pc.rgb)
    thinned, info = thin_by_detail(pc, 2000, 0.05, 0.05, seed=2)
    weights = initial._cos_latitude_weight(pc.xyz)
    monkeypatch.setattr(initial, "SPREAD_CHUNK", 997)  # several chunks, the last one partial
    chunked = site_spread(site, 60, pc.xyz, pc.rgb)
    for k in whole:
        np.testing.assert_allclose(chunked[k], whole[k], rtol=1e-10, atol=1e-12, equal_nan=True, err_msg=k)
    np.testing.assert_array_equal(initial._cos_latitude_weight(pc.xyz), weights)
    again, info_again = thin_by_detail(pc, 2000, 0.05, 0.05, seed=2)
    assert info_again == info and sum(info["points_per_level"].values()) == len(thinned)
    assert info["points_per_level"][0] > 0 and sum(v for k, v in info["points_per_level"].items() if k) > 0
    np.testing.assert_array_equal(again.xyz, thinned.xyz)
