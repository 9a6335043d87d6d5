"""Ctrl-C (SIGINT) and SIGTERM during `train` and `points`: one line, exit 130/143, nothing half-written, and
the rerun of `train` resumes from the checkpoint written at the interrupted step (subprocesses: a real signal)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

CLI = [sys.executable, "-c", "from panorecon.cli import main; import sys; sys.exit(main())"]


def _start(argv, cwd):
    return subprocess.Popen(
        [*CLI, *argv], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=dict(os.environ)
    )


def _signal_when(proc, ready, sig, timeout=240.0):
    t0 = time.monotonic()
    while not ready() and proc.poll() is None:
        if time.monotonic() - t0 > timeout:
            proc.kill()
            pytest.fail("the command never reached the point to interrupt")
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()
    proc.send_signal(sig)
    out, err = proc.communicate(timeout=120)
    return proc.returncode, out, [ln for ln in err.splitlines() if ln.strip()]


def _cpu_seconds(pid: int) -> float:
    """User + system CPU seconds of a process (Linux /proc), 0 when unreadable."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


TRAIN = [
    "train",
    "bedroom",
    "--source",
    "random",
    "--width",
    "32",
    "--iters",
    "100000",
    "--res",
    "16",
    "--labels",
    "2",
    "--checkpoint-every",
    "2",
    "--no-progress",
    "--out",
    "run",
]


def test_sigint_then_sigterm_during_train_checkpoint_and_resume(tmp_path):
    ckpt = tmp_path / "run" / "ckpt.pt"
    rc, _, err = _signal_when(_start(TRAIN, tmp_path), ckpt.exists, signal.SIGINT)
    assert rc == 130, err
    assert not any("Traceback" in ln for ln in err), err
    line = err[-1]
    m = re.fullmatch(r"panorecon: interrupted by SIGINT at step (\d+) of 100000; checkpoint at (\S+); rerun .*", line)
    assert m, line
    step = int(m[1])
    assert step >= 2 and Path(tmp_path / m[2]).resolve() == ckpt.resolve()
    # nothing half-written: no temp file, the checkpoint loads, no final outputs
    assert not [p.name for p in (tmp_path / "run").iterdir() if p.name.startswith(".ckpt")]
    assert not (tmp_path / "run" / "metrics.json").exists()
    mtime = ckpt.stat().st_mtime_ns
    # the rerun resumes from that step (logged), and SIGTERM ends it the same way with 143
    proc = _start(TRAIN, tmp_path)
    rc, _, err = _signal_when(proc, lambda: ckpt.stat().st_mtime_ns != mtime, signal.SIGTERM)
    assert rc == 143, err
    assert any(f"resuming {Path('run') / 'ckpt.pt'} at step {step} of 100000" in ln for ln in err), err
    m = re.fullmatch(r"panorecon: interrupted by SIGTERM at step (\d+) of 100000; checkpoint at .*", err[-1])
    assert m and int(m[1]) > step, err


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_during_points_writes_nothing(tmp_path, sig):
    argv = ["points", "bedroom", "--width", "2048", "--source", "fibonacci", "--teacher", "sim:relative"]
    argv += ["--out", "c.ply", "--report", "c.json"]
    proc = _start(argv, tmp_path)
    rc, _, err = _signal_when(proc, lambda: _cpu_seconds(proc.pid) > 5.0, sig)  # past the imports
    assert rc == 128 + sig, err
    assert len(err) == 1 and err[0].startswith(f"panorecon: interrupted by {sig.name}; no output was half-written"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == []
