"""The `panorecon` command end to end on small sizes (in-process: main() returns the exit code)."""

import json

import numpy as np
import pytest

from panorecon.cli import COMMANDS, TRAIN_VIEWS, main
from panorecon.io import read_image


def test_scenes_list_shows_synthetic_and_real(capsys):
    assert main(["scenes", "list"]) == 0
    out = capsys.readouterr().out
    for name in (
        "bedroom",
        "bathroom",
        "mountain",
        "grassland",
        "beach",
        "library",
        "exhibition-hall",
        "city-plaza",
        "hohonet",
        "py360-demo",
    ):
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


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["render", "atlantis", "--out", "X"], "unknown scene 'atlantis'"),
        (["render", "bedroom", "--out", "X", "--width", "20000"], "--width: 20000 is out of range"),
        (["render", "missing.png", "--out", "X"], "missing.png: no such file"),
        (["gt-cloud", "py360-demo", "--out", "X/c.ply"], "has no depth"),
        (["inspect", "nothing.ply", "--screenshot", "X/s.png"], "nothing.ply"),
        (["train", "bedroom", "--source", "fibonacci", "--out", "X", "--w-depth", "-0.1"], "--w-depth: -0.1 is out"),
        (["train", "bedroom", "--source", "fibonacci", "--out", "X", "--w-depth", "nan"], "--w-depth: nan is out"),
    ],
)
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

    argv = [
        "points",
        "bedroom",
        "--source",
        "fibonacci",
        "--teacher",
        "sim:relative",
        "--views",
        "12",
        "--width",
        "128",
        "--out",
        str(tmp_path / "c.ply"),
        "--report",
        str(tmp_path / "r.json"),
    ]
    assert main(argv) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    for key in ("source", "teacher", "views", "seconds", "peak_rss_mb", "depth", "points"):
        assert key in rep
    assert rep["views"] == 12 and "total" in rep["seconds"]
    assert {"abs_rel", "rmse", "delta1"} <= set(rep["depth"]) and {
        "count",
        "chamfer",
        "accuracy",
        "completeness",
    } <= set(rep["points"])
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
    for name in (
        "pano.png",
        "distance.npy",
        "mask.png",
        "gt_cloud.ply",
        "gt_cloud.png",
        "fibonacci_cloud.ply",
        "fibonacci_report.json",
        "fibonacci_cloud.png",
        "point_cloud.ply",
        "metrics.json",
        "renders/label_0.png",
        "cameras.json",
    ):
        assert (out / name).is_file(), name
    # pictures a person can look at: held-out renders 256 px tall, the panorama rendered back under the input
    assert Image.open(out / "renders" / "heldout_256_0.png").size == (512, 256)
    assert Image.open(out / "panorama.png").size == (128, 128)
    # the values behind the files: the input panorama on top, the truth's cloud one point per valid pixel, the
    # method's cloud close to the truth, and the rendered-back panorama's PSNR as printed
    pano = np.asarray(Image.open(out / "pano.png"))
    both = np.asarray(Image.open(out / "panorama.png"))
    np.testing.assert_array_equal(both[:64], pano)
    from panorecon.geometry import PointCloud

    assert len(PointCloud.load_ply(out / "gt_cloud.ply")) == np.isfinite(np.load(out / "distance.npy")).sum()
    report = json.loads((out / "fibonacci_report.json").read_text())
    assert report["depth"]["abs_rel"] < 0.1 and report["points"]["chamfer"] < 0.2
    err = both[64:].astype(float) / 255 - pano.astype(float) / 255
    psnr = -10 * np.log10(np.mean(err**2))
    captured = capfd.readouterr()
    assert f"PSNR {psnr:.2f} dB" in captured.out
    assert "bad X server" not in captured.err and "panorama rendered back" in captured.out
    # the summary's held-out part: the all-pixel PSNR, then the co-visible pixels against the oracle and the gap
    held = json.loads((out / "metrics.json").read_text())["held-out"]
    line = next(ln for ln in captured.out.splitlines() if "panorama rendered back" in ln)
    assert f"held-out PSNR {held['psnr']:.2f} dB (co-visible pixels" in line
    assert f"gap {held['oracle_gap']:.2f} dB)" in line


