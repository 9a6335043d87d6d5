"""``file:<path>[?scale=S&metric=1]``: a precomputed ERP ray-distance map used as a teacher.

A 16-bit PNG holds distance in units of ``scale`` metres (HoHoNet's ``*.pred_depth_mm.png``: scale=0.001;
0 = unknown); a ``.npy`` holds float metres (scale multiplies it). The map must be 2:1. Views sample it
with nearest-neighbour lookups along their rays.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from urllib.parse import parse_qs

import cv2
import numpy as np

from ..geometry import PinholeCamera, ViewDepth, sample_erp
from ..io import PanoreconInputError, read_image
from ..io.files import check_erp_shape
from .base import ErpDepth


class FileTeacher:
    def __init__(self, spec: str):
        path, _, query = spec.partition("?")
        opts = {k: v[-1] for k, v in parse_qs(query, keep_blank_values=True).items()}
        unknown = set(opts) - {"scale", "metric"}
        if unknown:
            raise PanoreconInputError(
                f"teacher file:{spec}: unknown option(s) {sorted(unknown)}; expected scale=, metric="
            )
        try:
            self.scale = float(opts.get("scale", 1.0))
        except ValueError:
            raise PanoreconInputError(f"teacher file:{spec}: scale={opts['scale']!r} is not a number") from None
        if not (np.isfinite(self.scale) and self.scale > 0):
            raise PanoreconInputError(f"teacher file:{spec}: scale must be a positive number")
        self.metric = opts.get("metric", "0").lower() in ("1", "true", "yes")
        self.path = Path(path)
        self.name = f"file:{spec}"
        self._distance = self._load()

    def _load(self) -> np.ndarray:
        if self.path.suffix.lower() == ".npy":
            if not self.path.is_file():
                raise PanoreconInputError(f"{self.path}: no such file")
            try:
                raw = np.load(self.path).astype(np.float64)
            except (ValueError, OSError) as e:
                raise PanoreconInputError(f"{self.path}: not a readable .npy depth map ({e})") from None
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
        return d

    def _for(self, scene) -> np.ndarray:
        d = self._distance
        if d.shape != (scene.height, scene.width):
            d = cv2.resize(d, (scene.width, scene.height), interpolation=cv2.INTER_NEAREST)
        return d

    def predict_views(self, scene, cameras: Sequence[PinholeCamera]) -> list[ViewDepth]:
        views = []
        for cam in cameras:
            d = sample_erp(self._distance, cam.world_rays(), "nearest")
            views.append(ViewDepth(cam, d, "distance", np.isfinite(d) & (d > 0), metric=self.metric))
        return views

    def predict_erp(self, scene) -> ErpDepth:
        d = self._for(scene)
        return ErpDepth(d, "distance", np.isfinite(d), metric=self.metric)
