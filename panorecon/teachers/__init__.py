"""Monocular depth teachers behind one interface: ``sim:<profile>``, ``onnx:<path>``, ``file:<path>``,
``hf:<model id or folder>`` (transformers), ``moge:<checkpoint>`` (MoGe's package)."""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

from ..io import PanoreconInputError
from .base import ErpDepth, Teacher
from .hf_teacher import OUTPUT_KINDS
from .sim import PROFILES, SimProfile, SimTeacher
from .spec import TEACHER_SPEC, TeacherSpec


def get_teacher(spec: str | TeacherSpec, seed: int = 0) -> Teacher:
    """The teacher a spec names (``TeacherSpec``, or its text, parsed here): ``sim:<profile>``,
    ``onnx:<model.onnx>``, ``file:<path>[?scale=S&metric=1]``, ``hf:<model id or folder>[?batch=N&device=D]`` or
    ``moge:<checkpoint>[?batch=N&device=D]``. ``seed`` seeds a simulated teacher's errors."""
    spec = TeacherSpec(spec)
    if spec.kind == "sim":
        if spec.arg not in PROFILES:
            raise PanoreconInputError(
                f"teacher {str(spec)!r}: unknown simulated profile; expected one of "
                + ", ".join(f"sim:{p}" for p in PROFILES)
            )
        return SimTeacher(PROFILES[spec.arg], seed)
    if spec.kind == "onnx":
        from .onnx_teacher import OnnxTeacher

        return OnnxTeacher(spec.arg)
    if spec.kind == "file":
        from .file_teacher import FileTeacher

        return FileTeacher(spec)
    if spec.kind == "hf":
        from .hf_teacher import HFTeacher

        return HFTeacher(spec)
    from .moge_teacher import MoGeTeacher

    return MoGeTeacher(spec)


def seeded_teacher(spec: str | None) -> bool:
    """Whether ``get_teacher(spec, seed)`` depends on ``seed`` (the simulated teachers' errors do; a model does
    not)."""
    return bool(spec) and spec.partition(":")[0] == "sim"


def teacher_fingerprint(spec: str | None) -> str | None:
    """``spec``, and for teachers that load files (onnx:, file:, hf:, moge:) ``spec#<digest>`` of the files'
    relative names and contents (SHA-256): a stage cache keyed by it recomputes when the model on disk changes,
    and a run's identity is the same on a fresh clone or another machine (modification times are not). A model
    id is looked up in the Hugging Face cache (its snapshot folder names the commit); a spec whose files are not
    found is returned as is (loading it fails with the reason)."""
    if not spec:
        return spec
    kind, _, arg = spec.partition(":")
    if kind not in ("onnx", "file", "hf", "moge"):
        return spec
    path = Path(arg.partition("?")[0])
    if kind == "onnx":
        root, files = path.parent, [path, path.with_suffix(".json")]
    elif path.is_file():
        root, files = path.parent, [path]
    else:
        root = path
        if not path.is_dir() and kind in ("hf", "moge"):
            try:
                from huggingface_hub import snapshot_download

                root = Path(snapshot_download(str(path), local_files_only=True))
            except Exception:  # noqa: BLE001 -- not in the cache, or not a repo id
                return spec
        files = sorted(f for f in root.rglob("*") if f.is_file())
    h = hashlib.sha256()
    for f in (f for f in files if f.is_file()):
        h.update(f"{f.relative_to(root)}:{_content_digest(f)}\n".encode())
    return f"{spec}#{h.hexdigest()[:12]}" if any(f.is_file() for f in files) else spec


_DIGESTS: dict[tuple[str, int, int], str] = {}  # (path, size, mtime_ns) -> SHA-256 of the contents, per process


def _content_digest(path: Path) -> str:
    """SHA-256 of a file's bytes, read once per process while its size and modification time stay the same."""
    st = path.stat()
    key = (str(path.resolve()), st.st_size, st.st_mtime_ns)
    if key not in _DIGESTS:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        _DIGESTS[key] = h.hexdigest()
    return _DIGESTS[key]


WEIGHTS = Path(__file__).parent / "weights"  # the learned teachers shipped with panorecon (`teachers train`)


def shipped_models() -> list[Path]:
    """The ONNX models in ``WEIGHTS`` (each with its ``.json`` config and ``.train.json`` record)."""
    return sorted(WEIGHTS.glob("*.onnx"))


def _shipped_row(path: Path) -> tuple[str, str]:
    """``onnx:<path>`` (relative to the working folder when under it) and what the model is, from its record."""
    rel = os.path.relpath(path)
    spec = f"onnx:{path if rel.startswith('..') else rel}"
    try:
        r = json.loads(path.with_suffix(".train.json").read_text())
        f = r["final"]
        desc = (
            f"learned (panorecon teachers train): U-Net width {r['config']['width']}, {r['parameters']:,} parameters, "
            f"{r['config']['steps']} steps; affine disparity; val AbsRel {f['seen_abs_rel']:.3f} seen / "
            f"{f['unseen_abs_rel']:.3f} unseen families"
        )
    except (OSError, ValueError, KeyError, TypeError) as e:
        desc = f"learned, shipped ONNX model (its record {path.with_suffix('.train.json').name} unreadable: {e})"
    return spec, desc


def list_teachers() -> list[tuple[str, str]]:
    """(spec, description) of every teacher kind, and the shipped learned models as ``onnx:`` specs."""
    rows = [(f"sim:{p.name}", f"simulated ({p.description})") for p in PROFILES.values()]
    rows += [_shipped_row(p) for p in shipped_models()]
    rows += [
        ("onnx:<model.onnx>", "an ONNX monocular depth model with a <model>.json config (needs onnxruntime)"),
        ("file:<depth>[?scale=S&metric=1]", "a precomputed ERP ray-distance map (16-bit PNG x scale, or .npy metres)"),
    ]
    rows += [("hf:<model id or folder>", "a transformers depth model, local only (needs transformers); by model_type:")]
    rows += [
        (
            f"  {m}" + (f" ({t})" if t else ""),
            f"{o.description}; fusion aligns: {o.alignment}" + ("; gets the view's FOV" if o.takes_fov else ""),
        )
        for (m, t), o in OUTPUT_KINDS.items()
    ]
    rows += [
        ("moge:<model.pt, folder or id>", "MoGe through its package dlr-moge, local only, each view's FOV given:"),
        ("  MoGe-1", "relative z-depth (affine point map, shift solved from the FOV); fusion aligns: scale"),
        ("  MoGe-2", "metric z-depth (m); fusion aligns: none"),
    ]
    return rows


__all__ = [
    "ErpDepth",
    "Teacher",
    "SimProfile",
    "SimTeacher",
    "PROFILES",
    "TEACHER_SPEC",
    "TeacherSpec",
    "get_teacher",
    "list_teachers",
    "seeded_teacher",
    "shipped_models",
    "teacher_fingerprint",
]
