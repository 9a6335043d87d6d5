"""OpenSplat (pierotofy/OpenSplat, a CPU build) beside panorecon's trainer on the same ``panorecon export``: same
pseudo-label images, same initial cloud, same step count; both scored by panorecon's own evaluation on the label
cameras and the held-out cameras. Prints JSON (machine, versions, commits, load averages, per format: seconds per
step, PSNR/SSIM/LPIPS, Gaussians, and the ratio of OpenSplat's seconds per step to panorecon's). A run that fails
(non-zero exit, no PLY, any non-finite mean) is "status": "failed: ..." with the count, and the script exits 1.

Time to quality: both trainers' held-out PSNR against training seconds every ``--curve-every`` steps (OpenSplat's
``--save-every`` PLYs, scored after its run; panorecon's history), and the seconds each takes to reach OpenSplat's
final held-out PSNR and panorecon's (``time_to_reach``), beside the per-step ratio. OpenSplat's clock
(``training_clock``) starts at its first step and leaves out the PLY saves.

    python eval/peers/opensplat.py --opensplat /path/to/opensplat OUT [--scene bedroom] [--iters 300]
    python eval/peers/opensplat.py --opensplat build/opensplat out/beach --scene beach --formats colmap nerfstudio
    python eval/peers/opensplat.py --opensplat build/opensplat out/bedroom --curve-every 0   # no curves

OpenSplat is optional and never a dependency: pass the path of a binary built with its own instructions
(``-DGPU_RUNTIME=CPU``; docs/benchmarks.md). It runs unpatched with the command ``export`` prints for it plus
``-n ITERS --num-downscales 0`` (train at the labels' resolution from step 1, as panorecon does; OpenSplat's
default starts at a quarter of it for 3000 steps). Its PLY (``--keep-crs``: the export's frame) is read with
``splat/ply.py`` and rendered with panorecon's rasterizer over OpenSplat's own background colour (what it trained
against). panorecon's run gets the same input: the exported cloud as it is (no disocclusion fill, no thinning),
no sky environment, no depth term.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

OPENSPLAT_BACKGROUND = (0.6130, 0.0101, 0.3984)  # model.hpp: backgroundColor ("Nerf Studio default")


def load_average() -> list[float]:
    """The 1, 5 and 15 minute load averages (/proc/loadavg; the machine may be shared)."""
    try:
        return [float(x) for x in Path("/proc/loadavg").read_text().split()[:3]]
    except OSError:
        return []


def opensplat_version(binary: str) -> str:
    """``opensplat --version``: e.g. "1.1.5 (git commit 15b7e80)"."""
    return subprocess.run([binary, "--version"], capture_output=True, text=True, timeout=60).stdout.strip()


def seconds_per_step(step_times: list[tuple[int, float]]) -> float:
    """Median seconds between consecutive "Step N" lines [(step, wall time)] (NaN with fewer than two)."""
    import numpy as np

    d = [(t1 - t0) / (s1 - s0) for (s0, t0), (s1, t1) in zip(step_times, step_times[1:]) if s1 > s0]
    return float(np.median(d)) if d else float("nan")


def training_clock(step_times: list[tuple[int, float]], save_steps=()) -> dict[int, float]:
    """Training seconds at each "Step N" line [(step, wall time)] of a run that wrote a PLY after each step in
    ``save_steps`` (OpenSplat saves after the step's line): the median step (``seconds_per_step``) per step up to
    the first line, then the wall time between lines, an interval that holds a save counted as the median step
    per step -> {step: seconds} (NaN with fewer than two lines)."""
    if not step_times:
        return {}
    med = seconds_per_step(step_times)
    clock = {step_times[0][0]: med * step_times[0][0]}
    total = clock[step_times[0][0]]
    for (s0, t0), (s1, t1) in zip(step_times, step_times[1:]):
        total += med * (s1 - s0) if s0 in save_steps else t1 - t0
        clock[s1] = total
    return clock


def time_to_reach(curve: list[tuple[float, float]], target: float) -> float | None:
    """Seconds at which a held-out curve [(seconds, PSNR dB)] in time order first reaches ``target`` dB: linear
    between the last sample below it and the first at or above it (that sample's seconds when it is the first);
    non-finite samples are skipped. None when the curve never reaches it or the target is not finite."""
    if not math.isfinite(target):
        return None
    prev = None
    for sec, p in curve:
        if not math.isfinite(p):
            continue
        if p >= target:
            return sec if prev is None else prev[0] + (sec - prev[0]) * (target - prev[1]) / (p - prev[1])
        prev = (sec, p)
    return None


def run_opensplat(binary: str, command: str, iters: int, log_path: Path, save_every: int = 0) -> dict:
    """Run the export's OpenSplat ``command`` with ``binary`` for ``iters`` steps at full resolution (a PLY every
    ``save_every`` steps: ``--save-every``); time each step from its "Step N:" lines -> {seconds_per_step, wall_s,
    returncode, argv, clock (``training_clock``: {step: training seconds})}."""
    argv = [binary, *shlex.split(command)[1:], "-n", str(iters), "--num-downscales", "0"]
    if save_every:
        argv += ["--save-every", str(save_every)]
    steps, t0 = [], time.perf_counter()
    with (
        open(log_path, "w") as log,
        subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as p,
    ):
        for line in p.stdout:
            log.write(line)
            log.flush()
            if line.startswith("Step "):
                steps.append((int(line.split()[1].rstrip(":")), time.perf_counter()))
    return {
        "argv": argv,
        "returncode": p.returncode,
        "wall_s": time.perf_counter() - t0,
        "steps_seen": len(steps),
        "seconds_per_step": seconds_per_step(steps),
        "clock": training_clock(steps, range(save_every, iters, save_every) if save_every else ()),
    }


def score_ply(ply: Path, labels, heldout, res: int, fov_deg: float, background) -> dict:
    """panorecon's evaluation of a 3DGS PLY: Gaussians, non-finite means, and PSNR/SSIM/LPIPS on ``labels`` and
    ``heldout`` rendered over a constant ``background`` (RGB in [0, 1])."""
    import dataclasses

    import numpy as np
    import torch

    from panorecon.splat.evaluate import _evaluate
    from panorecon.splat.ply import load_ply
    from panorecon.splat.trainer import TrainConfig

    model = load_ply(ply)
    bad = int((~torch.isfinite(model.means).all(1)).sum())
    out = {"gaussians": len(model), "non_finite_means": bad}
    if bad:
        return out | {"pseudo-label": f"n/a: {bad} non-finite means", "held-out": f"n/a: {bad} non-finite means"}
    bg = np.broadcast_to(np.asarray(background, np.float32), (res, res, 3)).copy()
    cfg = TrainConfig(res=res, fov_deg=fov_deg, backend="cpu")
    views = {k: [dataclasses.replace(v, background=bg) for v in vs] for k, vs in (("l", labels), ("h", heldout))}
    return out | {
        "pseudo-label": _evaluate(model, views["l"], cfg, "cpu"),
        "held-out": _evaluate(model, views["h"], cfg, "cpu") if heldout else "n/a: scene has no ground-truth world",
    }


def heldout_psnr_of_ply(ply: Path, heldout, res: int, fov_deg: float, background) -> float:
    """Mean held-out PSNR (dB) of a 3DGS PLY rendered over a constant ``background``, the history's cheap sample
    (``evaluate._heldout_psnr``: no SSIM, no LPIPS)."""
    import dataclasses

    import numpy as np

    from panorecon.splat.evaluate import _heldout_psnr
    from panorecon.splat.ply import load_ply
    from panorecon.splat.trainer import TrainConfig

    bg = np.broadcast_to(np.asarray(background, np.float32), (res, res, 3)).copy()
    views = [dataclasses.replace(v, background=bg) for v in heldout]
    return _heldout_psnr(load_ply(ply), views, TrainConfig(res=res, fov_deg=fov_deg, backend="cpu"), "cpu")


def opensplat_curve(run: dict, export_dir: Path, heldout, res: int, fov_deg: float, iters: int, every: int) -> list:
    """OpenSplat's held-out curve [(training seconds, PSNR dB)]: each ``opensplat_STEP.ply`` its ``--save-every
    every`` wrote before the last step and whose step has a clock reading (a "Step N:" line), scored, then the
    final PLY's score at the last step's seconds. Every such PLY is deleted after (150 MB each at 600k Gaussians;
    the last step's is the final PLY's twin)."""
    curve = []
    for step in range(every, iters + 1, every):
        ply = export_dir / f"opensplat_{step}.ply"
        if step < iters and step in run["clock"] and ply.is_file():
            curve.append((run["clock"][step], heldout_psnr_of_ply(ply, heldout, res, fov_deg, OPENSPLAT_BACKGROUND)))
        ply.unlink(missing_ok=True)
    final = run.get("held-out")
    if isinstance(final, dict) and iters in run["clock"]:
        curve.append((run["clock"][iters], final["psnr"]))
    return curve


def time_to_quality(result: dict) -> None:
    """Adds, in place, each trainer's seconds to reach OpenSplat's final held-out PSNR (per format) and
    panorecon's, from the curves: ``seconds_to[target]`` on each run and on panorecon, and on each OpenSplat run
    ``time_to_its_final_vs_panorecon`` (OpenSplat's seconds to its own final PSNR over panorecon's to the same)."""
    pan = result["panorecon"]
    targets = {"panorecon": pan["held-out"]["psnr"] if isinstance(pan["held-out"], dict) else float("nan")}
    for fmt, run in result["opensplat_runs"].items():
        if run["status"] == "ok" and run.get("heldout_curve"):
            targets[f"opensplat_{fmt}"] = run["held-out"]["psnr"]
    result["time_to_quality_targets"] = targets
    for run in (pan, *result["opensplat_runs"].values()):
        if run.get("heldout_curve"):
            run["seconds_to"] = {t: time_to_reach(run["heldout_curve"], dB) for t, dB in targets.items()}
    for fmt, run in result["opensplat_runs"].items():
        mine, theirs = (
            run.get("seconds_to", {}).get(f"opensplat_{fmt}"),
            pan.get("seconds_to", {}).get(f"opensplat_{fmt}"),
        )
        if mine is not None and theirs:
            run["time_to_its_final_vs_panorecon"] = mine / theirs


def run_status(run: dict) -> str:
    """ "ok", or "failed: ..." for a run that exited non-zero, wrote no PLY or left any non-finite mean: such a
    run is no comparison, whatever its other Gaussians score."""
    if "error" in run:
        return "failed: " + run["error"].removeprefix("n/a: ")
    if run["non_finite_means"]:
        return f"failed: {run['non_finite_means']} of {run['gaussians']} Gaussians have non-finite means"
    return "ok"


def main(argv=None) -> dict:
    import torch

    from panorecon.evaluation.environment import emit, environment
    from panorecon.export import FORMATS, export_scene
    from panorecon.scenes import load_scene
    from panorecon.sources import cloud_scale, run_source
    from panorecon.splat.labels import in_cloud_frame, make_heldout_views, make_pseudo_labels
    from panorecon.splat.trainer import TrainConfig, train

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", help="folder for the exports, both trainers' outputs and result.json")
    ap.add_argument("--opensplat", required=True, help="path to an OpenSplat binary")
    ap.add_argument("--scene", default="bedroom")
    ap.add_argument("--width", type=int, default=None, help="ERP width (default: the scene's, as `export`)")
    ap.add_argument("--source", default="fibonacci")
    ap.add_argument("--teacher", default="sim:relative")
    ap.add_argument("--formats", nargs="+", choices=FORMATS, default=list(FORMATS))
    ap.add_argument("--iters", type=int, default=300)
    ap.add_argument("--labels", type=int, default=120)
    ap.add_argument("--res", type=int, default=256)
    ap.add_argument("--fov", type=float, default=60.0)
    ap.add_argument("--heldout", type=int, default=8)
    ap.add_argument(
        "--curve-every", type=int, default=50, help="steps between held-out curve samples (0: none; needs held-out)"
    )
    args = ap.parse_args(argv)
    binary = str(Path(args.opensplat).resolve())
    if not Path(binary).is_file():
        ap.error(f"--opensplat {args.opensplat}: no such file (build OpenSplat first; docs/benchmarks.md)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    scene = load_scene(args.scene, args.width)
    cloud, report = run_source(scene, args.source, args.teacher, None)
    labels = make_pseudo_labels(scene, args.labels, args.res, args.fov)
    heldout = []
    if scene.world is not None:
        heldout = [
            in_cloud_frame(v, cloud_scale(report))
            for v in make_heldout_views(scene, args.heldout, args.res, args.fov, seed=0)
        ]
    curve_every = args.curve_every if heldout else 0
    result = {
        **environment(),
        "opensplat": opensplat_version(binary),
        "scene": scene.name,
        "source": args.source,
        "teacher": args.teacher,
        "cloud_points": len(cloud),
        "iters": args.iters,
        "labels": args.labels,
        "res": args.res,
        "torch_threads": torch.get_num_threads(),
        "curve_every": curve_every,
        "opensplat_runs": {},
    }
    about = {"scene": scene.name, "source": args.source, "teacher": report.get("teacher")}
    for fmt in args.formats:
        d = export_scene(scene, cloud, args.labels, fmt, out / fmt, args.res, args.fov, overwrite=True, about=about)
        meta = json.loads((d / "export.json").read_text())
        load = load_average()
        run = run_opensplat(
            binary, meta["commands"]["opensplat"], args.iters, out / f"opensplat_{fmt}.log", curve_every
        )
        run["load_before"], run["load_after"] = load, load_average()
        run["export_scale"] = meta["consumer_scales"]["opensplat"]
        ply = d / "opensplat.ply"
        if run["returncode"] == 0 and ply.is_file():
            run |= score_ply(ply, labels, heldout, args.res, args.fov, OPENSPLAT_BACKGROUND)
        else:
            run["error"] = f"n/a: OpenSplat exited {run['returncode']} (log: {out / f'opensplat_{fmt}.log'})"
        run["status"] = run_status(run)
        if curve_every and run["status"] == "ok":
            run["heldout_curve"] = opensplat_curve(run, d, heldout, args.res, args.fov, args.iters, curve_every)
        result["opensplat_runs"][fmt] = run
    failed = {fmt: run["status"] for fmt, run in result["opensplat_runs"].items() if run["status"] != "ok"}
    result["status"] = (
        "ok" if not failed else "failed: " + "; ".join(f"{k}: {v.removeprefix('failed: ')}" for k, v in failed.items())
    )

    cfg = TrainConfig(
        iters=args.iters,
        res=args.res,
        labels=args.labels,
        fov_deg=args.fov,
        backend="cpu",
        heldout=args.heldout,
        history_every=curve_every,
        sky="none",
        disocclusion_fill_deg=0.0,
        init_pixels_per_point=0.0,
    )
    shutil.rmtree(out / "panorecon", ignore_errors=True)  # train() would resume a finished run
    load = load_average()
    m = train(
        scene, cloud, cfg, out / "panorecon", None, progress=False, device="cpu", heldout_scale=cloud_scale(report)
    )
    result["panorecon"] = {
        "config": "same input: the exported cloud as is (no fill, no thinning), no sky, no depth term",
        "seconds_per_step": m["seconds"]["train"] / args.iters,
        "train_s": m["seconds"]["train"],
        "flatten_s": m["seconds"]["flatten"],  # within train_s
        "gaussians": m["gaussians"],
        "pseudo-label": m["pseudo-label"],
        "held-out": m["held-out"],
        "load_before": load,
        "load_after": load_average(),
    }
    if curve_every:
        result["panorecon"]["heldout_curve"] = [
            (h["seconds"], h["heldout_psnr"]) for h in m["history"] if "heldout_psnr" in h
        ]
        time_to_quality(result)
    for run in result["opensplat_runs"].values():
        sps = run.get("seconds_per_step")
        if isinstance(sps, float) and math.isfinite(sps):
            run["seconds_per_step_vs_panorecon"] = sps / result["panorecon"]["seconds_per_step"]
    return emit(result, str(out / "result.json"))


def exit_status(result: dict) -> int:
    """The command's exit status: 0 when every OpenSplat run is "ok", 1 when any failed."""
    return 0 if result["status"] == "ok" else 1


if __name__ == "__main__":
    sys.exit(exit_status(main()))
