"""WS-PSNR and WS-SSIM (cos-latitude weights, Sun et al. 2017) and the weighted depth metrics of ERP maps.

No reference implementation of WS-PSNR is installable from PyPI (none in the package list under ws-psnr, wspsnr
or 360), so the weights are checked against values worked out by hand below."""

import math

import numpy as np
import pytest
import torch

from panorecon.metrics import depth_metrics, ws_depth_metrics
from panorecon.metrics.panorama import erp_row_weights, panorama_scores, ssim_map, ws_psnr, ws_ssim
from panorecon.splat.losses import ssim_reference


def test_hand_computed_case():
    """A 4x2 ERP: rows at latitudes 67.5, 22.5, -22.5, -67.5 degrees; an error of 0.1 at a pole row's pixel and
    0.2 at an equator row's pixel."""
    a = np.zeros((4, 2))
    b = np.zeros((4, 2))
    b[0, 0], b[2, 1] = 0.1, 0.2
    w_pole, w_equator = math.cos(3 * math.pi / 8), math.cos(math.pi / 8)  # (j + 0.5 - 2) * pi / 4 for j = 0, 2
    assert w_pole == pytest.approx(0.3826834324) and w_equator == pytest.approx(0.9238795325)
    wmse = (w_pole * 0.1**2 + w_equator * 0.2**2) / (2 * (2 * w_pole + 2 * w_equator))
    assert ws_psnr(a, b) == pytest.approx(10 * math.log10(1 / wmse), abs=1e-12)
    np.testing.assert_allclose(erp_row_weights(4), [w_pole, w_equator, w_equator, w_pole], atol=1e-15)
    # the plain PSNR of the same images, for contrast
    assert ws_psnr(a, b) != pytest.approx(10 * math.log10(1 / ((0.1**2 + 0.2**2) / 8)), abs=0.1)


def _image(h=32, w=64, seed=0):
    return np.random.default_rng(seed).random((h, w, 3)) * 0.8 + 0.1


def test_error_moved_from_the_equator_to_a_pole_scores_higher():
    a = _image()
    equator, pole = a.copy(), a.copy()
    equator[14:18, 20:30] += 0.1  # the same 4x10 patch of error at the equator and at the top rows
    pole[0:4, 20:30] += 0.1
    assert ws_psnr(a, pole) > ws_psnr(a, equator) + 3
    plain = lambda x: 10 * math.log10(1 / np.mean((a - x) ** 2))  # noqa: E731
    assert plain(pole) == pytest.approx(plain(equator), abs=1e-9)
    blur = lambda x, rows: np.where(np.isin(np.arange(32), rows)[:, None, None], 0.5 * x + 0.25, x)  # noqa: E731
    assert ws_ssim(a, blur(a, range(0, 8))) > ws_ssim(a, blur(a, range(12, 20))) + 0.02


def test_uniform_error_agrees_with_the_plain_metrics():
    a = _image()
    b = np.clip(a + 0.05, 0, 1)
    s = panorama_scores(b, a)
    assert s["ws_psnr"] == pytest.approx(s["psnr"], abs=1e-9)
    # identical rows give identical rows of the SSIM map: the weighted mean is the plain one
    rows_a = np.repeat(a[:1], 32, 0)
    rows_b = np.repeat(np.clip(a[:1] + 0.1 * np.sin(np.arange(64))[None, :, None], 0, 1), 32, 0)
    plain = float(ssim_reference(torch.from_numpy(rows_b), torch.from_numpy(rows_a)))
    assert ws_ssim(rows_b, rows_a) == pytest.approx(plain, abs=1e-12)
    assert panorama_scores(rows_b, rows_a)["ssim"] == pytest.approx(plain, abs=1e-12)


def test_ssim_map_mean_is_the_trainers_ssim():
    a, b = _image(), np.clip(_image() + 0.1 * _image(seed=1), 0, 1)
    assert ssim_map(a, b).mean() == pytest.approx(float(ssim_reference(torch.from_numpy(a), torch.from_numpy(b))))
    assert ssim_map(a, b).shape == (22, 54, 3)


def test_equal_images_and_bad_input():
    a = _image()
    assert ws_psnr(a, a) == math.inf and ws_ssim(a, a) == pytest.approx(1.0)
    with pytest.raises(ValueError, match="one shape"):
        ws_psnr(a, a[:-1])
    bad = a.copy()
    bad[3, 3, 0] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        ws_psnr(a, bad)
    with pytest.raises(ValueError, match="at least 11"):
        ws_ssim(a[:8], a[:8])


def test_weighted_depth_metrics():
    rng = np.random.default_rng(0)
    truth = rng.uniform(1, 5, (16, 32))
    uniform = truth * 1.1  # the same relative error everywhere: weighted = plain
    plain, ws = depth_metrics(uniform, truth, "none"), ws_depth_metrics(uniform, truth, 1.0)
    assert ws["ws_abs_rel"] == pytest.approx(plain["abs_rel"]) and ws["ws_delta1"] == plain["delta1"] == 1.0
    pole, equator = truth.copy(), truth.copy()
    pole[0, :] *= 2  # a wrong row at the pole counts for less than a wrong row at the equator
    equator[8, :] *= 2
    assert ws_depth_metrics(pole, truth, 1.0)["ws_abs_rel"] < ws_depth_metrics(equator, truth, 1.0)["ws_abs_rel"] / 5
    w = erp_row_weights(16)
    assert ws_depth_metrics(pole, truth, 1.0)["ws_abs_rel"] == pytest.approx(w[0] / (16 * w.mean()))
    assert ws_depth_metrics(pole, truth, 1.0)["ws_delta1"] == pytest.approx(1 - w[0] / w.sum())
    # the alignment scale is applied, NaN and the mask are left out, nothing to compare reads NaN
    assert ws_depth_metrics(uniform / 1.1 * 2, truth, 0.5)["ws_abs_rel"] == pytest.approx(0, abs=1e-12)
    holed = uniform.copy()
    holed[:, :4] = np.nan
    assert ws_depth_metrics(holed, truth, 1.0)["ws_abs_rel"] == pytest.approx(0.1)
    assert math.isnan(ws_depth_metrics(truth, truth, 1.0, np.zeros_like(truth, bool))["ws_rmse"])


def test_weighted_depth_metrics_in_row_chunks_match(monkeypatch):
    import panorecon.metrics.depth as depth

    rng = np.random.default_rng(1)
    truth, pred = rng.uniform(1, 5, (16, 32)), rng.uniform(1, 5, (16, 32))
    whole = ws_depth_metrics(pred, truth, 1.3)
    monkeypatch.setattr(depth, "METRIC_CHUNK", 40)  # one row a chunk
    assert ws_depth_metrics(pred, truth, 1.3) == pytest.approx(whole, rel=1e-12)
