"""The held-out co-visible scores (``oracle_scores``) on hand-built views whose errors are known, and the summary
line that reports them."""

import numpy as np
import pytest

from panorecon.geometry import centred_camera
from panorecon.splat.evaluate import covisible_fraction, heldout_summary, oracle_scores
from panorecon.splat.labels import MIN_COVISIBLE_PIXELS, LabelView


def _view(covisible: np.ndarray, oracle_error: float, truth: float = 0.5) -> LabelView:
    """A 32 x 32 view of flat grey ``truth`` whose oracle is off by ``oracle_error`` on the co-visible pixels."""
    n = covisible.shape[0]
    oracle = np.full((n, n, 3), np.nan, np.float32)
    oracle[covisible] = truth + oracle_error
    rgb = np.full((n, n, 3), truth, np.float32)
    return LabelView(centred_camera(np.array([1.0, 0, 0]), n, 60.0), rgb, covisible=covisible, oracle=oracle)


def test_gap_is_oracle_minus_model_on_the_covisible_pixels_only():
    half = np.zeros((32, 32), bool)
    half[:, :16] = True  # 512 co-visible pixels
    v = _view(half, 0.01)  # oracle: 40 dB
    render = np.full((32, 32, 3), 0.5, np.float32)
    render[half] += 0.1  # 20 dB on the co-visible pixels...
    render[~half] = 0.0  # ... and far off elsewhere, which the co-visible scores must not see
    s = oracle_scores([(v, render)])
    assert s["covisible_psnr"] == pytest.approx(20.0, abs=1e-4)
    assert s["oracle_psnr"] == pytest.approx(40.0, abs=1e-4)
    assert s["oracle_gap"] == pytest.approx(20.0, abs=1e-4) and s["oracle_gap_views"] == 1
    # a view under MIN_COVISIBLE_PIXELS is left out of every co-visible score, not averaged in
    few = np.zeros((32, 32), bool)
    few.flat[: MIN_COVISIBLE_PIXELS - 1] = True
    s2 = oracle_scores([(v, render), (_view(few, 0.3), render)])
    assert s2["oracle_gap"] == s["oracle_gap"] and s2["oracle_psnr_views"] == 1
    assert covisible_fraction([v, _view(few, 0.3)]) == pytest.approx((512 + MIN_COVISIBLE_PIXELS - 1) / 2048)


def test_gap_is_averaged_view_by_view():
    m = np.ones((32, 32), bool)
    a, b = _view(m, 0.01), _view(m, 0.1)  # oracles at 40 and 20 dB
    ra, rb = np.full((32, 32, 3), 0.6, np.float32), np.full((32, 32, 3), 0.6, np.float32)  # 20 dB each
    s = oracle_scores([(a, ra), (b, rb)])
    assert s["oracle_gap"] == pytest.approx(10.0, abs=1e-4) and s["oracle_psnr"] == pytest.approx(30.0, abs=1e-4)
    assert s["oracle_gap"] == pytest.approx(s["oracle_psnr"] - s["covisible_psnr"])


def test_no_oracle_reads_na():
    v = LabelView(centred_camera(np.array([1.0, 0, 0]), 32, 60.0), np.zeros((32, 32, 3), np.float32))
    s = oracle_scores([(v, v.rgb)])
    assert s["oracle_gap"].startswith("n/a") and s["oracle_gap_views"] == 0
    assert covisible_fraction([v]).startswith("n/a")
    assert oracle_scores([], "n/a: because")["oracle_psnr"] == "n/a: because"


def test_summary_line():
    held = {"psnr": 27.281, "covisible_psnr": 29.5, "oracle_psnr": 36.25, "oracle_gap": 6.75, "covisible_fraction": 0.8}
    assert heldout_summary(held) == (
        "held-out PSNR 27.28 dB (co-visible pixels 80%: 29.50 dB against the oracle's 36.25 dB, gap 6.75 dB)"
    )
    assert heldout_summary({"psnr": 27.281}) == "held-out PSNR 27.28 dB"
    assert heldout_summary("n/a: no world") == "held-out PSNR n/a: no world"
