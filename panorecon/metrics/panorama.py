"""Panorama-weighted image metrics: WS-PSNR (Sun, Lu and Yu 2017) and WS-SSIM for equirectangular (ERP) images.

An ERP row covers a solid angle proportional to cos(latitude), so a pole pixel counts for less than an equator
pixel: row j of H (0 at the top) weighs w_j = cos((j + 0.5 - H / 2) * pi / H), the same for every column.
WS-PSNR = 10 log10(1 / WMSE) with WMSE = sum(w (a - b)^2) / sum(w) over the pixels (and channels) compared;
WS-SSIM is the SSIM map (the trainer's SSIM: 11x11 Gaussian window, sigma 1.5, 'valid' region) averaged with the
weight of each window's centre row. Both read as the plain PSNR and SSIM when every row has the same error.
Sums in float64.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F

SSIM_WINDOW = 11
SSIM_SIGMA = 1.5


def erp_row_weights(height: int) -> np.ndarray:
    """[height] float64: the WS-PSNR weight cos((j + 0.5 - height / 2) * pi / height) of ERP row j (top = 0)."""
    if height < 1:
        raise ValueError(f"erp_row_weights: height={height}, expected at least 1")
    return np.cos((np.arange(height) + 0.5 - height / 2) * np.pi / height)


def _check(a: np.ndarray, b: np.ndarray, name: str) -> tuple[np.ndarray, np.ndarray]:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape or a.ndim not in (2, 3):
        raise ValueError(f"{name}: images {a.shape} and {b.shape}: expected one shape, [H, W] or [H, W, C]")
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        raise ValueError(f"{name}: images hold NaN or Inf")
    return a, b


def ws_psnr(a: np.ndarray, b: np.ndarray, peak: float = 1.0) -> float:
    """WS-PSNR (dB) of two ERP images [H, W] or [H, W, C] (values up to ``peak``); inf when they are equal."""
    a, b = _check(a, b, "ws_psnr")
    w = erp_row_weights(a.shape[0]).reshape(-1, *([1] * (a.ndim - 1)))
    wmse = float(np.sum(w * (a - b) ** 2) / (np.sum(np.broadcast_to(w, a.shape))))
    return math.inf if wmse == 0 else 10 * math.log10(peak**2 / wmse)


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The SSIM map [H - 10, W - 10, C] float64 of two images [H, W, C] in [0, 1] (H, W >= 11): the trainer's SSIM
    (splat/losses.py) before its mean (separable window, float64); row r of the map is centred on image row r + 5."""
    a, b = _check(a, b, "ssim_map")
    if a.ndim == 2:
        a, b = a[..., None], b[..., None]
    H, W, C = a.shape
    if min(H, W) < SSIM_WINDOW:
        raise ValueError(f"ssim_map: images {H}x{W}: expected at least {SSIM_WINDOW} pixels each way")
    x = torch.from_numpy(a).permute(2, 0, 1)[None]
    y = torch.from_numpy(b).permute(2, 0, 1)[None]
    t = torch.arange(SSIM_WINDOW, dtype=torch.float64) - (SSIM_WINDOW - 1) / 2
    g = torch.exp(-(t**2) / (2 * SSIM_SIGMA**2))
    g = g / g.sum()
    row, col = g.view(1, 1, 1, -1).repeat(C, 1, 1, 1), g.view(1, 1, -1, 1).repeat(C, 1, 1, 1)
    conv = lambda z: F.conv2d(F.conv2d(z, row, groups=C), col, groups=C)  # noqa: E731  (the window is separable)
    mx, my = conv(x), conv(y)
    sxx, syy, sxy = conv(x * x) - mx**2, conv(y * y) - my**2, conv(x * y) - mx * my
    c1, c2 = 0.01**2, 0.03**2
    s = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx**2 + my**2 + c1) * (sxx + syy + c2))
    return s[0].permute(1, 2, 0).numpy()


def ws_ssim(a: np.ndarray, b: np.ndarray) -> float:
    """WS-SSIM of two ERP images [H, W, C] in [0, 1]: ``ssim_map`` averaged with each window centre's row weight."""
    s = ssim_map(a, b)
    w = erp_row_weights(np.asarray(a).shape[0])[SSIM_WINDOW // 2 : SSIM_WINDOW // 2 + s.shape[0]]
    return float(np.sum(w[:, None, None] * s) / (np.sum(w) * s.shape[1] * s.shape[2]))


def panorama_scores(render: np.ndarray, truth: np.ndarray) -> dict:
    """The plain and panorama-weighted scores of an ERP image against the true one ([H, W, 3] in [0, 1]):
    psnr and ssim (unweighted, every pixel alike), ws_psnr and ws_ssim (cos-latitude weights)."""
    a, b = _check(render, truth, "panorama_scores")
    mse = float(np.mean((a - b) ** 2))
    return {
        "psnr": math.inf if mse == 0 else 10 * math.log10(1 / mse),
        "ssim": float(ssim_map(a, b).mean()),
        "ws_psnr": ws_psnr(a, b),
        "ws_ssim": ws_ssim(a, b),
    }
