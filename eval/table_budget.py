"""The five tables' predicted cost from the budget pilot, to choose their settings.

    python eval/table_budget.py benchmarks/tables/pilot [--suites eval/suites/table{2,4,5,6,7}.toml] [--jobs 2]

Reads the pilot's two results.csv (``pilot/``: the reference configuration at candidate settings, evaluated in
full at several step counts; ``pilot_points/``: every Table 2 source's point-cloud stage) and the suites, and
prints JSON: per candidate setting (panorama width, label size, label count; at each evaluated step count) the
CPU seconds of one run, and the five tables' total over their distinct runs (a run the tables share counts
once) in CPU hours and in hours of wall time with ``--jobs`` one-thread workers on an otherwise idle machine.

Cost model (stated, not measured per row): a run costs its source's point-cloud CPU seconds at the suite's width
(pilot_points, mean over the pilot's scenes; a layout source with another view count scaled by views / its
pilot views) plus the training CPU seconds of the reference configuration at the row's label count (linear
between the pilot's label counts), scaled to a shorter step count by the training seconds measured at that
step. CPU seconds are process CPU time (user + system) at one thread: what a run costs alone, whatever else ran.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import pandas as pd


def _points_cpu(points: pd.DataFrame) -> dict[str, float]:
    """source -> mean CPU seconds of its point-cloud stage over the pilot's scenes (n/a sources: NaN)."""
    col = "cpu_points" if "cpu_points" in points else "sec_points"
    return {s: float(pd.to_numeric(g[col], errors="coerce").mean()) for s, g in points.groupby("source")}


def _train_cpu(pilot: pd.DataFrame, width: int, res: int) -> dict[tuple[int, int], float]:
    """(labels, step) -> mean training CPU seconds (labels, teacher depth, steps to ``step``) at one width and
    label size: the run's training CPU seconds times the share of its training seconds spent by ``step``."""
    rows = pilot[(pilot["width"] == width) & (pilot["res"] == res)]
    out: dict[tuple[int, int], float] = {}
    for labels, g in rows.groupby("labels"):
        steps = sorted({int(c.split("@")[1]) for c in g.columns if c.startswith("sec_train@") and g[c].notna().all()})
        for step in steps:
            share = g[f"sec_train@{step}"] / g["sec_train"]
            out[int(labels), step] = float((g["cpu_train"] * share).mean())
    return out


def _interp(table: dict[tuple[int, int], float], labels: int, step: int) -> float:
    have = sorted(lab for lab, s in table if s == step)
    if not have:
        return math.nan
    return float(np.interp(labels, have, [table[lab, step] for lab in have]))


def predict(pilot_dir: Path, suites: list[Path], jobs: int) -> dict:
    from panorecon.evaluation.suite import load_suite

    pilot = pd.read_csv(pilot_dir / "pilot" / "results.csv")
    points = pd.read_csv(pilot_dir / "pilot_points" / "results.csv")
    pts = _points_cpu(points)
    pilot_views = {s: float(g["views"].mean()) for s, g in points.groupby("source") if g["views"].notna().any()}
    rows = {}
    for path in suites:
        for r in load_suite(path).rows:
            rows.setdefault(r.run_id(), r)
    candidates = []
    for (width, res), _ in pilot.groupby(["width", "res"]):
        train = _train_cpu(pilot, int(width), int(res))
        for step in sorted({s for _, s in train}):
            total, unavailable = 0.0, 0
            for r in rows.values():
                p = pts.get(r.source, math.nan)
                if math.isnan(p):
                    unavailable += 1  # n/a here (e.g. colmap-mvs without CUDA): costs nothing
                    continue
                if r.views and r.source in pilot_views:
                    p *= r.views / pilot_views[r.source]
                labels = (r.train or {}).get("labels", 240)
                total += p * (width / 512) ** 2 + _interp(train, labels, step)
            candidates.append(
                {
                    "width": int(width),
                    "res": int(res),
                    "iters": step,
                    "cpu_s_reference_run_240_labels": round(_interp(train, 240, step), 1),
                    "distinct_runs": len(rows) - unavailable,
                    "cpu_hours": round(total / 3600, 2),
                    f"wall_hours_jobs_{jobs}": round(total / 3600 / jobs, 2),
                }
            )
    return {
        "suites": [str(p) for p in suites],
        "jobs": jobs,
        "points_cpu_s_at_512": {k: round(v, 2) for k, v in pts.items()},
        "candidates": candidates,
        "note": "points cost scaled by (width / 512)^2 for other widths (the pilot's points stage ran at 512 px)",
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("pilot", type=Path, help="the pilot's --out folder (pilot/ and pilot_points/ inside)")
    ap.add_argument(
        "--suites", nargs="+", type=Path, default=[Path(f"eval/suites/table{n}.toml") for n in (2, 4, 5, 6, 7)]
    )
    ap.add_argument("--jobs", type=int, default=2, help="one-thread workers the tables run with")
    args = ap.parse_args(argv)
    print(json.dumps(predict(args.pilot, args.suites, args.jobs), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
