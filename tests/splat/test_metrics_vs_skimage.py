"""The trainer's PSNR and SSIM equal scikit-image's (the chosen stack's reference): SSIM with
gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1, on random and real images."""

from pathlib import Path

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from panorecon.io import read_image
from panorecon.splat.losses import ssim
from panorecon.splat.trainer import psnr

LPIPS_IMAGES = Path(__file__).resolve().parents[1] / "data" / "lpips"


def _skimage(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    s = structural_similarity(
        a, b, gaussian_weights=True, sigma=1.5, use_sample_covariance=False, data_range=1, channel_axis=-1
    )
    return peak_signal_noise_ratio(a, b, data_range=1), s


def _ours(a: np.ndarray, b: np.ndarray, dtype) -> tuple[float, float]:
    ta, tb = torch.from_numpy(a).to(dtype), torch.from_numpy(b).to(dtype)
    return psnr(ta, tb), float(ssim(ta, tb))


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64], ids=["f32", "f64"])
@settings(max_examples=15)
@given(h=st.integers(11, 40), w=st.integers(11, 40), noise=st.floats(0.01, 0.5), seed=st.integers(0, 2**16))
def test_random_images_match_skimage(dtype, h, w, noise, seed):
    rng = np.random.default_rng(seed)
    a = rng.random((h, w, 3))
    b = np.clip(a + noise * rng.standard_normal(a.shape), 0, 1)
    a, b = a.astype(np.float32).astype(np.float64), b.astype(np.float32).astype(np.float64)  # exact in both dtypes
    (p_ref, s_ref), (p, s) = _skimage(a, b), _ours(a, b, dtype)
    assert p == pytest.approx(p_ref, abs=1e-4) and s == pytest.approx(s_ref, abs=1e-4)


@pytest.mark.parametrize("other", ["ex_p0", "ex_p1"])
def test_real_images_match_skimage(other):
    a = read_image(LPIPS_IMAGES / "ex_ref.png").astype(np.float64) / 255
    b = read_image(LPIPS_IMAGES / f"{other}.png").astype(np.float64) / 255
    for crop in (np.s_[:, :], np.s_[3:50, 7:64]):  # square and non-square
        (p_ref, s_ref), (p, s) = _skimage(a[crop], b[crop]), _ours(a[crop], b[crop], torch.float32)
        assert p == pytest.approx(p_ref, abs=1e-4) and s == pytest.approx(s_ref, abs=1e-4)


def test_identical_images():
    a = np.random.default_rng(0).random((16, 16, 3))
    assert _ours(a, a, torch.float64) == (float("inf"), pytest.approx(1.0))
