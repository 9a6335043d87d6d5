"""Per-view depth warped onto an ERP grid: the observations every fusion solve starts from."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import PinholeCamera, ViewDepth, erp_directions


@dataclass
class ErpObservation:
    """One view's log ray distance on the ERP grid, stored sparsely.

    index: [M] int64 flat ERP pixel indices the view sees with a valid depth; log_distance: [M] float64;
    confidence: [M] float64 in (0, 1], cos^2 of the angle between the pixel's ray and the optical axis.
    border: [M] bool, the observation lies on the border of a large invalid region such as the sky
    (``region_border``), where the teacher's depth is not evidence; all False unless asked for.
    """

    index: np.ndarray
    log_distance: np.ndarray
    confidence: np.ndarray
    border: np.ndarray | None = None

    def __post_init__(self):
        if self.border is None:
            self.border = np.zeros(len(self.index), bool)

    def dense(self, n_pixels: int, fill=np.nan) -> np.ndarray:
        out = np.full(n_pixels, fill, dtype=np.float64)
        out[self.index] = self.log_distance
        return out


def region_border(valid: np.ndarray, width_px: int) -> np.ndarray:
    """The valid pixels within ``width_px`` (view pixels, Euclidean) of a large invalid region, [h, w] bool.

    Large = what survives a 3 x 3 morphological opening of the invalid mask, so isolated dropped pixels do
    not count but the sky (or any invalid area at least 3 px across) does. Monocular teachers blend the
    foreground with the far background across such borders (flying pixels), so their depths there are not
    evidence. 0 px: no border."""
    if width_px <= 0:
        return np.zeros(valid.shape, bool)
    kernel = np.ones((3, 3), np.uint8)
    large = cv2.morphologyEx((~valid).astype(np.uint8), cv2.MORPH_OPEN, kernel, borderType=cv2.BORDER_CONSTANT,
                             borderValue=0).astype(bool)
    if not large.any():
        return np.zeros(valid.shape, bool)
    dist = cv2.distanceTransform((~large).astype(np.uint8), cv2.DIST_L2, 5)
    return valid & (dist <= width_px)


def warp_to_erp(view: ViewDepth, height: int, width: int, directions: np.ndarray | None = None,
                distance: np.ndarray | None = None, border_px: int = 0) -> ErpObservation:
    """Nearest-neighbour backward warp of a view's ray distance onto the ERP grid (no blending across depth
    edges). ``directions`` [H*W, 3] may be passed to share the ERP rays between views; ``distance`` [h, w]
    overrides ``view.to_distance()`` (e.g. after affine alignment); observations within ``border_px`` view
    pixels of a large invalid region are flagged in ``border`` (``region_border``)."""
    if directions is None:
        directions = erp_directions(height, width).reshape(-1, 3)
    dist = view.to_distance() if distance is None else distance
    r0, r1 = view_row_band(view.camera, height)
    index, rows, cols, cos = project_erp_rays(view.camera, directions[r0 * width:(r1 + 1) * width])
    index = index + r0 * width
    d = dist[rows, cols]
    ok = np.isfinite(d) & (d > 0)
    border = region_border(np.isfinite(dist) & (dist > 0), border_px)[rows, cols]
    return ErpObservation(index[ok], np.log(d[ok].astype(np.float64)), cos[ok] ** 2, border[ok])


def view_row_band(camera: PinholeCamera, height: int) -> tuple[int, int]:
    """The ERP rows (first, last; inclusive) that can hold rays of the view: the latitude range of its image
    border, widened by one row, extended to a pole when the pole is inside the view."""
    w, h = camera.width, camera.height
    t = np.linspace(0, 1, 33)
    border = np.concatenate([np.stack([t * w, np.zeros_like(t)], 1), np.stack([t * w, np.full_like(t, h)], 1),
                             np.stack([np.zeros_like(t), t * h], 1), np.stack([np.full_like(t, w), t * h], 1)])
    rays = np.stack([(border[:, 0] - camera.K[0, 2]) / camera.K[0, 0], (border[:, 1] - camera.K[1, 2]) / camera.K[1, 1],
                     np.ones(len(border))], 1) @ camera.rotation_c2w.T
    lat = np.arcsin(np.clip(rays[:, 2] / np.linalg.norm(rays, axis=1), -1, 1))
    lat_max, lat_min = lat.max(), lat.min()
    for pole in (1.0, -1.0):
        local = camera.rotation_c2w.T @ np.array([0.0, 0.0, pole])
        if local[2] > 0:
            u = camera.K[0, 0] * local[0] / local[2] + camera.K[0, 2]
            v = camera.K[1, 1] * local[1] / local[2] + camera.K[1, 2]
            if 0 <= u <= w and 0 <= v <= h:
                lat_max, lat_min = (np.pi / 2, lat_min) if pole > 0 else (lat_max, -np.pi / 2)
    # a border sampled at 33 points per side can miss the true extreme by a little: pad by 2 degrees
    pad = np.radians(2.0)
    r0 = int(np.floor((0.5 - (lat_max + pad) / np.pi) * height - 1))
    r1 = int(np.ceil((0.5 - (lat_min - pad) / np.pi) * height + 1))
    return max(r0, 0), min(r1, height - 1)


def project_erp_rays(camera: PinholeCamera, directions: np.ndarray):
    """Which ERP rays [M, 3] (unit) fall inside the view: (flat ray index [K], pixel row [K], pixel col [K],
    cos of the angle to the optical axis [K]); the pixel is the one whose area contains the ray (nearest)."""
    local = directions @ camera.rotation_c2w  # camera-frame components
    z = local[:, 2]
    front = np.flatnonzero(z > 1e-6)
    z = z[front]
    u = camera.K[0, 0] * local[front, 0] / z + camera.K[0, 2]
    v = camera.K[1, 1] * local[front, 1] / z + camera.K[1, 2]
    inside = (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
    front = front[inside]
    return front, v[inside].astype(np.int64), u[inside].astype(np.int64), z[inside]
