"""Panoramic-depth datasets as scene names: ``<dataset>:<root>/<...>`` -> a real ``Scene`` with true depth.

Each adapter knows its dataset's on-disk layout, depth encoding, pixel<->direction convention and pose from the
dataset's own code and documentation (cited beside it). No dataset file ships with panorecon; see the README for
where each comes from and its licence.

- ``stanford2d3d:<root>/<area>/<pano id>``: ``<area>/pano/{rgb,depth,pose,global_xyz}/<pano id>``
  ``_frame_equirectangular_domain_{rgb.png,depth.png,pose.json,global_xyz.exr}``; depth 16-bit PNG, 1/512 m,
  ray distance, 65535 missing; position ``camera_location`` (m); orientation per panorama from its
  ``global_xyz`` image (the dataset's own world position of every pixel), else unknown.
- ``structured3d:<root>/<scene>/<room>``: ``<scene>/2D_rendering/<room>/panorama/{full/rgb_rawlight.png,
  full/depth.png, camera_xyz.txt}``; depth 16-bit PNG, mm, ray distance; position ``camera_xyz.txt`` (mm);
  orientation fixed by the dataset (centre column along +y, +x to its right, +z up).
- ``matterport3d:<root>/<scene>/<pano>``: ``<scene>/pano_color/<pano>.jpg``, ``<scene>/pano_depth/<pano>.png``;
  depth 16-bit PNG, 1/4000 m, ray distance; no pose.
- ``panoramas:<dir>/<name>``: a user's own posed panoramas, ``<dir>/poses.json`` (``read_poses``; the layout is
  documented in docs/guide.md, "Your own posed panoramas"): images, optional depth with its unit, and each
  panorama's position and rotation in panorecon's own convention; one space.

A panorama's pose is its centre (metres, the dataset's world frame) and ``rotation`` [3, 3]: the dataset-world
direction of a panorecon sphere direction (``geometry/sphere.py``: centre column along +x, +y to its left,
+z up), i.e. world point = position + rotation @ (distance * d(lon, lat)). Held-out views and
``panorecon scenes check`` use a panorama only when both are known.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io import PanoreconInputError
from .real import DepthSpec, read_erp_depth, scene_from_image


@dataclass(frozen=True)
class Panorama:
    """One dataset panorama: ``name`` (``<dataset>:<key>``, without the root), its image, its depth file, its
    centre [3] float64 metres in the dataset's world frame and ``rotation`` [3, 3] float64 (world direction of a
    panorecon sphere direction, see the module doc), each None where the dataset gives none; ``orientation``:
    where the rotation comes from, or why there is none."""

    name: str
    rgb: Path
    depth: DepthSpec | None
    position: np.ndarray | None
    rotation: np.ndarray | None = None
    orientation: str = "none: the dataset gives no pose"


@dataclass(frozen=True)
class Dataset:
    """``locate(root, key)`` -> Panorama; ``keys(root)`` -> every key under ``root`` (sorted);
    ``group(key)``: the key of the space a panorama belongs to (the panoramas that share it, with poses,
    serve as held-out views)."""

    prefix: str
    description: str
    key_parts: int
    locate: Callable[[Path, str], Panorama]
    keys: Callable[[Path], list[str]]
    group: Callable[[str], str]


def _need(path: Path, what: str) -> Path:
    if not path.is_file():
        raise PanoreconInputError(f"{path}: no such file ({what})")
    return path


def _panorecon_directions(height: int, width: int) -> np.ndarray:
    from ..geometry import erp_directions

    return erp_directions(height, width)


def fit_rotation(local: np.ndarray, world: np.ndarray) -> tuple[np.ndarray, float]:
    """The proper rotation R [3, 3] minimising sum |R @ local_k - world_k|^2 (Kabsch; local, world [N, 3]
    float64 metres) and the median residual (metres) of the fit."""
    u, _, vt = np.linalg.svd(world.T @ local)
    d = np.sign(np.linalg.det(u @ vt))
    r = u @ np.diag([1.0, 1.0, d]) @ vt
    return r, float(np.median(np.linalg.norm(local @ r.T - world, axis=1)))


# ---------------------------------------------------------------- Stanford2D3D (2D-3D-S)
# github.com/alexsax/2D-3D-Semantics README: "Depth images are stored as 16-bit PNGs and have a maximum depth
# of 128m and a sensitivity of 1/512m. Missing values are encoded with the value 2^16 - 1 ... [depth] is defined
# as the distance from the point-center of the camera in the panoramics." Pose JSON: "camera_location": XYZ
# location of the camera; pano files: area_N/pano/<modality>/camera_<uuid>_<room>_<i>_frame_equirectangular_domain_*.
# Orientation: every panorama has its own (the pose JSON's camera_rt_matrix / final_camera_rotation differ per
# panorama), but neither the README nor the tools (assets/pcl_utils.h reads the XYZ-Euler angles only, for the
# perspective frames) say how an equirectangular pixel maps to that camera frame. The dataset does ship the
# mapping itself: "Global XYZ images contain the ground-truth location of each pixel in the mesh" (16-bit 3-channel
# OpenEXR, missing = 0, pano/global_xyz/<id>_global_xyz.exr). The adapter fits each panorama's rotation to it
# (world XYZ - camera_location against distance x panorecon direction, every 8th pixel); without that file the
# orientation is unknown and the panorama serves neither held-out views nor `scenes check`.
_S2D3D_SUFFIX = "_frame_equirectangular_domain_"
_S2D3D_FIT_STEP = 8
_S2D3D_FIT_MAX_RESIDUAL = 0.05  # metres: a worse fit means the global_xyz does not belong to this depth


def _s2d3d_file(root: Path, key: str, modality: str, ext: str) -> Path:
    area, pano = key.split("/")
    return root / area / "pano" / modality / f"{pano}{_S2D3D_SUFFIX}{modality}.{ext}"


def _s2d3d_rotation(xyz_path: Path, depth: DepthSpec, position: np.ndarray) -> tuple[np.ndarray | None, str]:
    xyz = _read_exr_rgb(xyz_path)
    dist = read_erp_depth(depth.path, depth.scale, depth.kind).astype(np.float64)
    if xyz.shape[:2] != dist.shape:
        raise PanoreconInputError(f"{xyz_path}: global XYZ is {xyz.shape[1]}x{xyz.shape[0]}, depth {dist.shape[::-1]}")
    s = (slice(None, None, _S2D3D_FIT_STEP), slice(None, None, _S2D3D_FIT_STEP))
    dirs = _panorecon_directions(*dist.shape)[s]
    xyz, dist = xyz[s], dist[s]
    ok = np.isfinite(dist) & np.isfinite(xyz).all(-1) & (np.abs(xyz).sum(-1) > 0)
    if ok.sum() < 100:
        return None, f"none: {xyz_path.name} has {int(ok.sum())} valid pixels where the depth is valid"
    r, res = fit_rotation(dist[ok][:, None] * dirs[ok], xyz[ok] - position)
    if res > _S2D3D_FIT_MAX_RESIDUAL:
        raise PanoreconInputError(
            f"{xyz_path}: the global XYZ image does not fit this panorama's depth and camera_location "
            f"(median residual {res:.3f} m after the best rotation; expected <= {_S2D3D_FIT_MAX_RESIDUAL} m)"
        )
    return r, f"2D-3D-S global_xyz fit (median residual {res * 1000:.1f} mm)"


def _read_exr_rgb(path: Path) -> np.ndarray:
    """A 3-channel EXR -> [H, W, 3] float64 (channels R, G, B; or one RGB layer of pixel triples)."""
    try:
        import OpenEXR
    except ImportError:
        raise PanoreconInputError(
            f"{path}: reading EXR needs the OpenEXR package: pip install 'panorecon[exr]'"
        ) from None
    try:
        with OpenEXR.File(str(path)) as f:
            ch = {n: np.asarray(c.pixels, np.float64) for n, c in f.channels().items()}
    except Exception as e:  # OpenEXR raises bare exceptions for truncated or foreign files
        raise PanoreconInputError(f"{path}: not a readable EXR file ({e})") from None
    if all(c in ch for c in "RGB"):
        return np.stack([ch["R"], ch["G"], ch["B"]], -1)
    one = next((v for v in ch.values() if v.ndim == 3 and v.shape[2] >= 3), None)
    if one is None:
        raise PanoreconInputError(f"{path}: expected an RGB (X, Y, Z) EXR, found channels {sorted(ch)}")
    return one[..., :3]


def _s2d3d_locate(root: Path, key: str) -> Panorama:
    rgb = _need(_s2d3d_file(root, key, "rgb", "png"), "Stanford2D3D panorama image")
    depth_path = _need(_s2d3d_file(root, key, "depth", "png"), "Stanford2D3D panorama depth")
    pose_path = _need(_s2d3d_file(root, key, "pose", "json"), "Stanford2D3D panorama pose")
    try:
        position = np.asarray(json.loads(pose_path.read_text())["camera_location"], np.float64)
    except (ValueError, KeyError, TypeError) as e:
        raise PanoreconInputError(f"{pose_path}: not a 2D-3D-S pose file with a camera_location ({e})") from None
    if position.shape != (3,) or not np.isfinite(position).all():
        raise PanoreconInputError(f"{pose_path}: camera_location {position.tolist()} is not three finite numbers")
    depth = DepthSpec(depth_path, 1 / 512, "distance", source="2D-3D-S, 1/512 m")
    xyz_path = _s2d3d_file(root, key, "global_xyz", "exr")
    if xyz_path.is_file():
        rotation, orientation = _s2d3d_rotation(xyz_path, depth, position)
    else:
        rotation, orientation = None, f"none: no {xyz_path.name} (the per-pixel world positions it is fitted to)"
    return Panorama(f"stanford2d3d:{key}", rgb, depth, position, rotation, orientation)


def _s2d3d_group(key: str) -> str:
    """``<area>/<room>``: pano ids are camera_<uuid>_<room type>_<room number>_<i> (README, "room")."""
    area, pano = key.split("/")
    return f"{area}/{'_'.join(pano.split('_')[2:-1])}"


def _s2d3d_keys(root: Path) -> list[str]:
    tail = f"{_S2D3D_SUFFIX}rgb.png"
    return sorted(f"{p.parents[2].name}/{p.name[: -len(tail)]}" for p in root.glob(f"*/pano/rgb/*{tail}"))


# ---------------------------------------------------------------- Structured3D
# github.com/bertjiazheng/Structured3D (commit a1aa97f) data_organization.md: <scene>/2D_rendering/<room>/panorama/
# {empty,simple,full}/{rgb_rawlight.png, depth.png}, panorama/camera_xyz.txt "the camera location in millimeters
# in global coordinates. The direction of the camera is always along the negative y-axis. The z-axis is upward";
# depth.png "16-bit ... millimeters ... A zero value denotes no reading", the distance from the camera centre.
# Pixel <-> direction: misc/panorama.py, coords2uv + uv2xyzN (planeID 1): u = (col - W/2) / W * 2 pi (pixel
# centres), v = -(row - H/2) / H * pi, direction = (cos v sin u, cos v cos u, sin v); xyz_2_coorxy is its inverse
# (u = atan2(x, y)). So the centre column looks along +y, +x is to its right, and the image's first column (u = -pi)
# along -y (the README's "direction of the camera"). panorecon's centre column looks along +x with +y to its left:
# world = Rz(+90 deg) @ panorecon direction. annotation_3d.json planes: normal . x + offset = 0 (mm; visualize_3d.py,
# project_inv), the normal towards the empty space.
_S3D_WORLD_FROM_PANO = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def _s3d_locate(root: Path, key: str) -> Panorama:
    scene, room = key.split("/")
    pano = root / scene / "2D_rendering" / room / "panorama"
    rgb = _need(pano / "full" / "rgb_rawlight.png", "Structured3D panorama image")
    depth = _need(pano / "full" / "depth.png", "Structured3D panorama depth")
    xyz = _need(pano / "camera_xyz.txt", "Structured3D camera location")
    try:
        position = np.asarray(xyz.read_text().split(), np.float64) / 1000.0
    except ValueError as e:
        raise PanoreconInputError(f"{xyz}: expected three numbers (millimetres), {e}") from None
    if position.shape != (3,) or not np.isfinite(position).all():
        raise PanoreconInputError(f"{xyz}: expected three finite numbers (millimetres)")
    return Panorama(
        f"structured3d:{key}",
        rgb,
        DepthSpec(depth, 1e-3, "distance", source="Structured3D, mm"),
        position,
        _S3D_WORLD_FROM_PANO,
        "Structured3D misc/panorama.py uv2xyzN: centre column along +y, +x to its right",
    )


def _s3d_keys(root: Path) -> list[str]:
    return sorted(
        f"{p.parents[4].name}/{p.parents[2].name}" for p in root.glob("*/2D_rendering/*/panorama/full/rgb_rawlight.png")
    )


def structured3d_planes(root: Path, scene: str, kind: str = "wall") -> np.ndarray | None:
    """The ``kind`` planes of a Structured3D scene's ``annotation_3d.json`` as [P, 4] float64 (unit normal, offset
    in metres: normal . x + offset = 0), or None without the file."""
    path = Path(root) / scene / "annotation_3d.json"
    if not path.is_file():
        return None
    try:
        planes = [p for p in json.loads(path.read_text())["planes"] if p["type"] == kind]
        arr = np.array([[*p["normal"], p["offset"] / 1000.0] for p in planes], np.float64).reshape(-1, 4)
    except (ValueError, KeyError, TypeError) as e:
        raise PanoreconInputError(f"{path}: not a Structured3D annotation_3d.json with planes ({e})") from None
    norm = np.linalg.norm(arr[:, :3], axis=1, keepdims=True)
    if not (np.isfinite(arr).all() and (norm > 0).all()):
        raise PanoreconInputError(f"{path}: a plane has a zero or non-finite normal")
    return arr / norm


# ---------------------------------------------------------------- Matterport3D (360° panoramas)
# The 360° Matterport3D that the panoramic-depth papers use (BiFuse, UniFuse: github.com/alibaba/
# UniFuse-Unidirectional-Fusion, Matterport3D/stitch.m): the skybox views stitched per scan into
# <scene>/pano_color/<pano>.jpg and <scene>/pano_depth/<pano>.png = uint16(ray distance * 4000); no pose file
# in that layout, so neither position nor orientation. The dataset itself (github.com/niessner/Matterport, commit
# 8cd7c81, data_organization.md) gives each panorama's centre in house_segmentations/<scene>.house ("P name
# panorama_index region_index 0 px py pz") and per-image poses of the 18 raw views, but documents no orientation
# for its skybox faces (matterport_skybox_images), so a stitched panorama's rotation is not guessed here.
def _mp3d_locate(root: Path, key: str) -> Panorama:
    scene, pano = key.split("/")
    rgb = next((p for p in (root / scene / "pano_color" / f"{pano}{e}" for e in (".jpg", ".png")) if p.is_file()), None)
    if rgb is None:
        raise PanoreconInputError(
            f"{root / scene / 'pano_color' / pano}.jpg: no such file (Matterport3D panorama image)"
        )
    depth = _need(root / scene / "pano_depth" / f"{pano}.png", "Matterport3D panorama depth")
    return Panorama(
        f"matterport3d:{key}", rgb, DepthSpec(depth, 1 / 4000, "distance", source="Matterport3D, 1/4000 m"), None
    )


def _mp3d_keys(root: Path) -> list[str]:
    return sorted({f"{p.parents[1].name}/{p.stem}" for e in ("jpg", "png") for p in root.glob(f"*/pano_color/*.{e}")})


# ---------------------------------------------------------------- your own posed panoramas
# Not a dataset's convention but panorecon's own (geometry/sphere.py, DESIGN.md): the world frame is right-handed,
# +z up, metres; a panorama's ``rotation`` R maps its camera frame to the world, world direction = R @ d(lon, lat)
# with d = (cos lat cos lon, -cos lat sin lon, sin lat), lon = 0 at the image's centre column, growing to the right;
# so R's columns are the world directions of the centre column on the horizon (+x), of the column a quarter of the
# width from the left edge (+y) and of the top row (+z). ``quaternion`` [w, x, y, z] is the same rotation
# (Hamilton, unit). Tested on a fixture whose pixels are turned into rays from this text in the test.
POSES_FILE = "poses.json"
DEPTH_UNITS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3, "1/512 m": 1 / 512, "1/4000 m": 1 / 4000}
ROTATION_TOL = 1e-3  # max |R^T R - I| entry, |det R - 1| and | |q| - 1 | accepted (then made exact)
_POSE_KEYS = ("name", "image", "position", "rotation", "quaternion", "depth", "depth_unit")


def quaternion_matrix(q) -> np.ndarray:
    """Unit quaternion [w, x, y, z] (Hamilton) -> rotation matrix [3, 3] float64."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _numbers(value, shape, what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, np.float64)
    except (ValueError, TypeError):
        arr = None
    if arr is None or arr.shape != shape or not np.isfinite(arr).all():
        raise PanoreconInputError(f"{what}: {json.dumps(value)} is not {' x '.join(map(str, shape))} finite numbers")
    return arr


