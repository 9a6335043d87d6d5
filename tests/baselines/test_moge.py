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


def test_a_panorama_too_large_for_the_memory_left_is_one_clear_n_a_before_any_work(monkeypatch):
    from types import SimpleNamespace

    import baselines.moge as bm
    from panorecon.io.process import MEMORY_BUDGET_ENV

    need_8k = bm.merge_memory_mb(4096, 8192)
    assert need_8k > 20_000  # the measured rate (820 MB per megapixel) at 8192 x 4096: about 27 GB
    monkeypatch.setenv(MEMORY_BUDGET_ENV, "14000")
    with pytest.raises(
        BaselineUnavailableError, match=r"^n/a: moge-merge at 8192 x 4096: .* about 26\.9 GB .* 13\.7 GB"
    ):
        bm.check_memory(SimpleNamespace(height=4096, width=8192))
    bm.check_memory(SimpleNamespace(height=1024, width=2048))  # 1.7 GB: runs


def test_the_source_check_says_n_a_through_run_source(monkeypatch):
    from panorecon.io.process import MEMORY_BUDGET_ENV
    from panorecon.scenes import load_scene
    from panorecon.sources import run_source

    monkeypatch.setenv(MEMORY_BUDGET_ENV, "1")  # 1 MB: nothing fits
    with pytest.raises(BaselineUnavailableError, match=r"^n/a: moge-merge at 64 x 32: .*io.memory_budget_mb"):
        run_source(load_scene("bedroom", 64), "moge-merge", "sim:relative")
