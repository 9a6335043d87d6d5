"""The learned teachers on the real panoramas of ../shared/data/real, beside HoHoNet's own prediction.

    python eval/real_teachers.py [--width 512] [--json out.json] [--md out.md] [--images DIR]   # from the repo root

Scenes: ``hohonet`` (a real indoor photograph with HoHoNet's predicted distance: a panoramic network's output, not
the truth) and ``py360-demo`` (no depth at all). Each teacher's views (Fibonacci 20, the ``points`` default) are
fused by the method's fusion, exactly as ``panorecon points SCENE --source fibonacci --teacher T`` does; the
teachers: both learned models (``onnx:``), HoHoNet's prediction itself as a ``file:`` teacher (what the views
and the fusion keep of a depth map that needs no alignment), and ``sim:relative`` applied to HoHoNet's prediction
as if it were the truth (the simulator's cloud beside the networks').

Agreement with HoHoNet's prediction over every pixel both have: AbsRel and delta1 after median (scale) alignment,
and AbsRel after scale-and-shift alignment in inverse distance. On ``py360-demo``, which has no depth, the two
learned teachers are compared with each other the same way. No real panorama with true depth ships here, so the
AbsRel against truth is ``n/a`` (``--depth`` and the dataset adapters ``structured3d:``, ``stanford2d3d:``,
``matterport3d:`` take one: docs/guide.md). With ``--images``: the fused distance maps side by side and each
cloud seen from above (pyvista, off screen). Float64 statistics.
"""

from __future__ import annotations

import argparse
import copy
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from panorecon.io import atomic_write, json_text
from panorecon.metrics import depth_metrics
from panorecon.scenes import load_scene
from panorecon.sources import run_source
from panorecon.teachers import shipped_models

HOHONET_FILE = "file:../shared/data/real/hohonet_pano.pred_depth_mm.png?scale=0.001&metric=1"
SIM_ON_HOHONET = "sim:relative"
LEARNED = ("learned-w16", "learned-w8")


def _agreement(pred: np.ndarray, ref: np.ndarray) -> dict:
    med = depth_metrics(pred, ref, "median")
    inv = depth_metrics(pred, ref, "inverse-affine")
    return {
        "abs_rel": med["abs_rel"],
        "delta1": med["delta1"],
        "abs_rel_inverse_affine": inv["abs_rel"],
        "pixels": med["pixels"],
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--md", type=Path)
    ap.add_argument("--images", type=Path, help="folder for the pictures (distance maps, clouds)")
    args = ap.parse_args(argv)
    models = {p.stem: f"onnx:{os.path.relpath(p)}" for p in shipped_models()}
    learned = {name: models[name] for name in LEARNED}
    rows, fused, clouds = [], {}, {}

    hoho = load_scene("hohonet", width=args.width)
    as_truth = copy.copy(hoho)
    as_truth.distance_kind = "truth"  # only for sim:, which passes a truth through its error model
    runs = [(hoho, label, spec) for label, spec in learned.items()]
    runs += [(hoho, "HoHoNet (file:)", HOHONET_FILE), (as_truth, "sim:relative on HoHoNet's depth", SIM_ON_HOHONET)]
    demo = load_scene("py360-demo", width=args.width)
    runs += [(demo, label, spec) for label, spec in learned.items()]
    for scene, label, spec in runs:
        pc, rep = run_source(scene, "fibonacci", spec)
        distance = pc.meta["erp_distance"]
        fused[(scene.name, label)], clouds[(scene.name, label)] = distance, pc
        row = {"scene": scene.name, "teacher": label, "spec": spec, "points": len(pc), "seconds": rep["seconds"]}
        if scene.name == "hohonet":
            row["vs_hohonet"] = _agreement(distance, hoho.distance)
        row["abs_rel_vs_truth"] = "n/a: no real panorama with true depth ships in ../shared/data/real"
        rows.append(row)
        print(json.dumps({k: v for k, v in row.items() if k != "seconds"}), file=sys.stderr, flush=True)
    w16, w8 = (fused[("py360-demo", name)] for name in LEARNED)
    between = {"scene": "py360-demo", "pair": "learned-w8 against learned-w16", **_agreement(w8, w16)}
    out = {"width": args.width, "source": "fibonacci", "views": 20, "rows": rows, "learned_between": between}
    text = json_text(out)
    print(text)
    md = _markdown(rows, between)
    print(md)
    for path, body in ((args.json, text), (args.md, md)):
        if path:
            with atomic_write(path) as tmp:
                Path(tmp).write_text(body)
    if args.images:
        _pictures(args.images, hoho, demo, fused, clouds)
    return 0


def _markdown(rows: list[dict], between: dict) -> str:
    lines = [
        "| panorama | teacher | against | AbsRel (scale) | δ1 | AbsRel (inverse affine) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        if "vs_hohonet" in r:
            a = r["vs_hohonet"]
            lines.append(
                f"| {r['scene']} | {r['teacher']} | HoHoNet's prediction | {a['abs_rel']:.3f} | {a['delta1']:.3f} | "
                f"{a['abs_rel_inverse_affine']:.3f} |"
            )
    lines.append(
        f"| py360-demo | learned-w8 | learned-w16 | {between['abs_rel']:.3f} | {between['delta1']:.3f} | "
        f"{between['abs_rel_inverse_affine']:.3f} |"
    )
    return "\n".join(lines) + "\n"


def _pictures(folder: Path, hoho, demo, fused: dict, clouds: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from panorecon.viz import screenshot

    folder.mkdir(parents=True, exist_ok=True)
    panels = [
        (hoho, "hohonet: HoHoNet's prediction", hoho.distance),
        *[(hoho, f"hohonet: {name}", fused[("hohonet", name)]) for name in LEARNED],
        (demo, "py360-demo: panorama", None),
        *[(demo, f"py360-demo: {name}", fused[("py360-demo", name)]) for name in LEARNED],
    ]
    fig, axes = plt.subplots(2, 3, figsize=(15, 5.2))
    for ax, (scene, title, d) in zip(axes.ravel(), panels):
        if d is None:
            ax.imshow(scene.rgb)
        else:
            ax.imshow(np.log(d / np.nanmedian(d)), cmap="turbo", vmin=-1.2, vmax=1.2)
        ax.set_title(title + ("" if d is None else " (log distance / median)"), fontsize=9)
        ax.axis("off")
    fig.tight_layout()
    with atomic_write(folder / "real_teachers_depth.jpg", suffix=".jpg") as tmp:
        fig.savefig(tmp, dpi=80)
    plt.close(fig)
    shots = [(f"{scene} / {label}", pc) for (scene, label), pc in clouds.items() if not label.startswith("sim")]
    fig, axes = plt.subplots(2, 3, figsize=(15, 6.6))
    with tempfile.TemporaryDirectory() as tmpdir:
        for ax, (title, pc) in zip(axes.ravel(), shots):
            ax.imshow(plt.imread(screenshot(pc, Path(tmpdir) / "cloud.png", window_size=(640, 400), clip_z=0.5)))
            ax.set_title(title + " (seen from above, ceiling cut)", fontsize=9)
    for ax in axes.ravel():
        ax.axis("off")
    fig.tight_layout()
    with atomic_write(folder / "real_teachers_clouds.jpg", suffix=".jpg") as tmp:
        fig.savefig(tmp, dpi=70)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
