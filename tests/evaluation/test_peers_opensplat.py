"""eval/peers/opensplat.py without OpenSplat: a fake binary that speaks its command line ("--version", "Step N:"
lines, ``-o`` PLY) stands in, so the export, the command, the step timing, the PLY scoring and the JSON are
checked; a NaN PLY and a failing run are reported as such, never scored."""

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
for i in range(1, n + 1):
    time.sleep(0.01)
    print(f"Step {{i}}: 0.1 ({{i * 100 // n}}%)", flush=True)
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


@pytest.mark.slow
def test_fake_opensplat_on_both_formats_is_scored_beside_panorecon(tmp_path):
    binary = fake_binary(tmp_path)
    res = script.main([str(tmp_path / "out"), "--opensplat", str(binary), *TINY])
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
    assert res["status"] == "ok"
    pan = res["panorecon"]
    assert pan["gaussians"] > 0 and isinstance(pan["held-out"]["psnr"], float) and pan["seconds_per_step"] > 0
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
