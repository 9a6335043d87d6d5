"""Monocular depth teachers behind one interface: ``sim:<profile>``, ``onnx:<path>``, ``file:<path>``,
``hf:<model id or folder>`` (transformers), ``moge:<checkpoint>`` (MoGe's package)."""
from __future__ import annotations

from .base import ErpDepth, Teacher
from .hf_teacher import OUTPUT_KINDS
from .sim import PROFILES, SimProfile, SimTeacher
from ..io import PanoreconInputError


def get_teacher(spec: str, seed: int = 0) -> Teacher:
    """Parse a teacher spec: ``sim:<profile>``, ``onnx:<model.onnx>``, ``file:<path>[?scale=S&metric=1]`` or
    ``hf:<model id or folder>[?batch=N&device=D]`` or ``moge:<checkpoint>[?batch=N&device=D]``."""
    kind, _, arg = spec.partition(":")
    if kind == "sim":
        if arg not in PROFILES:
            raise PanoreconInputError(f"teacher {spec!r}: unknown simulated profile; expected one of "
                                      + ", ".join(f"sim:{p}" for p in PROFILES))
        return SimTeacher(PROFILES[arg], seed)
    if kind == "onnx" and arg:
        from .onnx_teacher import OnnxTeacher

        return OnnxTeacher(arg)
    if kind == "file" and arg:
        from .file_teacher import FileTeacher

        return FileTeacher(arg)
    if kind == "hf":
        from .hf_teacher import HFTeacher

        return HFTeacher(arg)
    if kind == "moge":
        from .moge_teacher import MoGeTeacher

        return MoGeTeacher(arg)
    raise PanoreconInputError(f"teacher {spec!r}: expected sim:<profile>, onnx:<model.onnx>, file:<depth.png|.npy>, "
                              "hf:<model id or folder> or moge:<checkpoint>")


def list_teachers() -> list[tuple[str, str]]:
    """(spec, description) of every teacher kind."""
    rows = [(f"sim:{p.name}", f"simulated ({p.description})") for p in PROFILES.values()]
    rows += [("onnx:<model.onnx>", "an ONNX monocular depth model with a <model>.json config (needs onnxruntime)"),
             ("file:<depth>[?scale=S&metric=1]", "a precomputed ERP ray-distance map (16-bit PNG x scale, or .npy metres)")]
    rows += [("hf:<model id or folder>", "a transformers depth model, local only (needs transformers); by model_type:")]
    rows += [(f"  {m}" + (f" ({t})" if t else ""), f"{o.description}; fusion aligns: {o.alignment}"
              + ("; gets the view's FOV" if o.takes_fov else "")) for (m, t), o in OUTPUT_KINDS.items()]
    rows += [("moge:<model.pt, folder or id>", "MoGe through its package dlr-moge, local only, each view's FOV given:"),
             ("  MoGe-1", "relative z-depth (affine point map, shift solved from the FOV); fusion aligns: scale"),
             ("  MoGe-2", "metric z-depth (m); fusion aligns: none")]
    return rows


__all__ = ["ErpDepth", "Teacher", "SimProfile", "SimTeacher", "PROFILES", "get_teacher", "list_teachers"]
