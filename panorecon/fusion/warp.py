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
    large = cv2.morphologyEx(
        (~valid).astype(np.uint8), cv2.MORPH_OPEN, kernel, borderType=cv2.BORDER_CONSTANT, borderValue=0
    ).astype(bool)
    if not large.any():
        return np.zeros(valid.shape, bool)
    dist = cv2.distanceTransform((~large).astype(np.uint8), cv2.DIST_L2, 5)
    return valid & (dist <= width_px)


def warp_to_erp(
    view: ViewDepth,
    height: int,
    width: int,
    directions: np.ndarray | None = None,
    distance: np.ndarray | None = None,
    border_px: int = 0,
    sampling: str = "nearest",
    supersample: int = 1,
    edge_log: float = 0.1,
    edge_jump: float | None = None,
    edge_px: int = 1,
    edge_reach: int = 0,
) -> ErpObservation:
    """Backward warp of a view's ray distance onto the ERP grid. ``directions`` [H*W, 3] may be passed to
    share the ERP rays between views; ``distance`` [h, w] overrides ``view.to_distance()`` (e.g. after affine
    alignment); observations within ``border_px`` view pixels of a large invalid region are flagged in
    ``border`` (``region_border``).

    sampling="nearest": the view pixel whose area holds the ERP pixel's centre ray (no blending at all).
    sampling="linear": the mean log distance over ``supersample`` x ``supersample`` rays spread evenly over
    the ERP pixel (``supersample_rays``), each read bilinearly (``sample_log_linear``: edge-aware, taps more
    than ``edge_log`` in log distance from the nearest tap are left out), reads more than ``edge_log`` from the
    view pixel under the centre ray left out too: depth edges are not blended.
    Averaging what the view holds inside the ERP pixel's footprint is what averages the teacher's
    per-pixel noise; the pixel is observed where its centre ray's nearest view pixel is valid and, with
    ``edge_jump`` (log distance; None: off), not at a depth edge (``depth_edge_pixels`` with ``edge_reach``,
    dilated to ``edge_px``)."""
    if sampling not in ("nearest", "linear"):
        raise ValueError(f"warp_to_erp: sampling={sampling!r}; expected 'nearest' or 'linear'")
    if directions is None:
        directions = erp_directions(height, width).reshape(-1, 3)
    dist = view.to_distance() if distance is None else distance
    r0, r1 = view_row_band(view.camera, height)
    index, rows, cols, cos, x, y = project_erp_rays(view.camera, directions[r0 * width : (r1 + 1) * width], True)
    d = dist[rows, cols]
    ok = np.isfinite(d) & (d > 0)
    border = region_border(np.isfinite(dist) & (dist > 0), border_px)[rows, cols]
    with np.errstate(divide="ignore", invalid="ignore"):
        log_view = np.log(np.where(dist > 0, dist, np.nan).astype(np.float64))
    if edge_jump is not None:
        ok &= ~depth_edge_pixels(log_view, edge_jump, edge_px, edge_reach)[rows, cols]
    index, rows, cols, cos, border, x, y = index[ok], rows[ok], cols[ok], cos[ok], border[ok], x[ok], y[ok]
    if sampling == "nearest":
        value = log_view[rows, cols]
    else:
        k = supersample if supersample else footprint_supersample(view.camera, width)
        if k == 1:
            value = sample_log_linear(log_view, x, y, edge_log)
        else:
            value = _supersampled(
                view.camera, log_view, index + r0 * width, height, width, k, edge_log, log_view[rows, cols]
            )
        keep = np.isfinite(value)  # every sub-ray fell outside the view: the centre ray alone is not enough
        index, value, cos, border = index[keep], value[keep], cos[keep], border[keep]
    return ErpObservation(index + r0 * width, value, cos**2, border)


