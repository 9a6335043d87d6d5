"""`--depth` on the commands that take a SCENE: a real panorama with true depth is scored like a synthetic one."""

import json

import cv2
import numpy as np
import pytest

from panorecon.cli import build_parser, main
from panorecon.io import write_image
from panorecon.scenes import load_scene

WIDTH = 128


@pytest.fixture(scope="module")
def pano(tmp_path_factory):
    """bedroom written as a user's capture: pano.png + depth_mm.png (16-bit, mm, 0 = missing) + distance.npy."""
    d = tmp_path_factory.mktemp("capture")
    s = load_scene("bedroom", WIDTH)
    write_image(d / "pano.png", s.rgb)
    cv2.imwrite(
        str(d / "depth_mm.png"), np.where(np.isfinite(s.distance), np.round(s.distance * 1000), 0).astype(np.uint16)
    )
    np.save(d / "distance.npy", s.distance)
    return d


def test_every_scene_command_takes_the_depth_options():
    sub = next(a for a in build_parser()._actions if a.dest == "command").choices
    for command in ("render", "gt-cloud", "points", "train", "export", "demo"):
        opts = {o for a in sub[command]._actions for o in a.option_strings}
        assert {"--depth", "--depth-scale", "--depth-kind"} <= opts, command


def test_points_on_a_real_panorama_with_true_depth(tmp_path, pano, capsys):
    argv = [
        "points",
        str(pano / "pano.png"),
        "--depth",
        str(pano / "depth_mm.png"),
        "--depth-scale",
        "0.001",
        "--source",
        "fibonacci",
        "--teacher",
        "sim:relative",
        "--views",
        "12",
        "--out",
        str(tmp_path / "c.ply"),
        "--report",
        str(tmp_path / "r.json"),
        "--distance-out",
        str(tmp_path / "d.npy"),
    ]
    assert main(argv) == 0
    rep = json.loads((tmp_path / "r.json").read_text())
    assert isinstance(rep["depth"]["abs_rel"], float) and rep["depth"]["abs_rel"] < 0.1
    assert isinstance(rep["points"]["chamfer"], float) and rep["points"]["chamfer"] < 0.2
    fused = np.load(tmp_path / "d.npy")
    assert fused.dtype == np.float32 and fused.shape == (WIDTH // 2, WIDTH)
    # the written map is the one scored: its median-aligned AbsRel against the truth is the report's
    truth = np.load(pano / "distance.npy")
    ok = np.isfinite(fused) & np.isfinite(truth)
    f = fused[ok] * rep["depth"]["scale"]
    assert abs(np.mean(np.abs(f - truth[ok]) / truth[ok]) - rep["depth"]["abs_rel"]) < 2e-3
    # the same image without --depth has no truth
    assert main(argv[:2] + argv[6:-2]) == 2
    assert "has no true depth" in capsys.readouterr().err


def test_npy_default_scale_and_gt_cloud(tmp_path, pano, capsys):
    assert (
        main(
            [
                "gt-cloud",
                str(pano / "pano.png"),
                "--depth",
                str(pano / "distance.npy"),
                "--out",
                str(tmp_path / "gt.ply"),
            ]
        )
        == 0
    )
    out = capsys.readouterr().out
    assert "not ground truth" not in out and f"{(WIDTH // 2) * WIDTH} points" in out
    assert (
        main(["render", str(pano / "pano.png"), "--depth", str(pano / "depth_mm.png"), "--out", str(tmp_path / "r")])
        == 0
    )
    np.testing.assert_allclose(np.load(tmp_path / "r" / "distance.npy"), np.load(pano / "distance.npy"), atol=5e-4)


@pytest.mark.parametrize(
    "case,needle",
    [
        ("size", "expected the same size"),
        ("invalid", "no valid pixel"),
        ("8bit", "8-bit; expected 16-bit"),
        ("exr-scene", "is read as a depth file"),
        ("synthetic", "is synthetic and already has its true depth"),
        ("scale-alone", "--depth-scale/--depth-kind without --depth"),
        ("kind-alone", "--depth-scale/--depth-kind without --depth"),
    ],
)
def test_broken_inputs_are_one_line_exit_2(tmp_path, pano, capsys, case, needle):
    scene, depth = str(pano / "pano.png"), tmp_path / "d.png"
    if case == "size":
        cv2.imwrite(str(depth), np.full((WIDTH // 4, WIDTH // 2), 1000, np.uint16))
    elif case == "invalid":
        cv2.imwrite(str(depth), np.full((WIDTH // 2, WIDTH), 65535, np.uint16))
    elif case == "8bit":
        cv2.imwrite(str(depth), np.full((WIDTH // 2, WIDTH), 9, np.uint8))
    elif case == "exr-scene":
        scene = str(tmp_path / "pano.exr")
    elif case == "synthetic":
        scene = "bedroom"
        depth = pano / "depth_mm.png"
    argv = ["render", scene, "--out", str(tmp_path / "o")]
    alone = {"scale-alone": ["--depth-scale", "1"], "kind-alone": ["--depth-kind", "z"]}
    argv += alone.get(case, ["--depth", str(depth)])
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1
    assert not (tmp_path / "o").exists()


def test_scenes_list_root(tmp_path, pano, capsys):
    room = tmp_path / "scene_00000" / "2D_rendering" / "485140" / "panorama"  # Structured3D's layout
    (room / "full").mkdir(parents=True)
    for src, dst in (("pano.png", "full/rgb_rawlight.png"), ("depth_mm.png", "full/depth.png")):
        (room / dst).write_bytes((pano / src).read_bytes())
    (room / "camera_xyz.txt").write_text("0 0 1500")
    assert main(["scenes", "list", "--root", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f"structured3d:{tmp_path}/scene_00000/485140" in out and "1 panoramas" in out
    assert main(["scenes", "list", "--root", str(tmp_path / "nope")]) == 2


def test_depth_kind_z(tmp_path, pano):
    from panorecon.geometry import erp_z_to_distance_factor

    d = np.load(pano / "distance.npy")
    np.save(tmp_path / "z.npy", d / erp_z_to_distance_factor(*d.shape))
    assert (
        main(
            [
                "render",
                str(pano / "pano.png"),
                "--depth",
                str(tmp_path / "z.npy"),
                "--depth-kind",
                "z",
                "--out",
                str(tmp_path / "r"),
            ]
        )
        == 0
    )
    np.testing.assert_allclose(np.load(tmp_path / "r" / "distance.npy"), d, rtol=1e-6)
