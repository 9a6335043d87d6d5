"""Thinning on the sphere, banded back-projection and the streamed PLY writer (geometry/pointcloud.py)."""

import numpy as np
import pytest

from panorecon.geometry import PointCloud, back_project_erp, erp_directions, thin_on_sphere


def _erp_cloud(h):
    d = erp_directions(h, 2 * h).reshape(-1, 3)
    r = 2.0 + np.sin(3 * d[:, 0])
    return PointCloud(d * r[:, None], np.full((len(d), 3), 0.5))


def test_thinning_keeps_at_most_n_points_evenly_over_the_sphere():
    """An ERP cloud crowds the poles (pixels shrink with cos latitude): the thinned cloud has as many points per
    equal-area band as any other band (within 10 %), and its points are further apart than a random subset's."""
    pc = _erp_cloud(256)
    out, info = thin_on_sphere(pc, 20_000)
    assert 0.97 * 20_000 <= len(out) <= 20_000 and info["points"] == len(out) and info["thinned"]
    assert info["spacing_deg"] == pytest.approx(np.degrees(np.sqrt(4 * np.pi / info["sites"])))
    z = out.xyz[:, 2] / np.linalg.norm(out.xyz, axis=1)
    counts = np.histogram(z, bins=10, range=(-1, 1))[0]  # equal z-intervals are equal areas
    assert counts.min() > 0.9 * counts.max()
    from scipy.spatial import cKDTree

    def spacing(xyz):
        u = xyz / np.linalg.norm(xyz, axis=1, keepdims=True)
        return np.percentile(cKDTree(u).query(u, k=2)[0][:, 1], 1)

    rand = pc.xyz[np.random.default_rng(0).choice(len(pc), len(out), replace=False)]
    assert spacing(out.xyz) > 3 * spacing(rand)
    again, _ = thin_on_sphere(pc, 20_000)
    assert np.array_equal(again.xyz, out.xyz)  # deterministic


def test_thinning_a_partial_cloud_and_small_requests():
    pc = _erp_cloud(64)
    upper = pc.subset(pc.xyz[:, 2] > 0)  # half the sphere: the sites below find no point
    out, info = thin_on_sphere(upper, 1000)
    assert 970 <= len(out) <= 1000 and (out.xyz[:, 2] > 0).all()
    assert thin_on_sphere(pc, len(pc))[0] is pc
    assert len(thin_on_sphere(pc, 1)[0]) == 1
    with pytest.raises(ValueError, match="n_points"):
        thin_on_sphere(pc, 0)


def test_banded_back_projection_equals_the_whole_map():
    rng = np.random.default_rng(0)
    h = 40
    dist = rng.uniform(0.5, 9, (h, 2 * h)).astype(np.float32)
    keep = rng.random((h, 2 * h)) > 0.3
    rgb = rng.integers(0, 256, (h, 2 * h, 3)).astype(np.uint8)
    fwd = rng.normal(size=(5, 3))
    xyz, col, vid = back_project_erp(dist, keep, rgb, fwd, rows=7)
    d = erp_directions(h, 2 * h)[keep]
    np.testing.assert_allclose(xyz, d * dist[keep][:, None], rtol=1e-6, atol=1e-6)
    np.testing.assert_array_equal(col, rgb[keep] / np.float32(255))
    np.testing.assert_array_equal(vid, np.argmax(d @ fwd.T, axis=1))


def _nearest_per_site_by_sort(site, cos):
    """Reference: sort by (site, -cos) and keep each site's first point."""
    order = np.lexsort((np.arange(len(site)), -cos, site))
    first = np.ones(len(order), bool)
    first[1:] = site[order[1:]] != site[order[:-1]]
    return order[first]


@pytest.mark.parametrize("n, n_sites, levels", [(50_000, 1_000, None), (20_000, 5_000, 7), (10, 3, 2), (1, 1, None)])
def test_nearest_per_site_equals_the_sort(n, n_sites, levels):
    """The O(N) per-site maximum picks the same point per site as sorting by (site, -cos) with ties to the lowest
    index (``levels``: cos quantized to a few values, so ties are common); sites without a point give none."""
    from panorecon.geometry.pointcloud import nearest_per_site

    rng = np.random.default_rng(n)
    site = rng.integers(0, n_sites, n)
    cos = rng.random(n) if levels is None else rng.integers(0, levels, n) / levels
    fast = nearest_per_site(site, cos, n_sites)
    assert np.array_equal(fast, _nearest_per_site_by_sort(site, cos))
    assert len(fast) == len(np.unique(site))
