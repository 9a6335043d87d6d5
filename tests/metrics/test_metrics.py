import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from panorecon.metrics import depth_metrics, point_metrics


def brute_nearest(a, b):
    return np.sqrt(((a[:, None, :] - b[None]) ** 2).sum(-1)).min(1)


class TestDepth:
    @given(st.floats(0.01, 100.0))
    def test_median_alignment_is_scale_invariant(self, s):
        rng = np.random.default_rng(0)
        t = rng.uniform(1, 10, (16, 16))
        p = t * (1 + 0.05 * rng.standard_normal(t.shape))
        a, b = depth_metrics(p, t), depth_metrics(p * s, t)
        assert a["abs_rel"] == pytest.approx(b["abs_rel"], rel=1e-9)
        assert depth_metrics(t * s, t)["abs_rel"] < 1e-12

    def test_values_and_exclusions(self):
        t = np.array([[1.0, 2.0], [np.inf, np.nan]])
        p = np.array([[1.1, 2.0], [5.0, 5.0]])
        m = depth_metrics(p, t, align="none")
        assert m["pixels"] == 2 and m["abs_rel"] == pytest.approx(0.05) and m["delta1"] == 1.0
        assert m["rmse"] == pytest.approx(np.sqrt(0.01 / 2))
        assert depth_metrics(p, np.full((2, 2), np.nan))["pixels"] == 0

    @given(st.floats(0.05, 20.0), st.floats(-0.05, 0.05))
    def test_inverse_affine_alignment_undoes_scale_and_shift_of_inverse_depth(self, a, b):
        rng = np.random.default_rng(1)
        t = rng.uniform(1, 10, (16, 16))
        inv = a / t + b  # what an affine-invariant disparity model returns, as a "depth" 1 / inv
        p = np.where(inv > 0, 1.0 / np.where(inv > 0, inv, 1.0), np.nan)
        m = depth_metrics(p, t, align="inverse-affine")
        assert m["abs_rel"] < 1e-9 and m["pixels"] == int((inv > 0).sum())
        assert m["shift"] == pytest.approx(-b / a, abs=1e-9)
        # median alignment cannot undo the shift
        if abs(b) > 0.01:
            assert depth_metrics(p, t)["abs_rel"] > 1e-3

    def test_unknown_alignment_is_one_clear_error(self):
        with pytest.raises(ValueError, match="inverse-affine"):
            depth_metrics(np.ones((2, 2)), np.ones((2, 2)), align="affine")

    def test_shape_mismatch(self):
        with pytest.raises(ValueError, match="shape"):
            depth_metrics(np.ones((2, 2)), np.ones((3, 2)))


class TestPoints:
    def test_matches_brute_force_and_is_symmetric(self):
        rng = np.random.default_rng(1)
        a, b = rng.normal(size=(300, 3)), rng.normal(size=(200, 3)) + 0.1
        m = point_metrics(a, b, threshold=0.3)
        assert m["accuracy"] == pytest.approx(brute_nearest(a, b).mean(), rel=1e-9)
        assert m["completeness"] == pytest.approx(brute_nearest(b, a).mean(), rel=1e-9)
        assert m["chamfer"] == pytest.approx(point_metrics(b, a)["chamfer"], rel=1e-9)
        prec, rec = (brute_nearest(a, b) < 0.3).mean(), (brute_nearest(b, a) < 0.3).mean()
        assert m["fscore"] == pytest.approx(2 * prec * rec / (prec + rec))

    def test_identical_clouds(self):
        a = np.random.default_rng(2).normal(size=(100, 3))
        m = point_metrics(a, a)
        assert m["chamfer"] == 0 and m["fscore"] == 1

    def test_empty_cloud(self):
        with pytest.raises(ValueError, match="empty"):
            point_metrics(np.zeros((0, 3)), np.ones((3, 3)))


def test_edge_mask_marks_pixels_near_a_depth_step_and_the_sky():
    from panorecon.metrics.depth import depth_edge_mask, edge_depth_metrics

    truth = np.full((20, 40), 2.0, np.float32)
    truth[:, 20:] = 4.0  # a step between columns 19 and 20
    truth[:3] = np.inf  # sky on top
    m = depth_edge_mask(truth, px=2)
    assert m[10, 17:23].all() and not m[10, 16] and not m[10, 23] and not m[10, 10]  # 2 px from 19 and 20
    assert m[3:6, 10].all() and not m[6, 10]  # below the sky border
    assert m[10, [0, 1, 38, 39]].all()  # the seam: column 39 next to column 0 (4 m vs 2 m)
    pred = truth.copy()
    pred[:, 19] = 3.0  # a flying column at the step
    e = edge_depth_metrics(pred, truth, 1.0)
    assert e["edge_abs_rel"] > 0 and edge_depth_metrics(truth, truth, 1.0)["edge_abs_rel"] == 0.0


