"""Where tensors live: ``--device auto|cpu|cuda`` resolved once, and what a run records about its device.

Shared by every layer that holds torch tensors (fusion's CG solve, the trainer, the CLI), like ``io/``.
"""

from __future__ import annotations

import platform
import re

import torch

from . import checks as C
from .io import PanoreconInputError

DEVICES = ("auto", "cpu", "cuda")


class DeviceName:
    """The check of a ``--device`` setting (``checks.opt(check=...)``): ``auto``, ``cpu``, ``cuda`` or
    ``cuda:K``, checked where the command line is read; whether this machine has that device is
    ``resolve_device``'s question, asked once when the command starts."""

    __name__ = "device"

    def __call__(self, text: str) -> str:
        self.check(text)
        return text

    def check(self, value) -> None:
        if not re.fullmatch(r"auto|cpu|cuda(:\d+)?", str(value)):
            raise C.CheckError(f"{value!r} is not a device; expected one of {', '.join(DEVICES)} (or cuda:K)")


DEVICE_NAME = DeviceName()

# The float unary ops that ATen hands, chunk by chunk on its intra-op threads, to MKL's vector math library (VML)
# where torch is built with MKL (aten/src/ATen/cpu/vml.h).
VML_OPS = (
    "abs", "acos", "asin", "atan", "cos", "erf", "erfc", "exp", "expm1", "log", "log10", "log1p", "log2", "sin",
    "sqrt", "tan", "tanh", "trunc",
)  # fmt: skip


def warm_up_vml() -> None:
    """Call each of ``VML_OPS`` once on one element, in float32 and float64, on this thread. oneMKL picks each
    VML function's kernel on its first call, and where that first call runs on several intra-op threads at once,
    one thread can run a low-accuracy kernel for its whole chunk of that one call (pytorch/pytorch#188792): in
    the trainer, 5 of 30 fresh processes rendered the first step from a ``torch.exp`` of the log scales with
    relative errors up to 1.5e-4 on the second thread's half, so that identical runs, and a run resumed from its
    checkpoint, trained along different paths. A one-element call is serial, so each kernel is picked here,
    before any concurrent use. Run once, when this module is imported."""
    for dtype in (torch.float32, torch.float64):
        x = torch.full((1,), 0.5, dtype=dtype)
        for op in VML_OPS:
            getattr(torch, op)(x)


warm_up_vml()


def resolve_device(name: str | torch.device = "auto") -> torch.device:
    """'auto' -> CUDA when a CUDA device is present, else the CPU; 'cpu'; 'cuda' or 'cuda:K' (refused with a
    ``PanoreconInputError`` where torch sees no such device)."""
    if isinstance(name, torch.device):
        name = str(name)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cpu":
        return torch.device("cpu")
    if name == "cuda" or name.startswith("cuda:"):
        if not torch.cuda.is_available():
            why = "torch was built without CUDA" if torch.version.cuda is None else "no CUDA device is visible"
            raise PanoreconInputError(f"--device {name}: {why} (torch {torch.__version__}); use --device cpu or auto")
        dev = torch.device(name)
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise PanoreconInputError(f"--device {name}: only {torch.cuda.device_count()} CUDA device(s) here")
        return dev
    raise PanoreconInputError(f"--device {name!r}: expected one of {', '.join(DEVICES)} (or cuda:K)")


def synchronize(device: torch.device) -> None:
    """Wait for the device's queued work (so that wall-clock timings include it); a no-op on the CPU."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def reset_peak_memory(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)


def device_record(device: torch.device) -> dict:
    """{'device': 'cpu' | 'cuda:K', 'device_name': the GPU's or CPU's name, 'peak_gpu_memory_mb': peak
    allocated by torch on that GPU since the last ``reset_peak_memory`` (MiB), or 'n/a: ...' on the CPU}."""
    if device.type == "cuda":
        index = device.index if device.index is not None else torch.cuda.current_device()
        return {
            "device": f"cuda:{index}",
            "device_name": torch.cuda.get_device_name(index),
            "peak_gpu_memory_mb": torch.cuda.max_memory_allocated(index) / 2**20,
        }
    return {
        "device": "cpu",
        "device_name": platform.processor() or platform.machine(),
        "peak_gpu_memory_mb": "n/a: CPU run",
    }
