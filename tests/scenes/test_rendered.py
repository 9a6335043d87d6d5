"""A `panorecon render` folder loaded back as a scene with its truth, and scenes without Open3D."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from panorecon.cli import main
from panorecon.geometry import centred_camera
from panorecon.io import PanoreconInputError
from panorecon.scenes import load_scene
from panorecon.splat.labels import make_heldout_views

ROOT = Path(__file__).resolve().parents[2]
# imports of open3d fail in the child: what runs there must not need it
BLOCK_OPEN3D = """
import runpy, sys
class Block:
    def find_spec(self, name, path=None, target=None):
        if name == "open3d" or name.startswith("open3d."):
            raise ImportError("open3d is blocked in this test")
sys.meta_path.insert(0, Block())
sys.argv = ["panorecon"] + sys.argv[1:]
runpy.run_module("panorecon.cli", run_name="__main__")
"""


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    out = tmp_path_factory.mktemp("render") / "bedroom"
    assert (
        main(["render", "bedroom", "--width", "128", "--out", str(out), "--heldout", "3", "--heldout-res", "16", "24"])
        == 0
    )
    return out


def test_a_rendered_folder_is_the_scene_with_its_truth(rendered):
    orig = load_scene("bedroom", 128)
    for name in (str(rendered), f"rendered:{rendered}"):
        s = load_scene(name)
        np.testing.assert_array_equal(s.rgb, orig.rgb)
        np.testing.assert_array_equal(s.distance, orig.distance)
        np.testing.assert_array_equal(s.sky, orig.sky)
        assert s.name == "bedroom" and s.has_ground_truth and s.kind == "synthetic"
        assert s.world.free_space_radius() == pytest.approx(orig.world.free_space_radius())
    # the held-out views the trainer asks for are replayed exactly, at each recorded size
    s = load_scene(str(rendered))
    for res in (16, 24):
        a, b = make_heldout_views(s, 3, res), make_heldout_views(orig, 3, res)
        for va, vb in zip(a, b):
            np.testing.assert_array_equal(va.rgb, vb.rgb)
            np.testing.assert_array_equal(va.depth, vb.depth)
            np.testing.assert_array_equal(va.camera.viewmat, vb.camera.viewmat)


def test_an_unrecorded_view_is_refused_with_the_command_that_records_it(rendered):
    s = load_scene(str(rendered))
    with pytest.raises(PanoreconInputError, match="--heldout-res 32"):
        make_heldout_views(s, 3, 32)
    assert not s.world.can_render(centred_camera(np.array([1.0, 0, 0]), 16, 60.0))
    with pytest.raises(PanoreconInputError, match="--width 256"):
        load_scene(str(rendered), 256)


def test_a_broken_folder_is_one_clear_error(tmp_path, rendered):
    with pytest.raises(PanoreconInputError, match="scene.json"):
        load_scene(f"rendered:{tmp_path}")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "scene.json").write_text(json.dumps({"name": "x"}))
    with pytest.raises(PanoreconInputError, match="unreadable"):
        load_scene(str(bad))
    (bad / "scene.json").write_text((rendered / "scene.json").read_text())
    (bad / "pano.png").write_bytes((rendered / "pano.png").read_bytes())
    with pytest.raises(PanoreconInputError, match="distance.npy is missing"):
        load_scene(str(bad))


def _run_without_open3d(args, cwd):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run(
        [sys.executable, "-c", BLOCK_OPEN3D, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=300
    )


def test_real_panorama_and_rendered_folder_train_without_open3d(rendered, tmp_path):
    """A real panorama with a file: teacher, and a rendered synthetic folder (truth, held-out views, sim
    teacher), each run points -> train with every import of open3d failing."""
    common = [
        "--source",
        "fibonacci",
        "--views",
        "6",
        "--iters",
        "4",
        "--res",
        "16",
        "--labels",
        "4",
        "--no-progress",
        "--device",
        "cpu",
    ]
    real = _run_without_open3d(
        [
            "train",
            str(rendered / "pano.png"),
            "--teacher",
            f"file:{rendered / 'distance.npy'}",
            "--out",
            str(tmp_path / "real"),
            *common,
        ],
        tmp_path,
    )
    assert real.returncode == 0, real.stderr[-2000:]
    assert "held-out PSNR n/a" in real.stdout
    folder = tmp_path / "bedroom"  # train holds out 8 views (its default): record those
    assert main(["render", "bedroom", "--width", "128", "--out", str(folder), "--heldout-res", "16"]) == 0
    syn = _run_without_open3d(
        ["train", str(folder), "--teacher", "sim:clean", "--out", str(tmp_path / "syn"), *common], tmp_path
    )
    assert syn.returncode == 0, syn.stderr[-2000:]
    m = json.loads((tmp_path / "syn" / "metrics.json").read_text())
    assert isinstance(m["held-out"]["psnr"], float) and m["device"] == "cpu"
    assert m["peak_gpu_memory_mb"].startswith("n/a")


def test_held_out_views_are_recorded_for_each_seed_asked(tmp_path):
    folder = tmp_path / "bedroom"
    args = ["render", "bedroom", "--width", "128", "--heldout", "3", "--heldout-res", "16"]
    assert main([*args, "--heldout-seeds", "0", "2", "--out", str(folder)]) == 0
    assert json.loads((folder / "scene.json").read_text())["heldout_seeds"] == [0, 2]
    s, orig = load_scene(str(folder)), load_scene("bedroom", 128)
    for seed in (0, 2):
        for va, vb in zip(make_heldout_views(s, 3, 16, seed=seed), make_heldout_views(orig, 3, 16, seed=seed)):
            np.testing.assert_array_equal(va.rgb, vb.rgb)
            np.testing.assert_array_equal(va.camera.viewmat, vb.camera.viewmat)
    with pytest.raises(PanoreconInputError, match="no recorded true view"):
        make_heldout_views(s, 3, 16, seed=1)


def test_ablate_runs_a_suite_on_rendered_folders_without_open3d(tmp_path):
    """``ablate --scene-dir``: the suite's scenes read from their render folders (seed 1's held-out views
    recorded), every import of open3d failing; the rows' scene is the folder."""
    folders = tmp_path / "scenes"
    render = ["render", "bedroom", "--width", "128", "--heldout", "3", "--heldout-res", "16", "--heldout-seeds", "1"]
    assert main([*render, "--out", str(folders / "bedroom")]) == 0
    suite = tmp_path / "t7.toml"
    suite.write_text(
        'title = "t"\nrows = ["strategy"]\nseeds = [1]\nreference = { strategy = "adaptive" }\n'
        '[defaults]\nwidth = 128\nres = 16\nlabels = 4\niters = 4\nheldout = 3\nviews = 6\nsource = "fibonacci"\n'
        'teacher = "sim:relative"\n[grid]\nscene = ["bedroom"]\nstrategy = ["default", "adaptive"]\n'
    )
    run = _run_without_open3d(
        ["ablate", str(suite), "--scene-dir", str(folders), "--out", str(tmp_path / "out"), "--no-progress"],
        tmp_path,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    frame = pd.read_csv(tmp_path / "out" / "results.csv")
    assert sorted(frame["strategy"]) == ["adaptive", "default"]
    assert set(frame["scene"]) == {str(folders / "bedroom")} and set(frame["seed"]) == {1}
    assert frame["psnr_ho"].notna().all()
