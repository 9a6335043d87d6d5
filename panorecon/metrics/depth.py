"""Depth metrics (AbsRel, RMSE, delta < 1.25) over pixels with truth, median-aligned unless metric."""
from __future__ import annotations

import numpy as np


def depth_metrics(pred: np.ndarray, truth: np.ndarray, align: str = "median", mask: np.ndarray | None = None) -> dict:
    """pred, truth: same-shape depth/distance arrays (metres). Pixels count where both are finite and
    positive (and ``mask``). align="median" scales pred by median(truth / pred) first (for teachers known up
    to scale); "none" compares as is (metric). Returns abs_rel, rmse (metres), delta1 (fraction), pixels,
    scale (the alignment factor applied). With no pixel to compare, the values are NaN and pixels = 0."""
    if pred.shape != truth.shape:
        raise ValueError(f"depth_metrics: prediction {pred.shape} and truth {truth.shape} differ in shape")
    if align not in ("median", "none"):
        raise ValueError(f"depth_metrics: align={align!r}; expected 'median' or 'none'")
    p = pred.astype(np.float64)
    t = truth.astype(np.float64)
    ok = np.isfinite(p) & np.isfinite(t) & (p > 0) & (t > 0)
    if mask is not None:
        ok &= mask
    if not ok.any():
        return {"abs_rel": float("nan"), "rmse": float("nan"), "delta1": float("nan"), "pixels": 0, "scale": float("nan"), "align": align}
    p, t = p[ok], t[ok]
    scale = float(np.median(t / p)) if align == "median" else 1.0
    p = p * scale
    ratio = np.maximum(p / t, t / p)
    return {"abs_rel": float(np.mean(np.abs(p - t) / t)), "rmse": float(np.sqrt(np.mean((p - t) ** 2))),
            "delta1": float(np.mean(ratio < 1.25)), "pixels": int(ok.sum()), "scale": scale, "align": align}
