"""eval/peers/opensplat.py without OpenSplat: a fake binary that speaks its command line ("--version", "Step N:"
lines, ``-o`` PLY, ``--save-every`` PLYs) stands in, so the export, the command, the step timing, the PLY scoring,
the held-out curves and the JSON are checked; a NaN PLY and a failing run are reported as such, never scored. The
curves' clock and the time to reach a PSNR on made-up lines and curves."""

import importlib.util
import json
import stat
import sys
from pathlib import Path

import pytest

spec = importlib.util.spec_from_file_location(
    "peer_opensplat", Path(__file__).parents[2] / "eval" / "peers" / "opensplat.py"
)
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)

TINY = ["--width", "128", "--source", "random", "--iters", "3", "--labels", "4", "--res", "16", "--heldout", "2"]

FAKE = """#!{python}
import sys, time
from pathlib import Path
import numpy as np
from panorecon.geometry import PointCloud
from panorecon.splat.model import GaussianModel
from panorecon.splat.ply import save_ply

argv = sys.argv[1:]
if argv == ["--version"]:
    print("9.9.9 (git commit fake)")
    sys.exit(0)
Path("{argv_log}").write_text(" ".join(argv))
root, out, n = Path(argv[0]), argv[argv.index("-o") + 1], int(argv[argv.index("-n") + 1])
if (root / "sparse_pc.ply").is_file():
    pc = PointCloud.load_ply(root / "sparse_pc.ply")
else:
    import pycolmap
    rec = pycolmap.Reconstruction(root / "sparse" / "0")
    pc = PointCloud(np.array([p.xyz for p in rec.points3D.values()]), np.full((rec.num_points3D(), 3), 0.5))
pc = pc.subset(np.arange(0, len(pc), 50))
every = int(argv[argv.index("--save-every") + 1]) if "--save-every" in argv else -1
for i in range(1, n + 1):
    time.sleep(0.01)
    print(f"Step {{i}}: 0.1 ({{i * 100 // n}}%)", flush=True)
    if every > 0 and i % every == 0:
        save_ply(GaussianModel.from_point_cloud(pc, 3), Path(out).with_name(f"{{Path(out).stem}}_{{i}}.ply"))
if "{mode}" == "fail":
    sys.exit(3)
model = GaussianModel.from_point_cloud(pc, 3)
if "{mode}" == "nan":
    model.means.data[0] = float("nan")
save_ply(model, out)
"""


def fake_binary(tmp_path, mode="ok") -> Path:
    path = tmp_path / f"opensplat_{mode}"
    path.write_text(FAKE.format(python=sys.executable, argv_log=tmp_path / f"argv_{mode}.txt", mode=mode))
    path.chmod(path.stat().st_mode | stat.S_IEXEC)
    return path


def test_seconds_per_step_is_the_median_interval():
    assert script.seconds_per_step([(1, 0.0), (2, 1.0), (3, 1.5), (5, 9.5)]) == 1.0
    assert script.seconds_per_step([(1, 0.0)]) != script.seconds_per_step([(1, 0.0)])  # NaN


def test_the_training_clock_starts_at_the_first_step_and_leaves_out_the_saves():
    lines = [(1, 10.0), (2, 11.0), (3, 16.0), (4, 17.0), (6, 19.0)]  # a 4 s save after step 2's line
    assert script.training_clock(lines, {2}) == {1: 1.0, 2: 2.0, 3: 3.0, 4: 4.0, 6: 6.0}
    assert script.training_clock(lines) == {1: 1.0, 2: 2.0, 3: 7.0, 4: 8.0, 6: 10.0}  # the save counted
    assert script.training_clock([]) == {}


def test_time_to_reach_is_the_first_crossing_linear_between_samples():
    curve = [(1.0, 30.0), (2.0, 32.0), (3.0, 34.0), (4.0, 33.0)]
    assert script.time_to_reach(curve, 33.0) == 2.5
    assert script.time_to_reach(curve, 29.0) == 1.0  # the first sample already reaches it
    assert script.time_to_reach(curve, 34.0) == 3.0
    assert script.time_to_reach(curve, 35.0) is None
    assert script.time_to_reach(curve, float("nan")) is None
    assert script.time_to_reach([(1.0, 30.0), (2.0, float("nan")), (3.0, 34.0)], 32.0) == 2.0  # NaN skipped


