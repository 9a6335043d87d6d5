"""The normal equations ``_assemble`` builds from whole-band array arithmetic, against a per-equation loop over
every view, pair and stencil (the slow reference): same matrix, same right-hand side."""

import numpy as np
import pytest

from panorecon.fusion import FusionConfig
from panorecon.fusion.lsq import _assemble, _observe, _row_area, _trust_border_only_regions
from panorecon.geometry import make_layout

from .conftest import make_views


def reference_normal_equations(level, cfg: FusionConfig):
    """A (dense) and b0 (no data right-hand side) from the energy written out one equation at a time: for every
    view, every horizontal pair (wrapping), vertical pair and interior 5-point Laplacian whose taps the view
    observes outside the sky border, weight = w x area x the smallest confidence of the pair (the centre's for a
    Laplacian), plus the per-observation data weights on the diagonal; where a pixel is reached by border
    observations only (``fill``), target-0 membrane and Laplacian equations on every pair / stencil of seen pixels
    that touches it."""
    H, W = level.height, level.width
    N = H * W
    area = _row_area(H, W, cfg.area_weight)
    A, b = np.zeros((N, N)), np.zeros(N)

    def add(coeffs: dict, target: float, weight: float):
        for p, cp in coeffs.items():
            b[p] += weight * cp * target
            for q, cq in coeffs.items():
                A[p, q] += weight * cp * cq

    for o in level.obs:
        obs = {int(i): (ld, c) for i, ld, c, brd in zip(o.index, o.log_distance, o.confidence, o.border) if not brd}
        for r in range(H):
            for c in range(W):
                p, q = r * W + c, r * W + (c + 1) % W
                if p in obs and q in obs:
                    add({q: 1.0, p: -1.0}, obs[q][0] - obs[p][0], cfg.w_grad * area[p] * min(obs[p][1], obs[q][1]))
                if r + 1 < H and p in obs and p + W in obs:
                    s = p + W
                    w = cfg.w_grad * 0.5 * (area[p] + area[s]) * min(obs[p][1], obs[s][1])
                    add({s: 1.0, p: -1.0}, obs[s][0] - obs[p][0], w)
                if 0 < r < H - 1:
                    taps = [r * W + (c - 1) % W, q, p - W, p + W]
                    if p in obs and all(t in obs for t in taps):
                        coeffs = {t: 1.0 for t in taps}
                        coeffs[p] = -4.0
                        lap = sum(obs[t][0] for t in taps) - 4 * obs[p][0]
                        add(coeffs, lap, cfg.w_lap * area[p] * obs[p][1])
        w_data = cfg.w_data * o.confidence * area[o.index] * np.where(o.border, cfg.border_anchor, 1.0)
        A[o.index, o.index] += w_data
    _, fill = _trust_border_only_regions(level)
    seen = level.seen
    for r in range(H):
        for c in range(W):
            p, q = r * W + c, r * W + (c + 1) % W
            if (fill[p] or fill[q]) and seen[p] and seen[q]:
                add({q: 1.0, p: -1.0}, 0.0, cfg.w_grad * area[p] * cfg.border_smooth)
            if r + 1 < H and (fill[p] or fill[p + W]) and seen[p] and seen[p + W]:
                add({p + W: 1.0, p: -1.0}, 0.0, cfg.w_grad * 0.5 * (area[p] + area[p + W]) * cfg.border_smooth)
            if 0 < r < H - 1:
                taps = [r * W + (c - 1) % W, q, p - W, p + W, p]
                if any(fill[t] for t in taps) and all(seen[t] for t in taps):
                    coeffs = {t: 1.0 for t in taps[:4]}
                    coeffs[p] = -4.0
                    add(coeffs, 0.0, cfg.w_lap * area[p] * cfg.border_laplacian)
    A[~level.seen, ~level.seen] += 1.0  # unseen pixels are decoupled
    return A, b


@pytest.mark.parametrize("border_px", [0, 2])
def test_assembly_equals_the_per_equation_reference(border_px):
    """6 views of 60 degrees, 24 px, on a 12 x 24 ERP: overlaps, gaps, the seam and (border_px) sky borders."""
    rng = np.random.default_rng(3)
    views = make_views(make_layout("fibonacci", 6, fov_deg=60), 24, rng, noise=0.05)
    for v in views[:3]:  # a patch of sky in three views (border_px = 2: some pixels only border pixels reach)
        v.valid[8:14, 5:15] = False
    cfg = FusionConfig(border_px=border_px)
    level = _observe(views, [v.to_distance() for v in views], 12, border_px, cfg)
    assert level.seen.sum() > 100 and (~level.seen).any()
    assert _trust_border_only_regions(level)[1].any() == (border_px > 0)  # fill equations present with a border
    A, b0, _ = _assemble(level, cfg, sparse=True)
    A_ref, b_ref = reference_normal_equations(level, cfg)
    np.testing.assert_allclose(A.toarray(), A_ref, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(b0, b_ref, rtol=1e-12, atol=1e-12)
    op, b0_op, _ = _assemble(level, cfg, sparse=False)  # the matrix-free operator: the same system
    x = rng.standard_normal(A_ref.shape[0])
    np.testing.assert_allclose(op @ x, A_ref @ x, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(b0_op, b_ref, rtol=1e-12, atol=1e-12)
