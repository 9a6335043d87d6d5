"""Every fusion reports which views its equations connect; views that do not connect are flagged loudly."""

import logging

import numpy as np
import pytest

from panorecon.cli import main
from panorecon.scenes import load_scene
from panorecon.sources import run_source


@pytest.fixture(scope="module")
def scene_and_metric_file(tmp_path_factory):
    """(64 px scene, its true-depth file: spec, 256 px scene, its own file: spec): a file teacher's map has the
    scene's size (a much smaller one is refused)."""
    folder = tmp_path_factory.mktemp("teacher")
    out = []
    for width in (64, 256):
        scene = load_scene("bedroom", width)
        path = folder / f"truth{width}.npy"
        np.save(path, np.where(np.isfinite(scene.distance), scene.distance, np.nan))
        out += [scene, f"file:{path}?metric=1"]
    return tuple(out)


@pytest.mark.parametrize("teacher", ["sim:clean", "sim:relative", "sim:affine-disparity", "metric-file"])
@pytest.mark.parametrize("source", ["fibonacci", "moge-merge"])
def test_every_teacher_kind_reports_connectivity_and_two_fibonacci_views_are_flagged(
    scene_and_metric_file, caplog, teacher, source
):
    scene, metric_file, larger, larger_metric_file = scene_and_metric_file
    if source == "moge-merge":  # (at 64 px the affine alignment of its 12 small views leaves no valid depth)
        teacher = larger_metric_file if teacher == "metric-file" else teacher
        _, report = run_source(larger, source, teacher)  # icosahedron vertices: connected
        assert report["view_components"] == 1 and "warnings" not in report
        return
    teacher = metric_file if teacher == "metric-file" else teacher
    with caplog.at_level(logging.WARNING, logger="panorecon.fusion"):
        _, two = run_source(scene, source, teacher, views=2)
    assert two["view_components"] == 2 and two["fusion"]["connectivity"]["groups"] == [[0], [1]]
    assert "do not connect" in two["warnings"][0] and "do not connect" in caplog.text
    _, twelve = run_source(scene, source, teacher, views=12)
    assert twelve["view_components"] == 1 and "warnings" not in twelve


def test_the_cli_prints_the_warning(tmp_path, capsys):
    assert (
        main(
            [
                "points",
                "bedroom",
                "--source",
                "fibonacci",
                "--teacher",
                "sim:relative",
                "--views",
                "2",
                "--width",
                "64",
                "--out",
                str(tmp_path / "c.ply"),
                "--report",
                str(tmp_path / "r.json"),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "WARNING: the views do not connect" in out
    assert "do not connect" in (tmp_path / "r.json").read_text()


def test_result_rows_and_results_md_carry_the_flag(tmp_path):
    import pandas as pd

    from panorecon.evaluation.ablate import result_row
    from panorecon.evaluation.report import write_results_md
    from panorecon.evaluation.suite import Suite
    from panorecon.pipeline import Row

    scene = load_scene("bedroom", 64)
    _, report = run_source(scene, "fibonacci", "sim:clean", views=2)
    row = Row("bedroom", 64, "fibonacci", "sim:clean", views=2, label="two")
    rec = result_row(row, {"report": report, "seconds": 1.0, "peak_rss_mb": 1.0}, None, {"versions": {}}, False, False)
    assert rec["view_components"] == 2 and "do not connect" in rec["warning"]
    write_results_md(pd.DataFrame([rec]), Suite("s", "t", [row], ["label"]), tmp_path, 1.0)
    assert "**WARNING** (two, bedroom): the views do not connect" in (tmp_path / "results.md").read_text()


def test_a_view_that_sees_only_sky_is_empty_not_unconnected():
    """Outdoors the views near the zenith hold no valid depth: they add no equation and misplace nothing, so
    they are listed as empty and do not raise the warning (a view with depth and no overlap still does)."""
    from panorecon.fusion.connectivity import connectivity_warning, view_connectivity
    from panorecon.geometry import ViewDepth, centred_camera, make_layout
    from panorecon.teachers import get_teacher

    scene = load_scene("bedroom", 128)
    layout = make_layout("fibonacci", 20)
    cams = [centred_camera(f, 32, layout.fov_deg) for f in layout.directions]
    views = get_teacher("sim:clean").predict_views(scene, cams)
    sky = ViewDepth(views[0].camera, np.full_like(views[0].depth, np.nan), "z", np.zeros_like(views[0].valid))
    conn = view_connectivity([sky, *views[1:]])
    assert conn["empty_views"] == [0] and conn["components"] == 1 and connectivity_warning(conn) is None
    assert view_connectivity(views)["empty_views"] == []