def test_time_to_quality_reads_both_trainers_curves_against_both_finals():
    """Made-up curves: panorecon reaches OpenSplat's final 32 dB at 1.5 s and its own 34 at 3 s; OpenSplat reaches
    its final at 400 s and never panorecon's, so its time to its own final is 400 / 1.5 times panorecon's."""
    pan = {"held-out": {"psnr": 34.0}, "heldout_curve": [(1.0, 31.0), (2.0, 33.0), (3.0, 34.0)]}
    run = {"status": "ok", "held-out": {"psnr": 32.0}, "heldout_curve": [(100.0, 25.0), (400.0, 32.0)]}
    failed = {"status": "failed: 4 of 9 Gaussians have non-finite means"}
    result = {"panorecon": pan, "opensplat_runs": {"colmap": run, "nerfstudio": failed}}
    script.time_to_quality(result)
    assert result["time_to_quality_targets"] == {"panorecon": 34.0, "opensplat_colmap": 32.0}
    assert pan["seconds_to"] == {"panorecon": 3.0, "opensplat_colmap": 1.5}
    assert run["seconds_to"] == {"panorecon": None, "opensplat_colmap": 400.0}
    assert run["time_to_its_final_vs_panorecon"] == 400.0 / 1.5 and "seconds_to" not in failed


@pytest.mark.slow
def test_fake_opensplat_on_both_formats_is_scored_beside_panorecon(tmp_path):
    binary = fake_binary(tmp_path)
    res = script.main([str(tmp_path / "out"), "--opensplat", str(binary), *TINY, "--curve-every", "1"])
    assert res["opensplat"] == "9.9.9 (git commit fake)" and res["iters"] == 3
    argv = (tmp_path / "argv_ok.txt").read_text().split()
    assert (
        "--keep-crs" in argv and argv[argv.index("-n") + 1] == "3" and argv[argv.index("--num-downscales") + 1] == "0"
    )
    for fmt in ("colmap", "nerfstudio"):
        run = res["opensplat_runs"][fmt]
        assert run["returncode"] == 0 and run["steps_seen"] == 3 and 0.005 < run["seconds_per_step"] < 5
        assert run["gaussians"] == 2000 and run["non_finite_means"] == 0 and run["export_scale"] > 0
        assert isinstance(run["pseudo-label"]["psnr"], float) and isinstance(run["held-out"]["psnr"], float)
        assert run["seconds_per_step_vs_panorecon"] > 0 and run["status"] == "ok"
        seconds, psnrs = zip(*run["heldout_curve"])  # the PLYs after steps 1 and 2 (deleted), and the final
        assert len(seconds) == 3 and 0 < seconds[0] < seconds[1] < seconds[2] and psnrs[-1] == run["held-out"]["psnr"]
        assert not list((tmp_path / "out" / fmt).glob("opensplat_*.ply"))
        assert set(run["seconds_to"]) == {"panorecon", "opensplat_colmap", "opensplat_nerfstudio"}
        assert run["seconds_to"][f"opensplat_{fmt}"] <= seconds[-1]
    assert res["status"] == "ok" and "--save-every" in argv and argv[argv.index("--save-every") + 1] == "1"
    pan = res["panorecon"]
    assert pan["gaussians"] > 0 and isinstance(pan["held-out"]["psnr"], float) and pan["seconds_per_step"] > 0
    assert 0 <= pan["flatten_s"] < pan["train_s"]
    assert len(pan["heldout_curve"]) == 3 and pan["heldout_curve"][-1][1] == pytest.approx(pan["held-out"]["psnr"])
    assert json.loads((tmp_path / "out" / "result.json").read_text())["scene"] == "bedroom"


@pytest.mark.slow
@pytest.mark.parametrize("mode", ["nan", "fail"])
def test_nan_or_failed_runs_are_reported_not_scored(tmp_path, mode):
    res = script.main(
        [str(tmp_path / "o"), "--opensplat", str(fake_binary(tmp_path, mode)), "--formats", "colmap", *TINY]
    )
    run = res["opensplat_runs"]["colmap"]
    if mode == "nan":
        assert run["non_finite_means"] == 1 and run["pseudo-label"].startswith("n/a: 1 non-finite")
        assert run["status"] == "failed: 1 of 2000 Gaussians have non-finite means"
    else:
        assert run["returncode"] == 3 and run["error"].startswith("n/a: OpenSplat exited 3") and "gaussians" not in run
        assert run["status"].startswith("failed: OpenSplat exited 3")
    assert res["status"] == "failed: colmap: " + run["status"].removeprefix("failed: ")


@pytest.mark.parametrize(
    "run, status",
    [
        ({"gaussians": 9, "non_finite_means": 0}, "ok"),
        ({"gaussians": 9, "non_finite_means": 4}, "failed: 4 of 9 Gaussians have non-finite means"),
        ({"error": "n/a: OpenSplat exited 3 (log: x)"}, "failed: OpenSplat exited 3 (log: x)"),
    ],
)
def test_any_non_finite_mean_fails_the_run(run, status):
    assert script.run_status(run) == status


def test_the_script_exits_1_when_a_run_failed():
    assert script.exit_status({"status": "ok"}) == 0
    assert script.exit_status({"status": "failed: colmap: 4 of 9 Gaussians have non-finite means"}) == 1


def test_a_missing_binary_is_one_error(tmp_path, capsys):
    with pytest.raises(SystemExit):
        script.main([str(tmp_path / "x"), "--opensplat", str(tmp_path / "none")])
    assert "no such file" in capsys.readouterr().err
