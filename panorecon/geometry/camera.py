"""Pinhole cameras in OpenCV axes (x right, y down, z forward), world-to-camera ``viewmat`` 4x4.

Pixel convention: the centre of pixel (row i, col j) sits at continuous image coordinates
(x, y) = (j + 0.5, i + 0.5), as in gsplat; so a centred camera has cx = W / 2, cy = H / 2.
cv2.remap samples at integer coordinates, so callers subtract 0.5 before remapping.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

WORLD_UP = np.array([0.0, 0.0, 1.0])


def intrinsics_from_fov(width: int, height: int, fov_x_deg: float, fov_y_deg: float | None = None) -> np.ndarray:
    """3x3 K from horizontal (and vertical) field of view in degrees (paper eq. 14-15).

    f_x = W / (2 tan(FOV_x / 2)), f_y = H / (2 tan(FOV_y / 2)), principal point at the image centre.
    Without ``fov_y_deg`` the pixels are square (f_y = f_x).
    """
    if not (0.0 < fov_x_deg < 180.0):
        raise ValueError(f"fov_x_deg={fov_x_deg!r}: expected a field of view in (0, 180) degrees")
    if width <= 0 or height <= 0:
        raise ValueError(f"image size {width}x{height}: expected positive width and height")
    fx = width / (2.0 * math.tan(math.radians(fov_x_deg) / 2.0))
    if fov_y_deg is None:
        fy = fx
    else:
        if not (0.0 < fov_y_deg < 180.0):
            raise ValueError(f"fov_y_deg={fov_y_deg!r}: expected a field of view in (0, 180) degrees")
        fy = height / (2.0 * math.tan(math.radians(fov_y_deg) / 2.0))
    return np.array([[fx, 0.0, width / 2.0], [0.0, fy, height / 2.0], [0.0, 0.0, 1.0]])


def look_at_rotation(forward: np.ndarray, up: np.ndarray = WORLD_UP) -> np.ndarray:
    """Camera-to-world rotation(s) [..., 3, 3] whose columns are the camera's (right, down, forward).

    ``forward`` [..., 3] need not be unit. When it is parallel to ``up`` (looking straight up or down)
    the image's up direction falls back to +x for a camera looking down and -x looking up, so the
    rotation stays defined and continuous along the meridian lon = 0.
    """
    f = np.asarray(forward, dtype=np.float64)
    norm = np.linalg.norm(f, axis=-1, keepdims=True)
    if np.any(norm < 1e-12):
        raise ValueError("look_at_rotation: forward direction has zero length")
    f = f / norm
    up = np.broadcast_to(np.asarray(up, dtype=np.float64), f.shape)
    right = np.cross(f, up)
    rn = np.linalg.norm(right, axis=-1, keepdims=True)
    degenerate = rn[..., 0] < 1e-9
    if np.any(degenerate):
        # Looking along +-up: take image-up as -sign(f_z) * x so that 'down' in the image points to +x*sign.
        alt_up = np.zeros_like(f)
        alt_up[..., 0] = -np.sign(f[..., 2])
        right = np.where(degenerate[..., None], np.cross(f, alt_up), right)
        rn = np.linalg.norm(right, axis=-1, keepdims=True)
    right = right / rn
    down = np.cross(f, right)
    return np.stack([right, down, f], axis=-1)


def viewmat_from_pose(rotation_c2w: np.ndarray, position: np.ndarray) -> np.ndarray:
    """World-to-camera 4x4 from a camera-to-world rotation [3,3] and camera centre [3] (metres)."""
    R = np.asarray(rotation_c2w, dtype=np.float64)
    t = np.asarray(position, dtype=np.float64)
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def look_at_viewmat(position: np.ndarray, target: np.ndarray, up: np.ndarray = WORLD_UP) -> np.ndarray:
    """World-to-camera 4x4 of a camera at ``position`` looking at ``target``."""
    position = np.asarray(position, dtype=np.float64)
    return viewmat_from_pose(look_at_rotation(np.asarray(target, dtype=np.float64) - position, up), position)


def pixel_rays(K: np.ndarray, width: int, height: int) -> np.ndarray:
    """Camera-frame ray directions through every pixel centre, [H, W, 3], with z = 1 (not unit)."""
    j, i = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    x = (j - K[0, 2]) / K[0, 0]
    y = (i - K[1, 2]) / K[1, 1]
    return np.stack([x, y, np.ones_like(x)], -1)


@dataclass(frozen=True)
class PinholeCamera:
    """One perspective view: intrinsics, pose and size. ``viewmat`` is world-to-camera (OpenCV axes)."""

    K: np.ndarray  # [3, 3] pixels
    viewmat: np.ndarray  # [4, 4]
    width: int
    height: int

    @property
    def rotation_c2w(self) -> np.ndarray:
        return self.viewmat[:3, :3].T

    @property
    def position(self) -> np.ndarray:
        return -self.viewmat[:3, :3].T @ self.viewmat[:3, 3]

    @property
    def forward(self) -> np.ndarray:
        return self.rotation_c2w[:, 2]

    def world_rays(self) -> np.ndarray:
        """Unit world-frame ray directions through every pixel centre, [H, W, 3]."""
        d = pixel_rays(self.K, self.width, self.height) @ self.rotation_c2w.T
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def z_to_distance_factor(self) -> np.ndarray:
        """[H, W] factor turning z-depth into distance along the ray (distance = z * factor)."""
        return np.linalg.norm(pixel_rays(self.K, self.width, self.height), axis=-1)


def centred_camera(forward: np.ndarray, size: int, fov_deg: float, position=(0.0, 0.0, 0.0)) -> PinholeCamera:
    """Square perspective view of ``size`` pixels looking along ``forward`` from ``position``."""
    R = look_at_rotation(forward)
    return PinholeCamera(
        intrinsics_from_fov(size, size, fov_deg), viewmat_from_pose(R, np.asarray(position, float)), size, size
    )
