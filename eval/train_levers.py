"""One trainer lever at a time on issue 19's setting: bedroom (or ``--scene``) at 512 wide, the fibonacci cloud
(``--views``, default ``train``'s 40) from ``sim:relative``, 240 pseudo-labels of 256², the ``cpu`` backend,
``train``'s defaults otherwise; any
``TrainConfig`` field changed by ``key=value``. Prints one JSON line (held-out PSNR, training seconds, Gaussians,
the best history sample and the history as (iteration, seconds, held-out PSNR)).

    python eval/train_levers.py OUT [key=value ...] [--threads N]
    python eval/train_levers.py out/ref10k iters=10000 init_pixels_per_point=0 --threads 1
    python eval/train_levers.py out/beach20 disocclusion_fill_visits=0 --views 20 --scene beach
    python eval/train_levers.py out/erp --teacher-views erp

``--threads`` is part of a run's identity: the compositor's backward (at least) sums per-thread gradient
buffers, so one and two threads round differently and follow different sample paths from the first steps (two
threads, torch's default here, follow ``panorecon train``'s: checked over 200 steps); the machine's load changes
no history. Compare levers at one thread count.

``--heldout-seed S`` draws the held-out views with seed S whatever ``seed=`` the training takes, so that training
seeds (label order, splits) are compared on the same views: the spread of one setting's plateau between paths.

``--teacher-views erp`` gives the simulated teacher its views' true distance sampled from the ERP (as for a
``panorecon render`` folder or a real panorama with ``--depth``) instead of rendered by the synthetic world.

The cloud is the one ``panorecon train`` would start from (``run_source`` with the same fusion settings);
held-out cameras are placed in the cloud's scale exactly as ``panorecon train`` places them.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json


class ErpTeacherWorld:
    """A synthetic scene's world that renders held-out views as before but refuses the teacher's views
    (``can_render``), so ``teachers.base.true_view_distance`` samples them from the scene's ERP distance."""

    def __init__(self, world):
        self.world = world

    def can_render(self, camera) -> bool:
        return False

    def __getattr__(self, name):
        return getattr(self.world, name)


@contextlib.contextmanager
def heldout_views_seeded(seed: int | None):
    """Within it, the trainer draws its held-out views with ``seed`` instead of the run's (None: unchanged)."""
    from panorecon.splat import trainer

    draw = trainer.make_heldout_views
    if seed is not None:
        trainer.make_heldout_views = lambda scene, n, size, fov, _seed: draw(scene, n, size, fov, seed)
    try:
        yield
    finally:
        trainer.make_heldout_views = draw


def main(argv=None) -> dict:
    import torch

    from panorecon.cli import TRAIN_VIEWS
    from panorecon.pipeline import teacher_depth_fn
    from panorecon.pipeline.stages import fusion_config_for
    from panorecon.scenes import load_scene
    from panorecon.sources import cloud_scale, run_source
    from panorecon.splat.trainer import TrainConfig, train

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out")
    ap.add_argument("overrides", nargs="*", help="TrainConfig field=value")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--teacher", default="sim:relative", help="depth teacher of the cloud and the depth term")
    ap.add_argument("--scene", default="bedroom", help="scene at 512 wide (issue 19's: bedroom)")
    ap.add_argument("--views", type=int, default=TRAIN_VIEWS["fibonacci"], help="views of the fibonacci source")
    ap.add_argument(
        "--depth-target",
        choices=("teacher", "fused"),
        default="teacher",
        help="the Pearson term's depth: the teacher's per-view maps or the fused cloud's ERP depth seen by each view",
    )
    ap.add_argument(
        "--teacher-views",
        choices=("render", "erp"),
        default="render",
        help="the simulated teacher's true view distance: rendered by the synthetic world, or sampled from the ERP",
    )
    ap.add_argument("--heldout-seed", type=int, default=None, help="seed of the held-out views (default: seed=)")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    types = {f.name: type(f.default) for f in dataclasses.fields(TrainConfig)}
    overrides = {}
    for item in args.overrides:
        key, _, value = item.partition("=")
        if key not in types:
            ap.error(f"{item!r}: {key!r} is not a TrainConfig field ({', '.join(types)})")
        overrides[key] = types[key](value)
    cfg = TrainConfig(**{"res": 256, "labels": 240, "backend": "cpu", **overrides})  # frozen: built once
    scene = load_scene(args.scene, 512)
    if args.teacher_views == "erp":
        scene = dataclasses.replace(scene, world=ErpTeacherWorld(scene.world))
    pc, report = run_source(scene, "fibonacci", args.teacher, args.views, fusion_config_for(torch.device("cpu")))
    if args.depth_target == "fused":
        from panorecon.geometry import erp_to_perspective

        erp = pc.meta["erp_distance"]
        depth_fn = lambda cams: [  # noqa: E731
            (erp_to_perspective(erp, c) / c.z_to_distance_factor()).astype("float32") for c in cams
        ]
    else:
        depth_fn = teacher_depth_fn(scene, args.teacher)
    with heldout_views_seeded(args.heldout_seed):
        m = train(
            scene,
            pc,
            cfg,
            args.out,
            depth_fn,
            progress=False,
            device="cpu",
            heldout_scale=cloud_scale(report),
        )
    row = {
        "out": args.out,
        "scene": args.scene,
        "overrides": args.overrides,
        "teacher": args.teacher,
        "teacher_views": args.teacher_views,
        "heldout_seed": cfg.seed if args.heldout_seed is None else args.heldout_seed,
        "heldout_psnr": m["held-out"]["psnr"],
        "train_s": m["seconds"]["train"],
        "gaussians": m["gaussians"],
        "heldout_best": m["heldout_best"],
        "history": [(h["iteration"], round(h["seconds"], 1), round(h["heldout_psnr"], 2)) for h in m["history"]],
    }
    print(json.dumps(row))
    return row


if __name__ == "__main__":
    main()