def depth_edge_pixels(log_view: np.ndarray, jump: float, px: int = 1, reach: int = 0) -> np.ndarray:
    """[h, w] bool: the valid view pixels whose log distance differs from one of their 8 valid neighbours by more
    than ``jump`` (both pixels of every such pair), with ``reach`` > 0 also the steps of a blurred jump (below),
    all dilated to ``px`` pixels (Chebyshev).

    Such a pixel may straddle a depth edge: a ray through it can belong to either side, and a read or a blend
    there can be anything in between. A pixel put on the wrong side of (or blended across) a step of at most
    ``jump`` is off by less than that; a smooth slope steeper than ``jump`` per pixel (a floor within a degree of
    the horizon) is flagged too: the view does not resolve it. A teacher's blur spreads a jump over a few pixels,
    each step holding part of it. With ``reach``, a step over ``jump / 2`` within ``reach`` pixels (Chebyshev) of
    a flagged pixel goes with it where the pixels within ``2 * reach`` of it hold flat ones (steps at most
    ``jump / 2``) on both sides of its value, more than ``2 * jump`` apart: the flanks of one blurred jump that
    a blend could put more than ``jump`` off both sides of it. A grazing surface's steps grow all the
    way to its far end (the ground at the horizon, a ramp over decades), with nothing flat beyond them, and keep
    the ``jump`` test: its points are in the right direction and lose little in the wrong distance, while a
    blurred jump's middle lies between two surfaces, on neither."""
    h, w = log_view.shape
    pad = np.full((h + 2, w + 2), np.nan)
    pad[1:-1, 1:-1] = log_view
    step = np.zeros((h, w))  # the largest |difference| to a valid 8-neighbour (0 without one)
    with np.errstate(invalid="ignore"):
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if dr or dc:
                    step = np.fmax(step, np.abs(pad[1 + dr : 1 + dr + h, 1 + dc : 1 + dc + w] - log_view))
    edge = step > jump
    if reach > 0 and edge.any():
        near = cv2.dilate(edge.astype(np.uint8), np.ones((2 * reach + 1, 2 * reach + 1), np.uint8)).astype(bool)
        window = np.ones((4 * reach + 1, 4 * reach + 1), np.uint8)
        flat = np.isfinite(log_view) & (step <= jump / 2)
        # OpenCV's float32 morphology (log distances need no more); back in float64, as its borders are +-FLT_MAX
        far = cv2.dilate(np.where(flat, log_view, -np.inf).astype(np.float32), window).astype(np.float64)
        close = cv2.erode(np.where(flat, log_view, np.inf).astype(np.float32), window).astype(np.float64)
        with np.errstate(invalid="ignore"):
            between = (far - close > 2 * jump) & (log_view > close) & (log_view < far)
        edge |= near & between & (step > jump / 2)
    if px > 1:
        edge = cv2.dilate(edge.astype(np.uint8), np.ones((2 * px - 1, 2 * px - 1), np.uint8)).astype(bool)
    return edge & np.isfinite(log_view)


