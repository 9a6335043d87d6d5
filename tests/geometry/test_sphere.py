import math

import numpy as np
import pytest
import torch
from hypothesis import given
from hypothesis import strategies as st

from panorecon.geometry import (
    direction_to_erp_pixel,
    direction_to_lonlat,
    erp_directions,
    erp_pixel_solid_angle,
    erp_pixel_to_lonlat,
    erp_z_to_distance_factor,
    lonlat_to_direction,
)


class TestConvention:
    def test_centre_column_looks_along_plus_x(self):
        d = erp_directions(4, 8)
        # the two middle columns straddle lon = 0; their mean at the equator rows is +x
        mid = d[1:3, 3:5].mean((0, 1))
        assert mid[0] > 0.85 and abs(mid[1]) < 1e-9

    def test_row_zero_is_up_and_right_is_minus_y(self):
        d = erp_directions(64, 128)
        assert d[0, :, 2].min() > 0.99
        assert d[-1, :, 2].max() < -0.99
        # moving right of the centre column turns towards -y (not mirrored, seen from inside)
        assert d[32, 80, 1] < 0 and d[32, 48, 1] > 0

    def test_right_handed_z_up(self):
        x, y, z = (
            lonlat_to_direction(np.float64(a), np.float64(b)) for a, b in [(0, 0), (-math.pi / 2, 0), (0, math.pi / 2)]
        )
        np.testing.assert_allclose(np.cross(x, y), z, atol=1e-12)

    def test_unit_norm(self, float_dtype):
        d = erp_directions(33, 66, dtype=float_dtype)
        assert d.dtype == float_dtype
        np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1, atol=1e-6)


class TestRoundTrip:
    @given(st.integers(2, 200).map(lambda h: (h, 2 * h)), st.data())
    def test_pixel_direction_pixel(self, hw, data):
        h, w = hw
        r = data.draw(st.floats(-0.49, h - 0.51))
        c = data.draw(st.floats(-0.49, w - 0.51))
        lon, lat = erp_pixel_to_lonlat(np.float64(r), np.float64(c), h, w)
        r2, c2 = direction_to_erp_pixel(lonlat_to_direction(lon, lat), h, w)
        assert abs(r2 - r) < 1e-6 * h
        # columns are periodic
        assert min(abs(c2 - c), abs(abs(c2 - c) - w)) < 1e-6 * w

    def test_direction_lonlat_any_length(self):
        rng = np.random.default_rng(0)
        d = rng.normal(size=(1000, 3)) * rng.uniform(1e-3, 1e3, size=(1000, 1))
        lon, lat = direction_to_lonlat(d)
        u = lonlat_to_direction(lon, lat)
        np.testing.assert_allclose(u, d / np.linalg.norm(d, axis=-1, keepdims=True), atol=1e-12)

    def test_torch_matches_numpy_and_has_gradients(self):
        lon = torch.linspace(-3, 3, 7, dtype=torch.float64, requires_grad=True)
        lat = torch.linspace(-1.5, 1.5, 7, dtype=torch.float64, requires_grad=True)
        d = lonlat_to_direction(lon, lat)
        np.testing.assert_allclose(d.detach().numpy(), lonlat_to_direction(lon.detach().numpy(), lat.detach().numpy()))
        assert torch.autograd.gradcheck(lambda a, b: lonlat_to_direction(a, b), (lon, lat))
        t = erp_directions(8, 16, like=torch.zeros((), dtype=torch.float64))
        np.testing.assert_allclose(t.numpy(), erp_directions(8, 16), atol=1e-12)


def test_solid_angles_sum_to_sphere():
    for h in (2, 7, 512):
        assert erp_pixel_solid_angle(h, 2 * h).sum() * 2 * h == pytest.approx(4 * math.pi, rel=1e-12)


def _slow_z_factor(h, w):
    """Per pixel: the cube face a ray passes through is its largest |component|; z is the point's
    coordinate along that axis, so distance / z = 1 / |that component|."""
    out = np.empty((h, w))
    dirs = erp_directions(h, w)
    for r in range(h):
        for c in range(w):
            x = dirs[r, c]
            axis = int(np.argmax(np.abs(x)))
            point = 1.0 * x  # the point at distance 1
            out[r, c] = 1.0 / abs(point[axis])
    return out


def test_z_factor_matches_the_per_pixel_reference():
    np.testing.assert_allclose(erp_z_to_distance_factor(12, 24), _slow_z_factor(12, 24), rtol=1e-12)
    f = erp_z_to_distance_factor(64, 128)
    assert f.min() >= 1.0 and f.max() <= np.sqrt(3) + 1e-9


def test_a_distance_read_as_z_is_not_the_same():
    # the distinction matters: a far corner of a cube face differs by up to sqrt(3)
    f = erp_z_to_distance_factor(16, 32)
    assert (f > 1.5).any()


def test_erp_normals_of_a_sphere_are_radial_and_of_a_floor_vertical():
    from panorecon.geometry import erp_normals

    dirs = erp_directions(32, 64)
    n = erp_normals(np.full((32, 64), 3.0))
    inner = n[1:-1]
    np.testing.assert_allclose(np.abs((inner * dirs[1:-1]).sum(-1)), 1.0, atol=1e-5)  # along the ray
    assert np.isnan(n[0]).all() and np.isnan(n[-1]).all()  # the poles' rows have no latitude neighbour
    with np.errstate(divide="ignore"):
        floor = np.where(dirs[..., 2] < -0.1, -1.5 / dirs[..., 2], np.nan)  # the plane z = -1.5 below the centre
    nf = erp_normals(floor)
    ok = np.isfinite(nf).all(-1)
    assert ok.sum() > 0.3 * ok.size
    np.testing.assert_allclose(np.abs(nf[ok][:, 2]), 1.0, atol=1e-5)
    assert not np.isfinite(nf[dirs[..., 2] > 0]).any()  # no surface above the horizon: no normal
    with pytest.raises(ValueError, match="ERP map"):
        erp_normals(np.ones((8, 8)))
