"""Procedural building blocks for synthetic scenes: solid 3D textures (colour as a function of the 3D
surface point, so a point looks the same from every viewpoint) and simple meshes.

All textures take points [M, 3] and unit normals [M, 3] (float64, metres) and return albedo [M, 3] in [0, 1].
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import open3d as o3d

Texture = Callable[[np.ndarray, np.ndarray], np.ndarray]


# ---------------------------------------------------------------- noise
LATTICE_OFFSET = 0.5 / np.sqrt(2.0)  # irrational: keeps round-coordinate faces off cell boundaries


def _hash(ix: np.ndarray, iy: np.ndarray, iz: np.ndarray, seed: int) -> np.ndarray:
    """Integer lattice coordinates -> pseudo-random floats in [0, 1) (a 32-bit integer hash)."""
    h = (
        (ix.astype(np.int64) * 73856093)
        ^ (iy.astype(np.int64) * 19349663)
        ^ (iz.astype(np.int64) * 83492791)
        ^ (seed * 2654435761)
    )
    h = h & 0xFFFFFFFF
    h = (h ^ (h >> 16)) * 0x45D9F3B & 0xFFFFFFFF
    h = (h ^ (h >> 16)) * 0x45D9F3B & 0xFFFFFFFF
    h = h ^ (h >> 16)
    return (h & 0xFFFFFF).astype(np.float64) / float(0x1000000)


def value_noise(p: np.ndarray, seed: int = 0) -> np.ndarray:
    """Smooth 3D value noise in [0, 1] at points [M, 3] (lattice spacing 1), trilinear with smoothstep."""
    i = np.floor(p)
    f = p - i
    f = f * f * (3 - 2 * f)
    i = i.astype(np.int64)
    out = np.zeros(len(p))
    for dx in (0, 1):
        wx = f[:, 0] if dx else 1 - f[:, 0]
        for dy in (0, 1):
            wy = f[:, 1] if dy else 1 - f[:, 1]
            for dz in (0, 1):
                wz = f[:, 2] if dz else 1 - f[:, 2]
                out += wx * wy * wz * _hash(i[:, 0] + dx, i[:, 1] + dy, i[:, 2] + dz, seed)
    return out


def fbm(p: np.ndarray, octaves: int = 4, seed: int = 0, lacunarity: float = 2.0, gain: float = 0.5) -> np.ndarray:
    """Fractal sum of value noise, normalised to [0, 1]."""
    total, amp, norm = np.zeros(len(p)), 1.0, 0.0
    for k in range(octaves):
        total += amp * value_noise(p * lacunarity**k, seed + 17 * k)
        norm += amp
        amp *= gain
    return total / norm


def cell_random(p: np.ndarray, size: np.ndarray | float, seed: int) -> np.ndarray:
    """A random value in [0, 1) constant over axis-aligned cells of ``size`` metres.

    The lattice is offset by an irrational fraction of a cell so that faces placed at round coordinates
    (a floor at z = -1.6) never lie on a cell boundary, where float round-off would flip cells from ray to ray."""
    c = np.floor(p / size + LATTICE_OFFSET).astype(np.int64)
    return _hash(c[:, 0], c[:, 1], c[:, 2], seed)


def _mix(a, b, t):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return a + (b - a) * np.asarray(t, float)[:, None]


# ---------------------------------------------------------------- textures
def solid(color) -> Texture:
    c = np.asarray(color, float)
    return lambda p, n: np.broadcast_to(c, p.shape).copy()


def noisy(color, amount: float = 0.15, scale: float = 4.0, seed: int = 0) -> Texture:
    """A colour modulated by fractal noise (plaster, stone, fabric)."""
    c = np.asarray(color, float)

    def tex(p, n):
        return c * (1 - amount + 2 * amount * fbm(p * scale, 4, seed))[:, None]

    return tex


def checker(c1, c2, size: float, seed: int = 0, jitter: float = 0.06) -> Texture:
    """3D checkerboard of cells ``size`` metres, each cell's brightness jittered."""
    c1, c2 = np.asarray(c1, float), np.asarray(c2, float)

    def tex(p, n):
        k = np.floor(p / size + LATTICE_OFFSET).astype(np.int64).sum(1) % 2
        base = np.where(k[:, None] == 0, c1, c2)
        return base * (1 - jitter + 2 * jitter * cell_random(p, size, seed))[:, None]

    return tex


