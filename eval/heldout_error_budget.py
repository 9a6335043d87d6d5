"""Where a trained run's held-out error sits: per held-out view, the share of the squared error in holes (pixels
whose rendered alpha is below 0.9: what the centre never saw and nothing covers) and in pixels whose rendered
depth is more than 5 % off the true depth (geometry, mostly at depth edges), and the mean PSNR with either
share removed. Prints one JSON object.

    python eval/heldout_error_budget.py RUN_DIR --scene bedroom --width 512

RUN_DIR is a ``panorecon train`` output folder (metrics.json and point_cloud.ply); the held-out views are rebuilt
from its config (count, resolution, field of view, seed) and placed in the cloud's frame by its heldout_scale,
as the trainer placed them.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def main(argv=None) -> dict:
    import torch

    from panorecon.scenes import load_scene
    from panorecon.splat.evaluate import _render
    from panorecon.splat.initial import sky_environment, view_background
    from panorecon.splat.labels import in_cloud_frame, make_heldout_views
    from panorecon.splat.ply import load_ply
    from panorecon.splat.trainer import TrainConfig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--scene", required=True)
    ap.add_argument("--width", type=int, required=True)
    args = ap.parse_args(argv)
    metrics = json.loads((args.run / "metrics.json").read_text())
    c = metrics["config"]
    cfg = TrainConfig(res=c["res"], fov_deg=c["fov_deg"], backend="cpu")
    scene = load_scene(args.scene, args.width)
    views = [
        in_cloud_frame(v, metrics["heldout_scale"])
        for v in make_heldout_views(scene, c["heldout"], c["res"], c["fov_deg"], c["seed"])
    ]
    env = sky_environment(scene) if c["sky"] == "panorama" else None
    model = load_ply(args.run / "point_cloud.ply")
    rows = []
    for v in views:
        v.background = view_background(env, v.camera)
        with torch.no_grad():
            img, alpha, depth, _ = _render(model, [v], cfg, model.sh_degree, "cpu")
        a = alpha[0, ..., 0].numpy()
        z = depth[0, ..., 0].numpy() / np.maximum(a, 1e-6)
        se = ((img[0].clamp(0, 1).numpy().astype(np.float64) - v.rgb) ** 2).mean(-1)  # float64 sums
        hole = a < 0.9
        with np.errstate(invalid="ignore", divide="ignore"):
            off = ~hole & (np.abs(z - v.depth) > 0.05 * v.depth)  # sky (inf truth) is never "off"
        rows.append(
            {
                "psnr": float(10 * np.log10(1 / se.mean())),
                "hole_pixels": float(hole.mean()),
                "hole_error_share": float(se[hole].sum() / se.sum()),
                "depth_off_pixels": float(off.mean()),
                "depth_off_error_share": float(se[off].sum() / se.sum()),
                "_mse": (float(se.mean()), float(se[hole].sum() / se.size), float(se[off].sum() / se.size)),
            }
        )
    mse = np.array([r.pop("_mse") for r in rows])
    out = {
        "run": str(args.run),
        "views": rows,
        "psnr": float(np.mean([r["psnr"] for r in rows])),
        "hole_error_share": float(mse[:, 1].sum() / mse[:, 0].sum()),
        "depth_off_error_share": float(mse[:, 2].sum() / mse[:, 0].sum()),
        "psnr_without_hole_error": float(np.mean(10 * np.log10(1 / (mse[:, 0] - mse[:, 1])))),
        "psnr_without_depth_off_error": float(np.mean(10 * np.log10(1 / (mse[:, 0] - mse[:, 2])))),
    }
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
