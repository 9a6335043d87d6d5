"""Equirectangular (ERP) pixel <-> unit direction, the one sphere convention of panorecon.

World frame: right-handed, +z up. Longitude 0 looks along +x; longitude grows to the *right* in the
image as seen from inside the sphere, which is towards -y, so the panorama is not mirrored:

    d(lon, lat) = (cos(lat) cos(lon), -cos(lat) sin(lon), sin(lat))

ERP pixel (row r, col c) of an H x W image has its centre at u = (c + 0.5) / W, v = (r + 0.5) / H;
lon = (u - 0.5) * 2*pi (0 at the centre column), lat = (0.5 - v) * pi (row 0 is up).

Every function accepts numpy arrays or torch tensors and returns the same kind (float dtype kept).
"""

from __future__ import annotations

import math

import numpy as np
import torch

Array = np.ndarray | torch.Tensor


def _xp(x):
    return torch if isinstance(x, torch.Tensor) else np


def lonlat_to_direction(lon: Array, lat: Array) -> Array:
    """Longitude/latitude [...] (radians) -> unit directions [..., 3]."""
    xp = _xp(lon)
    cl = xp.cos(lat)
    return xp.stack([cl * xp.cos(lon), -cl * xp.sin(lon), xp.sin(lat)], -1)


def direction_to_lonlat(d: Array) -> tuple[Array, Array]:
    """Directions [..., 3] (any non-zero length) -> (lon in (-pi, pi], lat in [-pi/2, pi/2]) radians."""
    xp = _xp(d)
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    lon = xp.arctan2(-y, x)
    lat = xp.arctan2(z, xp.sqrt(x * x + y * y))
    return lon, lat


def erp_pixel_to_lonlat(rows: Array, cols: Array, height: int, width: int) -> tuple[Array, Array]:
    """Continuous pixel indices (centre of pixel (r, c) is at r, c) -> (lon, lat) radians."""
    u = (cols + 0.5) / width
    v = (rows + 0.5) / height
    return (u - 0.5) * (2 * math.pi), (0.5 - v) * math.pi


def lonlat_to_erp_pixel(lon: Array, lat: Array, height: int, width: int) -> tuple[Array, Array]:
    """(lon, lat) radians -> continuous (row, col) pixel indices, pixel centres at integers."""
    u = lon / (2 * math.pi) + 0.5
    v = 0.5 - lat / math.pi
    return v * height - 0.5, u * width - 0.5


def erp_directions(height: int, width: int, *, dtype=np.float64, like: Array | None = None) -> Array:
    """Unit direction of every ERP pixel centre, [H, W, 3].

    ``like`` (a tensor) makes the result a torch tensor on its device and dtype; otherwise numpy ``dtype``.
    """
    if isinstance(like, torch.Tensor):
        rows = torch.arange(height, dtype=like.dtype, device=like.device)
        cols = torch.arange(width, dtype=like.dtype, device=like.device)
        rr, cc = torch.meshgrid(rows, cols, indexing="ij")
    else:
        rr, cc = np.meshgrid(np.arange(height, dtype=dtype), np.arange(width, dtype=dtype), indexing="ij")
    lon, lat = erp_pixel_to_lonlat(rr, cc, height, width)
    return lonlat_to_direction(lon, lat)


def direction_to_erp_pixel(d: Array, height: int, width: int) -> tuple[Array, Array]:
    """Directions [..., 3] -> continuous (row, col) ERP pixel indices (pixel centres at integers)."""
    lon, lat = direction_to_lonlat(d)
    return lonlat_to_erp_pixel(lon, lat, height, width)


def erp_pixel_solid_angle(height: int, width: int) -> np.ndarray:
    """Solid angle (steradians) of each ERP row's pixels, [H]; they sum (times W) to 4*pi exactly."""
    edges = (0.5 - np.arange(height + 1) / height) * np.pi
    return (2 * np.pi / width) * (np.sin(edges[:-1]) - np.sin(edges[1:]))


def erp_z_to_distance_factor(height: int, width: int) -> np.ndarray:
    """[H, W] float64: distance / z for cube-face z-depth, 1 / max(|dx|, |dy|, |dz|) of each unit ERP ray (the
    cube face a ray passes through is the axis of its largest component)."""
    return 1.0 / np.abs(erp_directions(height, width)).max(-1)


def distance_to_points(distance: Array, directions: Array) -> Array:
    """Ray distance [...] (metres) and unit directions [..., 3] -> points [..., 3] (metres)."""
    return distance[..., None] * directions


def erp_grid_normals(points: np.ndarray) -> np.ndarray:
    """[H, W, 3] float32 unit normals of an ERP grid of 3D points [H, W, 3] (one surface point per pixel, NaN
    where none): the cross product of the points' central differences along longitude (wrapping) and latitude.
    NaN on the first and last rows and where a neighbour is missing; the sign is arbitrary. float64 inside."""
    p = np.asarray(points, np.float64)
    if p.ndim != 3 or p.shape[2] != 3:
        raise ValueError(f"erp_grid_normals: points of shape {p.shape}: expected [H, W, 3]")
    along_lon = np.roll(p, -1, 1) - np.roll(p, 1, 1)
    along_lat = np.full_like(p, np.nan)
    along_lat[1:-1] = p[2:] - p[:-2]
    n = np.cross(along_lon, along_lat)
    with np.errstate(invalid="ignore", divide="ignore"):
        return (n / np.linalg.norm(n, axis=-1, keepdims=True)).astype(np.float32)


def erp_normals(distance: np.ndarray) -> np.ndarray:
    """[H, W, 3] float32 unit normals of the surface an ERP ray-distance map [H, W] sees from its centre
    (``erp_grid_normals`` of its back-projected pixels; NaN where the distance is not finite and positive)."""
    d = np.asarray(distance, np.float64)
    if d.ndim != 2 or d.shape[1] != 2 * d.shape[0]:
        raise ValueError(f"erp_normals: distance of shape {d.shape}: expected an ERP map [H, 2H]")
    return erp_grid_normals(erp_directions(*d.shape) * np.where(np.isfinite(d) & (d > 0), d, np.nan)[..., None])
