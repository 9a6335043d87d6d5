"""Depth metrics (AbsRel, RMSE, delta < 1.25, the flying share) over pixels with truth, median-aligned unless
metric, or aligned by scale and shift in inverse depth for affine-invariant predictions.

Flying points: pixels (points) whose aligned distance is more than ``FLYING_REL`` (50 %) off the truth, the
points a fusion throws into the air between a foreground and its background when it blends across a depth edge
(or puts a pixel on the wrong side of one). A share, not a mean: one point a thousand times too far weighs as
much as one twice too far, so a few of them cannot hide in (or dominate) AbsRel."""

from __future__ import annotations

import math

import numpy as np

METRIC_CHUNK = 1 << 22  # pixels per chunk of depth_metrics' sums
FLYING_REL = 0.5  # a point more than this far off its true distance (relative) is a flying point


def depth_metrics(pred: np.ndarray, truth: np.ndarray, align: str = "median", mask: np.ndarray | None = None) -> dict:
    """pred, truth: same-shape depth/distance arrays (metres). Pixels count where both are finite and
    positive (and ``mask``). align="median" scales pred by median(truth / pred) first (for teachers known up
    to scale); "inverse-affine" fits 1/truth ~ a / pred + b by least squares (float64) and compares
    1 / (a / pred + b), dropping pixels where that is not positive (the usual protocol for affine-invariant
    disparity; ``shift`` = b, in 1/metres); "none" compares as is (metric). Returns abs_rel, rmse (metres),
    delta1 (fraction), flying (the share of pixels more than ``FLYING_REL`` off, after the alignment), pixels,
    scale (the alignment factor applied). With no pixel to compare, the values are NaN and pixels = 0."""
    if pred.shape != truth.shape:
        raise ValueError(f"depth_metrics: prediction {pred.shape} and truth {truth.shape} differ in shape")
    if align not in ("median", "none", "inverse-affine"):
        raise ValueError(f"depth_metrics: align={align!r}; expected 'median', 'inverse-affine' or 'none'")
    with np.errstate(invalid="ignore"):  # the pixels compared are copied to float64, not the whole maps
        ok = np.isfinite(pred) & np.isfinite(truth) & (pred > 0) & (truth > 0)
    if mask is not None:
        ok &= mask
    if not ok.any():
        return {
            "abs_rel": float("nan"),
            "rmse": float("nan"),
            "delta1": float("nan"),
            "flying": float("nan"),
            "pixels": 0,
            "scale": float("nan"),
            "align": align,
        }
    # the compared pixels in their own dtype (float32 maps: half a float64 copy); every product, ratio and sum
    # below is float64, chunk by chunk
    p, t = pred[ok], truth[ok]
    extra = {}
    if align == "inverse-affine":
        p, t = p.astype(np.float64), t.astype(np.float64)
        A = np.stack([1.0 / p, np.ones_like(p)], 1)
        scale, shift = np.linalg.lstsq(A, 1.0 / t, rcond=None)[0]
        inv = scale / p + shift
        keep = inv > 0
        if not keep.any():
            return {
                "abs_rel": float("nan"),
                "rmse": float("nan"),
                "delta1": float("nan"),
                "flying": float("nan"),
                "pixels": 0,
                "scale": float(scale),
                "shift": float(shift),
                "align": align,
            }
        p, t = 1.0 / inv[keep], t[keep]
        scale, extra = 1.0 / float(scale), {"shift": float(shift)}
    else:
        scale = _median_ratio(t, p) if align == "median" else 1.0
    # sums over chunks of float64 temporaries (full-size maps at 8K would need several 268 MB ones at once)
    rel, sq, d1, fly = 0.0, 0.0, 0, 0
    for i in range(0, len(p), METRIC_CHUNK):
        pc = p[i : i + METRIC_CHUNK].astype(np.float64) * (1.0 if align == "inverse-affine" else scale)
        tc = t[i : i + METRIC_CHUNK].astype(np.float64)
        r = np.abs(pc - tc) / tc
        rel += float(np.sum(r))
        sq += float(np.sum((pc - tc) ** 2))
        d1 += int(np.count_nonzero(np.maximum(pc / tc, tc / pc) < 1.25))
        fly += int(np.count_nonzero(r > FLYING_REL))
    return {
        "abs_rel": rel / len(p),
        "rmse": float(np.sqrt(sq / len(p))),
        "delta1": d1 / len(p),
        "flying": fly / len(p),
        "pixels": int(len(p)),
        "scale": float(scale),
        "align": align,
        **extra,
    }


