import numpy as np
import pytest

from panorecon.io import PanoreconInputError
from panorecon.scenes import load_scene
from panorecon.sources import get_source, list_sources, registry, run_source

ALL = {"fibonacci", "icosahedral", "latlong", "cube", "moge-merge", "erp-direct", "random"}


@pytest.fixture(scope="module")
def bedroom():
    return load_scene("bedroom", 256)


def test_registry_lists_every_source():
    assert ALL <= {s.name for s in list_sources()}
    with pytest.raises(PanoreconInputError, match="unknown point source"):
        get_source("vggt")


def test_peer_methods_are_plugins_of_the_baselines_package(tree_entry_points):
    """moge-merge, erp-direct and COLMAP come from the top-level baselines package through the entry points;
    nothing in the core imports that package."""
    import ast
    from pathlib import Path

    import panorecon

    assert {k: v.split(".")[0] for k, v in tree_entry_points.items()} == dict.fromkeys(
        ("moge-merge", "erp-direct", "colmap-sfm", "colmap-mvs"), "baselines"
    )
    for name in ("moge-merge", "erp-direct"):
        assert get_source(name).fn.__module__.startswith("baselines."), name
    for path in Path(panorecon.__file__).parent.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom) and node.level == 0
                else []
            )
            assert not any(n.split(".")[0] == "baselines" for n in names), f"{path} imports the baselines package"


def test_a_plugin_that_fails_to_import_is_listed_and_fails_only_when_run(monkeypatch):
    class EP:
        name, value = "broken-source", "no_such_pkg.mod:fn"

        @staticmethod
        def load():
            raise ModuleNotFoundError("No module named 'no_such_pkg'")

    monkeypatch.setattr(registry, "entry_points", lambda group: [EP] if group == "panorecon.sources" else [])
    monkeypatch.setattr(registry, "_loaded_entry_points", False)
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    assert "fibonacci" in {s.name for s in list_sources()}
    spec = get_source("broken-source")
    with pytest.raises(PanoreconInputError, match="no_such_pkg.mod:fn failed to load.*No module named"):
        spec.fn(None, None)


def test_entry_point_sources_are_loaded(monkeypatch):
    class EP:
        name, value = "my-source", "pkg:fn"

        @staticmethod
        def load():
            return lambda *a, **k: None

    monkeypatch.setattr(registry, "entry_points", lambda group: [EP] if group == "panorecon.sources" else [])
    monkeypatch.setattr(registry, "_loaded_entry_points", False)
    monkeypatch.setattr(registry, "_SOURCES", dict(registry._SOURCES))
    assert "my-source" in {s.name for s in list_sources()}


@pytest.mark.parametrize("source", sorted(ALL - {"random"}))
def test_every_source_reports_time_memory_and_error(bedroom, source):
    if source == "moge-merge":
        pytest.importorskip("moge.utils.panorama", reason="the moge extra (MoGe's own merge) is not installed")
    pc, rep = run_source(bedroom, source, "sim:clean")
    assert len(pc) > 0.9 * bedroom.height * bedroom.width
    assert set(rep["seconds"]) >= {"total", "metrics"} and rep["peak_rss_mb"] > 0
    assert rep["depth"]["abs_rel"] < 0.03, rep["depth"]
    assert rep["points"]["chamfer"] < 0.05 and rep["points"]["count"] == len(pc)
    if source != "erp-direct":
        assert pc.view_id is not None and pc.view_id.max() < rep["views"]


def test_fusion_beats_its_views_on_a_noisy_teacher():
    ratios = []
    for name in ("bedroom", "library"):
        _, rep = run_source(load_scene(name, 512), "fibonacci", "sim:relative")
        ratios.append(rep["depth"]["abs_rel"] / rep["teacher_per_view_abs_rel_median"])
    assert np.mean(ratios) <= 0.7, ratios


