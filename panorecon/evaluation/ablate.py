"""``panorecon ablate``: run a suite's grid through the cached pipeline and write results.csv / results.md / plots.

The grid is run as a two-level DAG: every distinct point-cloud stage first, then every training stage (which
reads its cloud from the cache), so a stage shared by several rows runs once, and a stage finished in an earlier
run (same settings, same code) is not run again. Each stage runs in a fresh spawned process (its peak memory
is its own) on a local process pool of ``jobs`` workers, or on a Dask cluster (``engine="dask"``: a
``LocalCluster`` of ``jobs`` workers, or an existing scheduler by address); there worker processes are reused,
so a stage's peak memory is its worker's peak so far.
"""

from __future__ import annotations

import functools
import math
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from multiprocessing import get_context
from pathlib import Path

import pandas as pd

from ..io import atomic_write
from ..pipeline import Row, StageCache, run_points, run_train
from .environment import environment, git_commit
from .suite import Suite, resolve_names

ENGINES = ("local", "dask")


class _Eta:
    """Without a progress bar: one line per finished stage at most every ``every`` seconds, with the estimated
    time left for this level (elapsed / done x remaining)."""

    def __init__(self, total: int, desc: str, quiet: bool, every: float = 30.0):
        self.total, self.desc, self.quiet, self.every = total, desc, quiet, every
        self.n, self.t0, self.last = 0, time.perf_counter(), -math.inf

    def done(self) -> None:
        self.n += 1
        now = time.perf_counter()
        if self.quiet or (now - self.last < self.every and self.n < self.total):
            return
        self.last = now
        left = (now - self.t0) / self.n * (self.total - self.n)
        print(f"{self.desc}: {self.n}/{self.total} stages done, about {left:.0f} s left", flush=True)


def check_scheduler(address: str, timeout: float = 3.0) -> None:
    """PanoreconInputError unless ``address`` (``tcp://HOST:PORT`` or ``HOST:PORT``) is well formed and accepts a
    TCP connection within ``timeout`` seconds (dask's own client waits 30 s, then raises a traceback)."""
    import socket
    from urllib.parse import urlsplit

    from ..io import PanoreconInputError

    hint = "start one with `dask scheduler --port PORT` (and `dask worker tcp://HOST:PORT`), or leave out --scheduler"
    parts = urlsplit(address if "://" in address else f"tcp://{address}")
    try:
        host, port = parts.hostname, parts.port
    except ValueError:
        host, port = None, None
    if parts.scheme != "tcp" or not host or port is None or parts.path not in ("", "/"):
        raise PanoreconInputError(f"--scheduler {address!r}: expected tcp://HOST:PORT; {hint}")
    try:
        socket.create_connection((host, port), timeout=timeout).close()
    except OSError as e:
        raise PanoreconInputError(
            f"--scheduler {address}: no Dask scheduler reachable there ({e.strerror or e}); {hint}"
        ) from None


def _init_worker(threads: int) -> None:
    import torch

    torch.set_num_threads(threads)


def _points_task(cache_root: str, task: tuple[Row, str, str | None], device: str = "auto") -> dict:
    from ..device import resolve_device

    row, points_key, _ = task
    return run_points(
        StageCache(cache_root), row, points_key, provenance={"commit": git_commit()}, device=resolve_device(device)
    )


def _train_task(cache_root: str, task: tuple[Row, str, str | None], device: str = "auto") -> dict:
    from ..device import resolve_device
    from ..splat.rasterize import cpu_backend, gsplat_backend

    dev = resolve_device(device)
    # a one-off build (or the wait for another worker's) is install time, not the stage's
    if dev.type == "cpu":
        cpu_backend.load()
    else:
        gsplat_backend.available()
    row, points_key, train_key = task
    return run_train(
        StageCache(cache_root),
        row,
        key=train_key,
        points_key=points_key,
        provenance={"commit": git_commit()},
        device=dev,
    )


