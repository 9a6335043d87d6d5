"""Camera layouts on the sphere: where the perspective views of a panorama look.

Every layout returns unit directions [N, 3] (float64, world frame of ``sphere.py``) and a
``Layout`` carries them with the field of view the views use by default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .sphere import erp_directions, erp_pixel_solid_angle, lonlat_to_direction

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))  # radians, ~137.508 degrees


def fibonacci_directions(n: int) -> np.ndarray:
    """Spherical Fibonacci lattice (paper eq. 13), [n, 3].

    z_i = 1 - (2i + 1) / n is the midpoint of the i-th of n equal-area bands of [-1, 1] (by Archimedes,
    equal z-intervals cover equal area), and phi_i = i * golden angle spreads azimuths evenly.
    """
    if n < 1:
        raise ValueError(f"fibonacci_directions: n={n}, expected at least 1 view")
    i = np.arange(n, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / n
    r = np.sqrt(np.clip(1.0 - z * z, 0.0, None))
    phi = i * GOLDEN_ANGLE
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], -1)


def icosahedron_vertices() -> np.ndarray:
    """The 12 unit vertices of a regular icosahedron with two vertices at the poles, [12, 3]."""
    lat = math.atan(0.5)  # the two rings of five sit at +-atan(1/2)
    dirs = [np.array([0.0, 0.0, 1.0])]
    for k in range(5):
        dirs.append(lonlat_to_direction(np.float64(2 * math.pi * k / 5), np.float64(lat)))
    for k in range(5):
        dirs.append(lonlat_to_direction(np.float64(2 * math.pi * (k + 0.5) / 5), np.float64(-lat)))
    dirs.append(np.array([0.0, 0.0, -1.0]))
    return np.stack(dirs)


def icosahedron_faces() -> np.ndarray:
    """Vertex indices [20, 3] of the icosahedron's faces, counter-clockwise seen from outside."""
    faces = []
    for k in range(5):
        a, b = 1 + k, 1 + (k + 1) % 5  # upper ring
        c, d = 6 + k, 6 + (k + 1) % 5  # lower ring (offset by half a step)
        faces += [(0, b, a), (a, b, c), (b, d, c), (11, c, d)]
    faces = np.array(faces, dtype=np.int64)
    v = icosahedron_vertices()
    # orient every face outward
    n = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    flip = np.einsum("ij,ij->i", n, v[faces].mean(1)) < 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces


def icosahedron_face_centres() -> np.ndarray:
    """Unit directions to the 20 face centres of the icosahedron (360MonoDepth's tangent images), [20, 3]."""
    c = icosahedron_vertices()[icosahedron_faces()].mean(1)
    return c / np.linalg.norm(c, axis=-1, keepdims=True)


def latlong_directions(n_lat: int, n_lon: int) -> np.ndarray:
    """A latitude-longitude grid of n_lat rings x n_lon azimuths at ring midpoints, [n_lat * n_lon, 3]."""
    if n_lat < 1 or n_lon < 1:
        raise ValueError(f"latlong_directions: n_lat={n_lat}, n_lon={n_lon}, expected both >= 1")
    lat = (0.5 - (np.arange(n_lat) + 0.5) / n_lat) * math.pi
    lon = (np.arange(n_lon) / n_lon - 0.5) * 2 * math.pi
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    return lonlat_to_direction(lo.ravel(), la.ravel())


def cube_directions() -> np.ndarray:
    """The six cube-face directions: front (+x), right (-y), back, left, up, down, [6, 3]."""
    return np.array([[1, 0, 0], [0, -1, 0], [-1, 0, 0], [0, 1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64)


def covering_radius_deg(directions: np.ndarray, samples: int = 256) -> float:
    """Largest angle (degrees) from any point of the sphere to its nearest view direction."""
    grid = erp_directions(samples // 2, samples).reshape(-1, 3)
    cos = grid @ (directions / np.linalg.norm(directions, axis=-1, keepdims=True)).T
    return float(np.degrees(np.arccos(np.clip(cos.max(1), -1.0, 1.0))).max())


@dataclass(frozen=True)
class Layout:
    """Named view directions [N, 3] and the square field of view (degrees) each view uses."""

    name: str
    directions: np.ndarray
    fov_deg: float

    @property
    def n_views(self) -> int:
        return len(self.directions)


def default_fov_deg(directions: np.ndarray, overlap_deg: float = 10.0) -> float:
    """A square FOV whose inscribed cone reaches past the covering radius by ``overlap_deg``, capped at 120."""
    return float(min(2.0 * (covering_radius_deg(directions) + overlap_deg), 120.0))


LAYOUT_NAMES = ("fibonacci", "icosahedral", "icosahedron-vertices", "latlong", "cube")


def make_layout(name: str, n_views: int | None = None, fov_deg: float | None = None) -> Layout:
    """Build a named layout. ``n_views`` applies to ``fibonacci`` (default 20) and ``latlong``
    (default 4 x 8 = 32; other counts take rows = round(sqrt(n / 2)))."""
    if name == "fibonacci":
        dirs = fibonacci_directions(20 if n_views is None else n_views)
    elif name == "icosahedral":
        dirs = icosahedron_face_centres()
    elif name == "icosahedron-vertices":
        dirs = icosahedron_vertices()
    elif name == "cube":
        dirs = cube_directions()
    elif name == "latlong":
        n = 32 if n_views is None else n_views
        rows = max(1, round(math.sqrt(n / 2)))
        dirs = latlong_directions(rows, max(1, round(n / rows)))
    else:
        raise ValueError(f"unknown layout {name!r}; expected one of {', '.join(LAYOUT_NAMES)}")
    if name in ("icosahedral", "icosahedron-vertices", "cube") and n_views not in (None, len(dirs)):
        raise ValueError(f"layout {name!r} has exactly {len(dirs)} views, got n_views={n_views}")
    if name == "cube" and fov_deg is None:
        fov_deg = 100.0  # 90 degrees tiles the sphere with no overlap, leaving the faces' relative scales unknown
    return Layout(name, dirs, default_fov_deg(dirs) if fov_deg is None else float(fov_deg))


def band_areas(directions: np.ndarray, n_bands: int) -> np.ndarray:
    """Number of directions falling in each of ``n_bands`` equal-area z-bands of [-1, 1]."""
    z = np.clip(directions[:, 2], -1.0, 1.0 - 1e-12)
    return np.bincount(((1.0 - z) / 2.0 * n_bands).astype(int).clip(0, n_bands - 1), minlength=n_bands)


def coverage_fraction(layout: Layout, height: int = 256) -> float:
    """Solid-angle fraction of the sphere seen by at least one view of ``layout`` (square views)."""
    from .camera import look_at_rotation

    d = erp_directions(height, 2 * height)
    seen = np.zeros(d.shape[:2], bool)
    t = math.tan(math.radians(layout.fov_deg) / 2)
    for f in layout.directions:
        cam = d @ look_at_rotation(f)  # camera-frame components (right, down, forward)
        z = cam[..., 2]
        ok = z > 1e-9
        seen |= ok & (np.abs(cam[..., 0]) <= t * z) & (np.abs(cam[..., 1]) <= t * z)
    w = erp_pixel_solid_angle(height, 2 * height)[:, None]
    return float((seen * w).sum() / (w.sum() * 2 * height))