def _pose_rotation(entry: dict, what: str) -> np.ndarray:
    if ("rotation" in entry) == ("quaternion" in entry):
        raise PanoreconInputError(
            f"{what}: expected exactly one of rotation (3x3, camera axes to world axes) or quaternion [w, x, y, z]"
        )
    if "quaternion" in entry:
        q = _numbers(entry["quaternion"], (4,), f"{what}: quaternion")
        if abs(np.linalg.norm(q) - 1) > ROTATION_TOL:
            raise PanoreconInputError(
                f"{what}: quaternion {q.tolist()} has length {np.linalg.norm(q):.4f}; expected a unit quaternion "
                f"[w, x, y, z] (length 1 within {ROTATION_TOL})"
            )
        return quaternion_matrix(q)
    r = _numbers(entry["rotation"], (3, 3), f"{what}: rotation")
    err = float(np.abs(r.T @ r - np.eye(3)).max())
    if err > ROTATION_TOL:
        raise PanoreconInputError(
            f"{what}: rotation is not orthonormal (max |R^T R - I| = {err:.3g}); expected a rotation matrix within "
            f"{ROTATION_TOL}"
        )
    det = float(np.linalg.det(r))
    if abs(det - 1) > ROTATION_TOL:
        raise PanoreconInputError(
            f"{what}: rotation has determinant {det:.4f} (a mirror); expected a proper rotation, determinant +1"
        )
    u, _, vt = np.linalg.svd(r)
    return u @ vt  # the nearest exact rotation