def supersample_rays(pixels: np.ndarray, height: int, width: int, k: int, sub: int | None = None) -> np.ndarray:
    """Unit rays through the centres of a k x k subdivision of each flat ERP pixel: [len(pixels), k*k, 3], or
    only sub-pixel ``sub`` (row-major in the subdivision) [len(pixels), 3]. Trigonometry on rows and columns
    only, gathered per pixel."""
    r, c = np.divmod(pixels, width)
    subs = range(k * k) if sub is None else [sub]
    out = []
    for s in subs:
        lat = (0.5 - (np.arange(height) + (s // k + 0.5) / k) / height) * np.pi
        lon = ((np.arange(width) + (s % k + 0.5) / k) / width - 0.5) * 2 * np.pi
        cl = np.cos(lat)[r]
        out.append(np.stack([cl * np.cos(lon)[c], -cl * np.sin(lon)[c], np.sin(lat)[r]], -1))
    return out[0] if sub is not None else np.stack(out, 1)


def footprint_supersample(camera: PinholeCamera, width: int, most: int = 3) -> int:
    """Sub-rays per ERP pixel side: the ERP pixel's angular width over the view's central pixel's, rounded,
    in [1, most] (1 where the view is no finer than the ERP grid: a bilinear read is then all there is)."""
    return int(np.clip(np.rint(2 * np.pi / width * camera.K[0, 0]), 1, most))


def _supersampled(
    camera: PinholeCamera,
    log_view: np.ndarray,
    pixels: np.ndarray,
    height: int,
    width: int,
    k: int,
    edge_log: float,
    centre: np.ndarray,
) -> np.ndarray:
    """Mean over k x k sub-rays of each ERP pixel of the edge-aware bilinear log distance, [len(pixels)],
    counting only reads within ``edge_log`` of ``centre`` [len(pixels)] (the view pixel under the ERP pixel's
    centre ray), so a pixel across a depth edge is not blended either (NaN where no sub-ray reads a value)."""
    total, count = np.zeros(len(pixels)), np.zeros(len(pixels))
    for chunk in range(k * k):  # one sub-ray offset at a time keeps the memory at one ray per pixel
        local = supersample_rays(pixels, height, width, k, chunk) @ camera.rotation_c2w
        z = local[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            x = camera.K[0, 0] * local[:, 0] / z + camera.K[0, 2] - 0.5  # pixel-centre coordinates
            y = camera.K[1, 1] * local[:, 1] / z + camera.K[1, 2] - 0.5
        val = sample_log_linear(log_view, np.where(z > 1e-6, x, np.nan), np.where(z > 1e-6, y, np.nan), edge_log)
        with np.errstate(invalid="ignore"):
            ok = np.abs(val - centre) <= edge_log
        total[ok] += val[ok]
        count += ok
    with np.errstate(invalid="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def sample_log_linear(img: np.ndarray, x: np.ndarray, y: np.ndarray, edge_log: float) -> np.ndarray:
    """Edge-aware bilinear read of ``img`` [h, w] (NaN = invalid) at pixel-centre coordinates x, y [M]
    (pixel (i, j) has its centre at x = j, y = i). Of the four taps, those that are invalid, outside the
    image, or more than ``edge_log`` from the tap nearest the point are left out and the bilinear weights
    of the rest renormalised; NaN where the nearest tap is invalid or the point lies outside the image
    (x, y outside [-0.5, size - 0.5) or NaN)."""
    h, w = img.shape
    pad = np.full((h + 2, w + 2), np.nan)  # a NaN frame: taps beyond the image are invalid taps
    pad[1:-1, 1:-1] = img
    flat = pad.ravel()
    with np.errstate(invalid="ignore"):
        inside = (x >= -0.5) & (x < w - 0.5) & (y >= -0.5) & (y < h - 0.5)
    x, y = np.where(inside, x, 0.0), np.where(inside, y, 0.0)
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = x - x0, y - y0
    i00 = (y0.astype(np.int64) + 1) * (w + 2) + x0.astype(np.int64) + 1
    taps = [flat[i00], flat[i00 + 1], flat[i00 + w + 2], flat[i00 + w + 3]]
    weights = [(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy]
    right, below = fx >= 0.5, fy >= 0.5
    near = np.where(below, np.where(right, taps[3], taps[2]), np.where(right, taps[1], taps[0]))
    total, wsum = np.zeros(len(x)), np.zeros(len(x))
    with np.errstate(invalid="ignore"):
        for tap, wt in zip(taps, weights):
            use = np.abs(tap - near) <= edge_log  # False for a NaN tap, and for every tap when near is NaN
            total += np.where(use, wt * tap, 0.0)
            wsum += np.where(use, wt, 0.0)
        out = total / wsum
    out[~inside | ~(wsum > 0)] = np.nan
    return out


def view_row_band(camera: PinholeCamera, height: int) -> tuple[int, int]:
    """The ERP rows (first, last; inclusive) that can hold rays of the view: the latitude range of its image
    border, widened by one row, extended to a pole when the pole is inside the view."""
    w, h = camera.width, camera.height
    t = np.linspace(0, 1, 33)
    border = np.concatenate(
        [
            np.stack([t * w, np.zeros_like(t)], 1),
            np.stack([t * w, np.full_like(t, h)], 1),
            np.stack([np.zeros_like(t), t * h], 1),
            np.stack([np.full_like(t, w), t * h], 1),
        ]
    )
    rays = (
        np.stack(
            [
                (border[:, 0] - camera.K[0, 2]) / camera.K[0, 0],
                (border[:, 1] - camera.K[1, 2]) / camera.K[1, 1],
                np.ones(len(border)),
            ],
            1,
        )
        @ camera.rotation_c2w.T
    )
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


def project_erp_rays(camera: PinholeCamera, directions: np.ndarray, subpixel: bool = False):
    """Which ERP rays [M, 3] (unit) fall inside the view: (flat ray index [K], pixel row [K], pixel col [K],
    cos of the angle to the optical axis [K]); the pixel is the one whose area contains the ray (nearest).
    ``subpixel``: also the ray's pixel-centre coordinates (x [K], y [K]; pixel (i, j) is centred at x=j, y=i)."""
    R = camera.rotation_c2w
    z = directions @ R[:, 2]  # camera-frame z; x and y only for the rays that can be in the image
    front = np.flatnonzero(z > max(1e-6, _cos_widest(camera) - 1e-6))
    z, d = z[front], directions[front]
    u = camera.K[0, 0] * (d @ R[:, 0]) / z + camera.K[0, 2]
    v = camera.K[1, 1] * (d @ R[:, 1]) / z + camera.K[1, 2]
    inside = (u >= 0) & (u < camera.width) & (v >= 0) & (v < camera.height)
    front, u, v = front[inside], u[inside], v[inside]
    out = (front, v.astype(np.int64), u.astype(np.int64), z[inside])
    return out + (u - 0.5, v - 0.5) if subpixel else out


def _cos_widest(camera: PinholeCamera) -> float:
    """Cosine of the widest angle between the optical axis and a ray through the image (at a corner): unit rays
    with a smaller camera-frame z fall outside it."""
    nx = (np.array([0.0, camera.width]) - camera.K[0, 2]) / camera.K[0, 0]
    ny = (np.array([0.0, camera.height]) - camera.K[1, 2]) / camera.K[1, 1]
    return float(1.0 / np.sqrt(1.0 + np.max(nx**2) + np.max(ny**2)))
