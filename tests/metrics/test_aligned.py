"""The per-view affine colour alignment (Mip-NeRF 360's color_correct, affine) and the masked scores."""

import math

import numpy as np
import pytest
import torch

from panorecon.metrics.aligned import (
    MIN_ALIGN_PIXELS,
    apply_color_affine,
    fit_color_affine,
    masked_psnr,
    masked_ssim,
)
from panorecon.splat.losses import ssim_reference

# a white-balance and exposure change with some crosstalk: [r, g, b, 1] @ M
M_TRUE = np.array([[0.8, 0.05, 0.0], [0.02, 0.7, 0.03], [0.0, 0.04, 0.6], [0.08, 0.1, 0.15]])


def test_fit_recovers_a_known_transform_and_maps_the_source_onto_the_target():
    src = np.random.default_rng(0).uniform(0.05, 0.95, (1000, 3))
    dst = np.concatenate([src, np.ones((1000, 1))], 1) @ M_TRUE
    M = fit_color_affine(src, dst)
    np.testing.assert_allclose(M, M_TRUE, atol=1e-12)
    np.testing.assert_allclose(apply_color_affine(src, M), dst, atol=1e-12)
    # the direction matters: the render (src) is mapped onto the true image (dst), not the other way round
    assert not np.allclose(apply_color_affine(dst, fit_color_affine(dst, src)), dst, atol=1e-3)


def test_saturated_rows_are_left_out_of_their_channel():
    src = np.random.default_rng(1).uniform(0.05, 0.95, (1000, 3))
    dst = np.concatenate([src, np.ones((1000, 1))], 1) @ M_TRUE
    dst[:100, 0] = 1.0  # blown out in the target's red: a linear fit through them would be biased
    np.testing.assert_allclose(fit_color_affine(src, dst), M_TRUE, atol=1e-12)


def test_refusals_name_the_reason():
    rng = np.random.default_rng(2)
    few = rng.uniform(0.1, 0.9, (MIN_ALIGN_PIXELS - 1, 3))
    assert fit_color_affine(few, few).startswith(f"n/a: colour alignment needs {MIN_ALIGN_PIXELS}")
    grey = np.repeat(rng.uniform(0.1, 0.9, (1000, 1)), 3, 1)  # r = g = b: RGB plus an offset is rank 2
    assert "rank-deficient" in fit_color_affine(grey, grey)
    flat = np.full((1000, 3), 0.5)
    assert "rank-deficient" in fit_color_affine(flat, rng.uniform(0.1, 0.9, (1000, 3)))
    with pytest.raises(ValueError, match="NaN"):
        fit_color_affine(np.full((300, 3), np.nan), few[:1].repeat(300, 0))


def test_apply_clips_to_the_unit_range():
    out = apply_color_affine(
        np.array([[0.9, 0.9, 0.9], [0.0, 0.0, 0.0]]), np.vstack([2 * np.eye(3), -0.5 * np.ones(3)])
    )
    np.testing.assert_allclose(out, [[1.0, 1.0, 1.0], [0.0, 0.0, 0.0]])


def test_masked_scores():
    rng = np.random.default_rng(3)
    a = rng.uniform(0.1, 0.9, (40, 40, 3))
    b = np.clip(a + 0.05 * rng.standard_normal(a.shape), 0, 1)
    everything = np.ones((40, 40), bool)
    assert masked_ssim(a, b, everything) == pytest.approx(
        float(ssim_reference(torch.from_numpy(a), torch.from_numpy(b)))
    )
    left = np.zeros((40, 40), bool)
    left[:, :20] = True
    # only windows wholly inside the mask count: 30 rows x 10 columns of centres
    noisy_right = b.copy()
    noisy_right[:, 20:] = rng.uniform(0, 1, (40, 20, 3))
    assert masked_ssim(a, noisy_right, left, min_windows=300) == pytest.approx(masked_ssim(a, b, left, 300))
    assert masked_ssim(a, b, left, min_windows=301).startswith("n/a: 300 SSIM windows")
    d = (a - b)[left]
    assert masked_psnr(a, b, left) == pytest.approx(10 * math.log10(1 / np.mean(d**2)))
    assert masked_psnr(a, a, left) == math.inf