def read_poses(root: Path) -> dict[str, Panorama]:
    """``<root>/poses.json`` -> {name: Panorama}, every entry checked (files present, pose a rotation, unit
    known) before any is used; one PanoreconInputError naming the file and what was expected otherwise."""
    path = Path(root) / POSES_FILE
    if not path.is_file():
        raise PanoreconInputError(f"{path}: no such file (the poses file of a posed-panoramas folder)")
    try:
        data = json.loads(path.read_text())
    except (ValueError, UnicodeDecodeError) as e:
        raise PanoreconInputError(f"{path}: not valid JSON ({e})") from None
    entries = data.get("panoramas") if isinstance(data, dict) else None
    if not isinstance(entries, list) or not entries:
        raise PanoreconInputError(f'{path}: expected {{"panoramas": [{{"image": ..., "position": ..., ...}}, ...]}}')
    unknown = sorted(set(data) - {"panoramas", "depth_unit"})
    if unknown:
        raise PanoreconInputError(f"{path}: unknown key {unknown[0]!r}; expected panoramas and optionally depth_unit")
    default_unit = data.get("depth_unit")
    out: dict[str, Panorama] = {}
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict) or "image" not in entry:
            raise PanoreconInputError(f"{path}: panoramas[{i}] is not an object with an image")
        name = str(entry.get("name", Path(str(entry["image"])).stem))
        what = f"{path}: panorama {name!r}"
        unknown = sorted(set(entry) - set(_POSE_KEYS))
        if unknown:
            raise PanoreconInputError(
                f"{what}: unknown key {unknown[0]!r}; expected keys among {', '.join(_POSE_KEYS)}"
            )
        if not name or "/" in name or "\\" in name or name in out:
            raise PanoreconInputError(f"{what}: expected a unique name without '/' (names a panorama in a scene name)")
        rgb = _need(Path(root) / str(entry["image"]), f"image of panorama {name!r} in {path}")
        position = _numbers(entry.get("position"), (3,), f"{what}: position (metres)")
        rotation = _pose_rotation(entry, what)
        depth = None
        if "depth" in entry:
            unit = entry.get("depth_unit", default_unit)
            if unit not in DEPTH_UNITS:
                raise PanoreconInputError(
                    f"{what}: depth_unit {unit!r} is not one of {', '.join(DEPTH_UNITS)} (metres per stored value of "
                    f"{entry['depth']})"
                )
            dpath = _need(Path(root) / str(entry["depth"]), f"depth of panorama {name!r} in {path}")
            depth = DepthSpec(dpath, DEPTH_UNITS[unit], "distance", source=f"{POSES_FILE}, {unit}")
        out[name] = Panorama(f"panoramas:{name}", rgb, depth, position, rotation, f"{POSES_FILE} (panorecon's frame)")
    return out


