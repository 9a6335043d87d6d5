"""Alignment of affine-invariant views (depth or disparity known up to an unknown scale AND shift).

For each view the quantity t = g(p) * (a_i * raw_i(p) + b_i) is the same for every view seeing ERP ray p:
t is inverse ray distance for disparity output (g = cos theta, since disparity ~ 1/z and z = d cos theta),
ray distance for z-depth output (g = 1 / cos theta) and for distance output (g = 1). Pairs of overlapping
views give linear equations g_i (a_i r_i + b_i) - g_j (a_j r_j + b_j) = 0 in (a, b), solved by least
squares with the gauge a_ref = 1 (ref: the view with the most valid pixels) and mean(b) = 0. A global
shift of t is almost unobservable from overlaps (only through the variation of g across an overlap), so
it is fixed by assuming the teacher's shifts average to zero over the views: its error is then the mean of
the per-view shift errors, not one view's. On scenes with a large depth range (outdoors) a small error in
inverse distance still moves far points a lot: the intrinsic weakness of affine-invariant disparity.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..geometry import ViewDepth, erp_directions
from .warp import project_erp_rays

_PAIR_SAMPLES = 4000


def align_affine_views(views: Sequence[ViewDepth], erp_height: int = 128, seed: int = 0):
    """-> (per-view ray distance [h, w] float32 with NaN invalid, per-view shift b [V], report dict)."""
    kinds = {v.kind for v in views if v.affine}
    if len(kinds) > 1:
        raise ValueError(f"affine views of mixed kinds {sorted(kinds)}: expected one output kind per fusion")
    kind = kinds.pop()
    V = len(views)
    dirs = erp_directions(erp_height, 2 * erp_height).reshape(-1, 3)
    N = len(dirs)
    raw_erp = np.full((V, N), np.nan)
    g_erp = np.full((V, N), np.nan)
    for i, v in enumerate(views):
        idx, rows, cols, cos = project_erp_rays(v.camera, dirs)
        r = v.depth[rows, cols].astype(np.float64)
        ok = v.valid[rows, cols] & np.isfinite(r)
        raw_erp[i, idx[ok]] = r[ok]
        g_erp[i, idx[ok]] = _g(kind, cos[ok])
    counts = np.isfinite(raw_erp).sum(1)
    ref = int(np.argmax(counts))
    rng = np.random.default_rng(seed)
    eqs = []
    pairs = 0
    for i in range(V):
        for j in range(i + 1, V):
            both = np.flatnonzero(np.isfinite(raw_erp[i]) & np.isfinite(raw_erp[j]))
            if len(both) < 8:
                continue
            if len(both) > _PAIR_SAMPLES:
                both = rng.choice(both, _PAIR_SAMPLES, replace=False)
            row = np.zeros((len(both), 2 * V))
            row[:, 2 * i] = g_erp[i, both] * raw_erp[i, both]
            row[:, 2 * i + 1] = g_erp[i, both]
            row[:, 2 * j] = -g_erp[j, both] * raw_erp[j, both]
            row[:, 2 * j + 1] = -g_erp[j, both]
            eqs.append(row / np.sqrt(len(both)))
            pairs += 1
    gauge = np.zeros((2, 2 * V))
    gauge[0, 2 * ref] = 1e3  # a_ref = 1
    gauge[1, 1::2] = 1e3 / V  # mean(b) = 0
    M = np.concatenate(eqs + [gauge]) if eqs else gauge
    rhs = np.zeros(len(M))
    rhs[-2] = 1e3
    sol, *_ = np.linalg.lstsq(M, rhs, rcond=None)
    a, b = sol[0::2], sol[1::2]
    unconnected = [i for i in range(V) if i != ref and not np.any(M[:-2, 2 * i] != 0)]
    a[unconnected], b[unconnected] = 1.0, 0.0
    dists = []
    for v, ai, bi in zip(views, a, b):
        cos = 1.0 / v.camera.z_to_distance_factor()
        t = _g(kind, cos) * (ai * v.depth.astype(np.float64) + bi)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = 1.0 / t if kind == "disparity" else t
        d[~v.valid | ~(d > 0) | ~np.isfinite(d)] = np.nan
        dists.append(d.astype(np.float32))
    report = {"kind": kind, "reference_view": ref, "pairs": pairs, "unconnected_views": unconnected,
              "scale": a.tolist(), "shift": b.tolist()}
    return dists, b, report


def _g(kind: str, cos: np.ndarray) -> np.ndarray:
    if kind == "disparity":
        return cos
    if kind == "z":
        return 1.0 / cos
    return np.ones_like(cos)
