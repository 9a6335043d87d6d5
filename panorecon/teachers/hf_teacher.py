"""``hf:<model id or local dir>[?batch=N&device=cpu|cuda]``: a depth network through transformers'
``AutoModelForDepthEstimation`` + ``AutoImageProcessor``.

Loading is local only (``local_files_only=True``: a folder, or a model id already in the Hugging Face cache);
nothing is fetched, so ``HF_HUB_OFFLINE`` or no network changes nothing. What a network outputs, and so how
fusion aligns its views, comes from :data:`OUTPUT_KINDS`, keyed by the config's ``model_type`` and
``depth_estimation_type`` (Depth Anything's relative vs metric checkpoints). Views go through the processor
in batches (on CUDA in float16 when present, else CPU float32), and back to each view's pixels through the
processor's own ``post_process_depth_estimation`` (its resize, and ZoeDepth's padding removal), so the
teacher never re-implements a model's resize, crop or padding. Depth Pro gets each view's true horizontal
FOV in place of its own FOV estimate, which sets its metric scale.
"""

from __future__ import annotations

import importlib.util
import inspect
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..geometry import PinholeCamera, ViewDepth, erp_to_perspective
from ..io import PanoreconInputError, specs
from .base import ErpDepth, batches_by_size, sky_of_view, view_fov_deg


@dataclass(frozen=True)
class OutputKind:
    """What a network's post-processed output is, and the alignment fusion gives its views.

    kind: ``ViewDepth.kind`` ("disparity" or "z"); affine: known up to scale and shift (fusion aligns
    scale and shift in inverse depth); metric: metres, no alignment; neither: known up to scale."""

    kind: str
    affine: bool
    metric: bool
    takes_fov: bool = False

    @property
    def description(self) -> str:
        what = {"disparity": "disparity", "z": "z-depth"}[self.kind]
        if self.affine:
            return f"affine-invariant {what}"
        return f"metric {what} (m)" if self.metric else f"relative {what}"

    @property
    def alignment(self) -> str:
        return "scale and shift in inverse depth" if self.affine else "none" if self.metric else "scale"


# (config.model_type, config.depth_estimation_type or None) -> output
OUTPUT_KINDS: dict[tuple[str, str | None], OutputKind] = {
    ("depth_anything", "relative"): OutputKind("disparity", affine=True, metric=False),  # V1, V2 relative
    ("depth_anything", "metric"): OutputKind("z", affine=False, metric=True),  # V2 metric (indoor / outdoor)
    ("dpt", None): OutputKind("disparity", affine=True, metric=False),  # DPT-Large / -Hybrid (MiDaS 3.0)
    ("zoedepth", None): OutputKind("z", affine=False, metric=True),  # ZoeDepth NYU / KITTI / NYU+KITTI
    ("depth_pro", None): OutputKind("z", affine=False, metric=True, takes_fov=True),  # Depth Pro, focal from FOV
    ("glpn", None): OutputKind("z", affine=False, metric=True),  # GLPN NYU / KITTI
}


# transformers (5.23) post-processes these with torchvision (its PIL fallback for ZoeDepth still calls it)
ARG = "<model id or folder>"  # the spec's argument (teachers/spec.py)
OPTIONS = {"batch": specs.positive_int, "device": specs.device}
_NEEDS_TORCHVISION = ("zoedepth", "depth_pro")


def output_kind(config) -> OutputKind:
    """The :data:`OUTPUT_KINDS` entry of a transformers config (PanoreconInputError when not in the table)."""
    key = (config.model_type, getattr(config, "depth_estimation_type", None))
    if key not in OUTPUT_KINDS:
        known = ", ".join(m if t is None else f"{m} ({t})" for m, t in OUTPUT_KINDS)
        raise PanoreconInputError(
            f"model_type {key[0]!r}"
            + (f" with depth_estimation_type {key[1]!r}" if key[1] else "")
            + f" is not in panorecon's table of depth outputs; known: {known}"
        )
    return OUTPUT_KINDS[key]


def _not_found(source: str) -> PanoreconInputError:
    return PanoreconInputError(
        f"teacher hf:{source}: no such local folder and not in the Hugging Face cache (loading is local only); on a "
        f"machine with network run `hf download {source} --local-dir DIR`, copy DIR here and use hf:DIR"
    )


