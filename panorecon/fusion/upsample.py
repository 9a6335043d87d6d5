"""The fused log distance brought from the level the views resolve to the panorama's size, with depth edges
following the panorama's own edges: a guided filter (He, Sun and Tang, 2013) fitted on the solve level and
transferred at full size (in the spirit of the fast guided filter, He and Sun, 2015).

On the solve level (h x w) the log distance p is fitted, in every (2r + 1)² window, by a linear function of the
panorama's colour I averaged onto that level (I_s): p ≈ a·I_s + b, a = (Σ + eps·1)⁻¹ cov(I_s, p) (Σ the 3 x 3
colour covariance of the window), a averaged over the windows covering each pixel. At full size the colour's own
detail, the part the solve level could not hold, is carried into the depth through a: q = p↑ + a↑·(I − I_s↑)
(↑: bilinear). Where the colour has an edge inside a solve-level pixel that the depth shares, the fine depth
steps where the colour steps (at the panorama's resolution, not the views'); where the colour is flat, or varies
without the depth, q is the bilinear upsampling of p (the guided filter's own output, a·I + b, would also smooth
p over the window there). ``eps`` (colour variance, colour in [0, 1]) sets how strong a colour edge must be to be
followed. With ``edge_log``, q is also kept inside the range of the seen solve-level pixels among the four around
it and, where these span a depth edge (more than ``edge_log`` apart) or one of the four is unseen, snapped to one
side (``snap_to_side``): a pixel at an edge the solve level cannot resolve takes one side's depth, never a blend of
the two (a flying point) nor of an unseen pixel's fill. ``fuse_views`` passes ``FusionConfig.edge_jump`` (ln 1.5:
a blend across a smaller jump is less than 50 % off either side); off here by default (None).

ERP conventions: windows and interpolation wrap at the seam (longitude) and clamp at the poles. Pixels the solve
did not see (NaN) take the median log distance inside the filter and come out NaN (a full-size pixel is unseen
where the bilinear weight of the unseen coarse pixels around it is above one half). The full-size maps are made
band by band (``rows`` rows at a time): the extra memory is a few float32 bands, never a full-size float64 map.
``bilinear_upsample_reference`` and ``guided_upsample_reference`` are the slow, whole-array NumPy forms the
fast path is tested against.
"""

from __future__ import annotations

import cv2
import numpy as np


def _box(x: np.ndarray, r: int) -> np.ndarray:
    """Mean over (2r + 1)² windows of x [h, w] or [h, w, c] (float), wrapping at the seam, reflected at the poles."""
    w = x.shape[1]
    padded = np.concatenate([x[:, w - r :], x, x[:, :r]], axis=1) if r else x
    out = cv2.boxFilter(padded, -1, (2 * r + 1, 2 * r + 1), normalize=True, borderType=cv2.BORDER_REFLECT)
    return out[:, r : r + w] if r else out


def guided_coefficients(p: np.ndarray, guide: np.ndarray, radius: int, eps: float) -> np.ndarray:
    """The guided filter's window-averaged a [h, w, 3] (float32, log distance per colour unit) for log distance
    p [h, w] (finite) against colour guide [h, w, 3] float in [0, 1]; solved per pixel in float64."""
    p64, g = p.astype(np.float64), guide.astype(np.float64)
    mean_i, mean_p = _box(g, radius), _box(p64, radius)
    cov_ip = _box(g * p64[..., None], radius) - mean_i * mean_p[..., None]
    sigma = np.empty(p.shape + (3, 3))
    for j in range(3):
        for k in range(j, 3):
            sigma[..., j, k] = sigma[..., k, j] = _box(g[..., j] * g[..., k], radius) - mean_i[..., j] * mean_i[..., k]
    sigma += eps * np.eye(3)
    a = np.linalg.solve(sigma, cov_ip[..., None])[..., 0]
    return _box(a, radius).astype(np.float32)


def _wrap_pad(x: np.ndarray) -> np.ndarray:
    """One column of the other side of the seam on each side of x [h, w, ...]."""
    return np.concatenate([x[:, -1:], x, x[:, :1]], axis=1)


def _coarse_coords(n_fine: int, n_coarse: int) -> np.ndarray:
    """Pixel-centre coordinate on the coarse grid of every fine index (float64), ERP pixel centres at i + 0.5."""
    return (np.arange(n_fine) + 0.5) * (n_coarse / n_fine) - 0.5


