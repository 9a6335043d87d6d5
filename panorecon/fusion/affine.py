"""Alignment of affine-invariant views (depth or disparity known up to an unknown scale AND shift).

For each view the quantity t = g(p) * (a_i * raw_i(p) + b_i) is the same for every view seeing ERP ray p:
t is inverse ray distance for disparity output (g = cos theta, since disparity ~ 1/z and z = d cos theta),
ray distance for z-depth output (g = 1 / cos theta) and for distance output (g = 1). Pairs of overlapping
views give homogeneous linear equations g_i (a_i r_i + b_i) - g_j (a_j r_j + b_j) = 0 in (a, b), rows of M.
Two unknowns are fixed by a gauge: a global scale (a_ref = 1; ref: the view with the most valid pixels) and a
global shift of t, which overlaps observe only weakly (through the variation of g across an overlap). Two gauges:

- ``"reference"`` (default): the reference view's shift b_ref is the one whose overlaps the other views fit best
  relative to the reference's own t: with (a_ref, b_ref) = (1, beta) each other view's (a, b) is the least-squares
  fit to its overlaps, leaving a misfit E(beta) = [1, beta] S [1, beta]^T (S: the Schur complement of the
  others' block of M^T M), and beta minimises E(beta) / D(beta), D = [1, beta] M_ref^T M_ref [1, beta]^T the
  reference's t over its overlaps: a 2 x 2 generalised eigenproblem, closed form, kept where the reference's t is
  positive on all its pixels (beta > -min raw_ref: output of noise can put the minimum below). (a, b) are then
  the total least squares solution under b_ref = beta a_ref. A network's raw output has an offset of its own (its
  value at zero disparity), so no assumption about the shifts' mean is made.
- ``"mean-shift"`` (the first alignment; the committed tables of ``sim:affine-disparity`` pin it): (a, b) from
  the two smallest right singular vectors of M (total least squares), combined so that a_ref = 1 and mean(b) = 0,
  i.e. assuming the teacher's shifts average to zero. Right for a noise model with zero-mean shifts; a network
  whose output is offset (learned-w16 on bedroom's 20 views at width 256: raw value -3.7 at zero disparity, the
  mean of each view's fit to the truth) breaks it, and under such noise the two singular vectors mix until scales
  turn negative.

Views not linked to the reference through overlaps keep a = 1, b = 0 and are reported. On scenes with a large
depth range (outdoors) a small error in inverse distance still moves far points a lot: the intrinsic weakness of
affine-invariant disparity. Float64 throughout.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from scipy.sparse.csgraph import connected_components

from ..geometry import ViewDepth, erp_directions
from .warp import project_erp_rays

_PAIR_SAMPLES = 4000
GAUGES = ("reference", "mean-shift")


def align_affine_views(views: Sequence[ViewDepth], erp_height: int = 128, seed: int = 0, gauge: str = "reference"):
    """-> (per-view ray distance [h, w] float32 with NaN invalid, per-view shift b [V], report dict).

    gauge: how the global shift is fixed (see the module docstring): "reference" or "mean-shift"."""
    if gauge not in GAUGES:
        raise ValueError(f"align_affine_views: gauge={gauge!r}: expected one of {', '.join(GAUGES)}")
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
        solve = _reference_shift_gauge if gauge == "reference" else _null_pair_with_gauge
        a[members], b[members] = solve(M[np.any(M != 0, axis=1)], int(np.searchsorted(members, ref)))
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
        "gauge": gauge,
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
    basis = _smallest_right_vectors(M, 2)
    C = np.stack([basis[2 * ref], basis[1::2].mean(0)])  # a_ref and mean(b) of each basis vector
    coef = np.linalg.lstsq(C, np.array([1.0, 0.0]), rcond=None)[0]
    x = basis @ coef
    return x[0::2], x[1::2]


def _reference_shift_gauge(M: np.ndarray, ref: int) -> tuple[np.ndarray, np.ndarray]:
    """(a, b) [V] each from the overlap equations M [rows, 2V] (columns a_0, b_0, a_1, ...): the reference's
    shift beta = b_ref / a_ref minimising E(beta) / D(beta) (module docstring; a 2 x 2 generalised eigenproblem),
    then (a, b) as the total-least-squares solution under b_ref = beta a_ref, scaled to a_ref = 1. The second
    step matters under noise: the least-squares fit that chooses beta shrinks the other views' scales (errors in
    variables; 3 % noise: fused AbsRel 0.029 against 0.008). Columns are scaled to unit norm first."""
    n = M.shape[1]
    r = [2 * ref, 2 * ref + 1]
    o = [k for k in range(n) if k not in r]
    norms = _column_norms(M)
    Ms = M / norms
    G = Ms.T @ Ms
    G_oo, G_or, G_rr = G[np.ix_(o, o)], G[np.ix_(o, r)], G[np.ix_(r, r)]
    S = G_rr - G_or.T @ np.linalg.lstsq(G_oo, G_or, rcond=None)[0]  # E = y^T S y, y the reference's scaled (a, b)
    # min y^T S y / y^T G_rr y: the generalised eigenvector of the smallest eigenvalue (G_rr is positive definite
    # when the reference's raw values vary over its overlaps)
    Li = np.linalg.inv(np.linalg.cholesky(G_rr))
    y = Li.T @ np.linalg.eigh(Li @ S @ Li.T)[1][:, 0]
    beta = (y[1] / norms[2 * ref + 1]) / (y[0] / norms[2 * ref]) if y[0] != 0 else -np.inf
    # t must be positive on the reference's pixels (a_ref = 1): beta > -min(raw_ref). Below that bound the ratio
    # falls towards it, so the constrained minimum is the bound (a farthest reference pixel at 1,000x the range)
    seen = M[:, 2 * ref + 1] != 0
    raw_ref = M[seen, 2 * ref] / M[seen, 2 * ref + 1]
    beta_min = -raw_ref.min() + 1e-3 * (np.ptp(raw_ref) or 1.0)
    beta = max(beta, beta_min)
    # total least squares in the 2V - 1 unknowns left once b_ref = beta a_ref
    keep = [k for k in range(n) if k != 2 * ref + 1]
    P = np.zeros((n, n - 1))
    P[keep, np.arange(n - 1)] = 1.0
    P[2 * ref + 1, keep.index(2 * ref)] = beta
    x = P @ _smallest_right_vectors(M @ P, 1)[:, 0]
    x = x / x[2 * ref]  # a_ref = 1
    return x[0::2], x[1::2]


def _smallest_right_vectors(M: np.ndarray, k: int) -> np.ndarray:
    """The k right singular vectors of M [rows, n] with the smallest singular values, found with M's columns
    scaled to unit norm and returned in the unscaled unknowns -> [n, k]."""
    norms = _column_norms(M)
    Ms = M / norms
    return np.linalg.eigh(Ms.T @ Ms)[1][:, :k] / norms[:, None]


def _column_norms(M: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(M, axis=0)
    norms[norms == 0] = 1.0
    return norms


def _g(kind: str, cos: np.ndarray) -> np.ndarray:
    if kind == "disparity":
        return cos
    if kind == "z":
        return 1.0 / cos
    return np.ones_like(cos)
