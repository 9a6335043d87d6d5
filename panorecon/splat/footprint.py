"""The label pixel's footprint as a floor on every Gaussian's size: Mip-Splatting's 3D smoothing filter (Yu et al.,
CVPR 2024, §4.1), the regulariser the held-out error budget points to (docs/benchmarks.md).

From the panorama's centre nothing constrains a Gaussian below the size of one pseudo-label pixel there: it may
be a needle or a speck that the labels see as a pixel's worth of colour. A view nearer to the surface (a held-out
view, a user's camera) resolves it and sees the gaps. The filter convolves each Gaussian with an isotropic
Gaussian of variance ``strength x (z / f)^2``, world units squared: the world size of the finest label pixel
that sees it (z its depth in that label camera, f the focal length in pixels), so the rendered Gaussian is
never thinner than what the labels could resolve. Convolution adds covariances, and an isotropic term keeps the
rotation: each scale becomes sqrt(s^2 + v) and the opacity is scaled by sqrt(det S / det S') so that the
Gaussian's integral is unchanged.

``filtered`` is the fast path, in log space (log s' = logaddexp(2 log s, log v) / 2, log of the opacity factor
= -sum softplus(log v - 2 log s) / 2): finite values and gradients for near-singular Gaussians (scale 1e-30,
whose s^2 underflows float32) and for huge ones. ``filtered_covariance`` is the reference: the 3x3 covariance
R S^2 R^T + v I and the factor from determinants, in float64.

``sampling_variance`` gives v per Gaussian from the label cameras, as Mip-Splatting computes it from its training
cameras: (z / f)^2 of the camera with the finest sampling among those whose frustum, widened by ``margin``,
holds the mean; Gaussians that no camera sees take the largest variance of those seen. It is recomputed when
the model changes size (densification, pruning, the late disocclusion fill) and every ``REFRESH_EVERY`` steps,
without gradient, as Mip-Splatting does after each densification.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from .rasterize.projection import quat_to_rotmat

MARGIN = 1.15  # Mip-Splatting's frustum margin: a Gaussian just outside the image still counts as seen
REFRESH_EVERY = 100  # steps between recomputations of the variances (Mip-Splatting: every densification step)
CHUNK = 1 << 14  # Gaussians per block of the [N, cameras] depth table (16k x 240 float32: 15 MiB)


@torch.no_grad()
def sampling_variance(
    means: torch.Tensor, viewmats: torch.Tensor, Ks: torch.Tensor, width: int, height: int, margin: float = MARGIN
) -> torch.Tensor:
    """[N] float32: (z / f)^2 of the finest-sampling camera whose frustum (``margin`` x the image, z > 0) holds
    each of ``means`` [N, 3]; ``viewmats`` [C, 4, 4] world-to-camera, ``Ks`` [C, 3, 3] pixels, images ``width``
    x ``height``. Gaussians no camera sees take the largest variance of those seen (all seen: their own)."""
    R, t = viewmats[:, :3, :3].float(), viewmats[:, :3, 3].float()
    fx, fy, cx, cy = Ks[:, 0, 0].float(), Ks[:, 1, 1].float(), Ks[:, 0, 2].float(), Ks[:, 1, 2].float()
    f = torch.minimum(fx, fy)  # the coarser axis bounds what the pixel resolves
    half_w, half_h = margin * width / 2, margin * height / 2
    out = torch.empty(len(means), device=means.device)
    for a in range(0, len(means), CHUNK):
        p = torch.einsum("cij,nj->nci", R, means[a : a + CHUNK].detach().float()) + t  # [n, C, 3] camera frame
        z = p[..., 2]
        zs = z.clamp_min(torch.finfo(torch.float32).tiny)
        u, v = fx * p[..., 0] / zs + cx, fy * p[..., 1] / zs + cy
        seen = (z > 0) & ((u - width / 2).abs() <= half_w) & ((v - height / 2).abs() <= half_h)
        step = torch.where(seen, z / f, torch.full_like(z, float("inf")))  # world size of one pixel
        out[a : a + CHUNK] = step.min(dim=1).values ** 2
    unseen = ~torch.isfinite(out)
    if unseen.any():
        seen_var = out[~unseen]
        out[unseen] = seen_var.max() if len(seen_var) else 0.0
    return out


def filtered(
    log_scales: torch.Tensor, logit_opacities: torch.Tensor, variance: torch.Tensor, strength: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Scales [N, 3] and opacities [N] of the Gaussians (``log_scales`` [N, 3], ``logit_opacities`` [N])
    convolved with isotropic Gaussians of variance ``strength x variance`` [N] (world units squared); with
    strength 0, exactly exp and sigmoid of the parameters."""
    if strength == 0:
        return torch.exp(log_scales), torch.sigmoid(logit_opacities)
    log_v = torch.log(variance * strength).clamp_min(-200.0)[:, None]  # a zero variance: no filter, finite
    two_log_s = 2 * log_scales
    scales = torch.exp(0.5 * torch.logaddexp(two_log_s, log_v))
    log_factor = -0.5 * F.softplus(log_v - two_log_s).sum(-1)
    return scales, torch.sigmoid(logit_opacities) * torch.exp(log_factor)


def filtered_covariance(
    quats: torch.Tensor,
    log_scales: torch.Tensor,
    logit_opacities: torch.Tensor,
    variance: torch.Tensor,
    strength: float,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The reference for ``filtered``, in float64: covariances [N, 3, 3] R S^2 R^T + strength x variance x I and
    opacities sigmoid(logit) x sqrt(det S / det S') from 3x3 determinants."""
    R = quat_to_rotmat(quats.double())
    S2 = torch.diag_embed(torch.exp(2 * log_scales.double()))
    cov = R @ S2 @ R.transpose(-1, -2)
    cov_f = cov + strength * variance.double()[:, None, None] * torch.eye(3, dtype=torch.float64, device=cov.device)
    factor = torch.sqrt(torch.linalg.det(cov) / torch.linalg.det(cov_f))
    return cov_f, torch.sigmoid(logit_opacities.double()) * factor


def refresh(model, strength: float, viewmats: torch.Tensor, Ks: torch.Tensor, size: int, step: int | None = None):
    """Keep ``model.footprint`` (splat/model.py) for the label cameras (``viewmats``, ``Ks`` at ``size`` pixels
    square): set when it is missing or the model changed size, and at every ``REFRESH_EVERY``-th ``step``; None
    when ``strength`` is 0."""
    if not strength:
        model.footprint = None
        return
    stale = model.footprint is None or len(model.footprint[0]) != len(model)
    if stale or (step is not None and step % REFRESH_EVERY == 0):
        model.footprint = (sampling_variance(model.means, viewmats, Ks, size, size), strength)