def test_train_command(tmp_path, capsys):
    import json

    argv = [
        "train",
        "bedroom",
        "--source",
        "fibonacci",
        "--teacher",
        "sim:clean",
        "--width",
        "128",
        "--iters",
        "20",
        "--res",
        "32",
        "--labels",
        "16",
        "--w-depth",
        "0.3",
        "--no-progress",
        "--out",
        str(tmp_path / "t"),
    ]
    assert main(argv) == 0
    m = json.loads((tmp_path / "t" / "metrics.json").read_text())
    assert m["iterations"] == 20 and "psnr" in m["pseudo-label"] and "psnr" in m["held-out"]
    assert m["config"]["w_depth"] == 0.3
    assert "pseudo-label PSNR" in capsys.readouterr().out
    report = json.loads((tmp_path / "t" / "fibonacci_report.json").read_text())
    assert report["views"] == TRAIN_VIEWS["fibonacci"] == 40  # train's default, not the source's 20


@pytest.mark.skipif(__import__("torch").cuda.is_available(), reason="this machine has CUDA")
@pytest.mark.parametrize(
    "argv,needle",
    [
        (["train", "bedroom", "--source", "fibonacci", "--out", "X", "--device", "cuda"], "--device cuda"),
        (["train", "bedroom", "--source", "fibonacci", "--out", "X", "--backend", "gsplat"], "--backend gsplat"),
        (
            ["train", "bedroom", "--source", "fibonacci", "--out", "X", "--device", "gpu"],
            "argument --device: 'gpu' is not a device",
        ),
        (["points", "bedroom", "--source", "fibonacci", "--out", "X/c.ply", "--device", "cuda"], "--device cuda"),
        (["ablate", "eval/suites/quick.toml", "--out", "X", "--device", "cuda"], "--device cuda"),
        (["bench", "--quick", "--device", "cuda", "--out", "X/b.json"], "--device cuda"),
    ],
)
def test_a_device_or_backend_this_machine_lacks_is_one_line_and_exit_2(tmp_path, monkeypatch, capsys, argv, needle):
    monkeypatch.chdir(tmp_path)
    if argv[0] == "ablate":
        from pathlib import Path

        argv[1] = str(Path(__file__).resolve().parents[1] / argv[1])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "X").exists()


def test_resolve_device():
    import torch

    from panorecon.device import device_record, resolve_device

    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    assert device_record(torch.device("cpu"))["peak_gpu_memory_mb"].startswith("n/a")


@pytest.mark.parametrize(
    "teacher, needle",
    [
        ("sim:relative", "has no true depth"),
        ("file:zero.npy", "zero.npy: holds no valid depth"),
        ("file:zero.npy?scale=", "scale='' is not a number"),
    ],
)
def test_teacher_mistakes_are_one_line_and_write_nothing(tmp_path, monkeypatch, capsys, teacher, needle):
    from panorecon.io import write_image

    monkeypatch.chdir(tmp_path)
    write_image(tmp_path / "pano.png", np.zeros((32, 64, 3), np.uint8))
    np.save(tmp_path / "zero.npy", np.zeros((32, 64)))
    scene = "pano.png" if teacher.startswith("sim") else "bedroom"
    assert (
        main(["points", scene, "--source", "fibonacci", "--teacher", teacher, "--width", "64", "--out", "X/c.ply"]) == 2
    )
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1 and not (tmp_path / "X").exists()


def test_a_screenshot_keeps_vtk_noise_off_the_terminal(tmp_path, capfd):
    from panorecon.geometry import PointCloud

    PointCloud(np.random.default_rng(0).normal(size=(200, 3)), np.full((200, 3), 0.5)).save_ply(tmp_path / "c.ply")
    capfd.readouterr()
    assert main(["inspect", str(tmp_path / "c.ply"), "--screenshot", str(tmp_path / "s.png")]) == 0
    out, err = capfd.readouterr()
    assert err == "" and "c.ply: 200 points" in out and read_image(tmp_path / "s.png").std() > 1


@pytest.mark.parametrize("words", [w for w, (_, config, _) in COMMANDS.items() if config])
def test_every_commands_help_prints(words, capsys):
    """argparse formats help text with % params: a literal % in a field's help must not break --help."""
    assert main([*words, "--help"]) == 0
    assert "usage:" in capsys.readouterr().out
