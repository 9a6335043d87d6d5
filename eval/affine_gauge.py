"""The affine views' two gauges side by side: fused depth error per scene and teacher (``fusion/affine.py``).

    python eval/affine_gauge.py [--width 512] [--json out.json] [--md out.md]   # from the repository root

Every affine-invariant teacher (``sim:affine-disparity``, seed 0, and each learned model shipped in
``panorecon/teachers/weights`` through ``onnx:``) on the eight table scenes, Fibonacci 20 views, fused with the
``mean-shift`` gauge (the teacher's shifts average to zero) and the ``reference`` gauge (the reference view's
shift that the others' overlaps fit best). Measures: the fused ERP distance's AbsRel and delta1 after median
(scale) alignment, the metric of Tables 2-7's points stage, and its AbsRel after scale-and-shift alignment in
inverse distance (``depth_inverse_affine``: what no gauge can fix). Prints JSON, then a markdown table of
means over the scenes; float64 statistics.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

import numpy as np

from panorecon.fusion import FusionOptions
from panorecon.fusion.affine import GAUGES
from panorecon.io import atomic_write, json_text
from panorecon.scenes import load_scene
from panorecon.scenes.catalog import SYNTHETIC_SCENES
from panorecon.sources import run_source
from panorecon.teachers import shipped_models


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--md", type=Path)
    args = ap.parse_args(argv)
    teachers = ["sim:affine-disparity"] + [f"onnx:{os.path.relpath(p)}" for p in shipped_models()]
    rows = []
    for name in SYNTHETIC_SCENES:
        scene = load_scene(name, width=args.width)
        for teacher in teachers:
            for gauge in GAUGES:
                config = FusionOptions(affine_gauge=gauge).config()
                _, rep = run_source(scene, "fibonacci", teacher, fusion_config=config)
                row = {
                    "scene": name,
                    "teacher": teacher,
                    "gauge": gauge,
                    "abs_rel": rep["depth"]["abs_rel"],
                    "delta1": rep["depth"]["delta1"],
                    "abs_rel_inverse_affine": rep["depth_inverse_affine"]["abs_rel"],
                    "teacher_per_view_abs_rel_median": rep["teacher_per_view_abs_rel_median"],
                }
                rows.append(row)
                print(json.dumps(row), file=sys.stderr, flush=True)
    out = {"width": args.width, "views": 20, "source": "fibonacci", "rows": rows}
    text = json_text(out)
    print(text)
    md = _markdown(rows)
    print(md)
    for path, body in ((args.json, text), (args.md, md)):
        if path:
            with atomic_write(path) as tmp:
                Path(tmp).write_text(body)
    return 0


def _markdown(rows: list[dict]) -> str:
    lines = [
        "| teacher | gauge | fused AbsRel | fused δ1 | AbsRel after inverse-affine alignment | worst scene AbsRel |",
        "|---|---|---|---|---|---|",
    ]
    for teacher in dict.fromkeys(r["teacher"] for r in rows):
        for gauge in GAUGES:
            sel = [r for r in rows if r["teacher"] == teacher and r["gauge"] == gauge]
            worst = max(sel, key=lambda r: r["abs_rel"])
            lines.append(
                f"| `{teacher}` | {gauge} | {np.mean([r['abs_rel'] for r in sel]):.3f} | "
                f"{np.mean([r['delta1'] for r in sel]):.3f} | "
                f"{np.mean([r['abs_rel_inverse_affine'] for r in sel]):.3f} | "
                f"{worst['abs_rel']:.3f} ({worst['scene']}) |"
            )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
