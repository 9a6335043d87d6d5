"""``ablate --verify K``: does a committed table still come out of today's code?

K committed rows of each suite's results.csv, chosen to cover its table rows, scenes and seeds, are recomputed
on the current code in a stage cache of their own (nothing under ``--out`` is read from a cache or rewritten but
``verify.md``), and each metric is set beside its committed value. The verdict weighs the difference against the
seed-to-seed spread of the committed table (the standard deviation over seeds of that table row, within each
scene, pooled over its scenes):

- *reproduced*: the same value to 1e-6 relative (float32 rounding: a sum taken in another order);
- *drifted*: another value, within 2.77 seed SDs (95 % of the difference between two runs of other seeds);
- *changed beyond noise*: further than that;
- *differs (no seed spread)*: another value, and the table has one seed, so no spread to weigh it by.
"""

from __future__ import annotations

import functools
import math
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from ..io import atomic_write
from ..pipeline import StageCache
from .ablate import _row_task, _run_tasks, read_results, result_row, suite_out_dirs
from .environment import environment, git_commit

METRICS = (
    "psnr_pl",
    "ssim_pl",
    "lpips_pl",
    "psnr_ho",
    "ssim_ho",
    "lpips_ho",
    "abs_rel",
    "chamfer",
    "points",
    "gaussians",
)
REPRODUCED_REL = 1e-6  # float32 rounding: a change in the order of a sum, not in the result
NOISE_SDS = 2.77  # 1.96 * sqrt(2): the 95 % range of the difference of two independent runs, in seed SDs


def pick_rows(rows: list, records: dict[str, dict], k: int) -> list:
    """Up to ``k`` of the suite's ``rows`` with a committed, computed record in ``records`` (run_id -> record),
    chosen greedily so that each adds as many table rows (labels), scenes and seeds not yet chosen as it can;
    ties go to the earlier row (deterministic)."""
    candidates = [r for r in rows if r.run_id() in records and not _failed(records[r.run_id()])]
    chosen, seen = [], (set(), set(), set())
    for _ in range(min(k, len(candidates))):
        best = max(
            (r for r in candidates if r not in chosen),
            key=lambda r: (r.label not in seen[0]) + (r.scene not in seen[1]) + (r.seed not in seen[2]),
        )
        chosen.append(best)
        for s, v in zip(seen, (best.label, best.scene, best.seed)):
            s.add(v)
    return chosen


def _failed(rec: dict) -> bool:
    """A record of a run that read n/a or failed: nothing to recompute."""
    return isinstance(rec.get("unavailable_note"), str)


def _float(v) -> float:
    try:
        return float(v)
    except (TypeError, ValueError):
        return math.nan


def seed_sd(records: dict[str, dict], label: str, metric: str) -> float:
    """Seed-to-seed standard deviation of ``metric`` for table row ``label``: the within-scene variances over
    seeds (ddof 1) pooled over the row's scenes by their degrees of freedom; NaN where no scene has two seeds.
    Labels compare as text (results.csv reads a label like 120 back as a number)."""
    by_scene: dict[str, list[float]] = {}
    for r in records.values():
        v = _float(r.get(metric))
        if str(r.get("label")) == str(label) and math.isfinite(v):
            by_scene.setdefault(str(r.get("scene")), []).append(v)
    groups = [v for v in by_scene.values() if len(v) > 1]
    df = sum(len(v) - 1 for v in groups)
    return math.sqrt(sum(float(np.var(v, ddof=1)) * (len(v) - 1) for v in groups) / df) if df else math.nan


def verdict(committed: float, recomputed: float, sd: float) -> str:
    if abs(recomputed - committed) <= REPRODUCED_REL * max(1.0, abs(committed)):
        return "reproduced"
    if not math.isfinite(sd):
        return "differs (no seed spread)"
    return "drifted" if abs(recomputed - committed) <= NOISE_SDS * sd else "changed beyond noise"


