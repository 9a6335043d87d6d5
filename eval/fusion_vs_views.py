"""Does the fusion really fuse? Fused AbsRel against the median per-view AbsRel of the same simulated teacher,
per synthetic scene and averaged (issue #3's target: <= 0.7 on average).

    python eval/fusion_vs_views.py [--teachers sim:relative,sim:clean] [--source fibonacci] [--width 512]
                                   [--border-px 4] [--out ratios.json]

Per scene: fused AbsRel (median-aligned; for affine teachers also after scale + shift alignment in inverse
distance), the teacher's median per-view AbsRel (per view median-aligned, or for affine views fitted to the
truth by scale and shift: an oracle) and their ratio. Prints one line per scene and JSON at the end.
"""

from __future__ import annotations

import argparse

import numpy as np

from panorecon.evaluation.environment import emit, environment
from panorecon.fusion import FusionConfig
from panorecon.scenes import list_scenes, load_scene
from panorecon.sources import run_source


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--teachers", default="sim:relative,sim:affine-disparity,sim:clean")
    ap.add_argument("--scenes", default=",".join(s.name for s in list_scenes() if s.kind == "synthetic"))
    ap.add_argument("--source", default="fibonacci")
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--border-px", type=int, default=FusionConfig.border_px)
    ap.add_argument("--out", default=None)
    args = ap.parse_args(argv)
    cfg = FusionConfig(border_px=args.border_px)
    results = {}
    for teacher in args.teachers.split(","):
        rows = []
        for name in args.scenes.split(","):
            _, rep = run_source(load_scene(name, args.width), args.source, teacher, fusion_config=cfg)
            fused, per_view = rep["depth"]["abs_rel"], rep["teacher_per_view_abs_rel_median"]
            row = {"scene": name, "fused_abs_rel": fused, "per_view_abs_rel": per_view, "ratio": fused / per_view}
            if "depth_inverse_affine" in rep:
                row["fused_abs_rel_inverse_affine"] = rep["depth_inverse_affine"]["abs_rel"]
                row["ratio_inverse_affine"] = row["fused_abs_rel_inverse_affine"] / per_view
            rows.append(row)
            print(
                f"{teacher:22s} {name:16s} fused {fused:.4f}  per-view {per_view:.4f}  ratio {row['ratio']:.3f}",
                flush=True,
            )
        summary = {"mean_ratio": float(np.mean([r["ratio"] for r in rows])), "scenes": rows}
        if rows and "ratio_inverse_affine" in rows[0]:
            summary["mean_ratio_inverse_affine"] = float(np.mean([r["ratio_inverse_affine"] for r in rows]))
        results[teacher] = summary
    return emit(
        {
            "benchmark": "fused vs per-view AbsRel",
            **environment(),
            "source": args.source,
            "width": args.width,
            "border_px": args.border_px,
            "results": results,
        },
        args.out,
    )


if __name__ == "__main__":
    main()
