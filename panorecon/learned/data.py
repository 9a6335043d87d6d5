"""Training crops for the learned teacher: perspective views of synthetic scene variants, rendered once and
cached.

Each crop is what the ``onnx:`` teacher is given at run time: the view resampled from the scene's ERP RGB
(``erp_to_perspective``, bilinear, at the tables' ERP width) -- with the target, the view's true z-depth, cast
from the scene's world for the same camera. The cameras carry the field's framing augmentation: a direction
uniform on the sphere, a field of view drawn from a range around the fusion views' (Fibonacci, 20 views: 89.4
degrees) and the labels' (60 degrees), a roll, and an off-centre principal point (a crop cut at another
position of a larger view).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ..geometry import PinholeCamera, erp_to_perspective, intrinsics_from_fov, look_at_rotation, viewmat_from_pose
from ..io import PanoreconInputError, atomic_write
from ..scenes.registry import load_scene

CACHE_VERSION = 1  # bump when the rendering below changes what a cached file holds


@dataclass(frozen=True)
class CropSpec:
    """What a crop set is made of: scene names (``NAME@K``), crops per scene, crop size (pixels), the scenes'
    ERP width, the field-of-view range (degrees), the roll range (+-degrees), the principal point's offset range
    (+- fraction of the size) and the seed of the cameras."""

    scenes: tuple[str, ...]
    per_scene: int
    size: int
    erp_width: int
    fov_deg: tuple[float, float]
    roll_deg: float
    shift: float
    seed: int

    def digest(self) -> str:
        text = json.dumps({**asdict(self), "version": CACHE_VERSION}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass
class Crops:
    """rgb [N, S, S, 3] uint8; depth [N, S, S] float32 true z-depth in metres (NaN: sky); scene [N] int32 index
    into ``names``; fov [N] float32 degrees; seconds: how long they took to render."""

    rgb: np.ndarray
    depth: np.ndarray
    scene: np.ndarray
    fov: np.ndarray
    names: tuple[str, ...]
    seconds: float

    def __len__(self) -> int:
        return len(self.rgb)


def random_camera(rng: np.random.Generator, size: int, fov_deg: tuple[float, float], roll_deg: float, shift: float):
    """A square ``size``-pixel view at the origin: direction uniform on the sphere, horizontal FOV uniform in
    ``fov_deg``, roll uniform in +-``roll_deg``, principal point moved by up to +-``shift`` x size on each axis."""
    z = rng.uniform(-1.0, 1.0)
    phi = rng.uniform(0.0, 2 * math.pi)
    r = math.sqrt(max(0.0, 1.0 - z * z))
    forward = np.array([r * math.cos(phi), r * math.sin(phi), z])
    roll = math.radians(rng.uniform(-roll_deg, roll_deg))
    c, s = math.cos(roll), math.sin(roll)
    R = look_at_rotation(forward) @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    fov = rng.uniform(*fov_deg)
    K = intrinsics_from_fov(size, size, fov)
    K[:2, 2] += rng.uniform(-shift, shift, 2) * size
    return PinholeCamera(K, viewmat_from_pose(R, np.zeros(3)), size, size), fov


def render_crops(spec: CropSpec, progress=None) -> Crops:
    """Render the crop set: for each scene in order, ``per_scene`` random cameras drawn from
    (seed, scene index). ``progress(i, n, name)`` is called per scene."""
    n = len(spec.scenes) * spec.per_scene
    rgb = np.zeros((n, spec.size, spec.size, 3), np.uint8)
    depth = np.zeros((n, spec.size, spec.size), np.float32)
    scene_idx = np.zeros(n, np.int32)
    fovs = np.zeros(n, np.float32)
    t0 = time.perf_counter()
    for si, name in enumerate(spec.scenes):
        if progress:
            progress(si, len(spec.scenes), name)
        scene = load_scene(name, spec.erp_width)
        rng = np.random.default_rng([spec.seed, si])
        for j in range(spec.per_scene):
            k = si * spec.per_scene + j
            cam, fovs[k] = random_camera(rng, spec.size, spec.fov_deg, spec.roll_deg, spec.shift)
            rgb[k] = erp_to_perspective(scene.rgb, cam)
            r = scene.world.render_view(cam)
            depth[k] = np.where(r.sky | ~np.isfinite(r.depth_z) | ~(r.depth_z > 0), np.nan, r.depth_z)
            scene_idx[k] = si
    return Crops(rgb, depth, scene_idx, fovs, spec.scenes, time.perf_counter() - t0)


def cache_dir() -> Path:
    """``$PANORECON_CACHE/teacher_crops`` (default ``~/.cache/panorecon/teacher_crops``)."""
    return Path(os.environ.get("PANORECON_CACHE", Path.home() / ".cache" / "panorecon")) / "teacher_crops"


def cached_crops(spec: CropSpec, progress=None) -> Crops:
    """The crop set from ``cache_dir()/<digest>.npz`` (written atomically by the first call that renders it)."""
    path = cache_dir() / f"{spec.digest()}.npz"
    if path.is_file():
        try:
            with np.load(path) as f:
                return Crops(
                    f["rgb"], f["depth"], f["scene"], f["fov"], tuple(str(s) for s in f["names"]), float(f["seconds"])
                )
        except (OSError, KeyError, ValueError) as e:
            raise PanoreconInputError(f"{path}: unreadable crop cache ({e}); delete it to render again") from None
    crops = render_crops(spec, progress)
    with atomic_write(path) as tmp, open(tmp, "wb") as f:
        np.savez(
            f,
            rgb=crops.rgb,
            depth=crops.depth,
            scene=crops.scene,
            fov=crops.fov,
            names=np.array(crops.names),
            seconds=np.float64(crops.seconds),
        )
    return crops
