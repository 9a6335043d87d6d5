"""Export to COLMAP and nerfstudio: the files read back with the same cameras, poses and points."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pycolmap
import pytest

from panorecon.export import add_export_parser, export_scene, viewmat_from_c2w_opengl
from panorecon.io import PanoreconInputError
from panorecon.scenes.synthetic import build_scene
from panorecon.splat.labels import make_pseudo_labels

VIEWS, SIZE = 12, 48


@pytest.fixture(scope="module")
def scene():
    return build_scene("bedroom", 256)


@pytest.fixture(scope="module")
def cloud(scene):
    pc = scene.point_cloud()
    return pc.subset(np.arange(0, len(pc), 9))


def test_colmap_round_trip(scene, cloud, tmp_path):
    out = export_scene(scene, cloud, VIEWS, "colmap", tmp_path / "c", view_size=SIZE)
    rec = pycolmap.Reconstruction(out / "sparse" / "0")
    cams = [lv.camera for lv in make_pseudo_labels(scene, VIEWS, SIZE)]
    assert rec.num_cameras() == 1 and rec.num_images() == VIEWS and rec.num_points3D() == len(cloud)
    cam = rec.cameras[1]
    assert cam.model_name == "PINHOLE" and (cam.width, cam.height) == (SIZE, SIZE)
    assert np.allclose(cam.calibration_matrix(), cams[0].K)
    for im in rec.images.values():
        i = int(im.name.removeprefix("view_").split(".")[0])
        assert (out / "images" / im.name).is_file()
        assert np.allclose(im.cam_from_world().matrix(), cams[i].viewmat[:3], atol=1e-9)
    xyz = np.array([p.xyz for p in rec.points3D.values()])
    assert np.allclose(np.sort(xyz, 0), np.sort(cloud.xyz, 0), atol=1e-6)


def test_nerfstudio_round_trip(scene, cloud, tmp_path):
    import open3d as o3d

    out = export_scene(scene, cloud, VIEWS, "nerfstudio", tmp_path / "n", view_size=SIZE, image_format="jpg")
    meta = json.loads((out / "transforms.json").read_text())
    cams = [lv.camera for lv in make_pseudo_labels(scene, VIEWS, SIZE)]
    assert (meta["w"], meta["h"], meta["fl_x"], meta["cx"]) == (SIZE, SIZE, cams[0].K[0, 0], cams[0].K[0, 2])
    assert len(meta["frames"]) == VIEWS
    for f, cam in zip(meta["frames"], cams):
        c2w = np.array(f["transform_matrix"])
        assert (out / f["file_path"]).is_file()
        assert np.allclose(viewmat_from_c2w_opengl(c2w), cam.viewmat, atol=1e-9)
        assert np.allclose(c2w[:3, 3], cam.position)
        assert np.allclose(c2w[:3, 2], -cam.forward)  # OpenGL cameras look down -z
    pc = o3d.io.read_point_cloud(str(out / meta["ply_file_path"]))
    assert len(pc.points) == len(cloud)
    assert np.allclose(np.asarray(pc.colors), np.round(cloud.rgb * 255) / 255, atol=1e-6)


def test_refuses_non_empty_out(scene, cloud, tmp_path):
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "keep").write_text("")
    with pytest.raises(PanoreconInputError, match="not empty"):
        export_scene(scene, cloud, VIEWS, "colmap", tmp_path / "x", view_size=SIZE)
    export_scene(scene, cloud, 3, "colmap", tmp_path / "x", view_size=SIZE, overwrite=True)
    assert not (tmp_path / "x" / "keep").exists() and [p.name for p in tmp_path.iterdir()] == ["x"]
    with pytest.raises(PanoreconInputError, match="export format"):
        export_scene(scene, cloud, VIEWS, "ply", tmp_path / "y")


def test_export_command(tmp_path, capsys):
    parser = argparse.ArgumentParser()
    add_export_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(
        [
            "export",
            "bedroom",
            "--source",
            "random",
            "--format",
            "nerfstudio",
            "--width",
            "128",
            "--labels",
            "4",
            "--res",
            "32",
            "--out",
            str(tmp_path / "e"),
        ]
    )
    assert args.fn(args) == 0
    assert "100000 points" in capsys.readouterr().out
    assert len(json.loads((tmp_path / "e" / "transforms.json").read_text())["frames"]) == 4