@pytest.mark.parametrize("align", ["median", "none", "inverse-affine"])
def test_depth_metrics_in_chunks_equal_one_piece(monkeypatch, align):
    import panorecon.metrics.depth as depth_module

    rng = np.random.default_rng(0)
    t = rng.uniform(1, 5, (60, 120)).astype(np.float32)
    p = (t * rng.uniform(0.8, 1.3, t.shape)).astype(np.float32)
    whole = depth_metrics(p, t, align)
    monkeypatch.setattr(depth_module, "METRIC_CHUNK", 1000)
    chunked = depth_metrics(p, t, align)
    assert chunked.keys() == whole.keys()
    for k in ("abs_rel", "rmse", "delta1", "scale"):
        assert chunked[k] == pytest.approx(whole[k], rel=1e-12)
    assert chunked["pixels"] == whole["pixels"] == t.size


def test_flying_is_the_share_of_pixels_more_than_half_off_after_the_alignment():
    from panorecon.metrics.depth import FLYING_REL

    truth = np.linspace(1.0, 5.0, 1000).reshape(10, 100)
    pred = 2.0 * truth  # a global scale: the median alignment removes it
    pred.ravel()[:7] *= 3.0  # 200 % off
    pred.ravel()[7:10] *= 0.99 + FLYING_REL  # 49 % off: not flying
    pred.ravel()[10:13] *= 0.4  # 60 % off
    m = depth_metrics(pred, truth)
    assert m["flying"] == pytest.approx(10 / 1000)
    assert depth_metrics(truth, truth, "none")["flying"] == 0.0
    assert np.isnan(depth_metrics(np.full((2, 2), np.nan), np.ones((2, 2)))["flying"])


def test_point_flying_share_measures_each_point_on_its_ray_from_the_centre():
    from panorecon.geometry import erp_directions
    from panorecon.metrics import point_flying_share

    truth = np.full((32, 64), 2.0, np.float32)
    truth[:4] = np.inf  # sky: no true distance on those rays
    d = erp_directions(32, 64)[4:].reshape(-1, 3)
    xyz = d * 2.0 / 3.0  # a cloud a third of the size: scale 3 aligns it
    xyz[:50] *= 4.0  # 50 points 4x too far
    share, n = point_flying_share(xyz, truth, 3.0)
    assert n == len(d) and share == pytest.approx(50 / len(d))
    up = erp_directions(32, 64)[:2].reshape(-1, 3)
    assert point_flying_share(up, truth) == (pytest.approx(float("nan"), nan_ok=True), 0)


def test_point_flying_share_in_chunks_equals_one_piece(monkeypatch):
    import panorecon.metrics.depth as depth_module
    from panorecon.geometry import erp_directions
    from panorecon.metrics import point_flying_share

    rng = np.random.default_rng(3)
    truth = rng.uniform(1, 4, (24, 48)).astype(np.float32)
    truth[:3] = np.inf  # sky rows: not compared
    d = erp_directions(24, 48).reshape(-1, 3)
    xyz = (d * truth.reshape(-1, 1) * rng.uniform(0.3, 2.0, (len(d), 1)) / 2.0)[3 * 48 :].astype(np.float32)
    xyz[:5] = 0.0  # points at the centre have no ray
    whole = point_flying_share(xyz, truth, 2.0)
    monkeypatch.setattr(depth_module, "METRIC_CHUNK", 97)
    assert point_flying_share(xyz, truth, 2.0) == whole
    assert whole[1] == len(xyz) - 5 and 0 < whole[0] < 1


def test_median_scale_equals_numpys_median_of_float64_ratios(monkeypatch):
    import panorecon.metrics.depth as depth_module

    rng = np.random.default_rng(1)
    for n in (1001, 1000):  # odd and even counts
        t = rng.uniform(1, 5, n).astype(np.float32)
        p = (t * rng.uniform(0.8, 1.3, n)).astype(np.float32)
        ref = float(np.median(t.astype(np.float64) / p.astype(np.float64)))
        assert depth_metrics(p.reshape(1, -1), t.reshape(1, -1))["scale"] == ref
        monkeypatch.setattr(depth_module, "METRIC_CHUNK", 64)
        assert depth_metrics(p.reshape(1, -1), t.reshape(1, -1))["scale"] == ref
        monkeypatch.undo()
