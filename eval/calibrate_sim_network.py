"""Calibrate ``sim:network``'s content and framing errors on the learned teacher learned-w16.

    python eval/calibrate_sim_network.py [--json out.json]   # from the repository root

Measures each (gamma, kappa, rho) of a grid (``teachers/sim.py``: compression to the view's median, luminance
copied into depth, bend with the framing) the way ``eval/teacher_errors.py`` measures a teacher (its ``measure``:
the 20 Fibonacci views at width 512, their border-turned and 60-degree twins), on the six families the learned
teachers were trained on, and compares three of its means with learned-w16's in
``benchmarks/teachers/teacher_errors.json``: per-view AbsRel, cross-view disagreement and centre-vs-border
disagreement. The choice is the grid point with the least sum of squared relative differences; the script says
whether ``teachers/sim.py``'s shipped ``NETWORK`` is that choice. Prints JSON; float64 statistics. Resumes: grid
points already in ``--json`` are read back, not measured again.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import sys
import time
from pathlib import Path

import numpy as np
from teacher_errors import measure, measurement_views, view_truths

from panorecon.io import atomic_write, json_text
from panorecon.learned.train import DepthTrainConfig
from panorecon.scenes import load_scene
from panorecon.teachers.sim import NETWORK, PROFILES, SimTeacher

TARGET_TEACHER = "onnx:panorecon/teachers/weights/learned-w16.onnx"
MATCHED = ("abs_rel", "cross_view", "centre_vs_border")
GRID = {"compress": (0.8, 0.9, 0.95), "texture": (0.05, 0.15, 0.3), "bend": (0.05, 0.15)}
ROOT = Path(__file__).resolve().parent.parent


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--errors", type=Path, default=ROOT / "benchmarks/teachers/teacher_errors.json")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    target = json.loads(args.errors.read_text())["summary"][TARGET_TEACHER]["seen"]
    _, _, cams, border, narrow, half = measurement_views(args.width, 20)
    scenes = []
    for name in DepthTrainConfig().families:
        scene = load_scene(name, args.width)
        scenes.append((scene, view_truths(scene, [*cams, *border, *narrow])))
    done = {}
    if args.json and args.json.is_file():
        done = {(r["compress"], r["texture"], r["bend"]): r for r in json.loads(args.json.read_text())["grid"]}
    rows = []
    for gamma, kappa, rho in itertools.product(*GRID.values()):
        if (gamma, kappa, rho) in done:
            rows.append(done[(gamma, kappa, rho)])
            continue
        profile = dataclasses.replace(PROFILES["network"], compress=gamma, texture=kappa, bend=rho)
        teacher = SimTeacher(profile, 0)
        per_scene = [measure(teacher, s, cams, border, narrow, truths, half) for s, truths in scenes]
        means = {m: float(np.mean([r[m] for r in per_scene])) for m in MATCHED}
        loss = float(sum(((means[m] - target[m]) / target[m]) ** 2 for m in MATCHED))
        rows.append({"compress": gamma, "texture": kappa, "bend": rho, **means, "loss": loss})
        print(json.dumps(rows[-1]), file=sys.stderr, flush=True)
    best = min(rows, key=lambda r: r["loss"])
    choice = (best["compress"], best["texture"], best["bend"])
    out = {
        "target": {"teacher": TARGET_TEACHER, "families": "seen", **{m: target[m] for m in MATCHED}},
        "grid": rows,
        "choice": dict(zip(GRID, choice)),
        "shipped": dict(zip(GRID, NETWORK)),
        "shipped_is_choice": tuple(NETWORK) == choice,
        "seconds": round(time.perf_counter() - t0, 1),
    }
    text = json_text(out)
    print(text)
    if args.json:
        with atomic_write(args.json) as tmp:
            Path(tmp).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
