"""Content-hash cache of pipeline stages.

A stage's key is the SHA-256 of its name, its parameters, the keys of the stages it consumes and a digest of
the source code it runs (the .py files of the subpackages it names), so a changed setting or changed code
recomputes and nothing else does. A stage's folder is ``ROOT/<stage>/<key>/``; ``done.json`` (the stage's
result record) is written last and atomically, so a folder without it is an interrupted stage: it is resumed
(the trainer picks up its checkpoint) or recomputed, never read.
"""
from __future__ import annotations

import hashlib
import json
from functools import lru_cache
from pathlib import Path

from ..io import write_json

PACKAGE_ROOT = Path(__file__).resolve().parent.parent


@lru_cache(maxsize=None)
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
    blob = json.dumps({"stage": stage, "params": params, "upstream": list(upstream), "code": code_digest(code)},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


class StageCache:
    """Folders of finished and interrupted stages under ``root``."""

    def __init__(self, root):
        self.root = Path(root)

    def folder(self, stage: str, key: str) -> Path:
        return self.root / stage / key

    def done(self, stage: str, key: str) -> dict | None:
        """The stored result record of a finished stage, or None."""
        f = self.folder(stage, key) / "done.json"
        return json.loads(f.read_text()) if f.is_file() else None

    def finish(self, stage: str, key: str, record: dict) -> dict:
        write_json(self.folder(stage, key) / "done.json", record)
        return record
