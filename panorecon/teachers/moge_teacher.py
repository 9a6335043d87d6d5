"""``moge:<checkpoint file, folder or model id>[?batch=N&device=cpu|cuda]``: MoGe through its own package
(``dlr-moge`` on PyPI, MIT; ``moge.model.v1`` / ``moge.model.v2``).

A checkpoint is MoGe's ``model.pt`` (``{"model_config", "model"}``): a file, a folder holding it, or a model id
already in the Hugging Face cache (``local_files_only``; nothing is fetched). MoGe-2 configs have a ``neck``;
with a ``scale_head`` their depth is metric. MoGe-1 gives an affine-invariant point map whose z-shift MoGe
solves from the view's true FOV (passed to ``infer``), so its depth is known up to scale. The output is
z-depth at the view's own pixels (MoGe resizes internally), ``inf`` where MoGe's mask drops a pixel (sky).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..geometry import PinholeCamera, ViewDepth, erp_to_perspective
from ..io import PanoreconInputError, specs
from ..io.files import first_sentence
from .base import ErpDepth, batches_by_size, sky_of_view, view_fov_deg
from .hf_teacher import OutputKind

MOGE1 = OutputKind("z", affine=False, metric=False, takes_fov=True)  # affine point map, shift solved with the FOV
MOGE2_METRIC = OutputKind("z", affine=False, metric=True, takes_fov=True)
ARG = "<checkpoint>"  # the spec's argument (teachers/spec.py)
OPTIONS = {"batch": specs.positive_int, "device": specs.device}
INSTALL = "pip install --no-deps dlr-moge==2.0.0 dlr-utils3d==1.3 (their own lists pull gradio and torchvision)"


def moge_output_kind(model_config: dict) -> tuple[int, OutputKind]:
    """(MoGe version, output kind) of a checkpoint's ``model_config``."""
    if "neck" in model_config:
        return 2, MOGE2_METRIC if model_config.get("scale_head") is not None else MOGE1
    return 1, MOGE1


class MoGeTeacher:
    """MoGe-1 / MoGe-2 as a panorecon teacher (see the module docstring)."""

    def __init__(self, spec, progress: bool = True):
        """``spec``: a ``teachers.spec.TeacherSpec`` of kind ``moge``."""
        source, opts = spec.arg, spec.options
        try:
            import torch
            from moge.model import v1, v2
        except ImportError:
            raise PanoreconInputError(f"the moge teacher needs MoGe's package: {INSTALL}") from None
        self.batch = opts.get("batch", 4)
        device = opts.get("device", "cuda" if torch.cuda.is_available() else "cpu")
        if device not in ("cpu", "cuda") or (device == "cuda" and not torch.cuda.is_available()):
            raise PanoreconInputError(f"teacher {spec}: device={device!r}: expected cpu, or cuda where CUDA exists")
        self.name, self.progress, self.device = str(spec), progress, torch.device(device)
        path = _checkpoint(source)
        try:
            ckpt = torch.load(path, map_location="cpu", weights_only=True)
            config, state = ckpt["model_config"], ckpt["model"]
        except Exception as e:  # noqa: BLE001 -- any unreadable file is the user's input
            raise PanoreconInputError(
                f"teacher moge:{source}: {path} is not a MoGe checkpoint ({first_sentence(e)})"
            ) from None
        self.version, self.output = moge_output_kind(config)
        model = (v2 if self.version == 2 else v1).MoGeModel(**config)
        missing = model.load_state_dict(state, strict=False).missing_keys
        if missing:
            raise PanoreconInputError(f"teacher moge:{source}: {path} lacks {len(missing)} weights, e.g. {missing[0]}")
        self.model = model.to(self.device).eval()

    def run(self, images: Sequence[np.ndarray], fovs_deg: Sequence[float] | None = None) -> list[np.ndarray]:
        """RGB uint8 images [h, w, 3] -> MoGe's z-depth [h, w] float32 of each (``inf`` where masked); with
        ``fovs_deg`` (horizontal, degrees) MoGe uses the given FOV instead of estimating it."""
        import torch
        from tqdm import tqdm

        batches = batches_by_size(images, self.batch)
        results: list[np.ndarray | None] = [None] * len(images)
        for idx in tqdm(batches, desc=self.name, unit="batch", disable=not self.progress or len(batches) < 2):
            x = torch.from_numpy(np.stack([images[i] for i in idx])).permute(0, 3, 1, 2).float().div(255)
            fov = None if fovs_deg is None else torch.tensor([float(fovs_deg[i]) for i in idx])
            out = self.model.infer(x.to(self.device), fov_x=fov, use_fp16=self.device.type == "cuda")
            for i, d in zip(idx, out["depth"].float().cpu().numpy()):
                results[i] = np.ascontiguousarray(d, dtype=np.float32)
        return results

    def predict_views(self, scene, cameras: Sequence[PinholeCamera]) -> list[ViewDepth]:
        outs = self.run([erp_to_perspective(scene.rgb, c) for c in cameras], [view_fov_deg(c) for c in cameras])
        o = self.output
        return [
            ViewDepth(
                c,
                np.where(np.isfinite(d), d, np.nan),
                o.kind,
                np.isfinite(d) & (d > 0) & ~sky_of_view(scene, c),
                affine=o.affine,
                metric=o.metric,
            )
            for c, d in zip(cameras, outs)
        ]

    def predict_erp(self, scene) -> ErpDepth:
        """MoGe on the whole ERP image with its own FOV estimate (an ERP image has none), its z-depth read as ray
        distance; MoGe-2's metric scale rests on that estimate."""
        d = self.run([scene.rgb])[0]
        return ErpDepth(
            np.where(np.isfinite(d), d, np.nan),
            "distance",
            np.isfinite(d) & (d > 0) & ~scene.sky,
            metric=self.output.metric,
        )


def _checkpoint(source: str) -> Path:
    p = Path(source)
    if p.is_file():
        return p
    if p.is_dir():
        if (p / "model.pt").is_file():
            return p / "model.pt"
        raise PanoreconInputError(f"teacher moge:{source}: the folder has no model.pt (MoGe's checkpoint file)")
    try:
        from huggingface_hub import hf_hub_download

        return Path(hf_hub_download(repo_id=source, filename="model.pt", local_files_only=True))
    except Exception:  # noqa: BLE001 -- not in the cache, or not a valid repo id
        raise PanoreconInputError(
            f"teacher moge:{source}: no such file or folder and not in the Hugging Face cache (loading is local "
            f"only); on a machine with network run `hf download {source} model.pt --local-dir DIR`, copy DIR here "
            "and use moge:DIR"
        ) from None
