"""MiDaS's loss against a plainly written reference (per image, per pixel pair, float64), values and
gradients; the alignment metrics on known cases."""

import numpy as np
import pytest
import torch

from panorecon.learned.loss import GRADIENT_SCALES, affine_disparity_metrics, ssi_loss


def reference_loss(pred: torch.Tensor, depth: torch.Tensor, alpha: float) -> torch.Tensor:
    """The loss, written out: per image the valid values sorted, the median element (n - 1) // 2, the mean
    absolute deviation from it, each map normalised; then every valid pixel and every valid neighbouring pair
    in loops."""
    n, h, w = depth.shape
    residuals, masks = [], []
    for i in range(n):
        valid = torch.isfinite(depth[i]) & (depth[i] > 0)
        r = torch.zeros(h, w, dtype=pred.dtype)
        normalised = []
        for x in (pred[i][valid], 1.0 / depth[i][valid]):
            med = torch.sort(x).values[(len(x) - 1) // 2]
            normalised.append((x - med) / (x - med).abs().mean())
        residuals.append(r.masked_scatter(valid, normalised[0] - normalised[1]))
        masks.append(valid)
    total_valid = sum(int(m.sum()) for m in masks)
    ssi = sum(r[m].abs().sum() for r, m in zip(residuals, masks)) / total_valid
    grad = 0.0
    for k in range(GRADIENT_SCALES):
        s = 2**k
        terms, count = [], 0
        for r, m in zip(residuals, masks):
            r, m = r[::s, ::s], m[::s, ::s]
            count += int(m.sum())
            for y in range(r.shape[0]):
                for x in range(r.shape[1]):
                    if x + 1 < r.shape[1] and m[y, x] and m[y, x + 1]:
                        terms.append((r[y, x + 1] - r[y, x]).abs())
                    if y + 1 < r.shape[0] and m[y, x] and m[y + 1, x]:
                        terms.append((r[y + 1, x] - r[y, x]).abs())
        grad = grad + torch.stack(terms).sum() / count
    return ssi + alpha * grad


@pytest.fixture
def batch():
    g = torch.Generator().manual_seed(0)
    depth = 1.0 + 9.0 * torch.rand(3, 12, 12, generator=g, dtype=torch.float64)
    depth[0, :3, :5] = float("nan")  # sky
    depth[1, 5:, 7:] = float("inf")
    depth[2, 0, 0] = 0.0
    pred = torch.randn(3, 12, 12, generator=g, dtype=torch.float64)
    return pred, depth


def test_loss_and_gradient_equal_the_reference(batch):
    pred, depth = batch
    a = pred.clone().requires_grad_(True)
    b = pred.clone().requires_grad_(True)
    fast, _ = ssi_loss(a, depth, 0.5)
    slow = reference_loss(b, depth, 0.5)
    fast.backward()
    slow.backward()
    assert float(fast.detach()) == pytest.approx(float(slow.detach()), rel=1e-10)
    assert torch.allclose(a.grad, b.grad, rtol=1e-8, atol=1e-12)
    # float32, as training runs it
    f32, _ = ssi_loss(pred.float(), depth.float(), 0.5)
    assert float(f32) == pytest.approx(float(slow.detach()), rel=1e-4)


def test_loss_is_invariant_to_positive_scale_and_shift_only_and_zero_at_the_truth(batch):
    pred, depth = batch
    base, _ = ssi_loss(pred, depth)
    moved, _ = ssi_loss(3.0 * pred - 7.0, depth)
    assert float(moved) == pytest.approx(float(base), rel=1e-9)
    disparity = torch.where(torch.isfinite(depth) & (depth > 0), 1.0 / depth, torch.zeros_like(depth))
    exact, _ = ssi_loss(0.25 * disparity + 2.0, depth)
    assert float(exact) < 1e-10  # rounding only (the loss of a random prediction is ~1)
    flipped, _ = ssi_loss(-disparity, depth)  # a depth-like output is not a disparity up to a positive scale
    assert float(flipped) > 1.0


def test_a_constant_prediction_or_an_all_sky_batch_gives_no_nan():
    depth = torch.linspace(1, 4, 64).reshape(1, 8, 8)
    pred = torch.ones(1, 8, 8, requires_grad=True)
    loss, _ = ssi_loss(pred, depth)
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(pred.grad).all()
    all_sky, _ = ssi_loss(torch.ones(1, 8, 8), torch.full((1, 8, 8), float("nan")))
    assert float(all_sky) == 0.0


def test_metrics_after_alignment():
    z = np.linspace(1.0, 5.0, 400).reshape(20, 20)
    assert affine_disparity_metrics(2.0 / z + 0.3, z) == pytest.approx((0.0, 1.0), abs=1e-9)
    rel, d1 = affine_disparity_metrics(np.ones_like(z), z)  # a constant: the mean disparity everywhere
    assert rel > 0.2 and d1 < 0.8
    assert affine_disparity_metrics(-1.0 / z, z) == pytest.approx((rel, d1))  # no negative scale: the constant
    sky = z.copy()
    sky[:, :19] = np.nan  # 20 pixels of truth: too few to measure
    assert all(np.isnan(affine_disparity_metrics(1.0 / z, sky)))
