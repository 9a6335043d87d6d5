"""Dataset adapters on fixtures written in each dataset's exact layout from a synthetic scene (truth known)."""

import json

import cv2
import numpy as np
import pytest

from panorecon.io import PanoreconInputError, read_image, write_image
from panorecon.scenes import load_scene
from panorecon.scenes.datasets import list_root

WIDTH = 64
ORIGIN = np.array([10.25, -3.5, 1.5])  # the dataset's world frame is not the panorama's
OFFSETS = [np.zeros(3), np.array([0.4, 0.2, 0.0])]


@pytest.fixture(scope="module")
def renders():
    """[(position in the dataset world, rgb, distance)] of bedroom from two positions."""
    world = load_scene("bedroom", WIDTH).world
    out = []
    for off in OFFSETS:
        r = world.render_erp(WIDTH // 2, off)
        out.append((ORIGIN + off, r.rgb, r.distance))
    return out


def _png16(path, distance, units_per_metre, missing=0):
    path.parent.mkdir(parents=True, exist_ok=True)
    v = np.where(np.isfinite(distance), np.round(distance * units_per_metre), missing)
    cv2.imwrite(str(path), v.astype(np.uint16))


def write_stanford2d3d(root, renders):
    """area_1/pano/{rgb,depth,pose}/camera_<uuid>_office_1_<i>_frame_equirectangular_domain_*; depth 1/512 m,
    65535 missing; pose JSON with camera_location (metres)."""
    keys = []
    for i, (pos, rgb, dist) in enumerate(renders):
        pano = f"camera_{i:032x}_office_1_{i}"
        base = root / "area_1" / "pano"
        write_image(base / "rgb" / f"{pano}_frame_equirectangular_domain_rgb.png", rgb)
        _png16(base / "depth" / f"{pano}_frame_equirectangular_domain_depth.png", dist, 512, missing=65535)
        (base / "pose").mkdir(parents=True, exist_ok=True)
        (base / "pose" / f"{pano}_frame_equirectangular_domain_pose.json").write_text(
            json.dumps({"camera_location": pos.tolist(), "camera_uuid": f"{i:032x}", "room": "office_1_area_1"})
        )
        keys.append(f"area_1/{pano}")
    return [(f"stanford2d3d:{root}/{k}", 1 / 512, 1e-9) for k in keys]


def write_structured3d(root, renders):
    """scene_00000/2D_rendering/<room>/panorama/{full/rgb_rawlight.png, full/depth.png (mm), camera_xyz.txt (mm)}."""
    names = []
    for i, (pos, rgb, dist) in enumerate(renders):
        pano = root / "scene_00000" / "2D_rendering" / f"48514{i}" / "panorama"
        write_image(pano / "full" / "rgb_rawlight.png", rgb)
        _png16(pano / "full" / "depth.png", dist, 1000)
        (pano / "camera_xyz.txt").write_text(" ".join(f"{v * 1000:.1f}" for v in pos))
        names.append((f"structured3d:{root}/scene_00000/48514{i}", 1e-3, 1e-4))
    return names


def write_matterport3d(root, renders):
    """<scene>/pano_color/<pano>.jpg and <scene>/pano_depth/<pano>.png = uint16(distance * 4000); no pose."""
    names = []
    for i, (_, rgb, dist) in enumerate(renders):
        write_image(root / "17DRP5sb8fy" / "pano_color" / f"pano{i}.jpg", rgb)
        _png16(root / "17DRP5sb8fy" / "pano_depth" / f"pano{i}.png", dist, 4000)
        names.append((f"matterport3d:{root}/17DRP5sb8fy/pano{i}", 1 / 4000, None))
    return names


WRITERS = {"stanford2d3d": write_stanford2d3d, "structured3d": write_structured3d, "matterport3d": write_matterport3d}


@pytest.mark.parametrize("dataset", sorted(WRITERS))
def test_adapter_recovers_truth_and_poses(tmp_path, renders, dataset):
    names = WRITERS[dataset](tmp_path, renders)
    for (name, unit, pose_tol), (pos, rgb, dist) in zip(names, renders):
        s = load_scene(name)
        assert s.kind == "real" and s.has_ground_truth and s.name.startswith(f"{dataset}:")
        assert str(tmp_path) not in s.name  # results do not depend on where the data is mounted
        assert s.rgb.shape == rgb.shape
        if dataset == "matterport3d":  # JPEG: lossy; the adapter gives the decoded file, which is the same picture
            assert (s.rgb == read_image(s.meta["image"])).all()
            assert np.corrcoef(s.rgb.ravel().astype(float), rgb.ravel().astype(float))[0, 1] > 0.9
        else:
            assert (s.rgb == rgb).all()
        np.testing.assert_array_equal(np.isfinite(s.distance), np.isfinite(dist))
        ok = np.isfinite(dist)
        assert np.abs(s.distance[ok] - dist[ok]).max() <= unit / 2 + 1e-6
        if pose_tol is None:
            assert s.meta["position"] is None and s.meta["others"] == []
        else:
            np.testing.assert_allclose(s.meta["position"], pos, atol=max(pose_tol, 1e-9) + 1e-4)
            assert len(s.meta["others"]) == 1 and s.meta["others"][0] != name
    listed = [n for n, _ in list_root(tmp_path)]
    assert sorted(listed) == sorted(n for n, _, _ in names)


def test_dataset_scene_resizes_and_scores(tmp_path, renders):
    from panorecon.sources import run_source

    (name, _, _), *_ = write_stanford2d3d(tmp_path, renders)
    s = load_scene(name, 32)
    assert s.distance.shape == (16, 32)
    _, rep = run_source(s, "fibonacci", "sim:relative", views=12)
    assert rep["depth"]["abs_rel"] < 0.1 and isinstance(rep["points"]["chamfer"], float)


def test_missing_pose_file(tmp_path, renders):
    (name, _, _), *_ = write_stanford2d3d(tmp_path, renders)
    (tmp_path / "area_1/pano/pose" / f"{name.rsplit('/', 1)[1]}_frame_equirectangular_domain_pose.json").unlink()
    with pytest.raises(PanoreconInputError, match="no such file .Stanford2D3D panorama pose"):
        load_scene(name)
    (name, _, _), *_ = write_structured3d(tmp_path, renders)
    (tmp_path / "scene_00000/2D_rendering/485140/panorama/camera_xyz.txt").write_text("1 2")
    with pytest.raises(PanoreconInputError, match="camera_xyz.txt: expected three"):
        load_scene(name)


@pytest.mark.parametrize(
    "name,needle",
    [("stanford2d3d:area_1", "expected Stanford2D3D"), ("structured3d:/no/such/root/scene_0/1", "is not a folder")],
)
def test_malformed_dataset_names(name, needle):
    with pytest.raises(PanoreconInputError, match=needle):
        load_scene(name)
