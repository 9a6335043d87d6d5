"""Error against run time for point-cloud fusion: Fibonacci N in {12, 15, 20, 25, 40}, the other layouts,
and solver settings (pyramid depth, CG tolerance, sky-border width, warp sampling), on the synthetic scenes;
``moge-merge`` is MoGe's own merge (the baselines plug-in, the ``moge`` extra).

    python eval/sweep_fusion.py --out out/sweep [--scenes bedroom,beach] [--width 512] [--teacher sim:relative]

Writes sweep.csv (one row per scene x configuration; rows already there are skipped, so an interrupted
sweep resumes) and pareto.png (AbsRel against seconds: single runs and per-configuration means, Pareto front marked).
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from panorecon.evaluation.report import pareto_plot
from panorecon.fusion import FusionConfig
from panorecon.io import atomic_write
from panorecon.scenes import list_scenes, load_scene
from panorecon.sources import run_source

FIELDS = [
    "scene",
    "config",
    "source",
    "views",
    "levels",
    "tol",
    "border_px",
    "abs_rel",
    "teacher_per_view_abs_rel",
    "delta1",
    "chamfer",
    "seconds",
    "fusion_seconds",
    "peak_rss_mb",
]


def configurations():
    """-> (name, source, views, FusionConfig or None for the source's default)."""
    for n in (12, 15, 20, 25, 40):
        yield f"fibonacci-{n}", "fibonacci", n, FusionConfig(tol=1e-5)
    for src in ("icosahedral", "latlong", "cube", "moge-merge"):
        yield src, src, None, None
    for levels in (1, 2, 3):
        yield f"fibonacci-20-levels{levels}", "fibonacci", 20, FusionConfig(levels=levels, tol=1e-5)
    for tol in (1e-3, 1e-7):
        yield f"fibonacci-20-tol{tol:g}", "fibonacci", 20, FusionConfig(tol=tol)
    for border in (0, 2, 8):
        yield f"fibonacci-20-border{border}", "fibonacci", 20, FusionConfig(tol=1e-5, border_px=border)
    yield "fibonacci-20-nearest", "fibonacci", 20, FusionConfig(tol=1e-5, sampling="nearest")


def plot(rows, path: Path) -> None:
    """AbsRel against seconds: per-config means over scenes (Pareto front marked), single runs faint."""
    import pandas as pd

    df = pd.DataFrame(rows)
    df[["abs_rel", "seconds"]] = df[["abs_rel", "seconds"]].astype(float)
    mean = df.groupby("config")[["seconds", "abs_rel"]].mean()
    pareto_plot(
        mean,
        df,
        "seconds",
        "abs_rel",
        "AbsRel (median-aligned, mean over scenes)",
        path,
        title="fusion: error against run time",
        label_col="config",
    )


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True)
    ap.add_argument("--scenes", default=",".join(s.name for s in list_scenes() if s.kind == "synthetic"))
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--teacher", default="sim:relative")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "sweep.csv"
    rows = list(csv.DictReader(csv_path.open())) if csv_path.exists() else []
    done = {(r["scene"], r["config"]) for r in rows}
    for scene_name in args.scenes.split(","):
        scene = None
        for name, source, n, cfg in configurations():
            if (scene_name, name) in done:
                continue
            scene = scene or load_scene(scene_name, args.width)
            _, rep = run_source(scene, source, args.teacher, n, cfg)
            row = {
                "scene": scene_name,
                "config": name,
                "source": source,
                "views": rep["views"],
                "levels": (cfg.levels or "auto") if cfg else "",
                "tol": cfg.tol if cfg else "",
                "border_px": cfg.border_px if cfg else "",
                "abs_rel": rep["depth"]["abs_rel"],
                "teacher_per_view_abs_rel": rep.get("teacher_per_view_abs_rel_median", ""),
                "delta1": rep["depth"]["delta1"],
                "chamfer": rep["points"]["chamfer"],
                "seconds": rep["seconds"]["total"] - rep["seconds"]["metrics"],
                "fusion_seconds": rep["seconds"].get("fusion", 0.0),
                "peak_rss_mb": rep["peak_rss_mb"],
            }
            rows.append(row)
            with atomic_write(csv_path) as tmp, open(tmp, "w", newline="") as f:
                w = csv.DictWriter(f, FIELDS)
                w.writeheader()
                w.writerows(rows)
            print(f"{scene_name:16s} {name:28s} AbsRel {row['abs_rel']:.4f}  {row['seconds']:.2f} s", flush=True)
    plot(rows, out / "pareto.png")
    print(f"{len(rows)} rows -> {csv_path}, {out / 'pareto.png'}")


if __name__ == "__main__":
    main()
