"""moge-merge: MoGe's own merge_panorama_depth (dlr-moge) through the baselines plug-in."""

import sys

import numpy as np
import pytest

from panorecon.geometry import ViewDepth, erp_directions
from panorecon.metrics import depth_metrics

from ..fusion.conftest import box_distance

pytest.importorskip("moge.utils.panorama", reason="the moge extra (MoGe's own merge) is not installed")

from baselines import BaselineUnavailableError  # noqa: E402
from baselines.moge import merge_views, moge_cameras  # noqa: E402


def _views(size, rng, hole=False):
    views = []
    for cam in moge_cameras(size):
        d = (box_distance(cam.world_rays()) * rng.uniform(0.7, 1.4)).astype(np.float32)
        valid = np.ones(d.shape, bool)
        if hole:
            d[: size // 4] = np.nan  # e.g. sky: invalid, and NaN in the map
            valid[: size // 4] = False
        views.append(ViewDepth(cam, d, "distance", valid))
    return views


def test_moges_merge_recovers_exact_views_in_panorecons_erp_convention():
    views = _views(64, np.random.default_rng(0))
    d = merge_views(views, 64, 128)
    truth = box_distance(erp_directions(64, 128))
    assert "moge.utils.panorama" in sys.modules
    err = depth_metrics(d, truth)["abs_rel"]
    assert err < 0.03
    # the half-turn between MoGe's ERP columns and panorecon's is undone: rolled, the error is far larger
    assert depth_metrics(np.roll(d, 64, axis=1), truth)["abs_rel"] > 4 * err


def test_invalid_view_pixels_do_not_spread_nan():
    d = merge_views(_views(64, np.random.default_rng(1), hole=True), 64, 128)
    seen = np.isfinite(d)
    assert seen.mean() > 0.9 and (d[seen] > 0).all()
    assert depth_metrics(d, box_distance(erp_directions(64, 128)))["abs_rel"] < 0.05


def test_missing_moge_is_one_clear_n_a(monkeypatch):
    import baselines.moge as bm

    monkeypatch.setitem(sys.modules, "moge.utils", None)  # an import of moge.utils now fails
    with pytest.raises(BaselineUnavailableError, match=r"^n/a: moge-merge needs MoGe's code.*dlr-moge"):
        bm.moge_cameras(16)
