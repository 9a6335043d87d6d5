"""Alignment of affine-invariant views (depth or disparity known up to an unknown scale AND shift).

For each view the quantity t = g(p) * (a_i * raw_i(p) + b_i) is the same for every view seeing ERP ray p:
t is inverse ray distance for disparity output (g = cos theta, since disparity ~ 1/z and z = d cos theta),
ray distance for z-depth output (g = 1 / cos theta) and for distance output (g = 1). Pairs of overlapping
views give homogeneous linear equations g_i (a_i r_i + b_i) - g_j (a_j r_j + b_j) = 0 in (a, b). Their
near-null space is two-dimensional -- the true (a, b) and, almost, a common shift of b -- so (a, b) is taken
from the two smallest right singular vectors (total least squares, which unlike a least-squares solve with
a pinned reference does not shrink the other views' scales under noise) and fixed by the gauge a_ref = 1
(ref: the view with the most valid pixels) and mean(b) = 0. A global shift of t is almost unobservable from
overlaps (only through the variation of g across an overlap), so it is fixed by assuming the teacher's
shifts average to zero over the views: its error is then the mean of the per-view shift errors, not one
view's. Views not linked to the reference through overlaps keep a = 1, b = 0 and are reported. On scenes with a
large depth range (outdoors) a small error in inverse distance still moves far points a lot: the intrinsic
weakness of affine-invariant disparity.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.sparse.csgraph import connected_components

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
    eqs, linked = [], []
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
            linked.append((i, j))
    # views linked to the reference through overlaps are aligned; the others keep a = 1, b = 0
    graph = np.zeros((V, V), bool)
    for i, j in linked:
        graph[i, j] = graph[j, i] = True
    component = connected_components(graph, directed=False)[1]
    members = np.flatnonzero(component == component[ref])
    a, b = np.ones(V), np.zeros(V)
    if len(members) > 1:
        cols = np.stack([2 * members, 2 * members + 1], 1).ravel()
        M = np.concatenate(eqs)[:, cols]
        a[members], b[members] = _null_pair_with_gauge(M[np.any(M != 0, axis=1)], int(np.searchsorted(members, ref)))
    unconnected = [int(i) for i in range(V) if component[i] != component[ref]]
    dists = []
    for v, ai, bi in zip(views, a, b):
        cos = 1.0 / v.camera.z_to_distance_factor()
        t = _g(kind, cos) * (ai * v.depth.astype(np.float64) + bi)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = 1.0 / t if kind == "disparity" else t
        d[~v.valid | ~(d > 0) | ~np.isfinite(d)] = np.nan
        dists.append(d.astype(np.float32))
    report = {
        "kind": kind,
        "reference_view": ref,
        "pairs": len(linked),
        "unconnected_views": unconnected,
        "scale": a.tolist(),
        "shift": b.tolist(),
    }
    return dists, b, report


def _null_pair_with_gauge(M: np.ndarray, ref: int) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) [V] each from the homogeneous overlap equations M [rows, 2V] (columns a_0, b_0, a_1, ...) of
    views linked by overlaps.

    Without noise M has a null space spanned by the true (a, b) and, nearly, by a common shift of b; an
    ordinary least-squares solve with a_ref = 1 pulls every other view's a towards 0 under noise (errors in
    variables: a flat overlap cannot tell scale from shift). Instead: the two right singular vectors of M with
    the smallest singular values (columns scaled to unit norm first, in float64), combined so that a_ref = 1
    and mean(b) = 0."""
    norms = np.linalg.norm(M, axis=0)
    norms[norms == 0] = 1.0
    G = (M / norms).T @ (M / norms)
    _, vecs = np.linalg.eigh(G)
    basis = vecs[:, :2] / norms[:, None]  # back to unscaled unknowns
    C = np.stack([basis[2 * ref], basis[1::2].mean(0)])  # a_ref and mean(b) of each basis vector
    coef = np.linalg.lstsq(C, np.array([1.0, 0.0]), rcond=None)[0]
    x = basis @ coef
    return x[0::2], x[1::2]


def _g(kind: str, cos: np.ndarray) -> np.ndarray:
    if kind == "disparity":
        return cos
    if kind == "z":
        return 1.0 / cos
    return np.ones_like(cos)
