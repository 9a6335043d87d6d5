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
from .orphans import check_leftovers
from .suite import Suite, resolve_names

ENGINES = ("local", "dask")


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


def _row_task(cache_root: str, task: tuple[Row, str, str | None], device: str = "auto", threads: int = 0) -> dict:
    """Compute (or read from the cache) one row's stages -> {"points": record, "train": record or None}, each
    record with its ``cached`` flag. ``threads`` > 0: torch's thread count in this process (a Dask worker is
    reused, so it is set per task)."""
    from ..device import resolve_device
    from ..splat.rasterize import cpu_backend, gsplat_backend

    if threads:
        _init_worker(threads)
    dev = resolve_device(device)
    row, points_key, train_key = task
    cache = StageCache(cache_root)
    pts = run_points(cache, row, points_key, provenance={"commit": git_commit()}, device=dev)
    if train_key is None or "unavailable" in pts:
        return {"points": pts, "train": None}
    # a one-off build (or the wait for another worker's) is install time, not the stage's
    if dev.type == "cpu":
        cpu_backend.load()
    else:
        gsplat_backend.available()
    tr = run_train(cache, row, key=train_key, points_key=points_key, provenance={"commit": git_commit()}, device=dev)
    return {"points": pts, "train": tr}


def _run_tasks(
    fn, tasks: list[tuple], cache_root: str, jobs: int, engine: str, scheduler: str | None, progress: bool, on_done
) -> None:
    """Run ``fn(cache_root, task)`` on every task, in order as workers free up, calling ``on_done(task, result)``
    in this process as each finishes."""
    from tqdm import tqdm

    if not tasks:
        return
    bar = tqdm(total=len(tasks), desc="runs", disable=not progress)
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
            index = {f.key: i for i, f in enumerate(futures)}
            for f in dask_completed(futures):
                on_done(tasks[index[f.key]], f.result())
                bar.update()
        if cluster is not None:
            cluster.close()
    else:
        pool = ProcessPoolExecutor(jobs, mp_context=get_context("spawn"), max_tasks_per_child=1)
        try:
            futures = {pool.submit(fn, cache_root, t): t for t in tasks}
            for f in as_completed(futures):
                on_done(futures[f], f.result())
                bar.update()
        except BaseException:  # Ctrl-C, SIGTERM (Interrupted) or a failed run: the runs in flight end too
            for worker in list((pool._processes or {}).values()):  # noqa: SLF001 -- the pool has no public kill
                worker.terminate()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        pool.shutdown()
    bar.close()


def suite_out_dirs(suites: list[Suite], out: Path) -> list[Path]:
    """Where each suite's outputs go: ``out`` itself for one suite, ``out/<suite file stem>/`` for several."""
    if len(suites) == 1:
        return [out]
    stems = [s.name for s in suites]
    if len(set(stems)) != len(stems):
        raise ValueError(f"suites {stems}: two suites share a file name; their outputs would share a folder")
    return [out / s for s in stems]


def read_results(path: Path) -> dict[str, dict]:
    """run_id -> record of a results.csv (empty when there is none); a run in it twice keeps the first."""
    if not path.is_file():
        return {}
    frame = pd.read_csv(path)
    if "run_id" not in frame:
        return {}
    found: dict[str, dict] = {}
    for rec in frame.to_dict("records"):
        found.setdefault(rec["run_id"], rec)
    return found


def unavailable(rec: dict) -> bool:
    """A results.csv record of a run that read n/a (its source cannot run on the machine that tried it)."""
    note = rec.get("unavailable_note")
    return isinstance(note, str) and note.startswith("n/a")


def finished_rows(results: list[dict[str, dict]], retry_unavailable: bool = False) -> dict[str, dict]:
    """run_id -> its results.csv record, over every file's records in ``results`` (``read_results``); a row in
    several files keeps the first. ``retry_unavailable``: a row that read n/a is left out, to be tried again (on
    another machine it may run); by default it is as finished as any other (a "failed: ..." row, the run's
    outcome, always is)."""
    found: dict[str, dict] = {}
    for records in results:
        for rid, rec in records.items():
            if not (retry_unavailable and unavailable(rec)):
                found.setdefault(rid, rec)
    return found


def _reused(rec: dict, row: Row) -> dict:
    """A results.csv record ``rec`` of the same run (same run_id) as ``row``, under this row's names: its label
    and suite columns from this suite, its measurements (and ``cached``: where its stages came from when it was
    computed) as recorded, so a table read back is rewritten unchanged."""
    return {
        **rec,
        "label": row.label,
        "scene": row.scene,
        "seed": row.seed,
        "source": row.source,
        "teacher": row.teacher,
        **row.extra,
    }


