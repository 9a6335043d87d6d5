"""What the trainer starts from, whatever the point source: the cloud thinned to the training resolution, and
the panorama's sky as a fixed environment at infinity behind the Gaussians.

Sky. Sources drop sky pixels (no finite distance), so without help the trainer covers the sky with Gaussians
at arbitrary depths that look wrong from anywhere but the centre. A sky is infinitely far: its colour depends
on the ray direction only. ``sky_environment`` keeps the panorama's sky pixels as an ERP environment map (other
pixels take the colour of the nearest sky pixel, so sky that parallax reveals next to the horizon is sky
coloured); the trainer composites ``image + (1 - alpha) x background(ray)`` for every view. It is fixed (not
learned), so it cannot take over the geometry that the pseudo-labels, all seen from the centre, would let a
learned map explain; it costs no Gaussians and adds nothing to the depth term (alpha is unchanged).
"""

from __future__ import annotations

import math

import numpy as np

from ..geometry import PointCloud, erp_to_perspective


def sky_environment(scene) -> np.ndarray | None:
    """[H, W, 3] float32 ERP in [0, 1]: the panorama's colour on ``scene.sky`` pixels, elsewhere the colour of the
    nearest sky pixel (Euclidean in pixels, no seam wrap); None when the scene has no sky pixel."""
    from scipy import ndimage

    sky = np.asarray(scene.sky, bool)
    if not sky.any():
        return None
    rgb = scene.rgb.astype(np.float32) / 255.0
    if sky.all():
        return rgb
    idx = ndimage.distance_transform_edt(~sky, return_distances=False, return_indices=True)
    return np.ascontiguousarray(rgb[idx[0], idx[1]])


def view_background(env: np.ndarray | None, camera) -> np.ndarray | None:
    """[h, w, 3] float32: the environment seen along ``camera``'s rays (direction only: the sky is at infinity)."""
    return None if env is None else erp_to_perspective(env, camera).astype(np.float32)


def points_for_resolution(res: int, fov_deg: float, pixels_per_point: float) -> int:
    """Initial points that give one point per ``pixels_per_point`` label pixels over the whole sphere: a
    ``res``² view of ``fov_deg`` has pixels of about (fov / res)² steradians at its centre."""
    pixel_sr = (math.radians(fov_deg) / res) ** 2
    return max(1, int(round(4 * math.pi / pixel_sr / pixels_per_point)))


def thin_cloud(pc: PointCloud, n_points: int, seed: int = 0) -> PointCloud:
    """At most ``n_points`` of ``pc``, drawn without replacement with weight cos(latitude) of each point's
    direction from the origin (the panorama centre), so a cloud back-projected from ERP pixels (whose solid
    angle is proportional to cos latitude) comes out evenly spread over the sphere; weights are floored at 0.02
    so points at the poles can be drawn. Weighted sampling by the largest u^(1/w) keys (Efraimidis-Spirakis).
    Returns ``pc`` itself when it already has at most ``n_points``."""
    if n_points < 1:
        raise ValueError(f"thin_cloud: n_points={n_points}: expected at least 1")
    if len(pc) <= n_points:
        return pc
    xyz = pc.xyz.astype(np.float64)
    r = np.linalg.norm(xyz, axis=1)
    w = np.maximum(np.divide(np.hypot(xyz[:, 0], xyz[:, 1]), r, out=np.ones_like(r), where=r > 0), 0.02)
    u = np.random.default_rng(seed).random(len(pc))
    keys = np.log(np.maximum(u, 1e-300)) / w  # log of u^(1/w): same order, no underflow
    keep = np.sort(np.argpartition(-keys, n_points - 1)[:n_points])
    return pc.subset(keep)