def compare(row, committed: dict, recomputed: dict, records: dict[str, dict]) -> list[dict]:
    """One dict per metric the committed record has a finite value of: committed, recomputed, difference, seed
    SD and verdict."""
    out = []
    for m in METRICS:
        c, r = _float(committed.get(m)), _float(recomputed.get(m))
        if not math.isfinite(c):
            continue
        sd = seed_sd(records, row.label, m)
        out.append(
            {
                "metric": m,
                "committed": c,
                "recomputed": r,
                "difference": r - c,
                "seed_sd": sd,
                "verdict": verdict(c, r, sd) if math.isfinite(r) else "not recomputed",
            }
        )
    return out


def verify_suites(
    suites: list, out_dir, k: int, jobs: int = 1, threads: int = 0, device: str = "auto", cache_dir=None
) -> list[str]:
    """Recompute ``k`` committed rows of each suite's results.csv under ``out_dir`` (``suite_out_dirs``) on the
    current code, write each suite's ``verify.md`` beside its results.csv and return those texts. The rows of
    every suite run together (a run two tables share once), in a fresh stage cache unless ``cache_dir``."""
    from ..pipeline.cache import code_digest
    from ..pipeline.stages import TRAIN_CODE

    outs = suite_out_dirs(suites, Path(out_dir))
    records = [read_results(o / "results.csv") for o in outs]
    picked = [pick_rows(s.rows, rec, k) for s, rec in zip(suites, records)]
    tasks = {}
    for rows in picked:
        for r in rows:
            tasks.setdefault(r.run_id(), (r, r.points_key(), r.train_key() if r.train is not None else None))
    print(f"verify: {sum(map(len, picked))} committed rows, {len(tasks)} distinct runs to recompute", flush=True)
    results: dict[str, dict] = {}
    env, t0 = environment(), time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="panorecon-verify-") as tmp:
        cache = StageCache(cache_dir or tmp)
        fn = functools.partial(_row_task, device=device, threads=threads or max(1, (os.cpu_count() or 1) // jobs))

        def done(task, result):
            row = task[0]
            pts, tr = result["points"], result["train"]
            results[row.run_id()] = result_row(row, pts, tr, env, pts["cached"], bool(tr and tr.get("cached")))
            print(f"verify: {row.scene} seed {row.seed} {row.label!r} recomputed", flush=True)

        _run_tasks(fn, list(tasks.values()), str(cache.root), jobs, "local", None, False, done)
    seconds = time.perf_counter() - t0
    code, commit = code_digest(TRAIN_CODE), git_commit()
    texts = []
    for suite, rows, rec, o in zip(suites, picked, records, outs):
        text = _markdown(suite, rows, rec, results, code, commit, seconds, threads, len(tasks), jobs)
        with atomic_write(o / "verify.md") as tmp_path:
            Path(tmp_path).write_text(text)
        texts.append(text)
    return texts


def _markdown(suite, rows, records, results, code, commit, seconds, threads, runs, jobs) -> str:
    lines = [
        f"# Verify: {suite.title}",
        "",
        f"{len(rows)} committed rows of `{suite.path or suite.name}` recomputed on code {code} (commit {commit}), "
        f"{threads or 'cores // jobs'} torch thread(s) a run; the check's runs took {seconds:.0f} s of wall time "
        f"together ({runs} distinct runs over every suite verified with it, {jobs} at a time). "
        f"Verdicts: `panorecon/evaluation/verify.py`.",
        "",
        "| row | scene | seed | committed by | metric | committed | recomputed | Δ | seed SD | verdict |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    tally: dict[str, int] = {}
    for r in rows:
        committed = records[r.run_id()]
        by = f"{committed.get('code')} ({str(committed.get('commit'))[:10]})"
        for c in compare(r, committed, results.get(r.run_id(), {}), records):
            tally[c["verdict"]] = tally.get(c["verdict"], 0) + 1
            lines.append(
                f"| {r.label} | {r.scene} | {r.seed} | {by} | {c['metric']} | {c['committed']:.6g} | "
                f"{c['recomputed']:.6g} | {c['difference']:+.4g} | {c['seed_sd']:.3g} | {c['verdict']} |"
            )
    lines += ["", "Verdicts: " + ", ".join(f"{v} {n}" for v, n in sorted(tally.items())), ""]
    return "\n".join(lines)
