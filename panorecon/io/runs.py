"""An output folder that belongs to one run: ``claim_run`` before a command writes its first byte there.

The folder keeps ``.panorecon-<command>.json``: the command's inputs (what decides its results). A rerun with
the same inputs resumes or redoes; a rerun with other inputs into a folder holding that command's outputs is
refused, naming what is there (with no such output left, e.g. after a run that failed early, it is simply
taken over), unless ``overwrite``, which deletes those outputs first (only the files the
command writes, matched by its declared patterns: nothing else in the folder is touched). Temp files left by a
killed run (``atomic_write``'s ``.<name>.<8 random>.<suffix>``) are deleted.
"""

from __future__ import annotations

import fnmatch
import json
import os
import re
from pathlib import Path

from .files import PanoreconInputError, write_json

# atomic_write's temp names: "." + the output's name + "." + mkstemp's 8 random characters + the suffix
_TEMP = re.compile(r"^\.(?P<name>.+)\.[a-z0-9_]{8}(\.[^.]+)?$")


def manifest_path(folder: str | os.PathLike, command: str) -> Path:
    return Path(folder) / f".panorecon-{command}.json"


def _outputs(folder: Path, patterns: tuple[str, ...]) -> list[Path]:
    if not folder.is_dir():
        return []
    return sorted(
        f
        for f in folder.rglob("*")
        if f.is_file() and any(fnmatch.fnmatchcase(str(f.relative_to(folder)), p) for p in patterns)
    )


def stale_temps(folder: Path, patterns: tuple[str, ...]) -> list[Path]:
    """Temp files of ``atomic_write`` for outputs matching ``patterns`` (left by a killed run)."""
    if not folder.is_dir():
        return []
    found = []
    for f in folder.rglob(".*"):
        m = _TEMP.match(f.name)
        rel = f.relative_to(folder).parent / (m["name"] if m else "")
        if m and f.is_file() and any(fnmatch.fnmatchcase(str(rel), p) for p in patterns):
            found.append(f)
    return found


def claim_run(
    folder: str | os.PathLike, command: str, inputs: dict, patterns: tuple[str, ...], overwrite: bool = False
) -> None:
    """Make ``folder`` this run's (see the module doc); PanoreconInputError when it holds another run's outputs
    and ``overwrite`` is False. ``inputs``: JSON scalars that identify the run; ``patterns``: the command's
    outputs, relative fnmatch patterns."""
    folder = Path(folder)
    record = manifest_path(folder, command)
    theirs = None
    if record.is_file():
        try:
            theirs = json.loads(record.read_text()).get("inputs")
        except (OSError, ValueError, AttributeError):
            theirs = {"unreadable": str(record)}
    existing = _outputs(folder, patterns)
    if theirs != inputs and existing:
        if not overwrite:
            if theirs is None:
                what = "a run that recorded no inputs"
            else:
                diff = sorted(k for k in set(inputs) | set(theirs) if inputs.get(k) != theirs.get(k))
                what = "another run (" + ", ".join(f"{k}: {theirs.get(k)!r}, now {inputs.get(k)!r}" for k in diff) + ")"
            names = ", ".join(str(f.relative_to(folder)) for f in existing[:4]) + (", ..." if len(existing) > 4 else "")
            raise PanoreconInputError(
                f"{folder} holds the {command} outputs of {what}: {names or record.name}; use another --out, or "
                "--overwrite to delete them first"
            )
        for f in existing:
            f.unlink()
    for f in stale_temps(folder, patterns):
        f.unlink(missing_ok=True)
    if theirs != inputs:
        write_json(record, {"command": command, "inputs": inputs})
