"""Wrap-around seam score of a panorama (a discontinuity score in the spirit of PanoEval's)."""

from __future__ import annotations

import numpy as np


def seam_discontinuity(image: np.ndarray, band: int = 8) -> float:
    """Mean |difference| across the wrap (last column -> first) divided by the mean |difference| between
    neighbouring columns within ``band`` columns of either edge. ~1: the wrap looks like any other column
    boundary; >> 1: a visible seam. image: [H, W] or [H, W, C] (any dtype; computed in float64)."""
    img = np.asarray(image, np.float64)
    if img.ndim == 2:
        img = img[..., None]
    if img.ndim != 3 or img.shape[1] < 2 * band + 2:
        raise ValueError(
            f"seam_discontinuity: image of shape {image.shape}: expected [H, W(, C)] with W >= {2 * band + 2}"
        )
    wrap = np.abs(img[:, 0] - img[:, -1]).mean()
    inner = np.concatenate(
        [np.abs(np.diff(img[:, : band + 1], axis=1)).ravel(), np.abs(np.diff(img[:, -band - 1 :], axis=1)).ravel()]
    ).mean()
    return float(wrap / inner) if inner > 0 else (0.0 if wrap == 0 else float("inf"))
