"""``panoramas:DIR/NAME``: a user's own posed panoramas, on a fixture written from the documented convention
(conftest.documented_directions turns pixels into rays from the guide's text, not with panorecon.geometry)."""

import json

import cv2
import numpy as np
import pytest

from panorecon.io import PanoreconInputError
from panorecon.scenes import load_scene
from panorecon.scenes.check import check_root, world_points
from panorecon.scenes.datasets import heldout_panoramas, list_root, quaternion_matrix
from panorecon.splat.labels import make_panorama_heldout_views

from .conftest import axis_angle, axis_angle_quaternion, write_posed_panorama, write_poses

H = 64
# a level panorama turned 40 deg, one tilted off the vertical (a hand-held capture), one turned -120 deg
POSES = {
    "hall": (np.array([1.2, 1.0, 1.5]), axis_angle([0, 0, 1], 40.0)),
    "desk": (np.array([3.6, 2.9, 1.4]), axis_angle([0.3, -0.2, 1.0], -75.0)),
    "door": (np.array([2.3, 1.9, 1.6]), axis_angle([0, 0, 1], -120.0)),
}


def _folder(root, transpose=(), **kw):
    """The three panoramas of POSES; those named in ``transpose`` get R^T in poses.json (the camera-from-world
    matrix written where the world-from-camera one belongs). Returns {name: world points}."""
    entries, truth = [], {}
    for name, (c, r) in POSES.items():
        entry, truth[name] = write_posed_panorama(root, name, c, r, H, **kw)
        if name in transpose:
            entry["rotation"] = r.T.tolist()
        entries.append(entry)
    write_poses(root, entries, depth_unit="mm")
    return truth


def _error(points, truth, valid):
    return np.quantile(np.linalg.norm(points - truth[valid], axis=1), 0.99)


def test_world_points_follow_the_documented_convention(tmp_path):
    truth = _folder(tmp_path)
    assert sorted(n for n, _ in list_root(tmp_path)) == sorted(f"panoramas:{tmp_path}/{n}" for n in POSES)
    for name, (_, r) in POSES.items():
        s = load_scene(f"panoramas:{tmp_path}/{name}")
        assert s.kind == "real" and s.has_ground_truth and s.name == f"panoramas:{name}"
        np.testing.assert_allclose(s.meta["rotation"], r, atol=1e-12)
        pts, valid = world_points(s)
        assert valid.mean() > 0.99 and _error(pts, truth[name], valid) < 2e-3  # depth in mm, rounded
        assert sorted(s.meta["others"]) == sorted(f"panoramas:{tmp_path}/{n}" for n in POSES if n != name)
    # the other reading of the matrix (camera from world) puts the tilted panorama's points elsewhere
    wrong = tmp_path / "wrong"
    wrong.mkdir()
    truth = _folder(wrong, transpose=("desk",))
    pts, valid = world_points(load_scene(f"panoramas:{wrong}/desk"))
    assert _error(pts, truth["desk"], valid) > 0.5


def test_quaternion_is_the_same_rotation(tmp_path):
    c, r = POSES["desk"]
    entry, truth = write_posed_panorama(tmp_path, "desk", c, r, H)
    del entry["rotation"]
    entry["quaternion"] = axis_angle_quaternion([0.3, -0.2, 1.0], -75.0)
    write_poses(tmp_path, [entry], depth_unit="mm")
    s = load_scene(f"panoramas:{tmp_path}/desk")
    np.testing.assert_allclose(s.meta["rotation"], r, atol=1e-12)
    # the outside convention: SciPy's Rotation (scalar-last [x, y, z, w], Hamilton) on the same quaternions
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    for q in rng.normal(size=(5, 4)):
        q /= np.linalg.norm(q)
        np.testing.assert_allclose(quaternion_matrix(q), Rotation.from_quat([*q[1:], q[0]]).as_matrix(), atol=1e-12)
    assert s.meta["heldout_note"].startswith("n/a: no other panorama")


def test_other_panoramas_are_held_out_views(tmp_path):
    _folder(tmp_path)
    s = load_scene(f"panoramas:{tmp_path}/hall", 2 * H)
    pans = heldout_panoramas(s)
    assert len(pans) == 2
    views = make_panorama_heldout_views(s, pans, 4, 32)
    assert min(v.mask.mean() for v in views) > 0.9  # one room: nearly every pixel co-visible
    # colours sampled from the other panoramas match the training panorama's at the same world points
    # (the texture is a function of the world point): compare a held-out view with the scene's own ERP
    from panorecon.geometry import sample_erp

    for v in views:
        rays = v.camera.world_rays()
        x = v.camera.position + rays * (v.depth[..., None] * v.camera.z_to_distance_factor()[..., None])
        own = sample_erp(s.rgb, x / np.linalg.norm(x, axis=-1, keepdims=True), "linear").astype(np.float32) / 255
        assert np.median(np.abs(own - v.rgb)[v.mask]) < 0.05
    wrong = tmp_path / "wrong"
    wrong.mkdir()
    _folder(wrong, transpose=("desk", "door"))
    s = load_scene(f"panoramas:{wrong}/hall", 2 * H)
    assert max(v.mask.mean() for v in make_panorama_heldout_views(s, heldout_panoramas(s), 4, 32)) < 0.9


