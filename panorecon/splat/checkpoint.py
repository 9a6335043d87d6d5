"""The trainer's checkpoint (``OUT/ckpt.pt``): written atomically, read back with ``weights_only=True`` (a file
found in an output folder can hold no code), and resumed only when it was written for the same inputs.

Inputs: scene name and ERP width, the TrainConfig digest, the SHA-256 of the initial cloud's positions and
colours, and what the caller adds (source, teacher, ...). A checkpoint for other inputs is refused with
``PanoreconInputError``; an unreadable or malformed one (cut, foreign format) is set aside with a warning and
training starts from step 0 (it never changes a result: a checkpoint is only a shortcut).
"""

from __future__ import annotations

import hashlib
import logging
import pickle
import zipfile
from pathlib import Path

import numpy as np
import torch

from ..io import PanoreconInputError, atomic_write
from ..io.files import first_sentence
from .model import PARAM_NAMES

log = logging.getLogger("panorecon.train")


def cloud_digest(point_cloud) -> str:
    """SHA-256 (16 hex) of a PointCloud's float32 positions and colours."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(point_cloud.xyz, np.float32).tobytes())
    h.update(np.ascontiguousarray(point_cloud.rgb, np.float32).tobytes())
    return h.hexdigest()[:16]


def checkpoint_inputs(scene, point_cloud, config_digest: str, extra: dict | None = None) -> dict:
    """The keys a checkpoint must match to be resumed (all JSON scalars)."""
    return {
        "scene": scene.name,
        "width": int(scene.width),
        "config": config_digest,
        "cloud": cloud_digest(point_cloud),
        **{
            k: (None if v is None else v if isinstance(v, (int, float, bool)) else str(v))
            for k, v in (extra or {}).items()
        },
    }


def save_checkpoint(path: Path, inputs: dict, state: dict) -> None:
    """torch.save ``{**state, "inputs": inputs}`` atomically (tensors, numbers, strings, lists and dicts only)."""
    with atomic_write(path) as tmp:
        torch.save({**state, "inputs": inputs}, tmp)


def load_checkpoint(path: Path, inputs: dict, iters: int) -> dict | None:
    """The checkpoint's state if ``path`` exists, is readable, and was written for ``inputs``; None if absent or
    unreadable (then it is renamed to ``ckpt.pt.bad`` with a warning); PanoreconInputError if foreign."""
    path = Path(path)
    if not path.exists():
        return None
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
        problem = _malformed(state, iters)
    except (RuntimeError, EOFError, OSError, ValueError, pickle.UnpicklingError, zipfile.BadZipFile) as e:
        problem = f"unreadable: {first_sentence(e)}"
    if problem is not None:
        bad = path.with_name(path.name + ".bad")
        path.replace(bad)
        log.warning("checkpoint %s is %s; moved to %s, training starts from step 0", path, problem, bad.name)
        return None
    theirs = state["inputs"]
    diff = sorted(k for k in set(inputs) | set(theirs) if inputs.get(k) != theirs.get(k))
    if diff:
        shown = ", ".join(f"{k}: {theirs.get(k)!r} (this run: {inputs.get(k)!r})" for k in diff)
        raise PanoreconInputError(f"{path} was written for a different run ({shown}); remove it or use another --out")
    return state


def _malformed(state, iters: int) -> str | None:
    """What makes a loaded checkpoint unusable, or None."""
    if not isinstance(state, dict) or not isinstance(state.get("inputs"), dict):
        return "not a panorecon checkpoint (no recorded inputs)"
    it = state.get("iteration")
    if not isinstance(it, int) or not 0 < it < iters:
        return f"malformed (iteration {it!r} outside 1..{iters - 1})"
    model = state.get("model")
    if not isinstance(model, dict) or any(not isinstance(model.get(k), torch.Tensor) for k in PARAM_NAMES):
        return "malformed (model parameters missing)"
    n = {len(model[k]) for k in PARAM_NAMES}
    if len(n) != 1 or not all(torch.isfinite(model[k]).all() for k in PARAM_NAMES):
        return "malformed (parameters of different lengths, or NaN/Inf)"
    for k in ("optimizer", "strategy", "history", "rng"):
        if k not in state:
            return f"malformed ({k} missing)"
    return None
