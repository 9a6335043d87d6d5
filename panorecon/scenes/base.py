"""The one ``Scene`` type: an ERP panorama, its ray distance where known, masks, and for synthetic
scenes a ``World`` that renders any view from any position (held-out truth)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ..geometry import PinholeCamera
from ..geometry.pointcloud import PointCloud, erp_point_cloud


@dataclass
class ViewRender:
    """A perspective render: rgb [h, w, 3] uint8; distance [h, w] float32 metres along the ray
    (inf for sky); depth_z [h, w] float32 metres along the optical axis (inf for sky); sky [h, w] bool."""

    rgb: np.ndarray
    distance: np.ndarray
    depth_z: np.ndarray
    sky: np.ndarray


@dataclass
class ErpRender:
    """An ERP render: rgb [H, W, 3] uint8; distance [H, W] float32 metres (inf for sky); sky [H, W] bool."""

    rgb: np.ndarray
    distance: np.ndarray
    sky: np.ndarray


class World(Protocol):
    """Anything that renders true images and depth (synthetic scenes)."""

    def render_erp(self, height: int, position: np.ndarray | None = None) -> ErpRender: ...

    def render_view(self, camera: PinholeCamera) -> ViewRender: ...

    def free_space_radius(self) -> float:
        """Radius (metres) around the panorama centre in which cameras can move without entering geometry."""
        ...

    def mesh(self):
        """The whole scene as one ``open3d.geometry.TriangleMesh`` with vertex colours."""
        ...


@dataclass
class Scene:
    """One scene as every stage sees it.

    rgb: [H, W, 3] uint8 ERP. distance: [H, W] float32 ray distance in metres, ``inf`` for sky,
    ``nan`` where unknown, or None when the scene has no depth at all. sky: [H, W] bool.
    ``distance_kind`` says what ``distance`` is: "truth" (synthetic), "predicted" (a model's output
    shipped with a real panorama) or "none". ``world`` renders true novel views (synthetic only).
    """

    name: str
    kind: str  # "synthetic" | "real"
    description: str
    rgb: np.ndarray
    distance: np.ndarray | None
    sky: np.ndarray
    distance_kind: str = "none"
    world: World | None = None
    meta: dict = field(default_factory=dict)

    @property
    def height(self) -> int:
        return self.rgb.shape[0]

    @property
    def width(self) -> int:
        return self.rgb.shape[1]

    @property
    def has_ground_truth(self) -> bool:
        return self.distance_kind == "truth"

    @property
    def valid(self) -> np.ndarray:
        """[H, W] bool: pixels with a finite, positive distance (never sky)."""
        if self.distance is None:
            return np.zeros(self.rgb.shape[:2], bool)
        return np.isfinite(self.distance) & (self.distance > 0)

    def point_cloud(self) -> PointCloud:
        """The coloured cloud of every valid pixel, from the scene's own distance."""
        if self.distance is None:
            raise ValueError(f"scene {self.name!r} has no depth, so it has no point cloud")
        pc = erp_point_cloud(self.rgb, self.distance, self.valid)
        pc.meta.update(scene=self.name, distance_kind=self.distance_kind)
        return pc