def _own_locate(root: Path, key: str) -> Panorama:
    if not (root / POSES_FILE).is_file() and (root / key / POSES_FILE).is_file():
        names = ", ".join(sorted(read_poses(root / key)))
        raise PanoreconInputError(
            f"scene 'panoramas:{root / key}' names the folder; expected panoramas:{root / key}/NAME, NAME one of "
            f"{names}"
        )
    poses = read_poses(root)
    if key not in poses:
        raise PanoreconInputError(f"{root / POSES_FILE}: no panorama {key!r}; expected one of {', '.join(poses)}")
    return poses[key]


def _own_keys(root: Path) -> list[str]:
    return sorted(read_poses(root)) if (Path(root) / POSES_FILE).is_file() else []


DATASETS = {
    d.prefix: d
    for d in (
        Dataset(
            "stanford2d3d",
            "Stanford2D3D (2D-3D-S) area panoramas, <root>/<area>/<pano id>",
            2,
            _s2d3d_locate,
            _s2d3d_keys,
            _s2d3d_group,
        ),
        Dataset(
            "structured3d",
            "Structured3D room panoramas, <root>/<scene>/<room>",
            2,
            _s3d_locate,
            _s3d_keys,
            lambda key: key.split("/")[0],
        ),
        Dataset(
            "matterport3d",
            "Matterport3D 360° panoramas (UniFuse layout), <root>/<scene>/<pano>",
            2,
            _mp3d_locate,
            _mp3d_keys,
            lambda key: key.split("/")[0],
        ),
        Dataset(
            "panoramas",
            f"your own posed panoramas ({POSES_FILE}), <dir>/<name>",
            1,
            _own_locate,
            _own_keys,
            lambda key: POSES_FILE,
        ),
    )
}


