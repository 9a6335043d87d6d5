"""Ctrl-C (SIGINT) and SIGTERM during `train` and `points`: one line, exit 130/143, nothing half-written, and
the rerun of `train` resumes from the checkpoint written at the interrupted step (subprocesses: a real signal).
`points` writes its outputs together: a signal while they are written leaves none (the files already there are
kept), one during the final renames leaves all of them whole, one while the interpreter exits (torch's
finalizers) is one line (in-process: a real signal sent from inside the write)."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

CLI = [sys.executable, "-c", "from panorecon.cli import main; import sys; sys.exit(main())"]
TREE = str(Path(__file__).resolve().parents[1])  # the checkout under test, first on the subprocesses' path


def _env() -> dict:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([TREE, *filter(None, [os.environ.get("PYTHONPATH")])])}


def _start(argv, cwd):
    return subprocess.Popen(
        [*CLI, *argv], cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env()
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


POINTS = ["points", "bedroom", "--width", "64", "--views", "6", "--source", "fibonacci", "--teacher", "sim:relative"]
POINTS += ["--out", "c.ply", "--report", "r.json", "--distance-out", "d.npy"]


def _points_in(folder: Path, capsys) -> tuple[int, list[str]]:
    from panorecon.cli import main

    capsys.readouterr()
    old = os.getcwd()
    os.chdir(folder)
    try:
        rc = main(POINTS)
    finally:
        os.chdir(old)
    return rc, [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]


def _sigint_on(monkeypatch, module, name, when=lambda *a: True):
    """Wrap module.name so that the first call for which when(*args) holds sends this process a SIGINT after it."""
    real, sent = getattr(module, name), []

    def wrapped(*args, **kwargs):
        out = real(*args, **kwargs)
        if not sent and when(*args):
            sent.append(1)
            os.kill(os.getpid(), signal.SIGINT)
        return out

    monkeypatch.setattr(module, name, wrapped)
    return sent


def test_a_signal_while_points_writes_leaves_none_of_its_outputs(tmp_path, monkeypatch, capsys):
    import numpy as np

    (tmp_path / "r.json").write_text("the previous report\n")
    sent = _sigint_on(monkeypatch, np, "save")  # the --distance-out array, after the cloud's temp file
    rc, err = _points_in(tmp_path, capsys)
    assert sent and rc == 130 and len(err) == 1, err
    assert err[0].startswith("panorecon: interrupted by SIGINT; no output was half-written"), err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]  # no c.ply, no d.npy, no temp file
    assert (tmp_path / "r.json").read_text() == "the previous report\n"


def test_a_signal_while_points_renames_its_outputs_leaves_them_all_whole(tmp_path, monkeypatch, capsys):
    import numpy as np

    from panorecon.geometry import PointCloud

    sent = _sigint_on(monkeypatch, os, "replace", lambda src, dst: Path(dst).name in ("c.ply", "r.json", "d.npy"))
    rc, err = _points_in(tmp_path, capsys)
    assert sent and rc == 130 and len(err) == 1 and "no output was half-written" in err[0], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.ply", "d.npy", "r.json"]
    report = json.loads((tmp_path / "r.json").read_text())
    assert len(PointCloud.load_ply(tmp_path / "c.ply")) == report["points"]["count"]
    assert np.load(tmp_path / "d.npy").shape == (32, 64)


EXITING = """
import os, signal, sys, weakref
class Box: pass
first, last = Box(), Box()
weakref.finalize(first, int)  # weakref.finalize's atexit hook registered before the command, as importing torch does
from panorecon.cli import main
rc = main(sys.argv[1:])
weakref.finalize(last, os.kill, os.getpid(), signal.SIGINT)  # a Ctrl-C among the exit's finalizers (torch's m.reset)
sys.exit(rc)
"""


def test_a_signal_while_the_interpreter_exits_is_one_line(tmp_path):
    proc = subprocess.run(
        [sys.executable, "-c", EXITING, *POINTS], cwd=tmp_path, capture_output=True, text=True, env=_env()
    )
    err = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 130 and "Traceback" not in proc.stderr, proc.stderr
    assert err == ["panorecon: SIGINT while exiting, after the command had finished; its outputs are whole"], err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.ply", "d.npy", "r.json"]


def test_a_signal_as_atomic_write_creates_its_temp_file_leaves_none(tmp_path, monkeypatch):
    import tempfile

    from panorecon import interrupts
    from panorecon.io import atomic_write

    sent = _sigint_on(monkeypatch, tempfile, "mkstemp")  # the file exists, its name not yet noted
    old = signal.signal(signal.SIGINT, interrupts._raise)
    try:
        with pytest.raises(interrupts.Interrupted), atomic_write(tmp_path / "x.txt") as tmp:
            tmp.write_text("x")
    finally:
        signal.signal(signal.SIGINT, old)
    assert sent and list(tmp_path.iterdir()) == []