def test_sky_gives_no_points():
    from panorecon.geometry import direction_to_erp_pixel

    plaza = load_scene("city-plaza", 128)
    pc, rep = run_source(plaza, "fibonacci", "sim:clean")
    ground = ~plaza.sky
    # one point per seen non-sky pixel, none for the sky; at 32 px views the pixels at depth edges that no view
    # sees off an edge (fusion.warp.depth_edge_pixels) are 15 % of the ground (11 % with FusionConfig.edge_reach
    # 0): no point there, no flying point
    assert 0.8 * ground.sum() <= len(pc) <= ground.sum() and rep["depth"]["flying"] < 1e-3
    # every point lies along a non-sky pixel's ray, at most a few times the farthest true distance
    r, c = direction_to_erp_pixel(pc.xyz / np.linalg.norm(pc.xyz, axis=1, keepdims=True), *plaza.sky.shape)
    rows = np.clip(np.rint(r).astype(int), 0, plaza.height - 1)
    assert not plaza.sky[rows, np.rint(c).astype(int) % plaza.width].any()
    far = np.nanmax(np.where(ground, plaza.distance, np.nan))
    assert np.linalg.norm(pc.xyz, axis=1).max() < 4 * far  # per-view scales are in [0.5, 2]: 2 x 2 at worst


def test_random_source_and_scene_without_truth(real_data):
    scene = load_scene("py360-demo", 128)
    pc, rep = run_source(scene, "random", None)
    assert len(pc) == 100_000 and np.linalg.norm(pc.xyz, axis=1).max() <= 10.0
    assert rep["points"]["chamfer"].startswith("n/a") and rep["depth"].startswith("n/a")


def test_metric_samples_are_point_metrics_own_subsamples():
    """run_source measures against the points point_metrics would draw from the prediction and the whole true
    cloud, without building the latter: the metrics are identical."""
    from panorecon.metrics import point_metrics
    from panorecon.scenes import load_scene
    from panorecon.sources.run import _metric_samples

    scene = load_scene("bedroom", 256)
    rng = np.random.default_rng(0)
    for n_pred in (500, 40_000):
        pred = rng.normal(size=(n_pred, 3)).astype(np.float32)
        full = point_metrics(pred, scene.point_cloud().xyz, max_points=3000)
        fast = point_metrics(*_metric_samples(scene, pred, 3000), max_points=3000)
        assert {**fast, "count": n_pred, "subsampled_to": full["subsampled_to"]} == full


def test_max_points_thins_the_cloud_evenly_and_reports_the_density():
    scene = load_scene("bedroom", 128)
    pc, report = run_source(scene, "fibonacci", "sim:clean", 6, None, max_points=1500)
    assert 0.97 * 1500 <= len(pc) <= 1500 == report["thinning"]["max_points"]
    assert report["thinning"]["points"] == len(pc) == report["points"]["count"]
    assert report["thinning"]["spacing_deg"] > 0 and "thinning" in report["seconds"]
    full, rep_full = run_source(scene, "fibonacci", "sim:clean", 6, None)
    assert "thinning" not in rep_full and len(full) > 4 * len(pc)


def test_points_report_weights_the_erp_distance_comparison_by_solid_angle():
    """The fused distance map against the truth: beside the plain AbsRel/RMSE/delta1 (unchanged), their
    cos-latitude-weighted versions with the same alignment scale."""
    from panorecon.metrics import depth_metrics, ws_depth_metrics

    scene = load_scene("bedroom", 128)
    pc, rep = run_source(scene, "fibonacci", "sim:relative", views=12)
    d, distance = rep["depth"], pc.meta["erp_distance"]
    plain = depth_metrics(distance, scene.distance, "median", ~scene.sky)
    assert {k: d[k] for k in ("abs_rel", "rmse", "delta1", "scale")} == {
        k: plain[k] for k in ("abs_rel", "rmse", "delta1", "scale")
    }
    ws = ws_depth_metrics(distance, scene.distance, plain["scale"], ~scene.sky)
    assert {k: d[k] for k in ws} == ws and 0 < d["ws_abs_rel"] != d["abs_rel"]
