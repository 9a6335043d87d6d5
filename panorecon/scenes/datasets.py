"""Panoramic-depth datasets as scene names: ``<dataset>:<root>/<...>`` -> a real ``Scene`` with true depth.

Each adapter knows its dataset's on-disk layout and depth encoding from the dataset's own documentation
(cited beside it). No dataset file ships with panorecon; see the README for where each comes from and its licence.

- ``stanford2d3d:<root>/<area>/<pano id>``: ``<area>/pano/{rgb,depth,pose}/<pano id>_frame_equirectangular_domain_``
  ``{rgb.png,depth.png,pose.json}``; depth 16-bit PNG, 1/512 m, ray distance, 65535 missing; pose
  ``camera_location`` (m).
- ``structured3d:<root>/<scene>/<room>``: ``<scene>/2D_rendering/<room>/panorama/{full/rgb_rawlight.png,
  full/depth.png, camera_xyz.txt}``; depth 16-bit PNG, mm, ray distance; pose ``camera_xyz.txt`` (mm).
- ``matterport3d:<root>/<scene>/<pano>``: ``<scene>/pano_color/<pano>.jpg``, ``<scene>/pano_depth/<pano>.png``;
  depth 16-bit PNG, 1/4000 m, ray distance; no pose.

Positions are metres in the dataset's world frame. The panoramas of one space are taken to share the world's
orientation (only their centres differ): Structured3D renders its panoramas so; for Stanford2D3D it is an
assumption this adapter does not check (the pose JSON's ``camera_rt_matrix`` is not read).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..io import PanoreconInputError
from .real import DepthSpec, scene_from_image


@dataclass(frozen=True)
class Panorama:
    """One dataset panorama: ``name`` (``<dataset>:<key>``, without the root), its image, its depth file,
    and its centre [3] float64 metres in the dataset's world frame (None where the layout has no pose)."""

    name: str
    rgb: Path
    depth: DepthSpec
    position: np.ndarray | None


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


# ---------------------------------------------------------------- Stanford2D3D (2D-3D-S)
# github.com/alexsax/2D-3D-Semantics README: "Depth images are stored as 16-bit PNGs and have a maximum depth
# of 128m and a sensitivity of 1/512m. Missing values are encoded with the value 2^16 - 1 ... [depth] is defined
# as the distance from the point-center of the camera in the panoramics." Pose JSON: "camera_location": XYZ
# location of the camera; pano files: area_N/pano/<modality>/camera_<uuid>_<room>_<i>_frame_equirectangular_domain_*.
_S2D3D_SUFFIX = "_frame_equirectangular_domain_"


def _s2d3d_file(root: Path, key: str, modality: str, ext: str) -> Path:
    area, pano = key.split("/")
    return root / area / "pano" / modality / f"{pano}{_S2D3D_SUFFIX}{modality}.{ext}"


def _s2d3d_locate(root: Path, key: str) -> Panorama:
    rgb = _need(_s2d3d_file(root, key, "rgb", "png"), "Stanford2D3D panorama image")
    depth = _need(_s2d3d_file(root, key, "depth", "png"), "Stanford2D3D panorama depth")
    pose_path = _need(_s2d3d_file(root, key, "pose", "json"), "Stanford2D3D panorama pose")
    try:
        position = np.asarray(json.loads(pose_path.read_text())["camera_location"], np.float64)
    except (ValueError, KeyError, TypeError) as e:
        raise PanoreconInputError(f"{pose_path}: not a 2D-3D-S pose file with a camera_location ({e})") from None
    if position.shape != (3,) or not np.isfinite(position).all():
        raise PanoreconInputError(f"{pose_path}: camera_location {position.tolist()} is not three finite numbers")
    return Panorama(
        f"stanford2d3d:{key}", rgb, DepthSpec(depth, 1 / 512, "distance", source="2D-3D-S, 1/512 m"), position
    )


def _s2d3d_keys(root: Path) -> list[str]:
    tail = f"{_S2D3D_SUFFIX}rgb.png"
    return sorted(f"{p.parents[2].name}/{p.name[: -len(tail)]}" for p in root.glob(f"*/pano/rgb/*{tail}"))


# ---------------------------------------------------------------- Structured3D
# github.com/bertjiazheng/Structured3D data_organization.md: <scene>/2D_rendering/<room>/panorama/
# {empty,simple,full}/{rgb_rawlight.png, depth.png}, panorama/camera_xyz.txt "camera global location"; depth and
# locations in millimetres (the dataset's unit), the panorama depth being the distance from the camera centre.
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
    return Panorama(f"structured3d:{key}", rgb, DepthSpec(depth, 1e-3, "distance", source="Structured3D, mm"), position)


def _s3d_keys(root: Path) -> list[str]:
    return sorted(
        f"{p.parents[4].name}/{p.parents[2].name}" for p in root.glob("*/2D_rendering/*/panorama/full/rgb_rawlight.png")
    )


# ---------------------------------------------------------------- Matterport3D (360° panoramas)
# The 360° Matterport3D that the panoramic-depth papers use (BiFuse, UniFuse: github.com/alibaba/
# UniFuse-Unidirectional-Fusion, Matterport3D/stitch.m): the skybox views stitched per scan into
# <scene>/pano_color/<pano>.jpg and <scene>/pano_depth/<pano>.png = uint16(ray distance * 4000); no pose file.
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


DATASETS = {
    d.prefix: d
    for d in (
        Dataset(
            "stanford2d3d",
            "Stanford2D3D (2D-3D-S) area panoramas, <root>/<area>/<pano id>",
            2,
            _s2d3d_locate,
            _s2d3d_keys,
            lambda key: key.split("/")[0],
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
    and ``others``: the scene names of the other panoramas of its space that have a pose."""
    ds, root, key = split_name(name)
    pano = locate(name)
    others = []
    if pano.position is not None:
        group = ds.group(key)
        others = [f"{ds.prefix}:{root / k}" for k in ds.keys(root) if k != key and ds.group(k) == group]
    meta = {
        "dataset": ds.prefix,
        "key": key,
        "position": None if pano.position is None else pano.position.tolist(),
        "others": others,
    }
    return scene_from_image(
        pano.rgb,
        width,
        name=pano.name,
        depth=pano.depth,
        meta=meta,
        description=f"{ds.description.split(',')[0]}: {key}, true depth ({pano.depth.source})",
    )


def list_root(root: Path) -> list[tuple[str, str]]:
    """Every panorama under ``root`` that some adapter recognises -> [(scene name, dataset description)]."""
    root = Path(root)
    if not root.is_dir():
        raise PanoreconInputError(f"--root {root}: not a folder")
    return [(f"{ds.prefix}:{root / k}", ds.description) for ds in DATASETS.values() for k in ds.keys(root)]


def heldout_panoramas(scene) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """The other posed panoramas of a dataset scene's space at the scene's size: [(offset [3] metres from the
    scene's centre, rgb [H, W, 3] uint8, ray distance [H, W] float32 metres, NaN unknown)]; [] for other scenes."""
    if scene.meta.get("position") is None or not scene.meta.get("others"):
        return []
    here = np.asarray(scene.meta["position"], np.float64)
    out = []
    for name in scene.meta["others"]:
        other = load_dataset_scene(name, scene.width)
        out.append((np.asarray(other.meta["position"]) - here, other.rgb, other.distance))
    return out
