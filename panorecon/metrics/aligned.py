"""Scores after a per-view colour alignment, for true images taken at another exposure or white balance.

Panoramas of one space are captured (or rendered) under different exposures and lighting, so a held-out view
of another panorama differs from any reconstruction by a colour transform the reconstruction cannot know. As
in Mip-NeRF 360's evaluation (multinerf ``internal/image.py`` ``color_correct``, called as
``color_correct(rendered_rgb, gt_rgb)``: the render is warped to match the true image, in float64, and the
result clipped to [0, 1]), the render is mapped onto the true image before scoring; here by an affine 3x4
transform (RGB -> RGB plus an offset; multinerf adds quadratic terms), fitted by least squares on the scored
(co-visible) pixels. As there, the rows where the input's or the target's channel is saturated (outside
[0.5/255, 1 - 0.5/255]) are left out of that channel's fit. The fit is refused (a reason string) when too few
pixels remain or the system is rank-deficient (e.g. a render of one flat colour).
"""

from __future__ import annotations

import math

import numpy as np

SATURATION_EPS = 0.5 / 255  # multinerf's eps: a channel at or within this of 0 or 1 is clipped
MIN_ALIGN_PIXELS = 256  # pixels per channel a fit needs (4 unknowns; the held-out views' MIN_COVISIBLE_PIXELS)
ALIGN_RCOND = 1e-6  # smallest singular value over the largest of the [N, 4] system below which it is rank-deficient


def fit_color_affine(src: np.ndarray, dst: np.ndarray, min_pixels: int = MIN_ALIGN_PIXELS) -> np.ndarray | str:
    """The affine colour transform M [4, 3] float64 with [src, 1] @ M ~ dst in least squares, from pixel colours
    src, dst [N, 3] in [0, 1] (src: the image to be mapped, e.g. the render; dst: the true image). Output channel
    c is fitted on the rows where src[:, c] and dst[:, c] are unsaturated. 'n/a: <reason>' when a channel has
    fewer than ``min_pixels`` such rows or its system's singular values span more than 1 / ALIGN_RCOND."""
    src, dst = np.asarray(src, np.float64).reshape(-1, 3), np.asarray(dst, np.float64).reshape(-1, 3)
    if len(src) != len(dst):
        raise ValueError(f"fit_color_affine: {len(src)} source and {len(dst)} target pixels")
    if not (np.isfinite(src).all() and np.isfinite(dst).all()):
        raise ValueError("fit_color_affine: colours hold NaN or Inf")
    A = np.concatenate([src, np.ones((len(src), 1))], 1)
    unclipped = lambda z: (z >= SATURATION_EPS) & (z <= 1 - SATURATION_EPS)  # noqa: E731
    M = np.zeros((4, 3))
    for c in range(3):
        rows = unclipped(src[:, c]) & unclipped(dst[:, c])
        n = int(rows.sum())
        if n < min_pixels:
            return f"n/a: colour alignment needs {min_pixels} unsaturated pixels per channel; {'RGB'[c]} has {n}"
        Ac = A[rows]
        s = np.linalg.svd(Ac / math.sqrt(n), compute_uv=False)
        if s[-1] <= ALIGN_RCOND * s[0]:
            return (
                f"n/a: colour alignment is rank-deficient for channel {'RGB'[c]} (singular values "
                f"{s[-1]:.2g} against {s[0]:.2g}: the image's colours do not span RGB plus an offset)"
            )
        M[:, c] = np.linalg.lstsq(Ac, dst[rows, c], rcond=None)[0]
    return M


def apply_color_affine(img: np.ndarray, M: np.ndarray) -> np.ndarray:
    """img [..., 3] mapped by ``fit_color_affine``'s M [4, 3] and clipped to [0, 1] -> [..., 3] float64."""
    img = np.asarray(img, np.float64)
    return np.clip(img @ M[:3] + M[3], 0.0, 1.0)


def masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float:
    """PSNR (dB, peak 1) of images [h, w, 3] over the pixels of ``mask`` [h, w] (float64; inf when equal)."""
    d = np.asarray(a, np.float64)[mask] - np.asarray(b, np.float64)[mask]
    if d.size == 0:
        raise ValueError("masked_psnr: the mask selects no pixel")
    mse = float(np.mean(d**2))
    return math.inf if mse == 0 else 10 * math.log10(1 / mse)


def masked_ssim(a: np.ndarray, b: np.ndarray, mask: np.ndarray, min_windows: int = MIN_ALIGN_PIXELS) -> float | str:
    """SSIM of images [h, w, 3] in [0, 1] averaged over the 11x11 windows lying wholly inside ``mask`` [h, w]
    (the map of ``metrics.panorama.ssim_map``); 'n/a: <reason>' with fewer than ``min_windows`` such windows."""
    from .panorama import SSIM_WINDOW, ssim_map

    h, w = mask.shape
    if min(h, w) < SSIM_WINDOW:
        return f"n/a: SSIM needs {SSIM_WINDOW}x{SSIM_WINDOW} windows; the view is {h}x{w}"
    m = mask.astype(np.int64)
    integral = np.pad(m.cumsum(0).cumsum(1), ((1, 0), (1, 0)))
    k = SSIM_WINDOW
    inside = integral[k:, k:] - integral[:-k, k:] - integral[k:, :-k] + integral[:-k, :-k] == k * k
    n = int(inside.sum())
    if n < min_windows:
        return f"n/a: {n} SSIM windows lie wholly in the co-visible pixels (fewer than {min_windows})"
    return float(ssim_map(a, b)[inside].mean())