def _run_tasks(
    fn, tasks: list[tuple], cache_root: str, jobs: int, engine: str, scheduler: str | None, desc: str, progress: bool
) -> set[str]:
    """Run ``fn`` on every task -> the keys of the stages this run computed (not those another run sharing the
    cache computed meanwhile: a task waits for that stage's lock and then reads it)."""
    from tqdm import tqdm

    computed: set[str] = set()
    if not tasks:
        return computed
    bar = tqdm(total=len(tasks), desc=desc, disable=not progress)
    eta = _Eta(len(tasks), desc, quiet=progress)  # the bar shows its own estimate
    if engine == "dask":
        from dask.distributed import Client, LocalCluster
        from dask.distributed import as_completed as dask_completed

        cluster = (
            None
            if scheduler
            else LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None)
        )
        with Client(scheduler or cluster) as client:
            futures = client.map(fn, [cache_root] * len(tasks), tasks, pure=False)
            for f in dask_completed(futures):
                r = f.result()
                computed |= {r["key"]} if not r["cached"] else set()
                bar.update()
                eta.done()
        if cluster is not None:
            cluster.close()
    else:
        threads = max(1, (os.cpu_count() or 1) // jobs)
        with ProcessPoolExecutor(
            jobs, mp_context=get_context("spawn"), initializer=_init_worker, initargs=(threads,), max_tasks_per_child=1
        ) as pool:
            for f in as_completed([pool.submit(fn, cache_root, r) for r in tasks]):
                r = f.result()
                computed |= {r["key"]} if not r["cached"] else set()
                bar.update()
                eta.done()
    bar.close()
    return computed


def run_suite(
    suite: Suite,
    out_dir,
    jobs: int = 1,
    engine: str = "local",
    scheduler: str | None = None,
    cache_dir=None,
    progress: bool = True,
    device: str = "auto",
) -> pd.DataFrame:
    """Run (or read from the cache) every row of ``suite``; write DIR/results.csv, results.md, plots and
    report.html. ``device``: where the stages compute (auto, cpu, cuda); a cached stage keeps the device it ran on."""
    from ..device import resolve_device

    if engine not in ENGINES:
        raise ValueError(f"engine={engine!r}: expected one of {ENGINES}")
    resolve_device(device)  # refused here, once, before anything is written or any worker starts
    if jobs < 1:
        raise ValueError(f"jobs={jobs}: expected at least 1")
    resolve_names(suite)  # every scene, source and teacher, before the first stage and before --out is made
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cache = StageCache(cache_dir or out / "cache")
    t0 = time.perf_counter()
    # keys fixed once, here: workers use them, so the run stays consistent even if the code changes meanwhile
    tasks = [(r, r.points_key(), r.train_key() if r.train is not None else None) for r in suite.rows]
    points_todo = {t[1]: t for t in tasks if cache.done("points", t[1]) is None}
    points_run = _run_tasks(
        functools.partial(_points_task, device=device),
        list(points_todo.values()),
        str(cache.root),
        jobs,
        engine,
        scheduler,
        "points",
        progress,
    )
    points_done = {t[1]: cache.done("points", t[1]) for t in tasks}
    train_todo = {
        t[2]: t
        for t in tasks
        if t[2] is not None and "unavailable" not in points_done[t[1]] and cache.done("train", t[2]) is None
    }
    train_run = _run_tasks(
        functools.partial(_train_task, device=device),
        list(train_todo.values()),
        str(cache.root),
        jobs,
        engine,
        scheduler,
        "train",
        progress,
    )
    env = environment()
    frame = pd.DataFrame(
        [
            result_row(
                row,
                points_done[pk],
                cache.done("train", tk) if tk else None,
                env,
                pk not in points_run,
                tk is not None and tk not in train_run,
            )
            for row, pk, tk in tasks
        ]
    )
    if suite.reference:
        frame["reference"] = frame["label"] == suite.reference
    from .report_html import RowAssets

    assets = [
        RowAssets(cache.folder("train", tk) / "renders" if tk else None, cache.folder("points", pk) / "cloud.ply", pk)
        for _, pk, tk in tasks
    ]
    write_outputs(frame, suite, out, assets, t0)
    return frame


def write_outputs(frame: pd.DataFrame, suite: Suite, out: Path, assets: list | None, t0: float) -> None:
    """DIR/results.csv, pareto.png and the learning curves, results.md and report.html from the results
    ``frame`` (``assets``: one ``RowAssets`` per row, or None: no pictures); ``t0``: perf_counter at the start."""
    from .report import write_plots, write_results_md
    from .report_html import write_report_html

    with atomic_write(out / "results.csv") as tmp:
        frame.to_csv(tmp, index=False)
    write_plots(frame, suite, out)
    write_results_md(frame, suite, out, wall_seconds=time.perf_counter() - t0)
    write_report_html(frame, suite, out, assets, wall_seconds=time.perf_counter() - t0)


def _num(v):
    """A float, or NaN for an 'n/a: ...' string (the reason is kept in its own column)."""
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else math.nan


# the held-out scores of other panoramas beside the raw psnr_ho: after a per-view colour alignment, and the
# reprojection oracle (the training panorama's colour at the true points) raw and aligned; results.csv column
# heldout_<key>, with heldout_<key>_note holding the reason where it reads n/a
HELDOUT_ALIGNED_KEYS = ("aligned_psnr", "aligned_ssim", "aligned_lpips", "oracle_psnr", "oracle_aligned_psnr")


def result_row(row: Row, pts: dict, tr: dict | None, env: dict, points_cached: bool, train_cached: bool) -> dict:
    """One results.csv row from the finished stages' records (points ``pts``, training ``tr``): the row's
    settings, every metric with its protocol, seconds per stage, peak memory, versions, commit, and which
    stages came from the cache."""
    if "unavailable" in pts:
        return {
            "label": row.label,
            "scene": row.scene,
            "seed": row.seed,
            "width": row.width,
            "source": row.source,
            "teacher": row.teacher,
            **row.extra,
            "unavailable_note": pts["unavailable"],
            "cached": "none",
            "commit": pts.get("commit", "unrecorded"),
        }
    rep = pts["report"]
    depth = rep.get("depth") if isinstance(rep.get("depth"), dict) else {}
    points = rep.get("points", {})
    rec = {
        "label": row.label,
        "scene": row.scene,
        "seed": row.seed,
        "width": row.width,
        "source": row.source,
        "teacher": row.teacher,
        "views": rep.get("views"),
        "panoramas": rep.get("panoramas", 1),
        **row.extra,
        "abs_rel": _num(depth.get("abs_rel")),
        "rmse": _num(depth.get("rmse")),
        "delta1": _num(depth.get("delta1")),
        "teacher_view_abs_rel": _num(rep.get("teacher_per_view_abs_rel_median")),
        "points": points.get("count"),
        "chamfer": _num(points.get("chamfer")),
        "fscore": _num(points.get("fscore")),
        "accuracy": _num(points.get("accuracy")),
        "completeness": _num(points.get("completeness")),
        "sec_points": pts["seconds"],
        "peak_mb_points": pts["peak_rss_mb"],
        "view_components": rep.get("view_components"),
        "warning": "; ".join(rep.get("warnings", [])),
    }
    for stage, sec in rep["seconds"].items():
        if stage != "total":
            rec[f"sec_points_{stage}"] = sec
    seconds_total, peak = pts["seconds"], pts["peak_rss_mb"]
    if tr is not None:
        m = tr["metrics"]
        for proto, tag in (("pseudo-label", "pl"), ("held-out", "ho")):
            block = m.get(proto)
            block = block if isinstance(block, dict) else {}
            for metric in ("psnr", "ssim", "lpips"):
                rec[f"{metric}_{tag}"] = _num(block.get(metric))
            if isinstance(block.get("lpips"), str):
                rec[f"lpips_{tag}_note"] = block["lpips"]
            if not block:
                rec[f"psnr_{tag}_note"] = m.get(proto)
            elif isinstance(block.get("psnr"), str):  # e.g. held-out panoramas with too few co-visible pixels
                rec[f"psnr_{tag}_note"] = block["psnr"]
        held = m.get("held-out")
        if isinstance(held, dict) and "aligned_psnr" in held:  # held-out views of other panoramas (trainer.py)
            for key in HELDOUT_ALIGNED_KEYS:
                rec[f"heldout_{key}"] = _num(held.get(key))
                if isinstance(held.get(key), str):
                    rec[f"heldout_{key}_note"] = held[key]
        rec.update(
            device=m.get("device", "cpu"),
            device_name=m.get("device_name", "unrecorded"),
            peak_gpu_mb=_num(m.get("peak_gpu_memory_mb")),
        )
        rec.update(
            gaussians=m["gaussians"],
            iters=m["iterations"],
            strategy=m["strategy"],
            labels=m["config"]["labels"],
            res=m["config"]["res"],
            sec_labels=m["seconds"]["labels"],
            sec_train=m["seconds"]["train"],
            sec_eval=m["seconds"]["eval"],
            peak_mb_train=tr["peak_rss_mb"],
            history=";".join(f"{h['iteration']}:{h['psnr']:.3f}" for h in m["history"]),
            # held-out PSNR against training seconds (runs made before it was recorded have none)
            history_heldout=";".join(
                f"{h['seconds']:.4f}:{h['heldout_psnr']:.3f}"
                for h in m["history"]
                if "heldout_psnr" in h and "seconds" in h
            )
            or None,
        )
        seconds_total += tr["seconds"]
        peak = max(peak, tr["peak_rss_mb"])
    rec.update(
        sec_total=seconds_total,
        peak_mb=peak,
        cached=",".join(s for s, c in (("points", points_cached), ("train", train_cached)) if c) or "none",
        # the commit of the run that computed the row's last stage; a cache written before commits were stored
        # has none
        commit=(tr if tr is not None else pts).get("commit", "unrecorded"),
        **{f"version_{k}": v for k, v in env["versions"].items()},
    )
    return rec
