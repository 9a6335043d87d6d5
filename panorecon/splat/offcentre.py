"""Pseudo-labels away from the panorama's centre: the panorama seen from other positions through the initial cloud's
geometry, co-visible pixels only (issue 55's candidate "labels warped with the fused depth").

Every pseudo-label of §2.3 looks out from the centre, so nothing tells the Gaussians how they should look from
anywhere else: colour spread over several semi-transparent Gaussians along a centre ray composites right from the
centre and wrong from the side. These labels are the reprojection oracle of the held-out views
(``labels.reprojection_oracle``) with the cloud in place of the truth: the view's depth is the cloud's (each
point splatted as a square of its own footprint, its spacing to its neighbours projected, into a z-buffer); each
pixel's 3D point takes the panorama's colour along its direction from the centre (bilinear) where the cloud's
own distance along that direction agrees within ``labels.COVISIBLE_REL_TOL``; other pixels (disocclusions, the
sky, a foreground square overhanging its silhouette) are masked out of the loss. The held-out truth is never
read: positions and directions come from the cloud and the seed alone.

``splat_depth`` is the fast path (one scatter per footprint offset, torch); ``splat_depth_reference`` the
per-point loop it must equal.
"""

from __future__ import annotations

import itertools
import math
from types import SimpleNamespace

import numpy as np
import torch

from ..geometry import PinholeCamera, intrinsics_from_fov, look_at_rotation, sample_erp, viewmat_from_pose
from .initial import erp_zbuffer
from .labels import LabelView, reprojection_oracle
from .model import nearest_neighbour_scale

MIN_COVERED = 0.25  # a view with fewer co-visible pixels than this share is not made
DRAWS = 2  # cameras drawn per view wanted
REFINE_STEPS = 2  # Newton steps that move each pixel's depth from its splatted point onto the cloud's surface
MAX_RADIUS = 3  # pixels: a point's square reaches at most this far from its pixel (a 7 x 7 square)
NEAR_QUANTILE = 0.01  # the free space's radius: this quantile of the cloud's distances from the centre


def free_space_radius(xyz: np.ndarray) -> float:
    """Distance (the cloud's units) from the panorama centre within which the cloud has almost no point: the
    ``NEAR_QUANTILE`` quantile of its points' distances from the origin."""
    return float(np.quantile(np.linalg.norm(np.asarray(xyz, np.float64), axis=1), NEAR_QUANTILE))


def offcentre_cameras(xyz: np.ndarray, n: int, size: int, fov_deg: float, radius: float, seed: int):
    """``n`` square pinhole cameras of ``size`` pixels: positions uniform in the ball of ``radius`` x the cloud's
    free-space radius around the centre, directions uniform on the sphere (seeded by ``seed``)."""
    rng = np.random.default_rng([seed, 55])
    reach = radius * free_space_radius(xyz)
    K = intrinsics_from_fov(size, size, fov_deg)
    cams = []
    for _ in range(n):
        p = rng.normal(size=3)
        p *= reach * rng.uniform() ** (1 / 3) / np.linalg.norm(p)
        forward = rng.normal(size=3)
        cams.append(
            PinholeCamera(K, viewmat_from_pose(look_at_rotation(forward / np.linalg.norm(forward)), p), size, size)
        )
    return cams


def _project(xyz: torch.Tensor, spacing: torch.Tensor, camera: PinholeCamera):
    """Pixel column, row (int64), z and footprint half-width in pixels (int64, 0..MAX_RADIUS) of the points in
    front of ``camera``; the rest dropped (their index kept in ``keep``)."""
    R = torch.as_tensor(camera.viewmat[:3, :3], dtype=torch.float64)
    t = torch.as_tensor(camera.viewmat[:3, 3], dtype=torch.float64)
    p = xyz @ R.T + t
    z = p[:, 2]
    keep = torch.nonzero(z > 0).squeeze(1)
    p, z = p[keep], z[keep]
    K = camera.K
    col = torch.floor(K[0, 0] * p[:, 0] / z + K[0, 2]).long()
    row = torch.floor(K[1, 1] * p[:, 1] / z + K[1, 2]).long()
    f = min(K[0, 0], K[1, 1])
    half = torch.ceil(f * spacing[keep] / z / 2 - 0.5).clamp(0, MAX_RADIUS).long()  # a square of >= 1 pixel
    return keep, col, row, z, half