def _median_ratio(t: np.ndarray, p: np.ndarray) -> float:
    """median(t / p) in float64 (``np.median``'s value), the ratios written chunk by chunk into one float64 array
    that the median then partitions in place (no float64 copies of t and p, no copy inside the median)."""
    ratio = np.empty(len(t), np.float64)
    for i in range(0, len(t), METRIC_CHUNK):
        np.divide(t[i : i + METRIC_CHUNK], p[i : i + METRIC_CHUNK], out=ratio[i : i + METRIC_CHUNK], dtype=np.float64)
    return float(np.median(ratio, overwrite_input=True))


def depth_edge_mask(truth: np.ndarray, jump: float = 0.05, px: int = 2) -> np.ndarray:
    """[H, W] bool: the pixels within ``px`` pixels (Chebyshev) of a true depth discontinuity, i.e. of a pair of
    4-neighbours (wrapping at the ERP seam) with finite positive truth whose log distances differ by more than
    ``jump``, or one of which has truth and the other none (a sky border)."""
    import cv2

    with np.errstate(divide="ignore", invalid="ignore"):
        lt = np.log(np.where(truth > 0, truth, np.nan).astype(np.float32))
    ok = np.isfinite(lt)
    right_l, right_ok = np.roll(lt, -1, axis=1), np.roll(ok, -1, axis=1)
    with np.errstate(invalid="ignore"):
        h_edge = (ok & right_ok & (np.abs(right_l - lt) > jump)) | (ok != right_ok)
        v_edge = (ok[1:] & ok[:-1] & (np.abs(lt[1:] - lt[:-1]) > jump)) | (ok[1:] != ok[:-1])
    edge = h_edge | np.roll(h_edge, 1, axis=1)
    edge[1:] |= v_edge
    edge[:-1] |= v_edge
    W = truth.shape[1]
    padded = np.concatenate([edge[:, W - px :], edge, edge[:, :px]], axis=1).astype(np.uint8)
    grown = cv2.dilate(padded, np.ones((2 * px + 1, 2 * px + 1), np.uint8), borderType=cv2.BORDER_CONSTANT)
    return grown[:, px : px + W].astype(bool)


def edge_depth_metrics(
    pred: np.ndarray, truth: np.ndarray, scale: float, mask: np.ndarray | None = None, jump: float = 0.05, px: int = 2
) -> dict:
    """AbsRel of ``pred`` x ``scale`` (the whole map's alignment, e.g. ``depth_metrics``' scale) on the pixels
    within ``px`` of a true depth discontinuity (``depth_edge_mask``) only, where both are finite and positive
    (and ``mask``): how sharp and well placed the depth edges are. -> edge_abs_rel, edge_pixels, jump, px."""
    near = depth_edge_mask(truth, jump, px)
    if mask is not None:
        near &= mask
    with np.errstate(invalid="ignore"):
        near &= np.isfinite(pred) & np.isfinite(truth) & (pred > 0) & (truth > 0)
    p, t = pred[near].astype(np.float64) * scale, truth[near].astype(np.float64)
    rel = float(np.mean(np.abs(p - t) / t)) if len(t) else float("nan")
    return {"edge_abs_rel": rel, "edge_pixels": int(len(t)), "jump": jump, "px": px}


