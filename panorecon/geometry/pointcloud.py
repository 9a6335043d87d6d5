"""The one point-cloud type every point source returns (its PLY files through ``io.ply``, on plyfile), and the
ERP back-projection and spherical thinning that make and reduce one."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from ..io import PanoreconInputError
from ..io.ply import read_ply, write_ply
from .layouts import fibonacci_directions
from .sphere import direction_to_lonlat, erp_pixel_to_lonlat, lonlat_to_direction

CHUNK = 1 << 20  # points per band in thin_on_sphere: its float64 temporaries are one band, whatever the size


@dataclass
class PointCloud:
    """Points in the world frame.

    xyz: [N, 3] float32 metres; rgb: [N, 3] float32 in [0, 1]; normals: [N, 3] float32 unit or None;
    view_id: [N] int32 index of the view that produced each point (-1 when none) or None.
    """

    xyz: np.ndarray
    rgb: np.ndarray
    normals: np.ndarray | None = None
    view_id: np.ndarray | None = None
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.xyz = np.ascontiguousarray(self.xyz, dtype=np.float32).reshape(-1, 3)
        self.rgb = np.ascontiguousarray(self.rgb, dtype=np.float32).reshape(-1, 3)
        if len(self.rgb) != len(self.xyz):
            raise ValueError(f"PointCloud: {len(self.xyz)} points but {len(self.rgb)} colours")
        if not np.isfinite(self.xyz).all():
            raise ValueError("PointCloud: xyz holds NaN or Inf; drop those points before building the cloud")
        if self.normals is not None:
            self.normals = np.ascontiguousarray(self.normals, dtype=np.float32).reshape(-1, 3)
        if self.view_id is not None:
            self.view_id = np.ascontiguousarray(self.view_id, dtype=np.int32).reshape(-1)

    def __len__(self) -> int:
        return len(self.xyz)

    def subset(self, index: np.ndarray) -> PointCloud:
        """The points selected by a boolean mask or index array (per-point scalars in meta['scalars'] too)."""
        meta = dict(self.meta)
        if "scalars" in meta:
            meta["scalars"] = {k: np.asarray(v)[index] for k, v in meta["scalars"].items()}
        return PointCloud(
            self.xyz[index],
            self.rgb[index],
            None if self.normals is None else self.normals[index],
            None if self.view_id is None else self.view_id[index],
            meta,
        )

    def to_open3d(self):
        """A legacy ``open3d.geometry.PointCloud`` (xyz, colours, normals)."""
        import open3d as o3d

        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(self.xyz.astype(np.float64)))
        pc.colors = o3d.utility.Vector3dVector(self.rgb.astype(np.float64))
        if self.normals is not None:
            pc.normals = o3d.utility.Vector3dVector(self.normals.astype(np.float64))
        return pc

    def save_ply(self, path: str | os.PathLike, uchar_rgb: bool = False) -> None:
        """Write a binary little-endian PLY (x,y,z, nx,ny,nz as float32; red,green,blue as float32 in [0, 1], or
        with ``uchar_rgb`` as uchar 0-255, the layout COLMAP-derived PLYs use and OpenSplat's reader assumes;
        view_id int32) atomically, streamed (``io.ply.write_ply``)."""
        cols = [("x", self.xyz[:, 0]), ("y", self.xyz[:, 1]), ("z", self.xyz[:, 2])]
        if self.normals is not None:
            cols += [(n, self.normals[:, k]) for k, n in enumerate(("nx", "ny", "nz"))]
        rgb = np.clip(np.round(self.rgb * 255), 0, 255).astype(np.uint8) if uchar_rgb else self.rgb
        cols += [(n, rgb[:, k]) for k, n in enumerate(("red", "green", "blue"))]
        if self.view_id is not None:
            cols.append(("view_id", self.view_id))
        write_ply(path, cols, comments=["panorecon"])

    @classmethod
    def load_ply(cls, path: str | os.PathLike) -> PointCloud:
        """Read a PLY written by ``save_ply`` or any PLY with positions (``io.ply.read_ply``: colours optional,
        uint8 ones are / 255; other scalar properties go to ``meta["scalars"]`` as [N, 1]), checked: the file's
        structure and size, and finite positions. A bad file raises ``PanoreconInputError`` naming it."""
        fields = read_ply(path, "point cloud")
        xyz = np.stack([fields.pop(k) for k in ("x", "y", "z")], 1)
        if not np.isfinite(xyz).all():
            raise PanoreconInputError(
                f"point cloud {path}: {int((~np.isfinite(xyz).all(1)).sum())} vertices have NaN or Inf positions"
            )
        rgb = np.full_like(xyz, 0.5, dtype=np.float32)
        if {"red", "green", "blue"} <= set(fields):
            rgb = np.stack([fields.pop(k) for k in ("red", "green", "blue")], 1)
            rgb = rgb / 255.0 if rgb.dtype == np.uint8 else rgb
        normals = np.stack([fields.pop(k) for k in ("nx", "ny", "nz")], 1) if "nx" in fields else None
        view_id = fields.pop("view_id", None)
        extra = {k: v.reshape(len(xyz), -1) for k, v in fields.items()}
        return cls(xyz, rgb, normals, view_id, {"scalars": extra} if extra else {})


def erp_point_cloud(
    rgb: np.ndarray, distance: np.ndarray, keep: np.ndarray | None = None, origin=(0.0, 0.0, 0.0)
) -> PointCloud:
    """Back-project an ERP image [H, W, 3] (uint8 or float in [0, 1]) and ray distance [H, W] (metres).

    Pixels with non-finite or non-positive distance, or outside ``keep``, give no point.
    """
    ok = np.isfinite(distance) & (distance > 0)
    if keep is not None:
        ok &= keep
    xyz, col, _ = back_project_erp(distance, ok, rgb)
    return PointCloud(xyz + np.asarray(origin, np.float32), col, normals=None, view_id=None)


def back_project_erp(
    distance: np.ndarray, keep: np.ndarray, rgb: np.ndarray, forwards: np.ndarray | None = None, rows: int = 256
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """The pixels ``keep`` [H, W] of an ERP ray distance [H, W] (metres) as points, ``rows`` ERP rows at a time
    (directions in float64 per band only): -> xyz [N, 3] float32, colour [N, 3] float32 in [0, 1] (``rgb``
    [H, W, 3] uint8 or float), and with ``forwards`` [V, 3] the index of the axis closest to each point's ray
    ([N] int32; else None). Row-major pixel order."""
    H, W = distance.shape
    n = int(keep.sum())
    xyz, col = np.empty((n, 3), np.float32), np.empty((n, 3), np.float32)
    vid = None if forwards is None else np.empty(n, np.int32)
    lon = erp_pixel_to_lonlat(np.zeros(1), np.arange(W, dtype=np.float64), H, W)[0]
    at = 0
    for r0 in range(0, H, rows):
        band = keep[r0 : r0 + rows]
        r, c = np.nonzero(band)
        lat = erp_pixel_to_lonlat(r + float(r0), np.zeros(1), H, W)[1]
        d = lonlat_to_direction(lon[c], lat)
        m = len(r)
        xyz[at : at + m] = d * distance[r0 : r0 + rows][band][:, None]
        col[at : at + m] = rgb[r0 : r0 + rows][band]
        if vid is not None:
            vid[at : at + m] = _nearest_axis(d, np.asarray(forwards, np.float64))
        at += m
    if rgb.dtype == np.uint8:
        col /= 255.0
    return xyz, col, vid


def _nearest_axis(d: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """argmax over axes [V, 3] of d [N, 3] · axis, [N] int32 (ties: the first), by a running maximum over the
    axes (elementwise, no N x V matrix)."""
    x, y, z = (np.ascontiguousarray(d[:, i]) for i in range(3))
    best = x * axes[0, 0] + y * axes[0, 1] + z * axes[0, 2]
    out = np.zeros(len(d), np.int32)
    for k in range(1, len(axes)):
        dot = x * axes[k, 0] + y * axes[k, 1] + z * axes[k, 2]
        better = dot > best
        out[better], best[better] = k, dot[better]
    return out


def thin_on_sphere(pc: PointCloud, n_points: int) -> tuple[PointCloud, dict]:
    """At most ``n_points`` of ``pc`` spread evenly over the sphere of directions from the origin (the panorama
    centre), deterministically: the point nearest each site of a spherical Fibonacci lattice of K sites (paper
    eq. 13), K the largest found (up to 8 tries, each rescaled by the share of sites that found a point) for which
    at most ``n_points`` sites find one (each point is a candidate of the site nearest its cell of a fine ERP
    grid), so a site over empty directions (sky) stays empty. Returns ``pc`` itself when it
    already has at most ``n_points``. -> (cloud, info: sites, points, spacing_deg = sqrt(4 pi / K) in degrees,
    points_per_sr = K / 4 pi over the directions the cloud covers)."""
    if not (isinstance(n_points, (int, np.integer)) and n_points >= 1):
        raise ValueError(f"thin_on_sphere: n_points={n_points!r}: expected an integer >= 1")
    if len(pc) <= n_points:
        return pc, {"sites": None, "points": len(pc), "thinned": False}
    lon, lat = np.empty(len(pc), np.float32), np.empty(len(pc), np.float32)
    for i in range(0, len(pc), CHUNK):
        lon[i : i + CHUNK], lat[i : i + CHUNK] = direction_to_lonlat(pc.xyz[i : i + CHUNK].astype(np.float64))
    best, sites = None, n_points
    for _ in range(8):
        keep = _nearest_to_sites(pc.xyz, lon, lat, sites)
        if len(keep) <= n_points and (best is None or len(keep) > len(best[0])):
            best = (keep, sites)
        if n_points * 0.99 <= len(keep) <= n_points:
            break
        sites = max(1, int(sites * n_points / max(len(keep), 1) * (0.995 if len(keep) > n_points else 1.0)))
    keep, sites = best if best is not None else (keep[:0], sites)
    info = {
        "sites": sites,
        "points": len(keep),
        "thinned": True,
        "spacing_deg": float(np.degrees(np.sqrt(4 * np.pi / sites))),
        "points_per_sr": sites / (4 * np.pi),
    }
    return pc.subset(np.sort(keep)), info


def _nearest_to_sites(xyz: np.ndarray, lon: np.ndarray, lat: np.ndarray, n_sites: int) -> np.ndarray:
    """Index of the point nearest (largest cosine) each of ``n_sites`` Fibonacci sites among the points that
    ``fibonacci_site_of`` gives that site; sites no point reaches give none. [<= n_sites] int64, in site order."""
    site, cos = fibonacci_site_of(xyz, lon, lat, n_sites)
    return nearest_per_site(site, cos, n_sites)


def fibonacci_site_of(xyz: np.ndarray, lon: np.ndarray, lat: np.ndarray, n_sites: int) -> tuple[np.ndarray, np.ndarray]:
    """The Fibonacci site (of ``n_sites``, ``fibonacci_directions``) each point [N, 3] belongs to, given its
    direction's ``lon``, ``lat`` [N] (radians): the site nearest the centre of the point's cell of an ERP lookup
    grid (g x 2g cells, g = ceil(sqrt(pi n_sites / 2)): cells half a site's area at the equator, smaller
    elsewhere; a KD-tree over the sites, queried once per cell, not per point), and the cosine between the point's
    direction and its site's. -> (site [N] int64, cos [N] float64)."""
    from scipy.spatial import cKDTree

    g = int(np.ceil(np.sqrt(np.pi * n_sites / 2)))
    site_dirs = fibonacci_directions(n_sites)
    rr, cc = np.meshgrid(np.arange(g, dtype=np.float64), np.arange(2 * g, dtype=np.float64), indexing="ij")
    centres = lonlat_to_direction(*erp_pixel_to_lonlat(rr, cc, g, 2 * g)).reshape(-1, 3)
    site_of_cell = cKDTree(site_dirs).query(centres, workers=-1)[1]
    site, cos = np.empty(len(lon), np.int64), np.empty(len(lon), np.float64)
    for i in range(0, len(lon), CHUNK):
        lo, la = lon[i : i + CHUNK].astype(np.float64), lat[i : i + CHUNK].astype(np.float64)
        row = np.clip(((0.5 - la / np.pi) * g).astype(np.int64), 0, g - 1)
        col = np.mod(((lo / (2 * np.pi) + 0.5) * 2 * g).astype(np.int64), 2 * g)
        s = site[i : i + CHUNK] = site_of_cell[row * 2 * g + col]
        d = xyz[i : i + CHUNK].astype(np.float64)
        cos[i : i + CHUNK] = np.einsum("nk,nk->n", d, site_dirs[s]) / np.maximum(np.linalg.norm(d, axis=1), 1e-300)
    return site, cos


def nearest_per_site(site: np.ndarray, cos: np.ndarray, n_sites: int) -> np.ndarray:
    """For each site that some point has (``site`` [N] in [0, n_sites)), the index of its point of largest ``cos``
    [N] (ties: the lowest index), in increasing site order. O(N): a per-site maximum, then the first point that
    attains it (the argsort by the float64 key site * 4 + (1 - cos) it replaced was 19x slower at 33.5M points and
    rounded away cosine differences below ~1e-9)."""
    best = np.full(n_sites, -np.inf)
    np.maximum.at(best, site, cos)
    candidates = np.flatnonzero(cos == best[site])
    _, first = np.unique(site[candidates], return_index=True)
    return candidates[first]
