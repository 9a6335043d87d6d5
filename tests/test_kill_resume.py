"""A real SIGKILL of `panorecon train` and of `panorecon ablate` (with its workers) mid-run, resumed to the
same metrics as an uninterrupted run. Subprocesses in their own session; the whole group is killed."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

pytestmark = pytest.mark.slow  # 0.5 to 3 min each on the shared 2-core machine

ROOT = Path(__file__).resolve().parents[1]
TRAIN = [
    "train",
    "bedroom",
    "--source",
    "fibonacci",
    "--teacher",
    "sim:clean",
    "--views",
    "8",
    "--width",
    "64",
    "--iters",
    "60",
    "--res",
    "24",
    "--labels",
    "8",
    "--checkpoint-every",
    "5",
    "--no-progress",
]
SUITE = """
title = "kill"
rows = ["source"]
[defaults]
scene = "bedroom"
width = 64
teacher = "sim:clean"
views = 8
iters = 60
res = 24
labels = 8
heldout = 2
sh_degree = 1
checkpoint_every = 5
history_every = 10
[grid]
source = ["fibonacci"]
"""


def _cli(argv, **kw):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-m", "panorecon.cli", *argv],
        env=env,
        cwd=ROOT,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
        **kw,
    )


def _kill_when(proc, ready, timeout=300.0):
    """SIGKILL the process group of ``proc`` as soon as ``ready()`` holds (fail if it ends first)."""
    t = time.monotonic()
    while not ready():
        assert proc.poll() is None, f"finished before it could be killed: {proc.communicate()}"
        assert time.monotonic() - t < timeout
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert proc.returncode == -signal.SIGKILL


def _finish(proc):
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err
    return out, err


def test_sigkill_of_train_resumes_to_identical_metrics(tmp_path):
    full = _cli(TRAIN + ["--out", str(tmp_path / "full")])
    killed = _cli(TRAIN + ["--out", str(tmp_path / "killed")])
    _kill_when(killed, lambda: (tmp_path / "killed" / "ckpt.pt").exists())
    _finish(full)
    _, err = _finish(_cli(TRAIN + ["--out", str(tmp_path / "killed")]))
    assert "resuming" in err and "at step" in err
    a, b = (json.loads((tmp_path / d / "metrics.json").read_text()) for d in ("full", "killed"))
    for key in ("pseudo-label", "held-out", "gaussians", "history", "iterations"):
        assert a[key] == b[key], key
    assert not (tmp_path / "killed" / "ckpt.pt").exists()


METRICS = ["psnr_pl", "ssim_pl", "psnr_ho", "ssim_ho", "gaussians", "history", "abs_rel", "chamfer", "points"]


def test_sigkill_of_ablate_resumes_to_identical_results(tmp_path):
    (tmp_path / "s.toml").write_text(SUITE)
    killed = _cli(["ablate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "killed"), "--no-progress"])
    _kill_when(killed, lambda: any((tmp_path / "killed" / "cache" / "train").glob("*/ckpt.pt")))
    assert not (tmp_path / "killed" / "results.csv").exists()
    _finish(_cli(["ablate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "killed"), "--no-progress"]))
    _finish(_cli(["ablate", str(tmp_path / "s.toml"), "--out", str(tmp_path / "full"), "--no-progress"]))
    a, b = (pd.read_csv(tmp_path / d / "results.csv") for d in ("full", "killed"))
    assert b.loc[0, "cached"] == "points"  # the points stage finished before the kill; training was resumed
    pd.testing.assert_frame_equal(a[METRICS], b[METRICS], check_exact=True)


def test_two_ablate_runs_on_one_cache_compute_each_stage_once(tmp_path):
    """Both runs wait on the stage lock (held here until both are blocked on it); one computes, the other
    reads its result, and each run's results.csv says which."""
    from panorecon.evaluation.suite import load_suite
    from panorecon.pipeline import StageCache

    (tmp_path / "s.toml").write_text(SUITE.replace("[grid]", "train = false\n[grid]"))
    row = load_suite(tmp_path / "s.toml").rows[0]
    cache = StageCache(tmp_path / "cache")
    with cache.lock("points", row.points_key()):
        inode = os.stat(cache.folder("points", row.points_key()) / ".lock").st_ino
        runs = [
            _cli(
                [
                    "ablate",
                    str(tmp_path / "s.toml"),
                    "--out",
                    str(tmp_path / name),
                    "--cache",
                    str(tmp_path / "cache"),
                    "--no-progress",
                ]
            )
            for name in ("a", "b")
        ]
        t = time.monotonic()
        while sum(f":{inode} " in ln and "->" in ln for ln in Path("/proc/locks").read_text().splitlines()) < 2:
            assert all(r.poll() is None for r in runs) and time.monotonic() - t < 300
            time.sleep(0.05)
    for r in runs:
        _finish(r)
    a, b = (pd.read_csv(tmp_path / d / "results.csv") for d in ("a", "b"))
    assert sorted([a.loc[0, "cached"], b.loc[0, "cached"]]) == ["none", "points"]
    pd.testing.assert_frame_equal(a[["abs_rel", "chamfer", "points"]], b[["abs_rel", "chamfer", "points"]])
