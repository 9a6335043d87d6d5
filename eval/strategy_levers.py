"""The adaptive strategy's settings one at a time on ``table7_quick``'s row: one scene at 512 wide, the fibonacci
cloud from ``sim:relative``, 1,500 steps at 64² on 120 pseudo-labels, 8 held-out views; any ``AdaptiveStrategy``
field changed by ``key=value`` (``strategy=default`` trains the 3DGS row instead). Prints one JSON line
(pseudo-label and held-out PSNR, Gaussians, training seconds).

    python eval/strategy_levers.py SCENE OUT [key=value ...] [--threads N] [--iters I --res R --labels L]
    python eval/strategy_levers.py bedroom out/ad threshold_start=0.0125 threshold_end=0.125 --threads 1
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json


def main(argv=None) -> dict:
    import torch

    from panorecon.pipeline import teacher_depth_fn
    from panorecon.pipeline.stages import fusion_config_for
    from panorecon.scenes import load_scene
    from panorecon.sources import cloud_scale, run_source
    from panorecon.splat import strategy
    from panorecon.splat.trainer import TrainConfig, train

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("out")
    ap.add_argument("overrides", nargs="*", help="AdaptiveStrategy field=value, or strategy=default")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--iters", type=int, default=1500)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--labels", type=int, default=120)
    ap.add_argument("--width", type=int, default=512, help="ERP width")
    args = ap.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    inherited = {f.name for f in dataclasses.fields(strategy.DefaultStrategy)}  # the trainer sets those
    types = {f.name: f.type for f in dataclasses.fields(strategy.AdaptiveStrategy) if f.name not in inherited}
    name, fields = "adaptive", {}
    for item in args.overrides:
        key, _, value = item.partition("=")
        if key == "strategy":
            name = value
        elif key in types:
            fields[key] = {"int": int, "float": float}[types[key]](value)
        else:
            ap.error(f"{item!r}: {key!r} is not an AdaptiveStrategy field ({', '.join(types)})")
    cfg = TrainConfig(iters=args.iters, res=args.res, labels=args.labels, heldout=8, strategy=name, backend="cpu")
    scene = load_scene(args.scene, args.width)
    pc, report = run_source(scene, "fibonacci", "sim:relative", None, fusion_config_for(torch.device("cpu")))
    saved = strategy.STRATEGIES["adaptive"]
    strategy.STRATEGIES["adaptive"] = functools.partial(saved, **fields)
    try:
        m = train(
            scene,
            pc,
            cfg,
            args.out,
            teacher_depth_fn(scene, "sim:relative"),
            progress=False,
            device="cpu",
            heldout_scale=cloud_scale(report),
        )
    finally:
        strategy.STRATEGIES["adaptive"] = saved
    row = {
        "scene": args.scene,
        "strategy": name,
        "overrides": fields,
        "psnr_pl": m["pseudo-label"]["psnr"],
        "psnr_ho": m["held-out"]["psnr"],
        "gaussians": m["gaussians"],
        "train_s": m["seconds"]["train"],
    }
    print(json.dumps(row))
    return row


if __name__ == "__main__":
    main()
