"""MiDaS's scale-and-shift-invariant loss with multi-scale gradient matching (Ranftl et al., TPAMI 2022,
eqs. 4 and 11), and the metrics after the alignment an affine disparity allows.

Why this loss and not the scale-invariant log loss (SILog, Eigen et al. 2014): SILog leaves only a scale
free, so the network would have to output depth up to scale -- a view of a bare wall or of the sky at the
horizon gives it no cue to the shift between near and far that disparity carries, and far outdoor depths
(hundreds of metres) dominate a log loss on depth. An output known up to scale *and* shift in disparity is
what MiDaS, DPT and Depth Anything (relative) give, so the exported model meets the ``onnx:`` teacher and the
fusion exactly as a user's export of those models does (``output: disparity, mode: affine``), and the fusion's
per-view affine alignment is exercised by a real network's errors. The gradient term keeps depth edges sharp
and planes flat, where an aligned L2 alone blurs them.

Targets are the true disparity 1 / z of each crop divided by its mean over the valid pixels, so indoor and
outdoor crops weigh alike. All reductions are batch-based (sums over the batch over the batch's valid pixels),
as MiDaS's reference code does.
"""

from __future__ import annotations

import numpy as np
import torch

GRADIENT_SCALES = 4  # the gradient term at strides 1, 2, 4, 8


def normalised_disparity(depth: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """True z-depth [N, H, W] (NaN: no target) -> (disparity / its per-image mean over valid pixels [N, H, W]
    float32, 0 where invalid; valid mask [N, H, W] float32)."""
    valid = torch.isfinite(depth) & (depth > 0)
    disp = torch.where(valid, 1.0 / torch.where(valid, depth, torch.ones_like(depth)), torch.zeros_like(depth))
    m = valid.to(depth.dtype)
    mean = disp.sum((1, 2)) / m.sum((1, 2)).clamp_min(1.0)
    return disp / mean.clamp_min(1e-12)[:, None, None], m


def scale_and_shift(pred: torch.Tensor, target: torch.Tensor, mask: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per image, the (s, t) [N] minimising sum(mask (s pred + t - target)^2) (closed-form normal equations;
    s = 0, t = the masked mean when pred is constant over the mask)."""
    a00 = (mask * pred * pred).sum((1, 2))
    a01 = (mask * pred).sum((1, 2))
    a11 = mask.sum((1, 2))
    b0 = (mask * pred * target).sum((1, 2))
    b1 = (mask * target).sum((1, 2))
    det = a00 * a11 - a01 * a01
    ok = det > 1e-12 * a11.clamp_min(1.0) ** 2
    safe = torch.where(ok, det, torch.ones_like(det))
    s = torch.where(ok, (a11 * b0 - a01 * b1) / safe, torch.zeros_like(det))
    t = torch.where(ok, (a00 * b1 - a01 * b0) / safe, b1 / a11.clamp_min(1.0))
    return s, t


def gradient_matching(residual: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Sum over the batch of |d/dx R| + |d/dy R| over pixel pairs both valid, [] (MiDaS's gradient_loss
    before its division by the valid pixels)."""
    r = residual * mask
    gx = (r[:, :, 1:] - r[:, :, :-1]).abs() * (mask[:, :, 1:] * mask[:, :, :-1])
    gy = (r[:, 1:, :] - r[:, :-1, :]).abs() * (mask[:, 1:, :] * mask[:, :-1, :])
    return gx.sum() + gy.sum()


def ssi_loss(pred: torch.Tensor, depth: torch.Tensor, alpha: float = 0.5) -> tuple[torch.Tensor, dict]:
    """MiDaS's loss: pred [N, 1, H, W] or [N, H, W] (disparity up to scale and shift), depth [N, H, W] true
    z-depth (NaN: sky / no target) -> (loss [], {"ssi", "grad"} floats). The prediction is aligned to the
    normalised target disparity per image (``scale_and_shift``; the alignment is differentiated through, as in
    MiDaS); ssi = sum(mask R^2) / (2 sum(mask)), grad = sum over 4 scales of ``gradient_matching`` / sum(mask)
    at that scale; loss = ssi + alpha grad. A batch without a valid pixel gives 0."""
    pred = pred.reshape(depth.shape)
    target, mask = normalised_disparity(depth)
    s, t = scale_and_shift(pred, target, mask)
    residual = s[:, None, None] * pred + t[:, None, None] - target
    m_sum = mask.sum().clamp_min(1.0)
    ssi = (mask * residual * residual).sum() / (2.0 * m_sum)
    grad = pred.new_zeros(())
    for k in range(GRADIENT_SCALES):
        step = 2**k
        m = mask[:, ::step, ::step]
        grad = grad + gradient_matching(residual[:, ::step, ::step], m) / m.sum().clamp_min(1.0)
    loss = ssi + alpha * grad
    return loss, {"ssi": float(ssi.detach()), "grad": float(grad.detach())}


def align_disparity(pred: np.ndarray, true_z: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """An affine disparity [H, W] aligned to the truth: least-squares scale and shift (float64) of ``pred`` to
    1 / ``true_z`` on ``mask``, then depth = 1 / aligned disparity, the depth capped at the farthest true depth
    on the mask (MiDaS's evaluation caps at its dataset's range: an aligned disparity at or below 0 has no depth)
    -> z-depth [H, W] float64, NaN off the mask."""
    p = pred[mask].astype(np.float64)
    d = 1.0 / true_z[mask].astype(np.float64)
    A = np.stack([p, np.ones_like(p)], 1)
    (s, t), *_ = np.linalg.lstsq(A, d, rcond=None)
    out = np.full(pred.shape, np.nan)
    out[mask] = 1.0 / np.maximum(s * p + t, d.min())
    return out


def abs_rel_delta1(pred_z: np.ndarray, true_z: np.ndarray, mask: np.ndarray) -> tuple[float, float]:
    """(AbsRel = mean |pred - true| / true, delta1 = share of max(pred / true, true / pred) < 1.25) on
    ``mask``, float64."""
    p, t = pred_z[mask].astype(np.float64), true_z[mask].astype(np.float64)
    return float(np.mean(np.abs(p - t) / t)), float(np.mean(np.maximum(p / t, t / p) < 1.25))


def affine_disparity_metrics(pred: np.ndarray, true_z: np.ndarray, min_pixels: int = 100) -> tuple[float, float]:
    """(AbsRel, delta1) of an affine disparity [H, W] against true z-depth [H, W] (NaN: no truth) after
    ``align_disparity``; (nan, nan) with fewer than ``min_pixels`` valid pixels."""
    mask = np.isfinite(true_z) & (true_z > 0) & np.isfinite(pred)
    if mask.sum() < min_pixels:
        return float("nan"), float("nan")
    return abs_rel_delta1(align_disparity(pred, true_z, mask), true_z, mask)