def _bilinear_band(coarse: np.ndarray, r0: int, r1: int, height: int, width: int) -> np.ndarray:
    """Rows r0:r1 of ``coarse`` [h, w] or [h, w, c] (float32) resampled bilinearly to height x width: seam wraps,
    poles clamp (cv2.remap on the seam-padded coarse map)."""
    h, w = coarse.shape[:2]
    mx = (_coarse_coords(width, w) + 1).astype(np.float32)  # +1: the padded column
    my = np.clip(_coarse_coords(height, h)[r0:r1], 0, h - 1).astype(np.float32)
    map_x = np.broadcast_to(mx[None], (r1 - r0, width)).copy()
    map_y = np.broadcast_to(my[:, None], (r1 - r0, width)).copy()
    return cv2.remap(_wrap_pad(coarse), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def bilinear_upsample_reference(coarse: np.ndarray, height: int, width: int) -> np.ndarray:
    """``_bilinear_band`` over all rows, in float64 NumPy (the reference): [height, width, ...]."""
    h, w = coarse.shape[:2]
    y = np.clip(_coarse_coords(height, h), 0, h - 1)
    x = _coarse_coords(width, w)
    y0 = np.minimum(np.floor(y).astype(int), h - 2) if h > 1 else np.zeros(height, int)
    fy = (y - y0) if h > 1 else np.zeros(height)
    x0 = np.floor(x).astype(int)
    fx = x - x0
    c = coarse.astype(np.float64)
    xa, xb = np.mod(x0, w), np.mod(x0 + 1, w)
    top = c[y0][:, xa] * _expand(1 - fx, c) + c[y0][:, xb] * _expand(fx, c)
    bottom = c[np.minimum(y0 + 1, h - 1)][:, xa] * _expand(1 - fx, c) + c[np.minimum(y0 + 1, h - 1)][:, xb] * _expand(
        fx, c
    )
    fy = fy.reshape((-1,) + (1,) * (c.ndim - 1))
    return top * (1 - fy) + bottom * fy


def _expand(v: np.ndarray, like: np.ndarray) -> np.ndarray:
    return v.reshape((1, -1) + (1,) * (like.ndim - 2))


def _taps(p: np.ndarray, r0: int, r1: int, height: int, width: int):
    """The four bilinear taps of rows r0:r1 of the height x width grid on ``p`` [h, w] (seam wraps, poles clamp):
    ([4, r1 - r0, width] values, [4, r1 - r0, width] weights), in the row/column conventions of ``_bilinear_band``."""
    h, w = p.shape
    y = np.clip(_coarse_coords(height, h)[r0:r1], 0, h - 1)
    y0 = np.minimum(np.floor(y).astype(np.int64), max(h - 2, 0))
    y1 = np.minimum(y0 + 1, h - 1)
    fy = (y - y0)[:, None].astype(np.float32)
    x = _coarse_coords(width, w)
    x0 = np.floor(x).astype(np.int64)
    fx = (x - x0)[None].astype(np.float32)
    xa, xb = np.mod(x0, w), np.mod(x0 + 1, w)
    values = np.stack([p[y0][:, xa], p[y0][:, xb], p[y1][:, xa], p[y1][:, xb]])
    weights = np.stack([(1 - fy) * (1 - fx), (1 - fy) * fx, fy * (1 - fx), fy * fx])
    return values, weights


def snap_to_side(
    q: np.ndarray, values: np.ndarray, weights: np.ndarray, edge_log: float, seen: np.ndarray | None = None
) -> np.ndarray:
    """The guided value ``q`` [...] kept inside the range of the seen ones of the four coarse taps ``values``
    [4, ...] around the pixel (the colour adds no depth the solve did not find); where the seen taps span a depth
    edge (max - min > ``edge_log``, log distance) or a tap is unseen (``seen`` [4, ...] bool; None: all seen),
    the bilinear mean of the seen taps within ``edge_log`` of the seen tap nearest q (renormalised ``weights``):
    the pixel lies on one side of the edge, never in between, and takes nothing of an unseen tap's fill value (no
    flying pixels). A pixel without a seen tap keeps q (it comes out unseen)."""
    seen = np.ones(values.shape, bool) if seen is None else seen
    lo = np.where(seen, values, np.inf).min(0)
    hi = np.where(seen, values, -np.inf).max(0)
    some = seen.any(0)
    qc = np.where(some, np.clip(q, np.where(some, lo, q), np.where(some, hi, q)), q)
    dist = np.where(seen, np.abs(values - qc), np.inf)
    near = np.take_along_axis(values, dist.argmin(0)[None], 0)[0]
    use = seen & (np.abs(values - near) <= edge_log)
    wsum = (weights * use).sum(0)
    side = (values * weights * use).sum(0) / np.maximum(wsum, 1e-12)
    snap = some & ((hi - lo > edge_log) | ~seen.all(0))
    return np.where(snap, side, qc)


def _filled(log_coarse: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """-> (log distance with NaN replaced by the median of the rest, seen mask as float32)."""
    seen = np.isfinite(log_coarse)
    fill = float(np.median(log_coarse[seen])) if seen.any() else 0.0
    return np.where(seen, log_coarse, fill).astype(np.float32), seen.astype(np.float32)


def guided_upsample(
    log_coarse: np.ndarray,
    guide: np.ndarray | None,
    height: int,
    width: int,
    radius: int = 2,
    eps: float = 1e-4,
    edge_log: float | None = None,
    rows: int = 256,
) -> np.ndarray:
    """Log distance [h, w] (NaN = unseen) -> distance [height, width] float32 metres (NaN = unseen): guided by the
    panorama ``guide`` [height, width, 3] (uint8 or float in [0, 1]), or plain bilinear in log distance without
    one. ``radius`` in solve-level pixels; built ``rows`` full-size rows at a time."""
    p, seen = _filled(log_coarse)
    h, w = p.shape
    if guide is not None:
        scale = 255.0 if guide.dtype == np.uint8 else 1.0
        small = cv2.resize(guide, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / scale
        a = guided_coefficients(p, small, radius, eps)
        coeff = np.concatenate([a, small, p[..., None], seen[..., None]], axis=2)
    else:
        coeff = np.stack([p, seen], axis=2)
    out = np.empty((height, width), np.float32)
    for r0 in range(0, height, rows):
        r1 = min(r0 + rows, height)
        c = _bilinear_band(coeff, r0, r1, height, width)
        if guide is not None:
            g = guide[r0:r1].astype(np.float32) / scale
            q = c[..., 6] + np.einsum("hwc,hwc->hw", c[..., :3], g - c[..., 3:6])
        else:
            q = c[..., 0]
        if edge_log is not None:
            values, weights = _taps(p, r0, r1, height, width)
            q = snap_to_side(q, values, weights, edge_log, _taps(seen, r0, r1, height, width)[0] > 0.5)
        band = out[r0:r1]
        np.exp(q, out=band)
        band[c[..., -1] < 0.5] = np.nan
    return out


def guided_upsample_reference(
    log_coarse: np.ndarray,
    guide: np.ndarray | None,
    height: int,
    width: int,
    radius: int = 2,
    eps: float = 1e-4,
    edge_log: float | None = None,
) -> np.ndarray:
    """``guided_upsample`` in one piece with the float64 NumPy bilinear resampling (the reference)."""
    p, seen = _filled(log_coarse)
    h, w = p.shape
    seen_up = bilinear_upsample_reference(seen, height, width) >= 0.5
    if guide is None:
        q = bilinear_upsample_reference(p, height, width)
    else:
        scale = 255.0 if guide.dtype == np.uint8 else 1.0
        small = cv2.resize(guide, (w, h), interpolation=cv2.INTER_AREA).astype(np.float32) / scale
        a = guided_coefficients(p, small, radius, eps)
        g = guide.astype(np.float64) / scale
        detail = g - bilinear_upsample_reference(small, height, width)
        q = bilinear_upsample_reference(p, height, width) + (
            bilinear_upsample_reference(a, height, width) * detail
        ).sum(-1)
    if edge_log is not None:
        q = _snap_reference(q, p.astype(np.float64), seen > 0.5, edge_log)
    return np.where(seen_up, np.exp(q), np.nan).astype(np.float32)


def _snap_reference(q: np.ndarray, p: np.ndarray, seen: np.ndarray, edge_log: float) -> np.ndarray:
    """``snap_to_side`` written per pixel with loops over the taps (the reference): [H, W] float64; ``seen``
    [h, w] bool the solve level's seen pixels."""
    H, W = q.shape
    h, w = p.shape
    y = np.clip((np.arange(H) + 0.5) * h / H - 0.5, 0, h - 1)
    x = (np.arange(W) + 0.5) * w / W - 0.5
    out = q.copy()
    for i in range(H):
        y0 = min(int(np.floor(y[i])), max(h - 2, 0))
        fy = y[i] - y0
        for j in range(W):
            x0 = int(np.floor(x[j]))
            fx = x[j] - x0
            taps = [
                (y0, x0 % w, (1 - fy) * (1 - fx)),
                (y0, (x0 + 1) % w, (1 - fy) * fx),
                (min(y0 + 1, h - 1), x0 % w, fy * (1 - fx)),
                (min(y0 + 1, h - 1), (x0 + 1) % w, fy * fx),
            ]
            kept = [(p[r, c], wt) for r, c, wt in taps if seen[r, c]]
            if not kept:
                continue
            vals = [v for v, _ in kept]
            out[i, j] = min(max(q[i, j], min(vals)), max(vals))
            if max(vals) - min(vals) <= edge_log and len(kept) == 4:
                continue
            near = min(vals, key=lambda v: abs(v - out[i, j]))
            side = [(v, wt) for v, wt in kept if abs(v - near) <= edge_log]
            out[i, j] = sum(v * wt for v, wt in side) / max(sum(wt for _, wt in side), 1e-12)
    return out
