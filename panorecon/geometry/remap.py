"""ERP <-> perspective resampling with cv2.remap, seamless across the 180° meridian and the poles.

The ERP is padded before sampling: columns wrap around, and rows past a pole continue on the other
side of the sphere (row -1-k, col c is row k, col c + W/2). So bilinear or bicubic taps that cross the
seam or a pole read the right neighbours, never a clamped or black border.
"""

from __future__ import annotations

import cv2
import numpy as np

from .camera import PinholeCamera
from .sphere import direction_to_erp_pixel, erp_directions

_INTERP = {"nearest": cv2.INTER_NEAREST, "linear": cv2.INTER_LINEAR, "cubic": cv2.INTER_CUBIC}
_PAD = 3  # enough for bicubic taps


def _interp_flag(name: str) -> int:
    if name not in _INTERP:
        raise ValueError(f"interpolation={name!r}; expected one of {sorted(_INTERP)}")
    return _INTERP[name]


def pad_erp(erp: np.ndarray, pad: int = _PAD) -> np.ndarray:
    """ERP [H, W, ...] -> [H + 2 pad, W + 2 pad, ...], padded across the poles and the seam."""
    H, W = erp.shape[:2]
    if W % 2:
        raise ValueError(f"ERP width {W} must be even to continue rows across the poles")
    if pad > H:
        raise ValueError(f"ERP of height {H} is too small to pad by {pad} rows")
    # one output array; only the pad rows are rolled (shifted[:, c] = erp[:, c - W/2] == erp[:, c + W/2]), so the
    # extra memory is the padded copy alone, not three full-size intermediates
    out = np.empty((H + 2 * pad, W + 2 * pad) + erp.shape[2:], erp.dtype)
    tall = out[:, pad : pad + W]
    tall[:pad] = np.roll(erp[:pad], W // 2, axis=1)[::-1]
    tall[pad : pad + H] = erp
    tall[pad + H :] = np.roll(erp[H - pad :], W // 2, axis=1)[::-1]
    out[:, :pad] = tall[:, W - pad :]
    out[:, pad + W :] = tall[:, :pad]
    return out


def sample_erp(
    erp: np.ndarray, directions: np.ndarray, interpolation: str = "linear", padded: np.ndarray | None = None
) -> np.ndarray:
    """Sample an ERP image [H, W, ...] along unit directions [h, w, 3] -> [h, w, ...] (same dtype).

    Interpolation happens in the image's own dtype; float images may hold NaN, which then spreads
    only to samples that touch it. ``padded``: ``pad_erp(erp)`` when the caller already has it (a caller
    sampling one large map in chunks pads it once).
    """
    H, W = erp.shape[:2]
    rows, cols = direction_to_erp_pixel(directions.reshape(-1, 3), H, W)
    cols = np.mod(cols + 0.5, W) - 0.5  # fold lon = pi exactly onto the left edge
    # cv2.remap wants 2-D maps under 32767 per side: lay the samples out in rows of 4096
    n = len(rows)
    m = -(-max(n, 1) // 4096) * 4096
    map_x = np.zeros(m, np.float32)
    map_y = np.zeros(m, np.float32)
    map_x[:n] = cols + _PAD
    map_y[:n] = rows + _PAD
    out = cv2.remap(
        pad_erp(erp) if padded is None else padded,
        map_x.reshape(-1, 4096),
        map_y.reshape(-1, 4096),
        _interp_flag(interpolation),
        borderMode=cv2.BORDER_REPLICATE,
    )
    return out.reshape((m,) + erp.shape[2:])[:n].reshape(directions.shape[:-1] + erp.shape[2:])


def erp_to_perspective(erp: np.ndarray, camera: PinholeCamera, interpolation: str = "linear") -> np.ndarray:
    """Render the perspective view ``camera`` (its rotation; the position is the ERP centre) from an
    ERP image [H, W, ...] -> [camera.height, camera.width, ...]."""
    return sample_erp(erp, camera.world_rays(), interpolation)


def perspective_to_erp(
    image: np.ndarray,
    camera: PinholeCamera,
    height: int,
    width: int,
    interpolation: str = "linear",
) -> tuple[np.ndarray, np.ndarray]:
    """Splat-free backward warp of a perspective image [h, w, ...] onto an ERP grid of ``height`` x ``width``.

    Returns (erp [height, width, ...], seen [height, width] bool): ``seen`` marks ERP pixels whose ray
    falls inside the view (in front of the camera, within the image's pixel-centre hull); others are 0.
    """
    d = erp_directions(height, width)
    cam = d @ camera.rotation_c2w  # camera-frame components of each ERP ray
    z = cam[..., 2]
    front = z > 1e-9
    zs = np.where(front, z, 1.0)
    x = camera.K[0, 0] * cam[..., 0] / zs + camera.K[0, 2]
    y = camera.K[1, 1] * cam[..., 1] / zs + camera.K[1, 2]
    h, w = image.shape[:2]
    seen = front & (x >= 0.5) & (x <= w - 0.5) & (y >= 0.5) & (y <= h - 0.5)
    map_x = np.where(seen, x - 0.5, -10).astype(np.float32)
    map_y = np.where(seen, y - 0.5, -10).astype(np.float32)
    out = cv2.remap(image, map_x, map_y, _interp_flag(interpolation), borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    out = out.reshape((height, width) + image.shape[2:])
    out[~seen] = 0
    return out, seen
