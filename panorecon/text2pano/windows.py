"""Sliding windows over a wide latent, and the seam block that straddles its wrap (paper §2.2, Figure 2).

Columns are latent columns. Windows run left to right without wrapping (the last one is moved left so it
ends at the right edge); the seam block is one more window made of the rightmost and leftmost
``window // 2`` columns, so the two ends of the panorama are denoised together.
"""

from __future__ import annotations

import numpy as np


def window_starts(latent_width: int, window: int, stride: int) -> list[int]:
    """First columns of the sliding windows: every column is covered, the last window ends at the edge."""
    if not (0 < window <= latent_width and 0 < stride <= window):
        raise ValueError(
            f"window {window}, stride {stride} on a latent {latent_width} wide: expected "
            "0 < window <= width and 0 < stride <= window (no uncovered columns)"
        )
    starts = list(range(0, latent_width - window + 1, stride))
    if starts[-1] + window < latent_width:
        starts.append(latent_width - window)
    return starts


def coverage(latent_width: int, window: int, stride: int) -> np.ndarray:
    """[latent_width] number of sliding windows covering each column."""
    c = np.zeros(latent_width)
    for s in window_starts(latent_width, window, stride):
        c[s : s + window] += 1
    return c


def seam_columns(latent_width: int, window: int) -> np.ndarray:
    """[2 * (window // 2)] latent columns of the seam block, in order across the wrap (right end, then left end)."""
    half = window // 2
    return np.concatenate([np.arange(latent_width - half, latent_width), np.arange(half)])


def seam_weights(latent_width: int, window: int, stride: int) -> np.ndarray:
    """Adaptive blend weight of the seam block over its columns [2 * (window // 2)].

    Rule: the seam block's *share* of a column's merged noise prediction falls linearly from ~1 at the wrap
    to 0 at the block's two edges (a hat over the block); its weight is the weight that gives that share
    against the sliding windows covering the column: w = coverage * share / (1 - share). At the wrap, where no
    sliding window sees both ends, the jointly denoised seam block decides (share 1 - 1/(2 * (window // 2)));
    towards the block's edges it hands over to the sliding windows, so no new seam appears there. The weight
    adapts to window and stride through the coverage.
    """
    half = window // 2
    cols = seam_columns(latent_width, window)
    cov = coverage(latent_width, window, stride)[cols]
    x = (np.arange(2 * half) + 0.5) / (2 * half)  # 0..1 across the block; the wrap is at 0.5
    share = 1.0 - np.abs(2 * x - 1)
    return cov * share / (1.0 - share)