def test_scenes_check_on_a_folder(tmp_path, capsys):
    from panorecon.cli import main

    _folder(tmp_path / "good")
    report = check_root(tmp_path / "good", 2 * H)
    (conv,) = report.conventions
    assert not report.flagged and conv.verdict == "ok" and conv.group == "panoramas:poses.json"
    assert conv.margin["walls"] is None and conv.margin["agreeing"] > 0.05
    _folder(tmp_path / "one", transpose=("desk",))
    report = check_root(tmp_path / "one", 2 * H)
    assert [r.name for r in report.panoramas if r.flags] == ["panoramas:desk"] and not report.conventions[0].flags
    _folder(tmp_path / "cm", unit_per_m=100.0)  # every depth in cm, poses.json says mm
    assert main(["scenes", "check", str(tmp_path / "cm"), "--width", "128"]) == 1
    assert "depth in cm gives" in capsys.readouterr().out


def test_panorama_without_depth(tmp_path):
    entries = []
    for name, (c, r) in POSES.items():
        entries.append(write_posed_panorama(tmp_path, name, c, r, H, depth=name != "door")[0])
    write_poses(tmp_path, entries, depth_unit="mm")
    s = load_scene(f"panoramas:{tmp_path}/door")
    assert s.distance is None and s.meta["heldout_note"].startswith("n/a: panoramas:door has no true depth")
    s = load_scene(f"panoramas:{tmp_path}/hall")
    assert len(heldout_panoramas(s)) == 1  # door has no depth to mark co-visible pixels
    report = check_root(tmp_path, 2 * H)
    assert [r.note for r in report.panoramas if r.name == "panoramas:door"] == ["not checked: no depth file"]


def _edit(root, fn):
    data = json.loads((root / "poses.json").read_text())
    fn(data)
    (root / "poses.json").write_text(json.dumps(data))


def _entry(data, name):
    return next(e for e in data["panoramas"] if e["name"] == name)


BAD = {
    "missing image": (lambda d: _entry(d, "desk").update(image="nope.jpg"), r"nope.jpg: no such file \(image of"),
    "not orthonormal": (
        lambda d: _entry(d, "desk").update(rotation=(1.1 * np.eye(3)).tolist()),
        r"'desk': rotation is not orthonormal .* expected a rotation matrix",
    ),
    "mirror": (
        lambda d: _entry(d, "desk").update(rotation=np.diag([1.0, -1.0, 1.0]).tolist()),
        r"'desk': rotation has determinant -1.0000 \(a mirror\); expected a proper rotation",
    ),
    "rotation and quaternion": (
        lambda d: _entry(d, "desk").update(quaternion=[1, 0, 0, 0]),
        r"'desk': expected exactly one of rotation",
    ),
    "quaternion not unit": (
        lambda d: _entry(d, "desk").pop("rotation") and _entry(d, "desk").update(quaternion=[1, 1, 0, 0]),
        r"'desk': quaternion .* expected a unit quaternion",
    ),
    "unknown unit": (
        lambda d: _entry(d, "desk").update(depth_unit="inch"),
        r"'desk': depth_unit 'inch' is not one of m, cm, mm",
    ),
    "no unit": (lambda d: d.pop("depth_unit"), r"depth_unit None is not one of"),
    "short position": (lambda d: _entry(d, "desk").update(position=[1, 2]), r"'desk': position \(metres\): \[1, 2\]"),
    "unknown key": (lambda d: _entry(d, "desk").update(rotaton=1), r"'desk': unknown key 'rotaton'"),
    "unknown top-level key": (lambda d: d.update(unit="mm"), r"poses.json: unknown key 'unit'"),
    "duplicate name": (lambda d: _entry(d, "desk").update(name="hall"), r"'hall': expected a unique name"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_folder_is_one_line(tmp_path, case):
    _folder(tmp_path)
    edit, needle = BAD[case]
    _edit(tmp_path, edit)
    with pytest.raises(PanoreconInputError, match=needle) as e:
        load_scene(f"panoramas:{tmp_path}/hall")  # the whole file is checked, whichever panorama is asked for
    assert "\n" not in str(e.value) and str(tmp_path) in str(e.value)


def test_bad_depth_size_and_names(tmp_path):
    _folder(tmp_path)
    cv2.imwrite(str(tmp_path / "desk_depth.png"), np.full((H // 2, H), 2000, np.uint16))
    with pytest.raises(PanoreconInputError, match=r"desk_depth.png: depth is 64x32 but the panorama .* same size"):
        load_scene(f"panoramas:{tmp_path}/desk")
    with pytest.raises(PanoreconInputError, match=r"no panorama 'attic'; expected one of hall, desk, door"):
        load_scene(f"panoramas:{tmp_path}/attic")
    with pytest.raises(PanoreconInputError, match=r"names the folder; expected panoramas:.*/NAME, NAME one of desk"):
        load_scene(f"panoramas:{tmp_path}")
    (tmp_path / "poses.json").write_text("{not json")
    with pytest.raises(PanoreconInputError, match=r"poses.json: not valid JSON"):
        load_scene(f"panoramas:{tmp_path}/hall")
    (tmp_path / "poses.json").unlink()
    with pytest.raises(PanoreconInputError, match=r"poses.json: no such file \(the poses file"):
        load_scene(f"panoramas:{tmp_path}/hall")