def splat_depth(xyz: np.ndarray, spacing: np.ndarray, camera: PinholeCamera) -> np.ndarray:
    """[h, w] float64 z-depth (the cloud's units) of the nearest of the points ``xyz`` [N, 3] whose footprint
    squares (``spacing`` [N], their distance to their neighbours) reach each pixel of ``camera``; inf where none."""
    h, w = camera.height, camera.width
    keep, col, row, z, half = _project(
        torch.as_tensor(np.asarray(xyz), dtype=torch.float64),
        torch.as_tensor(np.asarray(spacing), dtype=torch.float64),
        camera,
    )
    nearest = torch.full((h * w,), math.inf, dtype=torch.float64)
    for dy, dx in itertools.product(range(-MAX_RADIUS, MAX_RADIUS + 1), repeat=2):
        sel = half >= max(abs(dx), abs(dy))
        c, r, zs = col[sel] + dx, row[sel] + dy, z[sel]
        inside = (c >= 0) & (c < w) & (r >= 0) & (r < h)
        nearest.scatter_reduce_(0, r[inside] * w + c[inside], zs[inside], "amin")
    return nearest.reshape(h, w).numpy()


def splat_depth_reference(xyz, spacing, camera: PinholeCamera) -> np.ndarray:
    """``splat_depth`` point by point: the obviously-correct reference."""
    h, w = camera.height, camera.width
    keep, col, row, z, half = _project(
        torch.as_tensor(np.asarray(xyz), dtype=torch.float64),
        torch.as_tensor(np.asarray(spacing), dtype=torch.float64),
        camera,
    )
    out = np.full((h, w), np.inf)
    for c, r, zi, k in zip(col.tolist(), row.tolist(), z.tolist(), half.tolist()):
        for y in range(max(r - k, 0), min(r + k + 1, h)):
            for x in range(max(c - k, 0), min(c + k + 1, w)):
                out[y, x] = min(out[y, x], zi)
    return out


def erp_distance(cloud, height: int, width: int) -> np.ndarray:
    """[height, width] float32: the distance from the centre of the nearest point of ``cloud`` (a ``PointCloud``)
    in each ERP pixel (``initial.erp_zbuffer``: the cloud seen from the centre); NaN where no point falls."""
    dist, _ = erp_zbuffer(cloud, height, width)
    return np.where(np.isinf(dist), np.nan, dist).astype(np.float32)


def warp_panorama(rgb: np.ndarray, distance: np.ndarray, xyz, spacing, camera: PinholeCamera):
    """The panorama ``rgb`` [H, W, 3] uint8 seen by ``camera`` through the cloud ``xyz`` [N, 3] (``spacing`` [N])
    whose ERP distance is ``distance`` [H, W] (``erp_distance``): (rgb [h, w, 3] float32 in [0, 1], mask [h, w]
    bool: the co-visible pixels)."""
    z = splat_depth(xyz, spacing, camera)
    rays, origin = camera.world_rays(), camera.position
    t = np.where(np.isfinite(z), z * camera.z_to_distance_factor(), np.nan)
    for _ in range(REFINE_STEPS):  # onto the cloud's surface: |o + t ray| = its ERP distance along that direction
        x = origin + rays * t[..., None]
        r = np.linalg.norm(x, axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            seen = sample_erp(distance, x / r[..., None], "linear")
            t = t - (r - seen) * r / np.sum(x * rays, axis=-1)  # Newton, the surface locally a sphere about the centre
    panorama = SimpleNamespace(rgb=rgb, distance=distance)
    mask, colour = reprojection_oracle(panorama, origin, rays, t)
    return np.nan_to_num(colour), mask


def offcentre_labels(
    panorama: np.ndarray, cloud, n: int, size: int, fov_deg: float, radius: float, seed: int
) -> list[LabelView]:
    """``n`` masked pseudo-labels of ``size``² pixels (``offcentre_cameras``): the ``panorama`` [H, W, 3] uint8
    through the geometry of ``cloud`` (a ``PointCloud`` in the panorama's frame; ``warp_panorama``); no depth.
    The cloud's distances are binned at the panorama's resolution (``erp_distance``): a cloud much sparser than
    its pixels (SfM, random points) leaves most directions without a distance and gives few views or none.
    A view with less than ``MIN_COVERED`` of its pixels co-visible is passed over for the next of ``DRAWS x n``
    cameras (fewer than ``n`` when those run out)."""
    if n == 0:
        return []
    spacing = nearest_neighbour_scale(cloud.xyz)
    distance = erp_distance(cloud, *panorama.shape[:2])
    views = []
    for cam in offcentre_cameras(cloud.xyz, DRAWS * n, size, fov_deg, radius, seed):
        rgb, mask = warp_panorama(panorama, distance, cloud.xyz, spacing, cam)
        if mask.mean() >= MIN_COVERED:
            views.append(LabelView(cam, rgb, mask=mask))
            if len(views) == n:
                break
    return views
