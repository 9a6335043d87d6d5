"""MiDaS's scale-and-shift-invariant loss with multi-scale gradient matching (Ranftl et al., TPAMI 2022:
the median / mean-absolute-deviation alignment of eqs. 5-6, L_ssimae of eq. 7 and the gradient term of eq. 11),
and the metrics after the alignment an affine disparity allows.

Why this loss and not the scale-invariant log loss (SILog, Eigen et al. 2014): SILog leaves only a scale
free, so the network would have to output depth up to scale -- a view of a bare wall or of the sky at the
horizon gives it no cue to the shift between near and far that disparity carries, and far outdoor depths
(hundreds of metres) dominate a log loss on depth. An output known up to scale *and* shift in disparity is
what MiDaS, DPT and Depth Anything (relative) give, so the exported model meets the ``onnx:`` teacher and the
fusion exactly as a user's export of those models does (``output: disparity, mode: affine``), and the fusion's
per-view affine alignment is exercised by a real network's errors. The gradient term keeps depth edges sharp
and planes flat. Why the median / MAD alignment and not a least-squares fit of the prediction to the target:
a least-squares scale may be negative, and a network trained through it learns an orientation per image --
ours did (on bedroom's views the fitted scale came out negative for 11 of 20), which no user of a disparity
output expects and the fusion cannot undo. Each map divided by its own positive spread fixes the sign.

Targets are the true disparity 1 / z of each crop. Each image's prediction and target are normalised on its
valid pixels to (x - median) / mean |x - median| ("lower" median: element (n - 1) // 2 of the sorted values);
ssi = sum over the batch of |p - d| / sum of the valid pixels; grad = the sum over 4 scales (strides 1, 2, 4, 8)
of |d/dx R| + |d/dy R| of R = p - d over pixel pairs both valid, over the valid pixels at that scale (batch-based
reductions, as MiDaS's reference code).
"""

from __future__ import annotations

import numpy as np
import torch

GRADIENT_SCALES = 4  # the gradient term at strides 1, 2, 4, 8


def normalise(x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Per image (x - median) / mean |x - median| over ``mask`` ([N, H, W], bool), 0 off the mask; an image
    with no valid pixel or no spread gives 0."""
    flat = torch.where(mask, x, torch.full_like(x, float("nan"))).flatten(1)
    med = torch.nanmedian(flat, dim=1).values.nan_to_num(0.0)[:, None, None]
    m = mask.to(x.dtype)
    spread = ((x - med).abs() * m).sum((1, 2)) / m.sum((1, 2)).clamp_min(1.0)
    return torch.where(mask, (x - med) / spread.clamp_min(1e-12)[:, None, None], torch.zeros_like(x))


def gradient_matching(residual: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Sum over the batch of |d/dx R| + |d/dy R| over pixel pairs both valid, [] (MiDaS's gradient_loss
    before its division by the valid pixels)."""
    r = residual * mask
    gx = (r[:, :, 1:] - r[:, :, :-1]).abs() * (mask[:, :, 1:] * mask[:, :, :-1])
    gy = (r[:, 1:, :] - r[:, :-1, :]).abs() * (mask[:, 1:, :] * mask[:, :-1, :])
    return gx.sum() + gy.sum()


def ssi_loss(pred: torch.Tensor, depth: torch.Tensor, alpha: float = 0.5) -> tuple[torch.Tensor, dict]:
    """MiDaS's loss: pred [N, 1, H, W] or [N, H, W] (disparity up to a positive scale and a shift), depth
    [N, H, W] true z-depth (NaN: sky / no target) -> (loss [], {"ssi", "grad"} floats): ssi + alpha grad (the
    module doc). A batch without a valid pixel gives 0."""
    pred = pred.reshape(depth.shape)
    valid = torch.isfinite(depth) & (depth > 0)
    disparity = 1.0 / torch.where(valid, depth, torch.ones_like(depth))
    residual = normalise(pred, valid) - normalise(disparity, valid)
    mask = valid.to(pred.dtype)
    ssi = (mask * residual.abs()).sum() / mask.sum().clamp_min(1.0)
    grad = pred.new_zeros(())
    for k in range(GRADIENT_SCALES):
        step = 2**k
        m = mask[:, ::step, ::step]
        grad = grad + gradient_matching(residual[:, ::step, ::step], m) / m.sum().clamp_min(1.0)
    loss = ssi + alpha * grad
    return loss, {"ssi": float(ssi.detach()), "grad": float(grad.detach())}


def align_disparity(pred: np.ndarray, true_z: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """An affine disparity [H, W] aligned to the truth: least-squares scale and shift (float64) of ``pred`` to
    1 / ``true_z`` on ``mask``, the scale at least 0 (a disparity is known up to a positive scale: a fit that
    wants a negative one gets the best constant, the mean), then depth = 1 / aligned disparity, the depth capped
    at the farthest true depth on the mask (MiDaS's evaluation caps at its dataset's range: an aligned
    disparity at or below 0 has no depth) -> z-depth [H, W] float64, NaN off the mask."""
    p = pred[mask].astype(np.float64)
    d = 1.0 / true_z[mask].astype(np.float64)
    A = np.stack([p, np.ones_like(p)], 1)
    (s, t), *_ = np.linalg.lstsq(A, d, rcond=None)
    if s < 0:
        s, t = 0.0, d.mean()
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
