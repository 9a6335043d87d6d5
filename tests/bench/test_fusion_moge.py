"""The equal-input benchmark against MoGe's own merge (tiny ERP; the moge extra)."""

import json

import numpy as np
import pytest

pytest.importorskip("moge.utils.panorama", reason="the moge extra (MoGe's own merge) is not installed")

from panorecon.bench import fusion_moge as bm  # noqa: E402
from panorecon.geometry import erp_directions  # noqa: E402

from ..fusion.conftest import box_distance  # noqa: E402


def test_equal_views_are_moges_split_of_the_truth_perturbed_as_named():
    truth = box_distance(erp_directions(64, 128)).astype(np.float32)
    exact, ext, ints = bm.equal_views(truth, "moge", "exact", 0, size=32)
    scaled, _, _ = bm.equal_views(truth, "moge", "scale", 0, size=32)
    noisy, _, _ = bm.equal_views(truth, "moge", "scale+noise", 0, size=32)
    assert len(exact) == 12 and ext.shape == (12, 4, 4) and exact[0].shape == (32, 32)
    ratio = [s / e for s, e in zip(scaled, exact)]
    assert all(np.ptp(r) < 1e-5 and 0.7 <= r.mean() <= 1.4 for r in ratio)  # one scale per view
    assert 0.01 < np.std(noisy[0] / scaled[0]) < 0.03
    # the split agrees with panorecon's cameras: each view's centre pixel sees the truth along its axis
    vds = bm._view_depths(exact, ext, ints)
    for v in vds[:3]:
        axis = v.camera.forward
        assert np.isclose(v.depth[15:17, 15:17].mean(), box_distance(axis[None])[0], rtol=0.05)


def test_rows_carry_both_methods_and_the_ratios(tmp_path, monkeypatch):
    truth = box_distance(erp_directions(64, 128)).astype(np.float32)

    class Scene:
        distance = truth

    monkeypatch.setattr("panorecon.scenes.load_scene", lambda name, width: Scene)
    monkeypatch.setattr(bm, "in_fresh_process", lambda fn, *a: fn(*a))
    monkeypatch.setattr(bm, "VIEW_SIZE", 48)
    rows = bm.run("box", [128], ["scale+noise"], 0, variants=["nearest"])
    by = {r["method"]: r for r in rows}
    assert set(by) == {"moge", "fuse_views", "fibonacci-own", "fuse_views[nearest]"}
    for r in rows:
        # fuse_views leaves out the pixels every 48 px view sees at a depth step over 1.5x (depth_edge_pixels)
        assert np.isfinite(r["abs_rel"]) and r["abs_rel"] < 0.05 and r["pixels"] >= 0.99 * 64 * 128 and r["peak_mb"] > 0
    assert by["fuse_views"]["speedup_vs_moge"] == by["moge"]["seconds"] / by["fuse_views"]["seconds"]
    json.dumps(rows)


def test_repeats_give_the_median_of_fresh_runs(monkeypatch):
    truth = box_distance(erp_directions(32, 64)).astype(np.float32)

    class Scene:
        distance = truth

    monkeypatch.setattr("panorecon.scenes.load_scene", lambda name, width: Scene)
    calls = iter(range(100))

    def fake_run(fn, *a):
        r = fn(*a)
        return {**r, "seconds": float(next(calls)), "cpu_seconds": 1.0}

    monkeypatch.setattr(bm, "in_fresh_process", fake_run)
    monkeypatch.setattr(bm, "VIEW_SIZE", 32)
    rows = bm.run("box", [64], ["exact"], 0, repeats=3)
    assert [r["seconds_runs"] for r in rows] == [[0.0, 1.0, 2.0], [3.0, 4.0, 5.0], [6.0, 7.0, 8.0]]
    assert [r["seconds"] for r in rows] == [1.0, 4.0, 7.0] and rows[1]["speedup_vs_moge"] == 1.0 / 4.0
