"""Real panoramas from ``shared/data/real`` (and any ERP image by path) as ``Scene``s, with a depth file
attached either as a model's prediction (the built-in HoHoNet scene) or as true depth (``--depth``)."""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..geometry import erp_z_to_distance_factor
from ..io import PanoreconInputError, read_image
from ..io.depth import DEPTH_KINDS, check_scene_scale, default_depth_scale, read_depth_raw, unit_warning
from ..io.files import check_erp_shape
from .base import Scene
from .registry import SceneSpec, register_scene

log = logging.getLogger("panorecon.depth")


@dataclass(frozen=True)
class DepthSpec:
    """A depth file for a panorama: ``path``; ``scale`` metres per stored unit (None: the format's default,
    see ``panorecon.io.depth``); ``kind`` "distance" (along the ray) or "z" (cube-face z-depth);
    ``truth``: true depth (a sensor, a scanner, a dataset) rather than a model's prediction."""

    path: Path
    scale: float | None = None
    kind: str = "distance"
    truth: bool = True
    source: str = ""


def real_data_dir() -> Path:
    """``$PANORECON_REAL_DATA``, else ``shared/data/real`` beside the checkout."""
    env = os.environ.get("PANORECON_REAL_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "shared" / "data" / "real"


def _resize(img: np.ndarray, width: int | None, interpolation=cv2.INTER_AREA) -> np.ndarray:
    if width is None or width == img.shape[1]:
        return img
    return cv2.resize(img, (width, width // 2), interpolation=interpolation)


def scene_from_image(
    path: Path,
    width: int | None = None,
    *,
    name: str | None = None,
    description: str = "",
    depth: DepthSpec | None = None,
    meta: dict | None = None,
) -> Scene:
    """A real scene from an ERP image file and, optionally, its depth file (same pixel size as the image;
    resized to ``width`` with nearest neighbour). The depth is "truth" or "predicted" as ``depth.truth`` says."""
    full = read_image(path, erp=True)
    scene = Scene(
        name=name or Path(path).stem,
        kind="real",
        description=description or f"equirectangular image {path}",
        rgb=_resize(full, width),
        distance=None,
        sky=np.zeros((1, 1), bool),
        distance_kind="none",
        meta={"image": str(path), "image_hw": list(full.shape[:2]), **(meta or {})},
    )
    scene.sky = np.zeros(scene.rgb.shape[:2], bool)
    return with_depth(scene, depth) if depth is not None else scene


def read_erp_depth(path: str | os.PathLike, scale: float | None = None, kind: str = "distance") -> np.ndarray:
    """A panorama's true depth file -> ray distance [H, W] float32 metres, NaN where invalid (the file's stored
    values from ``io.depth.read_depth_raw`` times ``scale`` metres per unit; ``kind`` "z": cube-face z-depth,
    brought to ray distance).

    Raises PanoreconInputError for a file that is not a 2:1 ERP, a bad scale or kind, a map with no
    valid pixel, or one whose median distance is outside ``io.depth.SCENE_MEDIAN_RANGE_M``."""
    path = Path(path)
    if kind not in DEPTH_KINDS:
        raise PanoreconInputError(f"--depth-kind {kind!r}: expected one of {', '.join(DEPTH_KINDS)}")
    scale = default_depth_scale(path) if scale is None else float(scale)
    if not (np.isfinite(scale) and scale > 0):
        raise PanoreconInputError(f"--depth-scale {scale}: expected a positive number of metres per stored unit")
    raw = read_depth_raw(path)
    check_erp_shape(raw.shape, str(path))
    d = raw * scale
    if kind == "z":
        d = d * erp_z_to_distance_factor(*d.shape)
    if not np.isfinite(d).any():
        raise PanoreconInputError(f"{path}: the depth map has no valid pixel (all 0, 65535, NaN, negative or >= 1e9)")
    check_scene_scale(d, str(path))
    warning = unit_warning(d, scale, str(path))
    if warning:
        log.warning("WARNING: %s", warning)
    return d.astype(np.float32)


def with_depth(scene: Scene, depth: DepthSpec) -> Scene:
    """``scene`` with ``depth`` as its distance (resized like its image). A depth file of another pixel size than
    the image file (``meta["image_hw"]``), or one without a valid pixel, is refused."""
    if scene.kind == "synthetic":
        raise PanoreconInputError(
            f"--depth {depth.path}: scene {scene.name!r} is synthetic and already has its "
            "true depth; --depth is for real panoramas"
        )
    d = read_erp_depth(depth.path, depth.scale, depth.kind)
    hw = tuple(scene.meta.get("image_hw", scene.rgb.shape[:2]))
    if d.shape != hw:
        raise PanoreconInputError(
            f"{depth.path}: depth is {d.shape[1]}x{d.shape[0]} but the panorama "
            f"{scene.meta.get('image', scene.name)} is {hw[1]}x{hw[0]}; expected the same size"
        )
    scene.distance = _resize(d, scene.width, cv2.INTER_NEAREST)
    scene.distance_kind = "truth" if depth.truth else "predicted"
    scene.meta.update(
        depth=str(depth.path),
        depth_kind=depth.kind,
        depth_scale=depth.scale,
        depth_from=depth.source or ("true depth" if depth.truth else "predicted"),
    )
    return scene


def _hohonet(width):
    d = real_data_dir()
    return scene_from_image(
        d / "hohonet_pano.png",
        width,
        name="hohonet",
        description="real indoor panorama (HoHoNet demo), with HoHoNet's predicted depth (not ground truth)",
        depth=DepthSpec(
            d / "hohonet_pano.pred_depth_mm.png",
            1e-3,
            truth=False,
            source="HoHoNet prediction, millimetres, distance along the ray",
        ),
    )


def _py360(width):
    return scene_from_image(
        real_data_dir() / "py360convert_demo_equirec.png",
        width,
        name="py360-demo",
        description="real indoor panorama (py360convert demo), no depth",
    )


register_scene(
    SceneSpec(
        "hohonet",
        "real",
        False,
        "real indoor panorama with HoHoNet's predicted depth (a model output, not truth)",
        _hohonet,
    )
)
register_scene(
    SceneSpec("py360-demo", "real", False, "real indoor panorama from py360convert's demo, no depth", _py360)
)