def _block_order(todo: list[Row], every: list[Row]) -> list[Row]:
    """``todo`` ordered by (scene, seed) block: scenes in their order of first appearance in ``every`` (all the
    suites' rows), each scene's seeds ascending. The runs of one block finish together, so a table interrupted
    between sittings holds whole blocks, each computed by one version of the code, and the order does not
    depend on what is already done."""
    scenes = list(dict.fromkeys(r.scene for r in every))
    return sorted(todo, key=lambda r: (scenes.index(r.scene), r.seed))


def run_suites(
    suites: list[Suite],
    out_dir,
    jobs: int = 1,
    engine: str = "local",
    scheduler: str | None = None,
    cache_dir=None,
    progress: bool = True,
    device: str = "auto",
    threads: int = 0,
    retry_unavailable: bool = False,
) -> list[pd.DataFrame]:
    """Run every row of ``suites`` once: a run that several suites share (same settings: same ``Row.run_id``)
    computes once and appears in each. Runs already in a results.csv under ``out_dir`` (this suite's or another's
    of the same invocation) are not run again, cache or no cache; the others are computed (or read from the
    stage cache), (scene, seed) block by block, and every results.csv is rewritten as each run finishes.
    Writes results.csv, results.md, plots and report.html per suite (``suite_out_dirs``). ``threads``: torch
    threads per worker (0: cores // jobs). ``device``: where the stages compute (auto, cpu, cuda); a cached
    stage keeps the device it ran on. A results.csv holding runs its suite does not produce here is refused
    before anything runs (``orphans.check_leftovers``): nothing committed is dropped. ``retry_unavailable``: runs
    that read n/a are tried again (by default they are finished, as any other)."""
    from ..device import resolve_device
    from ..pipeline.cache import code_digest
    from ..pipeline.stages import TRAIN_CODE

    if engine not in ENGINES:
        raise ValueError(f"engine={engine!r}: expected one of {ENGINES}")
    resolve_device(device)  # refused here, once, before anything is written or any worker starts
    if jobs < 1:
        raise ValueError(f"jobs={jobs}: expected at least 1")
    if threads < 0:
        raise ValueError(f"threads={threads}: expected 0 (cores // jobs) or more")
    for suite in suites:
        resolve_names(suite)  # every scene, source and teacher, before the first stage and before --out is made
    out = Path(out_dir)
    outs = suite_out_dirs(suites, out)
    committed = [read_results(o / "results.csv") for o in outs]
    check_leftovers(suites, outs, committed, jobs)
    done_csv = finished_rows(committed, retry_unavailable)
    for o in outs:
        o.mkdir(parents=True, exist_ok=True)
    cache = StageCache(cache_dir or out / "cache")
    t0 = time.perf_counter()
    code = code_digest(TRAIN_CODE)
    # keys fixed once, here: workers use them, so the run stays consistent even if the code changes meanwhile
    keyed = {}
    for suite in suites:
        for r in suite.rows:
            keyed.setdefault(r.run_id(), (r, r.points_key(), r.train_key() if r.train is not None else None))
    env = environment()
    records: dict[str, dict] = {}

    def record(task, result) -> None:
        row, pk, tk = task
        pts, tr = result["points"], result["train"]
        rec = result_row(row, pts, tr, env, pts["cached"], bool(tr and tr.get("cached")))
        records[row.run_id()] = {"run_id": row.run_id(), "code": code, **rec}

    todo = []
    for run_id, task in keyed.items():
        if run_id in done_csv:
            continue
        row, pk, tk = task
        pts = cache.done("points", pk)
        tr = cache.done("train", tk) if tk and pts is not None and "unavailable" not in pts else None
        if pts is not None and (tk is None or "unavailable" in pts or tr is not None):
            record(task, {"points": {**pts, "cached": True}, "train": tr and {**tr, "cached": True}})
        else:
            todo.append(task)
    todo = [keyed[r.run_id()] for r in _block_order([t[0] for t in todo], [t[0] for t in keyed.values()])]
    print(
        f"{len(keyed)} distinct runs: {len(keyed) - len(done_csv.keys() & keyed.keys()) - len(todo)} in the stage "
        f"cache, {len(done_csv.keys() & keyed.keys())} in results.csv, {len(todo)} to run",
        flush=True,
    )

    def frames() -> list[pd.DataFrame]:
        out_frames = []
        for suite in suites:
            rows = []
            for r in suite.rows:
                rid = r.run_id()
                if rid in records:
                    rows.append({**records[rid], "label": r.label, **r.extra})
                elif rid in done_csv:
                    rows.append(_reused(done_csv[rid], r))
            frame = pd.DataFrame(rows)
            if suite.reference and len(frame):
                frame["reference"] = frame["label"] == suite.reference
            out_frames.append(frame)
        return out_frames

    def save_csvs() -> None:
        for frame, o in zip(frames(), outs):
            if len(frame):
                with atomic_write(o / "results.csv") as tmp:
                    frame.to_csv(tmp, index=False)

    started, finished, run_seconds = time.perf_counter(), [0], [0.0]

    def on_done(task, result) -> None:
        record(task, result)
        save_csvs()
        finished[0] += 1
        row = task[0]
        rec = records[row.run_id()]
        run_seconds[0] += float(rec.get("sec_total") or 0.0)
        left = (time.perf_counter() - started) / finished[0] * (len(todo) - finished[0])
        print(
            f"[{finished[0]}/{len(todo)}] {row.scene} seed {row.seed} {row.label!r}: {rec.get('sec_total', 0):.0f} s"
            f", psnr_ho {rec.get('psnr_ho', float('nan')):.2f}; about {left / 60:.0f} min left",
            flush=True,
        )

    fn = functools.partial(_row_task, device=device, threads=threads or max(1, (os.cpu_count() or 1) // jobs))
    _run_tasks(fn, todo, str(cache.root), jobs, engine, scheduler, progress, on_done)
    result = frames()
    from .report_html import RowAssets

    for suite, frame, o in zip(suites, result, outs):
        assets = []
        for r in suite.rows:
            _, pk, tk = keyed[r.run_id()]
            renders = cache.folder("train", tk) / "renders" if tk else None
            assets.append(RowAssets(renders, cache.folder("points", pk) / "cloud.ply", pk))
        write_outputs(frame, suite, o, assets, t0)
    return result


def run_suite(suite: Suite, out_dir, **kwargs) -> pd.DataFrame:
    """``run_suites`` of one suite: its outputs in ``out_dir`` itself."""
    return run_suites([suite], out_dir, **kwargs)[0]


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


# the held-out scores beside the all-pixel psnr_ho (splat/evaluate.py): on every held-out view with a true
# distance, the co-visible pixels' PSNR, the reprojection oracle's (the training panorama's colour at the true
# points) and the gap between them; on other panoramas also after a per-view colour alignment. results.csv
# column heldout_<key>, with heldout_<key>_note holding the reason where it reads n/a
HELDOUT_ORACLE_KEYS = ("covisible_psnr", "oracle_psnr", "oracle_gap", "covisible_fraction")
HELDOUT_ALIGNED_KEYS = ("aligned_psnr", "aligned_ssim", "aligned_lpips", "oracle_aligned_psnr", "oracle_aligned_gap")


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
        "cpu_points": _num(pts.get("cpu_seconds")),
        "load_points": _num(pts.get("load_average")),
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
        held = held if isinstance(held, dict) else {}
        keys = (HELDOUT_ORACLE_KEYS if "oracle_gap" in held else ()) + (  # runs before the gap have none
            HELDOUT_ALIGNED_KEYS if "aligned_psnr" in held else ()  # held-out views of other panoramas
        )
        for key in keys:
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
            cpu_train=_num(tr.get("cpu_seconds")),
            load_train=_num(tr.get("load_average")),
            history=";".join(f"{h['iteration']}:{h['psnr']:.3f}" for h in m["history"]),
            # held-out PSNR against training seconds (runs made before it was recorded have none)
            history_heldout=";".join(
                f"{h['seconds']:.4f}:{h['heldout_psnr']:.3f}"
                for h in m["history"]
                if "heldout_psnr" in h and "seconds" in h
            )
            or None,
        )
        for b in m.get("budgets", []):  # the full evaluation at each budget (TrainConfig.eval_at and the last step)
            step = b["iteration"]
            rec[f"sec_train@{step}"] = b["seconds"]
            rec[f"gaussians@{step}"] = b["gaussians"]
            for proto, tag in (("pseudo-label", "pl"), ("held-out", "ho")):
                block = b.get(proto) if isinstance(b.get(proto), dict) else {}
                for metric in ("psnr", "ssim", "lpips"):
                    rec[f"{metric}_{tag}@{step}"] = _num(block.get(metric))
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