def is_dataset_name(name: str) -> bool:
    return name.partition(":")[0] in DATASETS and ":" in name


def split_name(name: str) -> tuple[Dataset, Path, str]:
    """``<dataset>:<root>/<key>`` -> (Dataset, root, key); the key is the last ``key_parts`` path parts."""
    prefix, _, rest = name.partition(":")
    ds = DATASETS[prefix]
    parts = Path(rest).parts
    if len(parts) <= ds.key_parts:
        raise PanoreconInputError(f"scene {name!r}: expected {ds.description}")
    return ds, Path(*parts[: -ds.key_parts]), "/".join(parts[-ds.key_parts :])


def locate(name: str) -> Panorama:
    ds, root, key = split_name(name)
    if not root.is_dir():
        raise PanoreconInputError(f"scene {name!r}: dataset root {root} is not a folder")
    return ds.locate(root, key)


def load_dataset_scene(name: str, width: int | None = None):
    """A dataset panorama as a real scene with true depth. ``meta``: dataset, key, position (metres or None),
    rotation ([3, 3] list or None, see the module doc), orientation (its source), and ``others``: the scene names
    of the other panoramas of its space (only when this one has a full pose; ``heldout_panoramas`` keeps those
    that have one too), else ``heldout_note``: why none."""
    ds, root, key = split_name(name)
    pano = locate(name)
    others, note = [], None
    if pano.position is None or pano.rotation is None:
        note = f"n/a: {pano.name} has no full pose (orientation {pano.orientation})"
    elif pano.depth is None:
        note = f"n/a: {pano.name} has no true depth (held-out pixels are those it sees too)"
    else:
        group = ds.group(key)
        others = [f"{ds.prefix}:{root / k}" for k in ds.keys(root) if k != key and ds.group(k) == group]
        if not others:
            note = f"n/a: no other panorama in {pano.name}'s space ({ds.prefix} group {group})"
    meta = {
        "dataset": ds.prefix,
        "key": key,
        "position": None if pano.position is None else pano.position.tolist(),
        "rotation": None if pano.rotation is None else pano.rotation.tolist(),
        "orientation": pano.orientation,
        "others": others,
    }
    if note:
        meta["heldout_note"] = note
    return scene_from_image(
        pano.rgb,
        width,
        name=pano.name,
        depth=pano.depth,
        meta=meta,
        description=f"{ds.description.split(',')[0]}: {key}, "
        + (f"true depth ({pano.depth.source})" if pano.depth else "no depth"),
    )