def ws_depth_metrics(pred: np.ndarray, truth: np.ndarray, scale: float, mask: np.ndarray | None = None) -> dict:
    """``depth_metrics``' AbsRel, RMSE (metres) and delta1 of ERP distance maps [H, W] with ``pred`` x ``scale``
    (the plain metrics' alignment), each pixel weighted by its row's solid angle (``metrics.panorama``'s WS
    weights, cos latitude) over the pixels where both are finite and positive (and ``mask``): ws_abs_rel,
    ws_rmse, ws_delta1 (NaN with no such pixel). Float64."""
    from .panorama import erp_row_weights

    if pred.shape != truth.shape or pred.ndim != 2:
        raise ValueError(f"ws_depth_metrics: prediction {pred.shape} and truth {truth.shape}: expected one [H, W]")
    H, W = pred.shape
    weights = erp_row_weights(H)
    total, rel, sq, d1 = 0.0, 0.0, 0.0, 0.0
    step = max(1, METRIC_CHUNK // max(W, 1))  # rows per chunk: float64 temporaries of at most METRIC_CHUNK pixels
    for r in range(0, H, step):
        pc, tc = pred[r : r + step], truth[r : r + step]
        with np.errstate(invalid="ignore"):
            ok = np.isfinite(pc) & np.isfinite(tc) & (pc > 0) & (tc > 0)
        if mask is not None:
            ok &= mask[r : r + step]
        w = np.broadcast_to(weights[r : r + step, None], pc.shape)[ok]
        p, t = pc[ok].astype(np.float64) * scale, tc[ok].astype(np.float64)
        total += float(np.sum(w))
        rel += float(np.sum(w * np.abs(p - t) / t))
        sq += float(np.sum(w * (p - t) ** 2))
        d1 += float(np.sum(w * (np.maximum(p / t, t / p) < 1.25)))
    if total == 0:
        return {"ws_abs_rel": float("nan"), "ws_rmse": float("nan"), "ws_delta1": float("nan")}
    return {"ws_abs_rel": rel / total, "ws_rmse": math.sqrt(sq / total), "ws_delta1": d1 / total}


def point_flying_share(xyz: np.ndarray, truth: np.ndarray, scale: float = 1.0) -> tuple[float, int]:
    """The flying share of a cloud seen from the panorama centre: of the points ``xyz`` [N, 3] (metres, the
    panorama's frame) x ``scale`` whose ray from the centre meets a finite positive true ERP distance ``truth``
    [H, W] (nearest pixel), the share whose distance from the centre is more than ``FLYING_REL`` off that
    distance -> (share, points compared; NaN and 0 when none). For a cloud back-projected from a depth map it is
    that map's ``flying``; a point off the centre's line of sight (a multi-view baseline's point behind a
    surface) counts as flying too. Float64, ``METRIC_CHUNK`` points at a time (integer counts: the same share in
    any chunking; an 8K cloud's float64 copies would be several 805 MB arrays at once)."""
    from ..geometry import sample_erp
    from ..geometry.remap import pad_erp

    truth = np.asarray(truth, np.float32)
    padded = pad_erp(truth)  # sample_erp pads the map for every call: once here
    flying, compared = 0, 0
    for i in range(0, len(xyz), METRIC_CHUNK):
        pts = np.asarray(xyz[i : i + METRIC_CHUNK], np.float64) * scale
        r = np.linalg.norm(pts, axis=1)
        ok = r > 0
        true = sample_erp(truth, pts[ok] / r[ok, None], "nearest", padded=padded).astype(np.float64)
        with np.errstate(invalid="ignore"):
            use = np.isfinite(true) & (true > 0)
        off = np.abs(r[ok][use] - true[use]) / true[use]
        flying += int(np.count_nonzero(off > FLYING_REL))
        compared += int(use.sum())
    if not compared:
        return float("nan"), 0
    return flying / compared, compared