def tiles(color, grout, size: float, grout_width: float = 0.08, seed: int = 0, variation: float = 0.12) -> Texture:
    """Square tiles of ``size`` metres with grout lines, per-tile colour variation and fine noise."""
    color, grout = np.asarray(color, float), np.asarray(grout, float)

    def tex(p, n):
        f = np.mod(p / size, 1.0)
        # a line in both tangent directions: use the two axes least aligned with the normal
        axes = np.argsort(np.abs(n), axis=1)[:, :2]
        fu = np.take_along_axis(f, axes[:, :1], 1)[:, 0]
        fv = np.take_along_axis(f, axes[:, 1:], 1)[:, 0]
        line = (np.minimum(fu, 1 - fu) < grout_width / 2) | (np.minimum(fv, 1 - fv) < grout_width / 2)
        tile = color * (1 - variation + 2 * variation * cell_random(p, size, seed))[:, None]
        tile = tile * (0.92 + 0.16 * fbm(p * 12, 2, seed + 1))[:, None]
        return np.where(line[:, None], grout, tile)

    return tex


def wood(color, ring_freq: float = 9.0, seed: int = 0, axis: int = 0) -> Texture:
    """Wood grain: bands along ``axis`` distorted by noise, plus plank-to-plank tone changes."""
    c = np.asarray(color, float)

    def tex(p, n):
        q = np.delete(p, axis, axis=1)
        grain = 0.5 + 0.5 * np.sin(ring_freq * (q[:, 0] + 0.4 * q[:, 1]) * 6 + 6 * fbm(p * 1.5, 3, seed))
        plank = cell_random(p * np.array([1.0, 1.0, 1.0]), np.where(np.arange(3) == axis, 1.2, 0.18), seed + 3)
        return c * (0.72 + 0.22 * grain + 0.18 * plank)[:, None]

    return tex


def stripes(c1, c2, period: float, axis: int = 2, seed: int = 0) -> Texture:
    """Soft stripes (wallpaper) along ``axis`` with fine noise."""
    c1, c2 = np.asarray(c1, float), np.asarray(c2, float)

    def tex(p, n):
        horizontal = np.delete(p, axis, axis=1).sum(1)
        t = 0.5 + 0.5 * np.sin(2 * np.pi * horizontal / period)
        return _mix(c1, c2, t) * (0.93 + 0.14 * fbm(p * 8, 2, seed))[:, None]

    return tex


def patches(palette, size: float, seed: int = 0, noise: float = 0.1) -> Texture:
    """Cells of ``size`` metres (scalar or per-axis) each painted a colour from ``palette`` (book spines,
    posters, facades)."""
    pal = np.asarray(palette, float)

    def tex(p, n):
        r = cell_random(p, np.asarray(size, float), seed)
        col = pal[(r * len(pal)).astype(int) % len(pal)]
        shade = 0.75 + 0.5 * cell_random(p, np.asarray(size, float), seed + 5)
        return col * (shade * (1 - noise + 2 * noise * fbm(p * 10, 2, seed + 9)))[:, None]

    return tex


def facade(wall, window, floor_height: float = 3.2, window_width: float = 2.0, seed: int = 0) -> Texture:
    """Building facade: wall colour with a grid of windows, lit or dark at random."""
    wall, window = np.asarray(wall, float), np.asarray(window, float)

    def tex(p, n):
        horiz = np.where(np.abs(n[:, 0]) > np.abs(n[:, 1]), p[:, 1], p[:, 0])
        fu = np.mod(horiz / window_width, 1.0)
        fv = np.mod(p[:, 2] / floor_height, 1.0)
        is_win = (fu > 0.2) & (fu < 0.8) & (fv > 0.3) & (fv < 0.8) & (np.abs(n[:, 2]) < 0.5)
        lit = cell_random(
            np.stack([horiz, p[:, 2], np.zeros(len(p))], 1), np.array([window_width, floor_height, 1]), seed
        )
        win = window * (0.6 + 0.8 * lit)[:, None]
        return np.where(is_win[:, None], np.clip(win, 0, 1), wall * (0.9 + 0.2 * fbm(p * 2, 3, seed))[:, None])

    return tex


def by_height(stops: list[tuple[float, tuple]], slope_color=None, seed: int = 0, jitter: float = 0.15) -> Texture:
    """Terrain colour by height z (metres) with noisy boundaries; steep slopes take ``slope_color`` (rock)."""
    zs = np.array([s[0] for s in stops])
    cols = np.array([s[1] for s in stops], float)

    def tex(p, n):
        z = p[:, 2] + (fbm(p * 0.02, 4, seed) - 0.5) * jitter * (zs[-1] - zs[0] + 1)
        idx = np.clip(np.searchsorted(zs, z) - 1, 0, len(zs) - 2)
        t = np.clip((z - zs[idx]) / (zs[idx + 1] - zs[idx]), 0, 1)
        col = cols[idx] + (cols[idx + 1] - cols[idx]) * t[:, None]
        if slope_color is not None:
            steep = np.clip((0.8 - np.abs(n[:, 2])) / 0.25, 0, 1)[:, None]
            col = col * (1 - steep) + np.asarray(slope_color, float) * steep
        return col * (0.7 + 0.3 * fbm(p * 0.7, 4, seed + 2) + 0.25 * fbm(p * 6.0, 2, seed + 4))[:, None]

    return tex


SKY_HORIZON = (0.78, 0.86, 0.95)
SKY_ZENITH = (0.22, 0.45, 0.85)


