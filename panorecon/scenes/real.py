"""Real panoramas from ``shared/data/real`` (and any ERP image by path) as ``Scene``s."""
from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

from ..io import PanoreconInputError, read_image
from .base import Scene
from .registry import SceneSpec, register_scene


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


def scene_from_image(path: Path, width: int | None = None, *, name: str | None = None,
                     description: str = "", depth_path: Path | None = None, depth_scale: float = 1.0,
                     depth_from: str = "") -> Scene:
    """A real scene from an ERP image file; ``depth_path`` (optional) is a 16-bit PNG of ray distance
    in units of ``depth_scale`` metres (0 = unknown), resized with nearest neighbour."""
    rgb = _resize(read_image(path, erp=True), width)
    distance = None
    kind = "none"
    if depth_path is not None:
        raw = read_image(depth_path, erp=True, unchanged=True)
        if raw.ndim != 2:
            raise PanoreconInputError(f"{depth_path}: expected a single-channel depth image, got {raw.shape[2]} channels")
        d = raw.astype(np.float32) * np.float32(depth_scale)
        d[raw == 0] = np.nan
        distance = _resize(d, rgb.shape[1], cv2.INTER_NEAREST)
        kind = "predicted"
    return Scene(
        name=name or path.stem,
        kind="real",
        description=description or f"equirectangular image {path}",
        rgb=rgb,
        distance=distance,
        sky=np.zeros(rgb.shape[:2], bool),
        distance_kind=kind,
        meta={"image": str(path), **({"depth": str(depth_path), "depth_from": depth_from} if depth_path else {})},
    )


def _hohonet(width):
    d = real_data_dir()
    return scene_from_image(
        d / "hohonet_pano.png", width, name="hohonet",
        description="real indoor panorama (HoHoNet demo), with HoHoNet's predicted depth (not ground truth)",
        depth_path=d / "hohonet_pano.pred_depth_mm.png", depth_scale=1e-3,
        depth_from="HoHoNet prediction, millimetres, distance along the ray",
    )


def _py360(width):
    return scene_from_image(real_data_dir() / "py360convert_demo_equirec.png", width, name="py360-demo",
                            description="real indoor panorama (py360convert demo), no depth")


register_scene(SceneSpec("hohonet", "real", False,
                         "real indoor panorama with HoHoNet's predicted depth (a model output, not truth)", _hohonet))
register_scene(SceneSpec("py360-demo", "real", False, "real indoor panorama from py360convert's demo, no depth", _py360))
