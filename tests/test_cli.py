"""The `panorecon` command end to end on small sizes (in-process: main() returns the exit code)."""
import numpy as np
import pytest

from panorecon.cli import main
from panorecon.io import read_image


def test_scenes_list_shows_synthetic_and_real(capsys):
    assert main(["scenes", "list"]) == 0
    out = capsys.readouterr().out
    for name in ("bedroom", "bathroom", "mountain", "grassland", "beach", "library", "exhibition-hall", "city-plaza", "hohonet", "py360-demo"):
        assert name in out
    assert out.count("synthetic") >= 8


def test_render_gt_cloud_inspect(tmp_path, capsys):
    assert main(["render", "city-plaza", "--out", str(tmp_path / "r"), "--width", "128"]) == 0
    pano = read_image(tmp_path / "r" / "pano.png", erp=True)
    dist = np.load(tmp_path / "r" / "distance.npy")
    mask = read_image(tmp_path / "r" / "mask.png", unchanged=True)
    assert pano.shape == (64, 128, 3) and dist.dtype == np.float32 and dist.shape == (64, 128)
    assert np.isinf(dist).any() and ((mask > 0) == np.isfinite(dist)).all()
    assert main(["gt-cloud", "city-plaza", "--out", str(tmp_path / "c.ply"), "--width", "128"]) == 0
    assert main(["inspect", str(tmp_path / "c.ply"), "--screenshot", str(tmp_path / "c.png")]) == 0
    shot = read_image(tmp_path / "c.png")
    assert shot.std() > 5  # not a blank image


@pytest.mark.parametrize("argv,needle", [
    (["render", "atlantis", "--out", "X"], "unknown scene 'atlantis'"),
    (["render", "bedroom", "--out", "X", "--width", "20000"], "--width 20000"),
    (["render", "missing.png", "--out", "X"], "missing.png: no such file"),
    (["gt-cloud", "py360-demo", "--out", "X/c.ply"], "has no depth"),
    (["inspect", "nothing.ply", "--screenshot", "X/s.png"], "nothing.ply"),
])
def test_bad_input_gives_one_clear_error_and_writes_nothing(tmp_path, monkeypatch, capsys, argv, needle):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1
    assert not (tmp_path / "X").exists() or not any((tmp_path / "X").iterdir())


def test_not_two_to_one_image(tmp_path, capsys):
    from panorecon.io import write_image

    write_image(tmp_path / "square.png", np.zeros((32, 32, 3), np.uint8))
    assert main(["render", str(tmp_path / "square.png"), "--out", str(tmp_path / "o")]) == 2
    assert "not an equirectangular panorama" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_points_writes_cloud_and_report(tmp_path, capsys):
    import json

    from panorecon.geometry import PointCloud

    argv = ["points", "bedroom", "--source", "fibonacci", "--teacher", "sim:relative", "--views", "12", "--width", "128",
            "--out", str(tmp_path / "c.ply"), "--report", str(tmp_path / "r.json")]
    assert main(argv) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    for key in ("source", "teacher", "views", "seconds", "peak_rss_mb", "depth", "points"):
        assert key in rep
    assert rep["views"] == 12 and "total" in rep["seconds"]
    assert {"abs_rel", "rmse", "delta1"} <= set(rep["depth"]) and {"count", "chamfer", "accuracy", "completeness"} <= set(rep["points"])
    assert len(PointCloud.load_ply(tmp_path / "c.ply")) == rep["points"]["count"]
    assert main(["points", "bedroom", "--source", "fibonacci", "--out", str(tmp_path / "x.ply")]) == 2
    assert "needs --teacher" in capsys.readouterr().err


def test_lists(capsys):
    assert main(["teachers", "list"]) == 0 and "sim:affine-disparity" in capsys.readouterr().out
    assert main(["sources", "list"]) == 0 and "moge-merge" in capsys.readouterr().out


def test_demo_runs_the_main_job(tmp_path, capfd, monkeypatch):
    from PIL import Image

    monkeypatch.delenv("DISPLAY", raising=False)
    out = tmp_path / "demo"
    assert main(["demo", "--out", str(out), "--width", "128", "--iters", "10", "--res", "32"]) == 0
    for name in ("pano.png", "distance.npy", "mask.png", "gt_cloud.ply", "gt_cloud.png", "fibonacci_cloud.ply",
                 "fibonacci_report.json", "fibonacci_cloud.png", "point_cloud.ply", "metrics.json", "renders/label_0.png",
                 "cameras.json"):
        assert (out / name).is_file(), name
    # pictures a person can look at: held-out renders 256 px tall, the panorama rendered back under the input
    assert Image.open(out / "renders" / "heldout_256_0.png").size == (512, 256)
    assert Image.open(out / "panorama.png").size == (128, 128)
    captured = capfd.readouterr()
    assert "bad X server" not in captured.err and "panorama rendered back" in captured.out


def test_train_command(tmp_path, capsys):
    import json

    argv = ["train", "bedroom", "--source", "fibonacci", "--teacher", "sim:clean", "--width", "128", "--iters", "20",
            "--res", "32", "--labels", "16", "--no-progress", "--out", str(tmp_path / "t")]
    assert main(argv) == 0
    m = json.loads((tmp_path / "t" / "metrics.json").read_text())
    assert m["iterations"] == 20 and "psnr" in m["pseudo-label"] and "psnr" in m["held-out"]
    assert "pseudo-label PSNR" in capsys.readouterr().out
