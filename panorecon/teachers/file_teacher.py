"""``file:<path>[?scale=S&metric=1]``: a precomputed ERP ray-distance map used as a teacher.

A 16-bit PNG holds distance in units of ``scale`` metres (HoHoNet's ``*.pred_depth_mm.png``: scale=0.001;
0 = unknown); a ``.npy`` holds float metres (scale multiplies it). The map must be 2:1. Views sample it
with nearest-neighbour lookups along their rays.

Size rule: a map of another width than the scene's ERP (both are 2:1, so the pixels cover the same angles) is
resampled to it by nearest neighbour when it is at least half as wide (``MAX_UPSAMPLE`` = 2), with one line
saying so; a narrower map is refused, as a few depth pixels stretched over a panorama are no teacher. This is
what the field's precomputed maps need: a network predicts at its own input size (HoHoNet's
``*.pred_depth_mm.png`` is 1024x512), often below the panorama's, and nearest neighbour keeps each depth a value
the network gave (no blend of a foreground and a background depth at an edge). With ``metric=1`` a median
distance implausible for a metric scene gets the same unit warning as a true depth (``io.depth.unit_warning``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from ..geometry import PinholeCamera, ViewDepth, sample_erp
from ..io import PanoreconInputError, read_image, specs
from ..io.depth import check_depth_dtype, unit_warning
from ..io.files import check_erp_shape
from .base import ErpDepth

ARG = "<depth.png|.npy>"  # the spec's argument (teachers/spec.py)
OPTIONS = {"scale": specs.positive_float, "metric": specs.yes_no}
MAX_UPSAMPLE = 2
log = logging.getLogger("panorecon.teacher")


class FileTeacher:
    def __init__(self, spec):
        """``spec``: a ``teachers.spec.TeacherSpec`` of kind ``file``."""
        self.scale = spec.options.get("scale", 1.0)
        self.metric = spec.options.get("metric", False)
        self.path = Path(spec.arg)
        self.name = str(spec)
        self._distance = self._load()
        self._resample_said: set[tuple[int, int]] = set()

    def _load(self) -> np.ndarray:
        if self.path.suffix.lower() == ".npy":
            if not self.path.is_file():
                raise PanoreconInputError(f"{self.path}: no such file")
            try:
                raw = np.load(self.path, allow_pickle=False)
            except (ValueError, OSError) as e:
                raise PanoreconInputError(f"{self.path}: not a readable .npy depth map ({e})") from None
            check_depth_dtype(raw, str(self.path))
            raw = raw.astype(np.float64)
            if raw.ndim != 2:
                raise PanoreconInputError(f"{self.path}: expected a 2-D depth map, got shape {raw.shape}")
            check_erp_shape(raw.shape, str(self.path))
        else:
            raw = read_image(self.path, erp=True, unchanged=True)
            if raw.ndim != 2:
                raise PanoreconInputError(
                    f"{self.path}: expected a single-channel depth image, got {raw.shape[2]} channels"
                )
            raw = raw.astype(np.float64)
            raw[raw == 0] = np.nan
        with np.errstate(over="ignore", invalid="ignore"):
            d = (raw * self.scale).astype(np.float32)
        d[~((d > 0) & np.isfinite(d))] = np.nan
        if not np.isfinite(d).any():
            raise PanoreconInputError(
                f"{self.path}: holds no valid depth (every value is 0, NaN, Inf or negative); "
                "expected positive ray distances"
            )
        warning = unit_warning(d, self.scale, f"teacher file:{self.path}") if self.metric else None
        if warning:
            log.warning("WARNING: %s", warning)
        return d

    def _check_size(self, scene) -> None:
        w = self._distance.shape[1]
        if w * MAX_UPSAMPLE < scene.width:
            raise PanoreconInputError(
                f"teacher file:{self.path}: the depth map is {w}x{w // 2} but the scene is {scene.width}x"
                f"{scene.height}; a map narrower than 1/{MAX_UPSAMPLE} of the scene's width is refused (give "
                f"a map at least {-(-scene.width // MAX_UPSAMPLE)} px wide, or a smaller --width)"
            )
        size = (scene.width, scene.height)
        if w != scene.width and size not in self._resample_said:
            self._resample_said.add(size)
            log.warning(
                "note: teacher file:%s: the depth map is %dx%d and the scene %dx%d: sampled at the scene's size by "
                "nearest neighbour (a 2:1 map at least 1/%d of the scene's width is; a narrower one is refused)",
                self.path,
                w,
                w // 2,
                *size,
                MAX_UPSAMPLE,
            )

    def _for(self, scene) -> np.ndarray:
        self._check_size(scene)
        d = self._distance
        if d.shape != (scene.height, scene.width):
            d = cv2.resize(d, (scene.width, scene.height), interpolation=cv2.INTER_NEAREST)
        return d

    def predict_views(self, scene, cameras: Sequence[PinholeCamera]) -> list[ViewDepth]:
        self._check_size(scene)
        views = []
        for cam in cameras:
            d = sample_erp(self._distance, cam.world_rays(), "nearest")
            views.append(ViewDepth(cam, d, "distance", np.isfinite(d) & (d > 0), metric=self.metric))
        return views

    def predict_erp(self, scene) -> ErpDepth:
        d = self._for(scene)
        return ErpDepth(d, "distance", np.isfinite(d), metric=self.metric)
