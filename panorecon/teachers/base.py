"""The teacher interface: a monocular depth model that gives depth for perspective views and for the ERP."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from ..geometry import PinholeCamera, ViewDepth
from ..io import PanoreconInputError


@dataclass
class ErpDepth:
    """A teacher's depth for the whole ERP image: depth [H, W] float32 of ``kind`` ("distance" or
    "disparity" = 1 / distance), valid [H, W] bool; affine / metric as in ``ViewDepth``."""

    depth: np.ndarray
    kind: str
    valid: np.ndarray
    affine: bool = False
    metric: bool = False

    def to_distance(self) -> np.ndarray:
        """Ray distance [H, W] float32, NaN where invalid. An affine output's unknown shift is taken as 0:
        one image alone cannot resolve it."""
        with np.errstate(divide="ignore", invalid="ignore"):
            d = self.depth.astype(np.float64) if self.kind == "distance" else 1.0 / self.depth.astype(np.float64)
        d[~self.valid | ~np.isfinite(d) | ~(d > 0)] = np.nan
        return d.astype(np.float32)


class Teacher(Protocol):
    """``name`` is the spec it was made from (e.g. ``sim:relative``)."""

    name: str

    def predict_views(self, scene, cameras: Sequence[PinholeCamera]) -> list[ViewDepth]: ...

    def predict_erp(self, scene) -> ErpDepth: ...


def true_view_distance(scene, camera: PinholeCamera) -> tuple[np.ndarray, np.ndarray]:
    """(ray distance [h, w] float32 with inf for sky, sky [h, w] bool) of a view at the panorama centre, from
    the scene's world when it has one and can render it, else sampled (nearest) from its true ERP distance (a
    scene loaded from a ``panorecon render`` folder records only its held-out views)."""
    world = scene.world
    if world is not None and getattr(world, "can_render", lambda cam: True)(camera):
        r = world.render_view(camera)
        return r.distance, r.sky
    if scene.distance is None or scene.distance_kind != "truth":
        raise _no_truth(scene)
    from ..geometry import sample_erp

    d = sample_erp(scene.distance, camera.world_rays(), "nearest")
    sky = sample_erp(scene.sky.astype(np.uint8), camera.world_rays(), "nearest").astype(bool)
    return d.astype(np.float32), sky


def sky_of_view(scene, cam: PinholeCamera) -> np.ndarray:
    """[h, w] bool: the view's pixels whose nearest ERP pixel is sky."""
    if not scene.sky.any():
        return np.zeros((cam.height, cam.width), bool)
    from ..geometry import erp_to_perspective

    return erp_to_perspective(scene.sky.astype(np.uint8), cam, "nearest").astype(bool)


def batches_by_size(images: Sequence[np.ndarray], batch: int) -> list[list[int]]:
    """Indices of ``images`` in batches of at most ``batch``, each holding one image size."""
    order = sorted(range(len(images)), key=lambda i: images[i].shape[:2])
    batches: list[list[int]] = []
    for i in order:
        if batches and len(batches[-1]) < batch and images[i].shape[:2] == images[batches[-1][0]].shape[:2]:
            batches[-1].append(i)
        else:
            batches.append([i])
    return batches


def view_fov_deg(camera: PinholeCamera) -> float:
    """Horizontal field of view of a view, degrees."""
    return math.degrees(2 * math.atan(camera.width / (2 * camera.K[0, 0])))


def _no_truth(scene) -> PanoreconInputError:
    return PanoreconInputError(
        f"scene {scene.name!r} has no true depth (its depth is {scene.distance_kind!r}); "
        "simulated teachers need a synthetic scene or a real one with --depth"
    )


def require_truth(scene) -> None:
    """PanoreconInputError unless a simulated teacher can see the scene's truth: a world to render (synthetic)
    or a true ERP distance (a real panorama with --depth). Checked before any work (``sources.check_source``)."""
    if scene.world is None and (scene.distance is None or scene.distance_kind != "truth"):
        raise _no_truth(scene)
