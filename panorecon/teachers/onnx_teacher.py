"""``onnx:<model.onnx>``: any ONNX monocular depth model through onnxruntime.

A JSON config beside the model (``<model>.json``) declares how to call it::

    {"input_size": [H, W], "mean": [0.485, 0.456, 0.406], "std": [0.229, 0.224, 0.225],
     "channels": "RGB", "output": "disparity" | "z" | "distance", "mode": "affine" | "relative" | "metric"}

Input: float32 NCHW in [0, 1] then (x - mean) / std; output [1, H, W] or [1, 1, H, W], resized back to
the view (bilinear). On the whole ERP (``erp-direct``) a z-depth output is read as ray distance: a
perspective model run on an equirectangular image, as single-image baselines do.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from ..geometry import PinholeCamera, ViewDepth, erp_to_perspective
from ..io import PanoreconInputError
from .base import ErpDepth, sky_of_view

ARG = "<model.onnx>"  # the spec's argument (teachers/spec.py); its settings are in <model>.json beside it
OPTIONS: dict = {}
_OUTPUTS = ("disparity", "z", "distance")
_MODES = ("affine", "relative", "metric")


class OnnxTeacher:
    def __init__(self, path: str, config: dict | None = None):
        self.path = Path(path)
        self.name = f"onnx:{path}"
        if not self.path.is_file():
            raise PanoreconInputError(f"{self.path}: no such ONNX model file")
        if config is None:
            cfg_path = self.path.with_suffix(".json")
            if not cfg_path.is_file():
                raise PanoreconInputError(
                    f"{self.path}: expected its config {cfg_path} (input_size, mean, std, output, mode)"
                )
            try:
                config = json.loads(cfg_path.read_text())
            except json.JSONDecodeError as e:
                raise PanoreconInputError(f"{cfg_path}: not valid JSON ({e})") from None
        self.config = self._check(config)
        try:
            import onnxruntime as ort
        except ImportError:
            raise PanoreconInputError("the onnx teacher needs onnxruntime: pip install 'panorecon[onnx]'") from None
        self.session = ort.InferenceSession(str(self.path), providers=["CPUExecutionProvider"])
        self.input_name = self.session.get_inputs()[0].name

    def _check(self, c: dict) -> dict:
        where = f"config of {self.path}"
        if "input_size" not in c or len(c["input_size"]) != 2:
            raise PanoreconInputError(f"{where}: 'input_size' must be [height, width]")
        if c.get("output") not in _OUTPUTS:
            raise PanoreconInputError(f"{where}: 'output' must be one of {_OUTPUTS}, got {c.get('output')!r}")
        if c.get("mode") not in _MODES:
            raise PanoreconInputError(f"{where}: 'mode' must be one of {_MODES}, got {c.get('mode')!r}")
        c = dict(c)
        c.setdefault("mean", [0.0, 0.0, 0.0])
        c.setdefault("std", [1.0, 1.0, 1.0])
        c.setdefault("channels", "RGB")
        if c["channels"] not in ("RGB", "BGR"):
            raise PanoreconInputError(f"{where}: 'channels' must be 'RGB' or 'BGR'")
        return c

    def run(self, rgb: np.ndarray) -> np.ndarray:
        """RGB uint8 [h, w, 3] -> raw model output resized to [h, w] float32."""
        h, w = rgb.shape[:2]
        H, W = self.config["input_size"]
        x = (
            cv2.resize(rgb, (W, H), interpolation=cv2.INTER_AREA if H < h else cv2.INTER_LINEAR).astype(np.float32)
            / 255.0
        )
        if self.config["channels"] == "BGR":
            x = x[..., ::-1]
        x = (x - np.asarray(self.config["mean"], np.float32)) / np.asarray(self.config["std"], np.float32)
        out = self.session.run(None, {self.input_name: np.ascontiguousarray(x.transpose(2, 0, 1)[None])})[0]
        out = np.asarray(out, np.float32).reshape(out.shape[-2], out.shape[-1])
        return cv2.resize(out, (w, h), interpolation=cv2.INTER_LINEAR)

    def _valid(self, out: np.ndarray) -> np.ndarray:
        ok = np.isfinite(out)
        return ok if self.config["mode"] == "affine" else ok & (out > 0)

    def predict_views(self, scene, cameras: Sequence[PinholeCamera]) -> list[ViewDepth]:
        mode = self.config["mode"]
        views = []
        for cam in cameras:
            out = self.run(erp_to_perspective(scene.rgb, cam))
            views.append(
                ViewDepth(
                    cam,
                    out,
                    self.config["output"],
                    self._valid(out) & ~sky_of_view(scene, cam),
                    affine=mode == "affine",
                    metric=mode == "metric",
                )
            )
        return views

    def predict_erp(self, scene) -> ErpDepth:
        out = self.run(scene.rgb)
        kind = "disparity" if self.config["output"] == "disparity" else "distance"
        mode = self.config["mode"]
        return ErpDepth(out, kind, self._valid(out) & ~scene.sky, affine=mode == "affine", metric=mode == "metric")