class HFTeacher:
    """A transformers depth network as a panorecon teacher (see the module docstring)."""

    def __init__(self, spec, progress: bool = True):
        """``spec``: a ``teachers.spec.TeacherSpec`` of kind ``hf``."""
        source, opts = spec.arg, spec.options
        self.batch = opts.get("batch", 8)
        try:
            import torch
            from transformers import AutoConfig, AutoImageProcessor, AutoModelForDepthEstimation
        except ImportError:
            raise PanoreconInputError("the hf teacher needs transformers: pip install 'panorecon[hf]'") from None
        self.name, self.source, self.progress = str(spec), source, progress
        device = opts.get("device", "cuda" if torch.cuda.is_available() else "cpu")
        if device not in ("cpu", "cuda") or (device == "cuda" and not torch.cuda.is_available()):
            raise PanoreconInputError(f"teacher {spec}: device={device!r}: expected cpu, or cuda where CUDA exists")
        self.device, self.dtype = torch.device(device), torch.float16 if device == "cuda" else torch.float32
        try:
            config = AutoConfig.from_pretrained(source, local_files_only=True)
        except (OSError, ValueError):
            raise _not_found(source) from None
        try:
            self.output = output_kind(config)
        except PanoreconInputError as e:
            raise PanoreconInputError(f"teacher hf:{source}: {e}") from None
        if config.model_type in _NEEDS_TORCHVISION and importlib.util.find_spec("torchvision") is None:
            raise PanoreconInputError(
                f"teacher hf:{source}: transformers' {config.model_type} image processor needs "
                f"torchvision: pip install torchvision (the release built for torch "
                f"{torch.__version__.split('+')[0]})"
            )
        try:
            self.processor = AutoImageProcessor.from_pretrained(source, local_files_only=True)
            model = AutoModelForDepthEstimation.from_pretrained(source, local_files_only=True)
        except ImportError as e:
            first = (str(e).strip() or type(e).__name__).splitlines()[0]
            raise PanoreconInputError(f"teacher hf:{source}: {first}") from None
        except (OSError, ValueError) as e:
            first = str(e).strip().splitlines()[0] if str(e).strip() else type(e).__name__
            raise PanoreconInputError(f"teacher hf:{source}: cannot load it ({first})") from None
        self.model = model.to(self.device, self.dtype).eval()
        self._post_args = set(inspect.signature(self.processor.post_process_depth_estimation).parameters)

    def run(self, images: Sequence[np.ndarray], fovs_deg: Sequence[float] | None = None) -> list[np.ndarray]:
        """RGB uint8 images [h, w, 3] -> the post-processed output of each at its own [h, w], float32.
        ``fovs_deg``: each image's horizontal FOV (degrees), given to networks that take it in place of their
        own estimate (without it they keep their estimate)."""
        import torch
        from tqdm import tqdm

        batches = batches_by_size(images, self.batch)
        results: list[np.ndarray | None] = [None] * len(images)
        for idx in tqdm(batches, desc=self.name, unit="batch", disable=not self.progress or len(batches) < 2):
            sizes = [tuple(images[i].shape[:2]) for i in idx]
            inputs = self.processor(images=[images[i] for i in idx], return_tensors="pt")
            with torch.inference_mode():
                out = self.model(pixel_values=inputs["pixel_values"].to(self.device, self.dtype))
            out.predicted_depth = out.predicted_depth.float().cpu()
            if self.output.takes_fov and fovs_deg is not None:
                out.field_of_view = torch.tensor([float(fovs_deg[i]) for i in idx], dtype=torch.float32)
            kwargs = {"target_sizes": sizes}
            if "source_sizes" in self._post_args:
                kwargs["source_sizes"] = sizes
            for i, post in zip(idx, self.processor.post_process_depth_estimation(out, **kwargs)):
                d = post["predicted_depth"].float().reshape(sizes[0]).numpy()
                results[i] = np.ascontiguousarray(d, dtype=np.float32)
        return results

    def _valid(self, out: np.ndarray) -> np.ndarray:
        ok = np.isfinite(out)
        return ok if self.output.affine else ok & (out > 0)

    def predict_views(self, scene, cameras: Sequence[PinholeCamera]) -> list[ViewDepth]:
        outs = self.run([erp_to_perspective(scene.rgb, c) for c in cameras], [view_fov_deg(c) for c in cameras])
        o = self.output
        return [
            ViewDepth(c, d, o.kind, self._valid(d) & ~sky_of_view(scene, c), affine=o.affine, metric=o.metric)
            for c, d in zip(cameras, outs)
        ]

    def predict_erp(self, scene) -> ErpDepth:
        """The network on the whole ERP image, its z-depth read as ray distance (as single-image baselines do).
        An ERP image has no pinhole focal length: a network that takes one keeps its own FOV estimate and its
        output is treated as relative, not metric."""
        d = self.run([scene.rgb])[0]
        o = self.output
        return ErpDepth(
            d,
            "disparity" if o.kind == "disparity" else "distance",
            self._valid(d) & ~scene.sky,
            affine=o.affine,
            metric=o.metric and not o.takes_fov,
        )
