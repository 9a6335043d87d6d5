"""Perspective depth maps that say what they hold: ray distance, z-depth or disparity."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .camera import PinholeCamera

DEPTH_KINDS = ("distance", "z", "disparity")


@dataclass
class ViewDepth:
    """One perspective view's depth as a teacher gives it.

    camera: the view (OpenCV axes). depth: [h, w] float32 holding ``kind`` -- "distance" (metres along
    the ray), "z" (metres along the optical axis) or "disparity" (proportional to 1 / z).
    affine: the values are known only up to an unknown per-view scale and shift (affine-invariant
    models); otherwise up to scale (relative) or exact (``metric``). valid: [h, w] bool, pixels the
    teacher vouches for (never sky). rgb: [h, w, 3] uint8 of the view, when known.
    """

    camera: PinholeCamera
    depth: np.ndarray
    kind: str
    valid: np.ndarray
    affine: bool = False
    metric: bool = False
    rgb: np.ndarray | None = None

    def __post_init__(self):
        if self.kind not in DEPTH_KINDS:
            raise ValueError(f"ViewDepth.kind={self.kind!r}; expected one of {DEPTH_KINDS}")
        shape = (self.camera.height, self.camera.width)
        if self.depth.shape != shape or self.valid.shape != shape:
            raise ValueError(
                f"ViewDepth: depth {self.depth.shape} / valid {self.valid.shape} do not match the camera's {shape}"
            )
        self.depth = np.asarray(self.depth, dtype=np.float32)
        self.valid = np.asarray(self.valid, dtype=bool) & np.isfinite(self.depth)

    def to_distance(self) -> np.ndarray:
        """Ray distance [h, w] float32 (NaN where invalid or non-positive). For ``affine`` views this is
        the distance implied by the raw values, before any scale/shift alignment."""
        with np.errstate(divide="ignore", invalid="ignore"):
            if self.kind == "distance":
                d = self.depth.copy()
            elif self.kind == "z":
                d = self.depth * self.camera.z_to_distance_factor().astype(np.float32)
            else:
                d = self.camera.z_to_distance_factor().astype(np.float32) / self.depth
        d[~self.valid | ~(d > 0) | ~np.isfinite(d)] = np.nan
        return d
