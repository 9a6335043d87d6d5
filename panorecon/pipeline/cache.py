"""Content-hash cache of pipeline stages.

A stage's key is the SHA-256 of its name, its parameters, the keys of the stages it consumes and a digest of
the source code it runs (the .py files of the subpackages it names), so a changed setting or changed code
recomputes and nothing else does. A stage's folder is ``ROOT/<stage>/<key>/``; ``done.json`` (the stage's
result record) is written last and atomically, so a folder without it is an interrupted stage: it is resumed
(the trainer picks up its checkpoint) or recomputed, never read.

Everything read back is checked: ``done.json`` must parse and name its stage and key, and it records the
SHA-256 of each output file of the stage (``files``); a record that does not parse, or whose files are
missing or changed, is a corrupt entry: it is logged as a warning naming it, removed, and the stage is
recomputed. ``lock`` serialises the computation of one stage between processes (two ``ablate`` runs on one
cache compute each stage once; the second reads the first's result).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
from functools import cache
from pathlib import Path

from ..io import file_sha256, write_json

log = logging.getLogger("panorecon.cache")

PACKAGE_ROOT = Path(__file__).resolve().parent.parent


@cache
def code_digest(subpackages: tuple[str, ...]) -> str:
    """SHA-256 (16 hex) over the .py and .cpp files of the named panorecon subpackages."""
    h = hashlib.sha256()
    for sub in sorted(subpackages):
        for p in sorted((PACKAGE_ROOT / sub).rglob("*")):
            if p.suffix in (".py", ".cpp"):
                h.update(str(p.relative_to(PACKAGE_ROOT)).encode())
                h.update(p.read_bytes())
    return h.hexdigest()[:16]


def stage_key(stage: str, params: dict, upstream: tuple[str, ...] = (), code: tuple[str, ...] = ()) -> str:
    blob = json.dumps(
        {"stage": stage, "params": params, "upstream": list(upstream), "code": code_digest(code)},
        sort_keys=True,
        default=str,
    )
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


class StageCache:
    """Folders of finished and interrupted stages under ``root``."""

    def __init__(self, root):
        self.root = Path(root)

    def folder(self, stage: str, key: str) -> Path:
        return self.root / stage / key

    def done(self, stage: str, key: str) -> dict | None:
        """The stored result record of a finished stage, or None (not finished, or corrupt: then the entry is
        removed with a warning so that the stage is recomputed)."""
        f = self.folder(stage, key) / "done.json"
        if not f.is_file():
            return None
        problem = self._check(stage, key, f)
        if problem is None:
            return json.loads(f.read_text())
        log.warning("cache entry %s is corrupt (%s): recomputing it", f.parent, problem)
        f.unlink(missing_ok=True)
        return None

    def _check(self, stage: str, key: str, f: Path) -> str | None:
        """What is wrong with a finished stage's record and files, or None."""
        try:
            record = json.loads(f.read_text())
        except (ValueError, UnicodeDecodeError) as e:
            return f"done.json does not parse: {e}"
        if not isinstance(record, dict) or record.get("stage") != stage or record.get("key") != key:
            return "done.json is not this stage's record"
        files = record.get("files")
        if not isinstance(files, dict):
            return "done.json records no content hashes"
        for name, digest in files.items():
            p = f.parent / name
            if not p.is_file():
                return f"{name} is missing"
            if file_sha256(p) != digest:
                return f"{name} does not match its recorded SHA-256"
        return None

    def finish(self, stage: str, key: str, record: dict, files: tuple[str, ...] = ()) -> dict:
        """Write the record of a finished stage with the SHA-256 of its output ``files`` (names in its folder)."""
        folder = self.folder(stage, key)
        record = {**record, "files": {name: file_sha256(folder / name) for name in files}}
        write_json(folder / "done.json", record)
        return record

    @contextlib.contextmanager
    def lock(self, stage: str, key: str):
        """Hold an exclusive lock on one stage's folder (blocking; released when the process dies)."""
        folder = self.folder(stage, key)
        folder.mkdir(parents=True, exist_ok=True)
        with open(folder / ".lock", "a") as f:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX)
            yield
