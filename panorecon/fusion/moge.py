"""MoGe-style reference merge (after MoGe's ``merge_panorama_depth``), kept as the baseline the method's
fusion is measured against.

Per view: log-distance gradient rows (horizontal, wrapping, and vertical) and 5-point Laplacian rows,
each equation weighted 1 and *stacked* per view (not aggregated), no per-view scale, no zero-order term,
solved by scipy's LSMR on a multi-scale pyramid (coarse solution upsampled as the next initial guess).
The constant of integration is left in the null space during the solve and fixed afterwards by the median
of (x - l_i) over every observed pixel, so the output has the views' own (median) scale.
Designed for 12 icosahedron-vertex views at 90 degrees FOV; it takes whatever views it is given.
"""
from __future__ import annotations

import time
from typing import Sequence

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from ..geometry import ViewDepth
from .connectivity import check_connectivity
from .lsq import FusionResult, _check_views, _observe, _upsample, pyramid_heights
from .operators import horizontal_pairs, laplacian_matrix, vertical_pairs


def _rows(level, lap_weight: float):
    H, W = level.height, level.width
    N = H * W
    hp, hq = horizontal_pairs(H, W)
    vp, vq = vertical_pairs(H, W)
    lap = laplacian_matrix(H, W).tocsr()
    blocks, rhs = [], []
    for o in level.obs:
        L = o.dense(N)
        for p, q in ((hp, hq), (vp, vq)):
            g = L[q] - L[p]
            ok = np.flatnonzero(np.isfinite(g))
            m = len(ok)
            blocks.append(sp.csr_matrix((np.tile([1.0, -1.0], m), (np.repeat(np.arange(m), 2), np.stack([q[ok], p[ok]], 1).ravel())), shape=(m, N)))
            rhs.append(g[ok])
        with np.errstate(invalid="ignore"):
            lv = lap @ L
        ok = np.flatnonzero(np.isfinite(lv))
        blocks.append(lap_weight * lap[ok])
        rhs.append(lap_weight * lv[ok])
    return sp.vstack(blocks).tocsr(), np.concatenate(rhs)


def moge_merge(views: Sequence[ViewDepth], height: int, width: int, *, levels: int | None = None,
               lap_weight: float = 1.0, atol: float = 1e-5, maxiter: int = 500) -> FusionResult:
    """The reference merge; the same ``FusionResult`` as ``fuse_views`` (view_scale all 1, no shift)."""
    _check_views(views, height, width)
    if any(v.affine for v in views):
        raise ValueError("moge_merge takes scale-only (relative or metric) views; align affine-invariant views first")
    t0 = time.perf_counter()
    dists = [v.to_distance() for v in views]
    report = {"solver": "lsmr, coarse-to-fine (MoGe-style)", "levels": [], "connectivity": check_connectivity(views)}
    x = None
    prev = None
    for h in pyramid_heights(height, levels, coarsest=64):
        tl = time.perf_counter()
        level = _observe(views, dists, h)
        A, b = _rows(level, lap_weight)
        if x is None:
            x0 = np.zeros(h * 2 * h)
            cnt = np.zeros_like(x0)
            for o in level.obs:
                np.add.at(x0, o.index, o.log_distance)
                np.add.at(cnt, o.index, 1.0)
            x = np.where(cnt > 0, x0 / np.maximum(cnt, 1), 0.0)
        else:
            x = _upsample(x, prev.seen, prev.height, h)
        r0 = b - A @ x
        out = spla.lsmr(A, r0, atol=atol, btol=atol, maxiter=maxiter)
        x = x + out[0]
        resid = float(np.linalg.norm(A.T @ (A @ x - b)) / max(np.linalg.norm(A.T @ b), 1e-300))
        report["levels"].append({"height": h, "width": 2 * h, "rows": A.shape[0], "iterations": int(out[2]),
                                 "residual": resid, "seconds": time.perf_counter() - tl})
        prev = level
    seen = prev.seen
    # fix the constant of integration: median of (x - l_i) over all observations is 0
    offsets = np.concatenate([x[o.index] - o.log_distance for o in prev.obs])
    x = x - np.median(offsets)
    distance = np.full(height * width, np.nan, np.float32)
    distance[seen] = np.exp(x[seen]).astype(np.float32)
    if not np.isfinite(distance[seen]).all():
        raise ValueError("moge_merge: non-finite fused distances")
    report.update(iterations=[lv["iterations"] for lv in report["levels"]], residual=report["levels"][-1]["residual"],
                  seconds=time.perf_counter() - t0, views=len(views))
    return FusionResult(distance.reshape(height, width), seen.reshape(height, width), np.ones(len(views)), np.zeros(len(views)), report)