def list_root(root: Path) -> list[tuple[str, str]]:
    """Every panorama under ``root`` that some adapter recognises -> [(scene name, dataset description)]."""
    root = Path(root)
    if not root.is_dir():
        raise PanoreconInputError(f"--root {root}: not a folder")
    return [(f"{ds.prefix}:{root / k}", ds.description) for ds in DATASETS.values() for k in ds.keys(root)]


def heldout_panoramas(scene) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The other fully posed panoramas of a dataset scene's space at the scene's size, in the scene's own frame
    (panorecon's sphere frame at its centre): [(offset [3] metres of that panorama's centre, rotation [3, 3]
    float64 taking a direction in the scene's frame to that panorama's frame, rgb [H, W, 3] uint8, ray distance
    [H, W] float32 metres, NaN unknown)]; [] for other scenes."""
    if scene.meta.get("rotation") is None or not scene.meta.get("others"):
        return []
    here = np.asarray(scene.meta["position"], np.float64)
    rot = np.asarray(scene.meta["rotation"], np.float64)
    out = []
    for name in scene.meta["others"]:
        other = load_dataset_scene(name, scene.width)
        if other.meta["rotation"] is None or other.distance is None:
            continue
        r_other = np.asarray(other.meta["rotation"], np.float64)
        offset = rot.T @ (np.asarray(other.meta["position"]) - here)
        out.append((offset, r_other.T @ rot, other.rgb, other.distance))
    return out
