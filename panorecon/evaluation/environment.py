"""What every benchmark prints beside its numbers: machine, versions, commit."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import platform
import subprocess
import sys
from pathlib import Path

from ..io import atomic_write, peak_rss_mb


def environment() -> dict:
    import numpy
    import scipy
    import torch

    from .. import __version__

    try:  # optional where nothing builds a synthetic scene (a GPU machine training rendered folders)
        import open3d

        open3d_version = open3d.__version__
    except ImportError:
        open3d_version = "n/a: not installed"

    return {
        "machine": {"platform": platform.platform(), "processor": platform.machine(), "cpus": os.cpu_count()},
        "versions": {
            "python": sys.version.split()[0],
            "numpy": numpy.__version__,
            "scipy": scipy.__version__,
            "torch": torch.__version__,
            "open3d": open3d_version,
            "panorecon": __version__,
        },
        "commit": git_commit(),
    }


def git_commit() -> str:
    """HEAD of the checkout panorecon runs from, with "+dirty" when tracked files differ from it; "unknown"
    outside a git checkout."""
    try:
        commit = subprocess.run(
            ["git", "rev-parse", "HEAD"], capture_output=True, text=True, check=True, cwd=Path(__file__).parent
        ).stdout.strip()
        dirty = bool(
            subprocess.run(
                ["git", "status", "--porcelain", "--untracked-files=no"],
                capture_output=True,
                text=True,
                cwd=Path(__file__).parent,
            ).stdout.strip()
        )
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return commit + ("+dirty" if dirty else "")


def _child(fn, args, queue):
    try:
        out = fn(*args)
        out["peak_rss_mb"] = peak_rss_mb()
    except BaseException as e:  # the parent re-raises it: without this it would wait forever for a result
        import pickle
        import traceback

        text = traceback.format_exc()
        try:
            pickle.dumps(e)
        except Exception:
            e = RuntimeError(f"{type(e).__name__}: {e}")
        queue.put(("error", e, text))
        return
    queue.put(("ok", out, None))


def in_fresh_process(fn, *args) -> dict:
    """Run fn(*args) -> dict in a new process (spawned, so its peak RSS is its own) and add 'peak_rss_mb'.
    An exception in the child is raised here (its traceback chained as the cause's message); a child that dies
    without answering (killed, out of memory) raises RuntimeError instead of leaving the parent waiting."""
    import queue as queue_mod

    ctx = mp.get_context("spawn")
    q = ctx.Queue()
    p = ctx.Process(target=_child, args=(fn, args, q))
    p.start()
    while True:
        try:
            status, value, text = q.get(timeout=1.0)
            break
        except queue_mod.Empty:
            if not p.is_alive():
                try:  # it may have answered just before exiting
                    status, value, text = q.get(timeout=1.0)
                    break
                except queue_mod.Empty:
                    p.join()
                    raise RuntimeError(
                        f"{getattr(fn, '__name__', fn)} died in its fresh process (exit code {p.exitcode})"
                    ) from None
    p.join()
    if status == "error":
        raise value from RuntimeError(f"in the fresh process:\n{text}")
    return value


def emit(result: dict, out_path: str | None) -> dict:
    """Print the benchmark's JSON and, when asked, write it to ``out_path``."""
    text = json.dumps(result, indent=2)
    print(text)
    if out_path:
        with atomic_write(Path(out_path)) as tmp:
            Path(tmp).write_text(text + "\n")
    return result