def sky_color(
    directions: np.ndarray, seed: int = 0, cloudiness: float = 0.5, horizon=SKY_HORIZON, zenith=SKY_ZENITH
) -> np.ndarray:
    """Sky radiance [M, 3] in [0, 1] for unit directions [M, 3]: ``horizon``-to-``zenith`` gradient (RGB) plus
    clouds covering more of the sky as ``cloudiness`` (0..1) grows."""
    z = np.clip(directions[:, 2], -1, 1)
    horizon = np.asarray(horizon, float)
    zenith = np.asarray(zenith, float)
    t = np.clip(z, 0, 1) ** 0.5
    base = horizon + (zenith - horizon) * t[:, None]
    # clouds: noise on the direction projected onto a virtual cloud layer (stable under any resolution)
    layer = directions[:, :2] / np.maximum(z, 0.05)[:, None] * 1.5
    c = fbm(np.concatenate([layer, np.zeros((len(z), 1))], 1), 5, seed)
    cloud = np.clip((c - (1 - cloudiness)) * 3.0, 0, 1) * np.clip(z * 6, 0, 1)
    return np.clip(base * (1 - cloud[:, None]) + np.array([0.97, 0.97, 0.98]) * cloud[:, None], 0, 1)


# ---------------------------------------------------------------- meshes
def box(center, size, yaw: float = 0.0) -> o3d.geometry.TriangleMesh:
    """Axis-aligned box of ``size`` (metres) centred at ``center``, rotated by ``yaw`` radians about z."""
    m = o3d.geometry.TriangleMesh.create_box(*size)
    m.translate(-np.asarray(size, float) / 2)
    if yaw:
        m.rotate(o3d.geometry.get_rotation_matrix_from_xyz((0, 0, yaw)), center=(0, 0, 0))
    return m.translate(np.asarray(center, float))


def cylinder(center, radius: float, height: float, resolution: int = 32) -> o3d.geometry.TriangleMesh:
    """Vertical cylinder with its base centre at ``center``."""
    m = o3d.geometry.TriangleMesh.create_cylinder(radius, height, resolution)
    return m.translate(np.asarray(center, float) + np.array([0, 0, height / 2]))


def sphere(center, radius: float, resolution: int = 24) -> o3d.geometry.TriangleMesh:
    return o3d.geometry.TriangleMesh.create_sphere(radius, resolution).translate(np.asarray(center, float))


def torus(center, radius: float, tube: float) -> o3d.geometry.TriangleMesh:
    return o3d.geometry.TriangleMesh.create_torus(radius, tube, 40, 16).translate(np.asarray(center, float))


def quad(corner, edge_u, edge_v) -> o3d.geometry.TriangleMesh:
    """A planar rectangle spanned by two edges from ``corner`` (both sides are hit by rays)."""
    c, u, v = (np.asarray(a, float) for a in (corner, edge_u, edge_v))
    m = o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(np.stack([c, c + u, c + u + v, c + v])),
        o3d.utility.Vector3iVector(np.array([[0, 1, 2], [0, 2, 3]])),
    )
    return m


def heightfield(
    height_fn: Callable[[np.ndarray, np.ndarray], np.ndarray],
    r_min: float,
    r_max: float,
    n_rings: int = 160,
    n_azimuth: int = 360,
) -> o3d.geometry.TriangleMesh:
    """Terrain z = height_fn(x, y) on a polar grid with log-spaced rings from the centre to ``r_max``:
    fine near the viewer, coarse far away, so a few hundred thousand triangles reach the horizon."""
    radii = np.concatenate([[0.0], np.geomspace(r_min, r_max, n_rings)])
    az = np.linspace(0, 2 * np.pi, n_azimuth, endpoint=False)
    rr, aa = np.meshgrid(radii[1:], az, indexing="ij")
    x, y = rr * np.cos(aa), rr * np.sin(aa)
    verts = np.concatenate(
        [
            [[0.0, 0.0, float(height_fn(np.zeros(1), np.zeros(1))[0])]],
            np.stack([x, y, height_fn(x.ravel(), y.ravel()).reshape(x.shape)], -1).reshape(-1, 3),
        ]
    )
    tris = []
    ring = lambda k, j: 1 + k * n_azimuth + (j % n_azimuth)  # noqa: E731
    j = np.arange(n_azimuth)
    tris.append(np.stack([np.zeros(n_azimuth, int), ring(0, j), ring(0, j + 1)], 1))
    for k in range(n_rings - 1):
        a, b, c, d = ring(k, j), ring(k, j + 1), ring(k + 1, j), ring(k + 1, j + 1)
        tris += [np.stack([a, c, d], 1), np.stack([a, d, b], 1)]
    return o3d.geometry.TriangleMesh(
        o3d.utility.Vector3dVector(verts), o3d.utility.Vector3iVector(np.concatenate(tris))
    )
