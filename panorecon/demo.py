"""The demo's pictures at a size a person can look at: held-out renders at 256 px beside the truth, and the
trained Gaussians rendered back to a full panorama under the input (``panorecon demo``)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from .io import write_image


def demo_pictures(
    scene, out, backend: str = "auto", size: int = 256, views: int = 3, fov_deg: float = 60.0, seed: int = 0
) -> dict:
    """From OUT/point_cloud.ply: OUT/renders/heldout_{size}_k.png (render | truth, ``size`` px tall; the first
    ``views`` held-out poses of a training run with this ``seed``) on scenes with a world, and
    OUT/panorama.png (input above, render from the centre below, 8 bits). Returns that picture's PSNR and
    WS-PSNR (dB) and WS-SSIM: panorama_psnr, panorama_ws_psnr, panorama_ws_ssim."""
    import json

    from .metrics.panorama import panorama_scores
    from .splat.labels import in_cloud_frame, make_heldout_views
    from .splat.panorama import render_panorama
    from .splat.ply import load_ply
    from .splat.rasterize import rasterize

    out = Path(out)
    model = load_ply(out / "point_cloud.ply")
    scale = json.loads((out / "metrics.json").read_text()).get("heldout_scale", 1.0)  # as the trainer placed them
    if scene.world is not None:
        for k, v in enumerate(make_heldout_views(scene, views, size, fov_deg, seed)):
            v = in_cloud_frame(v, scale)
            V = torch.tensor(v.camera.viewmat[None], dtype=torch.float32)
            K = torch.tensor(v.camera.K[None], dtype=torch.float32)
            with torch.no_grad():
                img = (
                    rasterize(
                        model.means,
                        model.quats,
                        model.scales(),
                        model.opacities(),
                        model.sh(),
                        V,
                        K,
                        size,
                        size,
                        sh_degree=model.sh_degree,
                        near_plane=model.near_plane,
                        backend=backend,
                    )[0][0]
                    .clamp(0, 1)
                    .numpy()
                )
            write_image(
                out / "renders" / f"heldout_{size}_{k}.png",
                (np.concatenate([img, v.rgb], 1) * 255).round().astype(np.uint8),
            )
    pano = (render_panorama(model, scene.height, backend=backend) * 255).round().astype(np.uint8)
    write_image(out / "panorama.png", np.concatenate([scene.rgb.astype(np.uint8), pano], 0))
    # the PSNR of the picture as written (8 bits), so that anyone can recompute it from panorama.png; beside it
    # WS-PSNR and WS-SSIM, each ERP pixel weighted by its solid angle (metrics/panorama.py)
    mse = float(np.mean((pano.astype(np.float64) / 255 - scene.rgb.astype(np.float64) / 255) ** 2))
    ws = panorama_scores(pano.astype(np.float64) / 255, scene.rgb.astype(np.float64) / 255)
    return {
        "panorama_psnr": math.inf if mse == 0 else 10 * math.log10(1 / mse),
        "panorama_ws_psnr": ws["ws_psnr"],
        "panorama_ws_ssim": ws["ws_ssim"],
    }


def run_demo(cfg) -> int:
    """``panorecon demo`` (a ``configs.DemoConfig``): the main job on the built-in default scene: render,
    ground-truth cloud and its screenshot, the method's initial cloud (40 Fibonacci views, the teacher, log-depth
    fusion) with its report, a short Gaussian training from it (point_cloud.ply, renders/, metrics.json), held-out
    renders at 256 px and the panorama rendered back from the Gaussians (panorama.png). Its settings are explicit
    here, not train's defaults."""
    import dataclasses
    import json
    import time

    from . import commands
    from . import configs as K
    from .geometry import PointCloud
    from .scenes import DEFAULT_SCENE
    from .splat.evaluate import heldout_summary

    t0 = time.perf_counter()
    out = Path(cfg.out)
    scene = dataclasses.replace(cfg.scene, scene=cfg.scene.scene or DEFAULT_SCENE)
    scene.load(64)  # everything the steps below need, checked before the first of them writes a byte
    commands.claim(out, "demo", {**scene.identity(), "teacher": cfg.teacher}, K.DEMO_WRITES, cfg.overwrite)
    commands.render(K.RenderConfig(scene=scene, out=str(out), heldout=0), claimed=True)
    commands.gt_cloud(K.GtCloudConfig(scene=scene, out=str(out / "gt_cloud.ply")))
    gt = PointCloud.load_ply(out / "gt_cloud.ply")
    outdoor = bool(np.isinf(np.load(out / "distance.npy")).any()) if (out / "distance.npy").exists() else True
    # indoor scenes (no sky) are shown from above with the ceiling cut away
    clip_z = None if outdoor else float(0.5 * gt.xyz[:, 2].max())
    for name in ("gt", "fibonacci"):
        if name == "fibonacci":
            train = K.TrainConfig(iters=cfg.iters, res=cfg.res, labels=120, heldout=8)
            src = K.SourceArgs(source="fibonacci", teacher=cfg.teacher)
            commands.train(K.TrainCommandConfig(scene=scene, source=src, train=train, out=str(out)), claimed=True)
        cloud, shot = out / f"{name}_cloud.ply", str(out / f"{name}_cloud.png")
        commands.inspect_cloud(K.InspectConfig(cloud=str(cloud), screenshot=shot, point_size=2.0, clip_z=clip_z))
    p = demo_pictures(scene.load(), out)
    held = json.loads((out / "metrics.json").read_text())["held-out"]
    print(
        f"panorama rendered back from the Gaussians: PSNR {p['panorama_psnr']:.2f} dB against the input -> "
        f"{out / 'panorama.png'}; {heldout_summary(held)}; held-out renders at 256 px -> {out / 'renders'}; demo "
        f"took {time.perf_counter() - t0:.0f} s"
    )
    return 0
