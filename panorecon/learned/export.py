"""The learned teacher as ONNX: the eval-mode network traced for one RGB image, read by the ``onnx:`` teacher
through onnxruntime like any user's export (input ``image`` float32 [1, 3, S, S], output ``disparity`` float32
[1, 1, S, S])."""

from __future__ import annotations

import warnings
from pathlib import Path

import torch

from ..io import atomic_write
from .model import DepthNet

OPSET = 17


def export_onnx(model: DepthNet, size: int, path: str | Path) -> None:
    """Write ``model`` (put in eval mode) as ONNX to ``path`` atomically, traced on a [1, 3, size, size] input."""
    model.eval()
    with atomic_write(path) as tmp, warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the TorchScript exporter: no onnxscript needed
        torch.onnx.export(
            model,
            (torch.zeros(1, 3, size, size),),
            str(tmp),
            input_names=["image"],
            output_names=["disparity"],
            opset_version=OPSET,
            dynamo=False,
        )
