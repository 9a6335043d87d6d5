"""How `points` scales with the panorama's size: seconds and peak memory per stage, one fresh process per width.

    python eval/fusion_scaling.py [--widths 1024,2048,4096,8192] [--reference-widths 1024,2048]
                                  [--scene bedroom] [--teacher sim:relative] [--out benchmarks/fusion_scaling.json]
                                  [--plot docs/images/fusion_scaling.png]

Per width: the stages of `panorecon points SCENE --source fibonacci --teacher T --width W` (scene render, views,
teacher, fusion, back-projection, metrics, then the PLY written to a temporary folder), each with its seconds and
the process's peak RSS while it ran (RSS sampled every 10 ms), plus the report's levels solved and skipped, AbsRel,
AbsRel near true depth edges and Chamfer. ``--reference-widths`` also runs the full solve (``FusionConfig(
resolution='full')``, every level up to the panorama's) in the same run: the ratios of seconds, peak memory and
errors against it are the comparison. Prints JSON (machine, versions, commit, load average) and draws seconds and
MB against pixels, log-log.
"""

from __future__ import annotations

import argparse
import os
import tempfile
import threading
import time
from pathlib import Path

STAGES = ("views", "teacher", "fusion", "points", "metrics")


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def one_width(scene_name: str, teacher: str, width: int, resolution: str) -> dict:
    """The stages of `points` at one width in this process -> {stage: {seconds, peak_mb}}, errors, fusion levels."""
    from panorecon.fusion import FusionConfig
    from panorecon.scenes import load_scene
    from panorecon.sources import run_source

    samples: list[tuple[float, float]] = []
    stop = threading.Event()

    def sample():
        while not stop.is_set():
            samples.append((time.perf_counter(), _rss_mb()))
            time.sleep(0.01)

    thread = threading.Thread(target=sample, daemon=True)
    thread.start()
    marks = [("start", time.perf_counter())]
    scene = load_scene(scene_name, width)
    marks.append(("scene", time.perf_counter()))
    pc, report = run_source(scene, "fibonacci", teacher, None, FusionConfig(resolution=resolution))
    t = marks[-1][1]
    for stage in STAGES:  # run_source's stages run in this order; its seconds place them on the timeline
        t += report["seconds"].get(stage, 0.0)
        marks.append((stage, t))
    with tempfile.TemporaryDirectory() as tmp:
        pc.save_ply(Path(tmp) / "cloud.ply")
        marks.append(("ply", time.perf_counter()))
        ply_mb = (Path(tmp) / "cloud.ply").stat().st_size / 2**20
    stop.set()
    thread.join()
    stages = {}
    for (_, t0), (name, t1) in zip(marks, marks[1:]):
        inside = [mb for ts, mb in samples if t0 <= ts <= t1]
        stages[name] = {"seconds": round(t1 - t0, 3), "peak_mb": round(max(inside), 1) if inside else None}
    fusion = report["fusion"]
    return {
        "width": width,
        "pixels": width * width // 2,
        "resolution": resolution,
        "stages": stages,
        "total_seconds": round(marks[-1][1] - marks[0][1], 3),
        "report_total_seconds": round(report["seconds"]["total"], 3),
        "peak_mb": round(max(mb for _, mb in samples), 1),
        "levels_solved": fusion["resolution"]["solved"],
        "levels_skipped": fusion["resolution"]["skipped"],
        "upsample": {k: v for k, v in (fusion.get("upsample") or {}).items() if k != "seconds"} or None,
        "points": len(pc),
        "ply_mb": round(ply_mb, 1),
        "abs_rel": report["depth"]["abs_rel"],
        "edge_abs_rel": report["depth_edges"]["edge_abs_rel"],
        "chamfer_m": report["points"]["chamfer"],
    }


def plot(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for res, style in (("views", "o-"), ("full", "s--")):
        sel = sorted((r for r in rows if r["resolution"] == res), key=lambda r: r["pixels"])
        if not sel:
            continue
        px = [r["pixels"] for r in sel]
        label = "solve at the views' resolution" if res == "views" else "full solve (reference)"
        for stage, colour in (("fusion", "C0"), ("scene", "C2"), ("metrics", "C3")):
            axes[0].loglog(
                px, [r["stages"][stage]["seconds"] for r in sel], style, color=colour, label=f"{stage}, {label}"
            )
        axes[0].loglog(px, [r["report_total_seconds"] for r in sel], style, color="k", label=f"points total, {label}")
        axes[1].loglog(px, [r["peak_mb"] for r in sel], style, color="k", label=label)
        axes[1].loglog(
            px, [r["stages"]["fusion"]["peak_mb"] for r in sel], style, color="C0", label=f"during fusion, {label}"
        )
    axes[0].set(xlabel="panorama pixels", ylabel="seconds", title="time per stage")
    axes[1].set(xlabel="panorama pixels", ylabel="peak RSS (MB)", title="peak memory")
    for ax in axes:
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=6)
    fig.tight_layout()
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv=None) -> dict:
    from panorecon.evaluation.environment import emit, environment, in_fresh_process

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--widths", default="1024,2048,4096,8192")
    ap.add_argument("--reference-widths", default="1024,2048", help="widths also run with the full solve ('' none)")
    ap.add_argument("--scene", default="bedroom")
    ap.add_argument("--teacher", default="sim:relative")
    ap.add_argument("--out", default=None)
    ap.add_argument("--plot", default=None)
    args = ap.parse_args(argv)
    widths = [int(w) for w in args.widths.split(",") if w]
    refs = [int(w) for w in args.reference_widths.split(",") if w]
    rows = []
    for w in widths:
        for res in ("views",) + (("full",) if w in refs else ()):
            load = os.getloadavg()
            row = in_fresh_process(one_width, args.scene, args.teacher, w, res)
            row["load_average_before"] = [round(x, 2) for x in load]
            st = row["stages"]
            print(
                f"{w:6d} {res:5s}: points {row['report_total_seconds']:7.1f} s (scene {st['scene']['seconds']:.1f} s, "
                f"fusion {st['fusion']['seconds']:.1f} s), peak {row['peak_mb']:.0f} MB, AbsRel {row['abs_rel']:.4f}, "
                f"edge {row['edge_abs_rel']:.4f}, Chamfer {row['chamfer_m']:.4f} m, load {load[0]:.1f}",
                flush=True,
            )
            rows.append(row)
    ratios = []
    for r in rows:
        ref = next((x for x in rows if x["width"] == r["width"] and x["resolution"] == "full"), None)
        if r["resolution"] == "views" and ref is not None:
            ratios.append(
                {
                    "width": r["width"],
                    "fusion_seconds": r["stages"]["fusion"]["seconds"] / ref["stages"]["fusion"]["seconds"],
                    "points_seconds": r["report_total_seconds"] / ref["report_total_seconds"],
                    "peak_mb": r["peak_mb"] / ref["peak_mb"],
                    "abs_rel": r["abs_rel"] / ref["abs_rel"],
                    "edge_abs_rel": r["edge_abs_rel"] / ref["edge_abs_rel"],
                    "chamfer": r["chamfer_m"] / ref["chamfer_m"],
                }
            )
    if args.plot:
        plot(rows, args.plot)
    result = {
        "benchmark": "fusion_scaling",
        **environment(),
        "load_average_after": [round(x, 2) for x in os.getloadavg()],
        "scene": args.scene,
        "teacher": args.teacher,
        "rows": rows,
        "ratios_views_over_full": ratios,
    }
    return emit(result, args.out)


if __name__ == "__main__":
    main()
