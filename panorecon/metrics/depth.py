"""Depth metrics (AbsRel, RMSE, delta < 1.25) over pixels with truth, median-aligned unless metric, or aligned by
scale and shift in inverse depth for affine-invariant predictions."""

from __future__ import annotations

import numpy as np


def depth_metrics(pred: np.ndarray, truth: np.ndarray, align: str = "median", mask: np.ndarray | None = None) -> dict:
    """pred, truth: same-shape depth/distance arrays (metres). Pixels count where both are finite and
    positive (and ``mask``). align="median" scales pred by median(truth / pred) first (for teachers known up
    to scale); "inverse-affine" fits 1/truth ~ a / pred + b by least squares (float64) and compares
    1 / (a / pred + b), dropping pixels where that is not positive (the usual protocol for affine-invariant
    disparity; ``shift`` = b, in 1/metres); "none" compares as is (metric). Returns abs_rel, rmse (metres),
    delta1 (fraction), pixels, scale (the alignment factor applied). With no pixel to compare, the values are
    NaN and pixels = 0."""
    if pred.shape != truth.shape:
        raise ValueError(f"depth_metrics: prediction {pred.shape} and truth {truth.shape} differ in shape")
    if align not in ("median", "none", "inverse-affine"):
        raise ValueError(f"depth_metrics: align={align!r}; expected 'median', 'inverse-affine' or 'none'")
    p = pred.astype(np.float64)
    t = truth.astype(np.float64)
    ok = np.isfinite(p) & np.isfinite(t) & (p > 0) & (t > 0)
    if mask is not None:
        ok &= mask
    if not ok.any():
        return {
            "abs_rel": float("nan"),
            "rmse": float("nan"),
            "delta1": float("nan"),
            "pixels": 0,
            "scale": float("nan"),
            "align": align,
        }
    p, t = p[ok], t[ok]
    extra = {}
    if align == "inverse-affine":
        A = np.stack([1.0 / p, np.ones_like(p)], 1)
        scale, shift = np.linalg.lstsq(A, 1.0 / t, rcond=None)[0]
        inv = scale / p + shift
        keep = inv > 0
        if not keep.any():
            return {
                "abs_rel": float("nan"),
                "rmse": float("nan"),
                "delta1": float("nan"),
                "pixels": 0,
                "scale": float(scale),
                "shift": float(shift),
                "align": align,
            }
        p, t = 1.0 / inv[keep], t[keep]
        scale, extra = 1.0 / float(scale), {"shift": float(shift)}
    else:
        scale = float(np.median(t / p)) if align == "median" else 1.0
        p = p * scale
    ratio = np.maximum(p / t, t / p)
    return {
        "abs_rel": float(np.mean(np.abs(p - t) / t)),
        "rmse": float(np.sqrt(np.mean((p - t) ** 2))),
        "delta1": float(np.mean(ratio < 1.25)),
        "pixels": int(len(p)),
        "scale": float(scale),
        "align": align,
        **extra,
    }
