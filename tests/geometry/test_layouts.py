import math

import numpy as np
import pytest

from panorecon.geometry import (
    coverage_fraction,
    cube_directions,
    fibonacci_directions,
    icosahedron_face_centres,
    icosahedron_faces,
    icosahedron_vertices,
    latlong_directions,
    make_layout,
)
from panorecon.geometry.layouts import GOLDEN_ANGLE, band_areas, covering_radius_deg


class TestFibonacci:
    @pytest.mark.parametrize("n", [1, 2, 12, 15, 20, 25, 40, 360])
    def test_one_view_per_equal_area_band(self, n):
        # eq. 13: z_i are the midpoints of n equal-area bands of [-1, 1]
        np.testing.assert_array_equal(band_areas(fibonacci_directions(n), n), np.ones(n))

    def test_golden_angle_azimuth_steps(self):
        d = fibonacci_directions(50)
        phi = np.arctan2(d[:, 1], d[:, 0])
        steps = np.mod(np.diff(phi), 2 * np.pi)
        np.testing.assert_allclose(steps, GOLDEN_ANGLE, atol=1e-9)
        assert math.degrees(GOLDEN_ANGLE) == pytest.approx(137.5078, abs=1e-4)

    def test_uniform_on_the_sphere_caps(self):
        # any spherical cap holds a share of points close to its area share (low discrepancy)
        d = fibonacci_directions(4000)
        rng = np.random.default_rng(1)
        for _ in range(20):
            axis = rng.normal(size=3)
            axis /= np.linalg.norm(axis)
            h = rng.uniform(0.2, 1.8)  # cap height; area share = h / 2
            share = (d @ axis > 1 - h).mean()
            assert share == pytest.approx(h / 2, abs=0.01)

    def test_unit_and_refuses_zero(self):
        np.testing.assert_allclose(np.linalg.norm(fibonacci_directions(33), axis=-1), 1, atol=1e-12)
        with pytest.raises(ValueError):
            fibonacci_directions(0)


class TestIcosahedron:
    def test_vertices_are_equidistant_neighbours(self):
        v = icosahedron_vertices()
        assert v.shape == (12, 3)
        cos = v @ v.T
        np.fill_diagonal(cos, -2)
        nearest = np.sort(cos, axis=1)[:, -5:]  # each vertex has exactly 5 nearest neighbours
        np.testing.assert_allclose(nearest, 1 / math.sqrt(5), atol=1e-12)

    def test_faces_are_equilateral_and_outward(self):
        v, f = icosahedron_vertices(), icosahedron_faces()
        assert f.shape == (20, 3) and len(np.unique(np.sort(f, 1), axis=0)) == 20
        edges = np.linalg.norm(v[f] - v[np.roll(f, 1, 1)], axis=-1)
        np.testing.assert_allclose(edges, edges[0, 0], rtol=1e-12)
        n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
        assert (np.einsum("ij,ij->i", n, v[f].mean(1)) > 0).all()
        c = icosahedron_face_centres()
        np.testing.assert_allclose(np.linalg.norm(c, axis=-1), 1)
        # face centres are the vertices of a dodecahedron: covering radius equals the vertices'
        assert covering_radius_deg(c) == pytest.approx(covering_radius_deg(v), abs=0.5)


def test_latlong_and_cube_shapes():
    assert latlong_directions(3, 8).shape == (24, 3)
    c = cube_directions()
    np.testing.assert_array_equal(np.abs(c).sum(1), 1)
    assert make_layout("latlong", 32).n_views == 32


@pytest.mark.parametrize(
    "name,n",
    [
        ("fibonacci", 12),
        ("fibonacci", 20),
        ("fibonacci", 40),
        ("icosahedral", None),
        ("icosahedron-vertices", None),
        ("latlong", None),
        ("cube", None),
    ],
)
def test_default_fov_covers_the_sphere(name, n):
    layout = make_layout(name, n)
    cov = coverage_fraction(layout, height=128)
    assert cov == pytest.approx(1.0, abs=1e-9), f"{name}({layout.n_views}) at {layout.fov_deg:.1f} deg covers {cov:.4f}"


def test_narrow_fov_covers_less():
    full = coverage_fraction(make_layout("fibonacci", 20))
    narrow = coverage_fraction(make_layout("fibonacci", 20, fov_deg=30.0))
    assert narrow < 0.5 * full


def test_unknown_layout_and_fixed_counts():
    with pytest.raises(ValueError, match="unknown layout"):
        make_layout("hexagonal")
    with pytest.raises(ValueError, match="exactly 20"):
        make_layout("icosahedral", 12)
