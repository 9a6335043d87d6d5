"""The ``panorecon`` command. Each subcommand imports only what it needs."""

from __future__ import annotations

import argparse
import errno
import logging
import sys
import threading
import time
from pathlib import Path

import numpy as np

from . import cli_types as T
from .io import PanoreconInputError

log = logging.getLogger("panorecon")

# what each command writes into its --out folder (relative fnmatch patterns; ``*`` crosses folders): the path
# collision check (cli_types.path_collisions) and the run-folder claim (io.runs.claim_run) both use them
RENDER_WRITES = ("pano.png", "mask.png", "distance.npy", "scene.json", "heldout_*.npz")
TRAIN_WRITES = (
    "*_cloud.ply",
    "*_report.json",
    "point_cloud.ply",
    "sky.png",
    "cameras.json",
    "metrics.json",
    "ckpt.pt",
    "ckpt.pt.bad",
    "renders/*",
)
DEMO_WRITES = (*RENDER_WRITES, *TRAIN_WRITES, "gt_cloud.ply", "gt_cloud.png", "*_cloud.png", "panorama.png")
ABLATE_WRITES = (
    "results.csv",
    "results.md",
    "*.png",
    "report.html",
    "cache/*",
    "*/results.csv",
    "*/results.md",
    "*/*.png",
    "*/report.html",
)


def _claim(args, command: str, inputs: dict, writes: tuple[str, ...]) -> None:
    """The run-folder claim of ``args.out`` (see io.runs), unless a caller (demo) claimed it already."""
    from .io.runs import claim_run

    if not getattr(args, "claimed", False):
        claim_run(args.out, command, inputs, writes, getattr(args, "overwrite", False))


def _input_identity(args) -> dict:
    """The SCENE and --depth of a command as JSON scalars, files by their SHA-256 (what decides the results)."""
    import os

    from .io import file_sha256

    def ident(path):
        return None if path is None else f"{path}#{file_sha256(path)[:16]}" if os.path.isfile(path) else str(path)

    return {
        "scene": ident(args.scene),
        "width": args.width,
        **{k: ident(getattr(args, k, None)) if k == "depth" else getattr(args, k, None) for k in DEPTH_OPTIONS},
    }


# ---------------------------------------------------------------- scenes
def cmd_scenes_list(args) -> int:
    from .scenes import list_scenes

    if getattr(args, "root", None):
        from .scenes.datasets import list_root

        found = list_root(Path(args.root))
        for name, desc in found:
            print(f"{name}  ({desc.split(',')[0]})")
        print(f"{len(found)} panoramas with true depth under {args.root}")
        return 0
    rows = [(s.name, s.kind, "yes" if s.has_ground_truth else "no", s.description) for s in list_scenes()]
    w = max(len(r[0]) for r in rows)
    print(f"{'name':<{w}}  {'kind':<9}  {'truth':<5}  description")
    for name, kind, gt, desc in rows:
        print(f"{name:<{w}}  {kind:<9}  {gt:<5}  {desc}")
    return 0


def cmd_scenes_check(args) -> int:
    from .io import write_json
    from .scenes.check import check_root, report_table, summary_line
    from .scenes.datasets import list_root

    if not Path(args.root).is_dir():
        raise PanoreconInputError(f"{args.root}: not a folder; expected a dataset folder")
    if not list_root(Path(args.root)):
        raise PanoreconInputError(
            f"{args.root}: no Stanford2D3D, Structured3D or Matterport3D panorama under it, and no poses.json "
            "(a posed-panoramas folder)"
        )
    report = check_root(Path(args.root), args.width)
    print(report_table(report))
    print(summary_line(report))
    if args.json:
        write_json(args.json, {"root": str(args.root), "width": args.width, **report.to_dict()})
    return 1 if report.flagged else 0


def cmd_render(args) -> int:
    import dataclasses

    import numpy as np

    from .io import save_npy, write_image, write_json
    from .scenes import scene_from_args

    t0 = time.perf_counter()
    scene = scene_from_args(args)
    seconds = time.perf_counter() - t0
    out = Path(args.out)
    _claim(args, "render", {**_input_identity(args), "heldout": getattr(args, "heldout", 0)}, RENDER_WRITES)
    write_image(out / "pano.png", scene.rgb)
    mask = scene.valid if scene.distance is not None else ~scene.sky
    write_image(out / "mask.png", (mask * 255).astype(np.uint8))
    if scene.distance is not None:
        save_npy(out / "distance.npy", scene.distance.astype(np.float32))
    heldout_note = ""
    radius = None
    if scene.world is not None and getattr(args, "heldout", 0):
        # the true views `train` holds out, so that the folder trains and evaluates without Open3D
        from .scenes.rendered import RecordingWorld, save_heldout
        from .splat.labels import make_heldout_views
        from .splat.trainer import TrainConfig

        cfg = TrainConfig()
        radius = scene.world.free_space_radius()
        for res in args.heldout_res:
            rec = RecordingWorld(scene.world)
            make_heldout_views(dataclasses.replace(scene, world=rec), args.heldout, res, cfg.fov_deg, cfg.seed)
            save_heldout(out, rec.cameras, rec.renders)
        heldout_note = f", {args.heldout} held-out views at {'/'.join(map(str, args.heldout_res))} px"
    write_json(
        out / "scene.json",
        {
            "name": scene.name,
            "kind": scene.kind,
            "description": scene.description,
            "distance_kind": scene.distance_kind,
            "meta": scene.meta,
            "free_space_radius": radius,
        },
    )
    print(
        f"{scene.name}: {scene.width}x{scene.height} rendered in {seconds:.2f} s{heldout_note} -> {out}"
        + ("" if scene.distance is not None else " (no depth: distance.npy not written)")
    )
    return 0


def cmd_gt_cloud(args) -> int:
    from .scenes import scene_from_args

    scene = scene_from_args(args)
    if scene.distance is None:
        raise PanoreconInputError(f"scene {scene.name!r} has no depth, so it has no ground-truth cloud")
    if not scene.has_ground_truth:
        print(f"note: {scene.name}'s depth is {scene.meta.get('depth_from', scene.distance_kind)}, not ground truth")
    pc = scene.point_cloud()
    pc.save_ply(args.out)
    print(f"{scene.name}: {len(pc)} points -> {args.out}")
    return 0


def cmd_inspect(args) -> int:
    from .geometry.pointcloud import PointCloud
    from .viz import screenshot, show

    path = Path(args.cloud)
    pc = PointCloud.load_ply(path)
    if args.clip_z is not None and not (pc.xyz[:, 2] <= args.clip_z).any():
        raise PanoreconInputError(
            f"--clip-z {args.clip_z:g} hides every point of {path} (its heights run from "
            f"{pc.xyz[:, 2].min():.3g} to {pc.xyz[:, 2].max():.3g} m)"
        )
    if args.screenshot:
        screenshot(pc, args.screenshot, args.color, args.point_size, args.clip_z)
        print(f"{path}: {len(pc)} points -> {args.screenshot}")
    else:
        show(pc, args.color, args.point_size, args.clip_z)
    return 0


def cmd_demo(args) -> int:
    """The main job on the built-in default scene: render, ground-truth cloud and its screenshot, the method's
    initial cloud (40 Fibonacci views, simulated teacher, log-depth fusion) with its report, a short Gaussian
    training from it (point_cloud.ply, renders/, metrics.json), held-out renders at 256 px and the panorama
    rendered back from the Gaussians (panorama.png). Its settings are explicit here, not train's defaults."""
    from .demo import demo_pictures
    from .scenes import DEFAULT_SCENE, scene_from_args

    t0 = time.perf_counter()
    out = Path(args.out)
    scene = args.scene or DEFAULT_SCENE
    depth = {k: getattr(args, k) for k in DEPTH_OPTIONS}
    # everything the steps below need, checked before the first of them writes a byte
    scene_from_args(argparse.Namespace(scene=scene, width=64, **depth))  # the teacher spec: at parse time
    _claim(
        args,
        "demo",
        {**_input_identity(argparse.Namespace(scene=scene, width=args.width, **depth)), "teacher": args.teacher},
        DEMO_WRITES,
    )
    claimed = {"claimed": True}
    cmd_render(argparse.Namespace(scene=scene, out=str(out), width=args.width, **depth, **claimed))
    cmd_gt_cloud(argparse.Namespace(scene=scene, out=str(out / "gt_cloud.ply"), width=args.width, **depth))
    from .geometry import PointCloud

    gt = PointCloud.load_ply(out / "gt_cloud.ply")
    outdoor = bool(np.isinf(np.load(out / "distance.npy")).any()) if (out / "distance.npy").exists() else True
    # indoor scenes (no sky) are shown from above with the ceiling cut away
    clip_z = None if outdoor else float(0.5 * gt.xyz[:, 2].max())
    cmd_inspect(
        argparse.Namespace(
            cloud=str(out / "gt_cloud.ply"),
            screenshot=str(out / "gt_cloud.png"),
            color=None,
            point_size=2.0,
            clip_z=clip_z,
        )
    )
    cmd_train(
        argparse.Namespace(
            scene=scene,
            source="fibonacci",
            teacher=args.teacher,
            views=TRAIN_VIEWS["fibonacci"],
            width=args.width,
            iters=args.iters,
            res=args.res,
            labels=120,
            heldout=8,
            sh_degree=3,
            backend=None,
            strategy="default",
            seed=0,
            checkpoint_every=None,
            no_progress=False,
            out=str(out),
            **depth,
            **claimed,
        )
    )
    cmd_inspect(
        argparse.Namespace(
            cloud=str(out / "fibonacci_cloud.ply"),
            screenshot=str(out / "fibonacci_cloud.png"),
            color=None,
            point_size=2.0,
            clip_z=clip_z,
        )
    )
    p = demo_pictures(scene_from_args(argparse.Namespace(scene=scene, width=args.width, **depth)), out)
    print(
        f"panorama rendered back from the Gaussians: PSNR {p['panorama_psnr']:.2f} dB against the input -> "
        f"{out / 'panorama.png'}; held-out renders at 256 px -> {out / 'renders'}; demo took "
        f"{time.perf_counter() - t0:.0f} s"
    )
    return 0


# ---------------------------------------------------------------- teachers, sources, points
def cmd_teachers_list(args) -> int:
    from .teachers import list_teachers

    for spec, desc in list_teachers():
        print(f"{spec:<34}  {desc}")
    return 0


def cmd_sources_list(args) -> int:
    from .sources import list_sources

    for s in list_sources():
        print(f"{s.name:<12}  {s.description}")
    return 0


def _initial_cloud(args, scene, cloud_path, report_path):
    """Run the point source, write its cloud (and report, and --distance-out) and print one summary line ->
    (PointCloud, report). The outputs are written together (``atomic_write_all``): an error or a Ctrl-C/SIGTERM
    before they are all written leaves none of them (files already at those paths are kept), one during the
    final renames leaves all of them whole."""
    from .device import resolve_device
    from .io import atomic_write_all, json_text
    from .pipeline.stages import fusion_config_for
    from .sources import run_source

    fusion = fusion_config_for(resolve_device(getattr(args, "device", "auto")))
    pc, report = run_source(
        scene,
        args.source,
        args.teacher,
        args.views,
        fusion,
        view_size=getattr(args, "view_size", None),
        max_points=getattr(args, "max_points", None),
    )
    distance_out = getattr(args, "distance_out", None)
    if distance_out and pc.meta.get("erp_distance") is None:
        raise PanoreconInputError(f"--distance-out {distance_out}: source {args.source!r} gives no ERP distance")
    outputs = [p for p in (cloud_path, distance_out, report_path) if p]
    with atomic_write_all(outputs) as tmps:
        written = dict(zip(outputs, tmps))
        pc.save_ply(written[cloud_path])
        if distance_out:
            with open(written[distance_out], "wb") as f:  # a file object: np.save adds no ".npy" to the name
                np.save(f, pc.meta["erp_distance"])
        if report_path:
            written[report_path].write_text(json_text(report))
    depth = report.get("depth")
    d = (
        f"AbsRel {depth['abs_rel']:.4f}, delta1 {depth['delta1']:.3f}"
        if isinstance(depth, dict) and isinstance(depth.get("abs_rel"), float)
        else str(depth)
    )
    pts = report["points"]
    chamfer = f"{pts['chamfer']:.4f} m" if isinstance(pts.get("chamfer"), float) else pts.get("chamfer")
    thin = report.get("thinning")
    if thin and thin.get("thinned"):
        print(
            f"thinned to {thin['points']} points, {thin['spacing_deg']:.3f} deg apart "
            f"({thin['points_per_sr']:.0f} per sr)"
        )
    print(
        f"{scene.name} / {args.source} / {report['teacher']}: {len(pc)} points, depth {d}, chamfer {chamfer}, "
        f"{report['seconds']['total']:.2f} s, peak {report['peak_rss_mb']:.0f} MB -> {cloud_path}"
    )
    for warning in report.get("warnings", []):
        print(f"WARNING: {warning}")
    return pc, report


def cmd_points(args) -> int:
    from .device import resolve_device
    from .scenes import scene_from_args
    from .sources import get_source

    resolve_device(args.device)  # --device cuda without CUDA: refused before any work
    _check_source(args)  # an unknown source, or views it cannot take, fail before the scene is rendered
    get_source(args.source)
    _initial_cloud(args, scene_from_args(args), args.out, args.report)
    return 0


def _check_source(args) -> None:
    """The source's name and its view count, and the teacher spec, checked before any work."""
    from .geometry.layouts import LAYOUT_NAMES, make_layout
    from .sources import get_source

    get_source(args.source)
    if args.source in LAYOUT_NAMES and args.views is not None:
        try:
            make_layout(args.source, args.views)
        except ValueError as e:
            raise PanoreconInputError(f"--views {args.views}: {e}") from None


# `train`'s point-source views where they differ from the source's own default (Fibonacci: 20, the paper's):
# 40 views give each direction twice the overlaps to average the teacher's per-view error over (issue 19;
# docs/benchmarks.md "Time to quality")
TRAIN_VIEWS = {"fibonacci": 40}


def cmd_train(args) -> int:
    import dataclasses

    from .device import resolve_device
    from .pipeline import teacher_depth_fn
    from .scenes import scene_from_args
    from .sources import check_source, cloud_scale
    from .splat.trainer import TrainConfig, train

    device = resolve_device(getattr(args, "device", "auto"))
    _check_backend(args, device)
    fields = {f.name for f in dataclasses.fields(TrainConfig)}
    cfg = TrainConfig(**{k: v for k, v in vars(args).items() if k in fields and v is not None})
    if args.views is None:
        args = argparse.Namespace(**{**vars(args), "views": TRAIN_VIEWS.get(args.source)})
    _check_source(args)
    scene = scene_from_args(args)
    check_source(scene, args.source, args.teacher)  # what the source needs of this scene: before the claim
    out = Path(args.out)
    _claim(
        args,
        "train",
        {
            **_input_identity(args),
            "source": args.source,
            "teacher": args.teacher,
            "views": args.views,
            "config": cfg.digest(),
        },
        TRAIN_WRITES,
    )
    pc, report = _initial_cloud(args, scene, out / f"{args.source}_cloud.ply", out / f"{args.source}_report.json")
    m = train(
        scene,
        pc,
        cfg,
        args.out,
        teacher_depth_fn(scene, args.teacher),
        progress=not args.no_progress,
        inputs={"source": args.source, "teacher": args.teacher, "views": args.views, "depth": args.depth},
        device=device,
        heldout_scale=cloud_scale(report),
    )
    held = m["held-out"]
    held_txt = (
        f"{held['psnr']:.2f} dB"
        if isinstance(held, dict) and isinstance(held["psnr"], float)
        else (held["psnr"] if isinstance(held, dict) else held)
    )
    lp = m["pseudo-label"]["lpips"]
    lp_txt = f"{lp:.3f}" if isinstance(lp, float) else lp
    print(
        f"{scene.name} / {args.source}: pseudo-label PSNR {m['pseudo-label']['psnr']:.2f} dB, SSIM "
        f"{m['pseudo-label']['ssim']:.3f}, LPIPS {lp_txt}; held-out PSNR {held_txt}; {m['gaussians']} Gaussians; "
        f"{m['seconds']['total']:.1f} s ({m['seconds']['train']:.1f} s training); peak {m['peak_rss_mb']:.0f} MB; "
        f"{m['backend']} on {m['device_name']} -> {args.out}"
    )
    return 0


def _check_backend(args, device) -> None:
    """A backend that cannot render on ``device`` is bad input: one line, before any work."""
    from .splat.rasterize import cpu_backend, gsplat_backend

    backend = getattr(args, "backend", None) or "auto"
    if backend == "gsplat" and device.type != "cuda":
        raise PanoreconInputError(f"--backend gsplat renders on CUDA, but the device is {device}: use --device cuda")
    if backend == "gsplat" and not gsplat_backend.available():
        raise PanoreconInputError(f"--backend gsplat: {gsplat_backend.unavailable_reason()}")
    if backend == "cpu" and device.type != "cpu":
        raise PanoreconInputError(
            f"--backend cpu renders on the CPU, but the device is {device}: use --backend "
            "gsplat or torch, or --device cpu"
        )
    if backend == "cpu" and not cpu_backend.available():
        raise PanoreconInputError("--backend cpu: the C++ rasterizer could not be built here (see the log)")


# ---------------------------------------------------------------- evaluation
def cmd_ablate(args) -> int:
    from .device import resolve_device
    from .evaluation.ablate import run_suites, suite_out_dirs
    from .evaluation.report import average_table
    from .evaluation.suite import load_suite

    if args.from_csv:
        return _ablate_from_csv(args)
    if not args.suite:
        raise PanoreconInputError("ablate: give a suite file (e.g. eval/suites/quick.toml) or --from-csv results.csv")
    resolve_device(args.device)
    if args.scheduler and args.engine != "dask":
        raise PanoreconInputError(f"--scheduler {args.scheduler}: a scheduler is used only with --engine dask")
    if args.root is not None and not Path(args.root).is_dir():
        raise PanoreconInputError(f"--root {args.root}: no such folder (expected a dataset root)")
    from .evaluation.suite import parse_override

    overrides = dict(parse_override(t) for t in args.set)
    suites = [load_suite(s, args.root, overrides) for s in args.suite]
    stems = [s.name for s in suites]
    if len(set(stems)) != len(stems):
        raise PanoreconInputError(f"ablate: suites {', '.join(args.suite)} share a file name; rename one")
    runs = {r.run_id() for s in suites for r in s.rows}
    if len(runs) > args.max_runs:
        raise PanoreconInputError(
            f"suite {' '.join(args.suite)} expands to {len(runs)} runs, more than --max-runs {args.max_runs}; "
            "pass a larger --max-runs to run it"
        )
    if args.engine == "dask" and args.scheduler:
        from .evaluation.ablate import check_scheduler

        check_scheduler(args.scheduler)
    for s in suites:
        print(f"{s.title}: {len(s.rows)} runs")
    frames = run_suites(
        suites,
        args.out,
        jobs=args.jobs,
        engine=args.engine,
        scheduler=args.scheduler,
        cache_dir=args.cache,
        progress=not args.no_progress,
        device=args.device,
        threads=args.threads,
    )
    for suite, frame, o in zip(suites, frames, suite_out_dirs(suites, Path(args.out))):
        cols = [c for c in ("psnr_pl", "psnr_ho", "abs_rel", "chamfer", "sec_total", "peak_mb") if c in frame]
        print(suite.title)
        print(average_table(frame)[cols].to_string(float_format=lambda v: f"{v:.4g}"))
        if "warning" in frame:
            for _, r in frame[frame["warning"].fillna("").astype(str) != ""].iterrows():
                print(f"WARNING ({r['label']}, {r['scene']}): {r['warning']}")
        print(f"-> {o / 'results.csv'}, results.md, pareto.png, report.html")
    return 0


def _ablate_from_csv(args) -> int:
    """``ablate --from-csv CSV [SUITE] --out DIR``: tables, report and plots from a results.csv, nothing run."""
    from .evaluation.rerender import rerender
    from .evaluation.suite import load_suite

    if len(args.suite) > 1:
        raise PanoreconInputError(f"ablate --from-csv: give at most one suite (got {len(args.suite)})")
    suite = load_suite(args.suite[0], args.root) if args.suite else None
    frame = rerender(args.from_csv, args.out, suite)
    print(f"{len(frame)} runs from {args.from_csv} -> {Path(args.out) / 'results.md'}, report.html, pareto.png")
    return 0


MAX_RUNS = 10_000  # a larger suite needs an explicit --max-runs


def cmd_bench(args) -> int:
    from .bench.command import run_bench

    return run_bench(
        args.suite, args.baseline, args.out, quick=args.quick, update_baseline=args.update_baseline, device=args.device
    )


# ---------------------------------------------------------------- parser
class _Parser(argparse.ArgumentParser):
    """argparse with a one-line error (``panorecon <command>: error: ...``, exit 2) instead of usage + error;
    subcommand parsers inherit it."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _add_device(p) -> None:
    p.add_argument(
        "--device", default="auto", help="auto (CUDA when present), cpu or cuda[:K]: where fusion's CG and training run"
    )


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="panorecon", description=__doc__)
    p.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = p.add_subparsers(dest="command", required=True)

    scenes = sub.add_parser("scenes", help="list the built-in scenes").add_subparsers(dest="what", required=True)
    sc = scenes.add_parser("list", help="name, synthetic or real, ground truth, description")
    sc.add_argument(
        "--root",
        default=None,
        type=T.in_path,
        help="list instead the dataset panoramas (Stanford2D3D, Structured3D, "
        "Matterport3D) found under this folder, as scene names",
    )
    sc.set_defaults(fn=cmd_scenes_list)
    ck = scenes.add_parser(
        "check",
        help="every posed dataset panorama under ROOT: does its true depth agree with the other panoramas of its "
        "space and with the dataset's annotated planes? (exit 1 when one is flagged)",
    )
    ck.add_argument("root", type=T.in_path, help="a dataset folder (as for `scenes list --root`)")
    ck.add_argument("--width", type=T.int_in(64, 8192, "width", even=True), default=512, help="ERP width to check at")
    ck.add_argument("--json", type=T.out_file, default=None, help="also write the results as JSON to this file")
    ck.set_defaults(fn=cmd_scenes_check)

    r = sub.add_parser("render", help="write pano.png, distance.npy (float32 metres, inf = sky) and mask.png")
    r.add_argument("scene", type=T.scene, help="scene name (see `panorecon scenes list`) or an ERP image path")
    r.add_argument("--out", required=True, type=T.out_dir_writing(*RENDER_WRITES), help="output folder")
    r.add_argument("--overwrite", action="store_true", help="delete another run's outputs in --out first")
    r.add_argument("--width", type=T.ERP_WIDTH, default=None, help="ERP width in pixels (height = width / 2)")
    r.add_argument(
        "--heldout",
        type=T.int_in(0, 1000, "held-out view count"),
        default=8,
        help="synthetic scenes: true held-out views to record (as `train --heldout`; 0: none)",
    )
    r.add_argument(
        "--heldout-res",
        type=T.LABEL_RES,
        nargs="+",
        default=[128],
        help="sizes of the recorded held-out views (each a `train --res`)",
    )
    r.set_defaults(fn=cmd_render)

    g = sub.add_parser("gt-cloud", help="the ground-truth coloured point cloud from the true distance")
    g.add_argument("scene", type=T.scene)
    g.add_argument("--out", required=True, type=T.out_file, help="output .ply")
    g.add_argument("--width", type=T.ERP_WIDTH, default=None)
    g.set_defaults(fn=cmd_gt_cloud)

    i = sub.add_parser("inspect", help="look at a point cloud with pyvista")
    i.add_argument("cloud", type=T.in_path, help="a .ply point cloud")
    i.add_argument("--screenshot", type=T.out_file, help="render off-screen to this PNG instead of opening a window")
    i.add_argument("--color", default=None, help="colour by this per-point scalar (e.g. view_id, error) instead of RGB")
    i.add_argument("--point-size", type=T.float_in(0.1, 100.0, "point size"), default=2.0)
    i.add_argument(
        "--clip-z", type=T.FINITE_FLOAT, default=None, help="hide points above this height (metres), e.g. a ceiling"
    )
    i.set_defaults(fn=cmd_inspect)

    tl = sub.add_parser("teachers", help="depth teachers").add_subparsers(dest="what", required=True)
    tl.add_parser("list", help="teacher specs").set_defaults(fn=cmd_teachers_list)
    sl = sub.add_parser("sources", help="point sources").add_subparsers(dest="what", required=True)
    sl.add_parser("list", help="registered point sources").set_defaults(fn=cmd_sources_list)

    pt = sub.add_parser("points", help="build an initial point cloud with a point source and report its error")
    pt.add_argument("scene", type=T.scene)
    pt.add_argument("--source", required=True, help="see `panorecon sources list`")
    pt.add_argument(
        "--teacher",
        default=None,
        type=T.teacher_spec,
        help="sim:<profile> | onnx:<model.onnx> | file:<depth>[?scale=S] | "
        "hf:<model id or folder> | moge:<checkpoint> (see `panorecon teachers list`)",
    )
    pt.add_argument("--views", type=T.VIEWS, default=None, help="number of views (fibonacci, latlong)")
    pt.add_argument(
        "--view-size",
        type=T.VIEW_SIZE,
        default=None,
        help="perspective view size in pixels (default: ERP width / 4, at most 512)",
    )
    pt.add_argument("--width", type=T.ERP_WIDTH, default=None, help="ERP width")
    pt.add_argument(
        "--max-points",
        type=T.int_in(1, None, "point count"),
        default=None,
        help="thin the cloud evenly over the sphere (Fibonacci lattice) to at most this many points",
    )
    pt.add_argument("--out", required=True, type=T.out_file, help="output .ply")
    pt.add_argument("--report", default=None, type=T.out_file, help="output report .json")
    pt.add_argument(
        "--distance-out",
        default=None,
        type=T.out_file,
        help="also write the fused ERP ray distance (.npy, float32 metres)",
    )
    _add_device(pt)
    pt.set_defaults(fn=cmd_points)

    tr = sub.add_parser("train", help="fit Gaussians from a point source to the scene's pseudo-labels")
    tr.add_argument("scene", type=T.scene)
    tr.add_argument("--source", required=True)
    tr.add_argument(
        "--teacher", default=None, type=T.teacher_spec, help="depth teacher for the source and the Pearson depth term"
    )
    tr.add_argument(
        "--views",
        type=T.VIEWS,
        default=None,
        help=f"views of the point source (default: {', '.join(f'{v} for {k}' for k, v in TRAIN_VIEWS.items())}, "
        "the source's own otherwise)",
    )
    tr.add_argument("--width", type=T.ERP_WIDTH, default=None, help="ERP width")
    tr.add_argument("--iters", type=T.ITERS, default=None, help="optimisation steps (default 3000)")
    tr.add_argument("--res", type=T.LABEL_RES, default=None, help="label view size in pixels (default 128)")
    tr.add_argument("--labels", type=T.LABELS, default=None, help="pseudo-label views (default 240)")
    tr.add_argument(
        "--checkpoint-every", type=T.ITERS, default=None, help="steps between checkpoints (OUT/ckpt.pt; default 500)"
    )
    tr.add_argument(
        "--backend",
        choices=["auto", "torch", "cpu", "gsplat"],
        default=None,
        help="rasterizer: auto (gsplat on CUDA, cpu on the CPU), torch (the reference), cpu (C++), gsplat (CUDA)",
    )
    _add_device(tr)
    tr.add_argument(
        "--strategy",
        choices=["default", "adaptive"],
        default=None,
        help="densify/prune: default (3DGS) or adaptive (§2.5 contribution pruning)",
    )
    tr.add_argument(
        "--coarse-until",
        type=T.FRACTION,
        default=None,
        help="fraction of the steps at half the label size, coarse to fine (default 0.2; labels of 256 px and more)",
    )
    tr.add_argument(
        "--densify-from", type=T.STEP, default=None, help="step of the first clone/split (default 100; 3DGS: 500)"
    )
    tr.add_argument(
        "--w-depth",
        type=T.LOSS_WEIGHT,
        default=None,
        help="weight of the Pearson depth term against the teacher's view depth (default: TrainConfig.w_depth)",
    )
    tr.add_argument("--seed", type=T.SEED, default=None)
    tr.add_argument("--no-progress", action="store_true")
    tr.add_argument(
        "--out",
        required=True,
        type=T.out_dir_writing(*TRAIN_WRITES),
        help="output folder (point_cloud.ply, renders/, metrics.json; resumes ckpt.pt)",
    )
    tr.add_argument("--overwrite", action="store_true", help="delete another run's outputs in --out first")
    tr.set_defaults(fn=cmd_train)

    ab = sub.add_parser(
        "ablate", help="run an ablation suite (eval/suites/*.toml): results.csv, results.md, plots, report.html"
    )
    ab.add_argument(
        "suite",
        nargs="*",
        type=T.in_path,
        help="suite files, e.g. eval/suites/quick.toml; several run as one grid, a run they share once, each "
        "suite's outputs in OUT/<file stem>/ (with --from-csv: one, optional, for its titles)",
    )
    ab.add_argument(
        "--out",
        required=True,
        type=T.out_dir_writing(*ABLATE_WRITES),
        help="output folder (its cache/ makes a rerun or a resumed run cheap)",
    )
    ab.add_argument("--jobs", type=T.JOBS, default=1, help="parallel worker processes")
    ab.add_argument(
        "--threads",
        type=T.int_in(0, 1024, "thread count"),
        default=0,
        help="torch threads per worker (0: cores // jobs); results are bit-identical only at one thread count",
    )
    ab.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="override a suite's [defaults] setting in every suite given, e.g. --set iters=10000 (repeatable; "
        "the runs are then other runs, with their own results)",
    )
    ab.add_argument(
        "--engine",
        choices=["local", "dask"],
        default="local",
        help="local process pool, or Dask (a LocalCluster, or --scheduler ADDRESS)",
    )
    ab.add_argument("--scheduler", default=None, help="address of a running Dask scheduler (with --engine dask)")
    ab.add_argument(
        "--cache",
        default=None,
        type=T.out_dir_writing("*"),
        help="stage cache folder shared between suites (default OUT/cache)",
    )
    ab.add_argument("--no-progress", action="store_true")
    ab.add_argument(
        "--max-runs",
        type=T.int_in(1, None, "run count"),
        default=MAX_RUNS,
        help=f"refuse a suite that expands to more runs than this (default {MAX_RUNS})",
    )
    ab.add_argument(
        "--root",
        default=None,
        type=T.in_path,
        help="dataset root for a suite's {root} (default $PANORECON_DATASET_ROOT)",
    )
    ab.add_argument(
        "--from-csv",
        default=None,
        metavar="CSV",
        type=T.in_path,
        help="re-render results.md, report.html and plots from a results.csv into --out; nothing is run",
    )
    _add_device(ab)
    ab.set_defaults(fn=cmd_ablate)

    be = sub.add_parser("bench", help="the benchmark CI job: tiny suite + micro-benchmarks against a baseline")
    be.add_argument("--quick", action="store_true", help="tiny sizes (CI)")
    be.add_argument("--suite", default="eval/suites/bench.toml", type=T.in_path)
    be.add_argument("--baseline", default="benchmarks/baseline.json", type=T.in_path)
    be.add_argument("--out", default=None, type=T.out_file, help="also write the result JSON here")
    be.add_argument("--update-baseline", action="store_true", help="store this run as the baseline")
    _add_device(be)
    be.set_defaults(fn=cmd_bench)

    from .export import add_export_parser
    from .mesh import add_mesh_parser
    from .text2pano.command import add_generate_parser
    from .viewer import add_view_parser

    add_generate_parser(sub)
    add_export_parser(sub)
    add_view_parser(sub)
    add_mesh_parser(sub)

    d = sub.add_parser("demo", help="the main job on the default scene (render, cloud, screenshot)")
    d.add_argument("--out", default="out/demo", type=T.out_dir_writing(*DEMO_WRITES))
    d.add_argument("--overwrite", action="store_true", help="delete another run's outputs in --out first")
    d.add_argument("--scene", default=None, type=T.scene, help="scene name (default: the built-in default scene)")
    d.add_argument("--width", type=T.ERP_WIDTH, default=512)
    d.add_argument(
        "--teacher", default="sim:relative", type=T.teacher_spec, help="depth teacher for the method's point cloud"
    )
    d.add_argument("--iters", type=T.ITERS, default=300, help="training steps")
    d.add_argument("--res", type=T.LABEL_RES, default=128, help="label view size in pixels for training")
    d.set_defaults(fn=cmd_demo)

    for command in ("render", "gt-cloud", "points", "train", "export", "demo"):  # every command that takes a SCENE
        _add_depth_options(sub.choices[command])
    return p


DEPTH_OPTIONS = ("depth", "depth_scale", "depth_kind")


def _add_depth_options(parser: argparse.ArgumentParser) -> None:
    """--depth / --depth-scale / --depth-kind: a real panorama's true depth (see panorecon.io.depth)."""
    g = parser.add_argument_group("true depth of a real panorama")
    g.add_argument(
        "--depth",
        default=None,
        type=T.in_path,
        help="true depth file (16-bit .png, .exr, .npy) of the same pixel size as the image",
    )
    g.add_argument(
        "--depth-scale",
        type=T.float_in(1e-9, 1e9, "depth scale"),
        default=None,
        help="metres per stored unit (default 0.001 for 16-bit PNG, i.e. millimetres as Structured3D; Stanford2D3D: "
        "1/512 = 0.001953125; Matterport3D: 1/4000 = 0.00025; 1 for .exr/.npy)",
    )
    g.add_argument(
        "--depth-kind",
        choices=("distance", "z"),
        default=None,
        help="distance along the ray (default) or cube-face z-depth",
    )


# OS errors that mean the user's paths or disk, not a bug: reported as one line like bad input
USER_OS_ERRORS = {
    errno.EACCES,
    errno.EPERM,
    errno.EROFS,
    errno.EEXIST,
    errno.ENOTDIR,
    errno.EISDIR,
    errno.ENOENT,
    errno.ENOSPC,
    errno.EDQUOT,
    errno.ENAMETOOLONG,
}


def _option_names(parser: argparse.ArgumentParser) -> dict[str, str]:
    """dest -> the option as typed (``--out``; a positional by its upper-case name), over every subcommand."""
    names = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                names.update(_option_names(sub))
        elif action.dest not in names:
            names[action.dest] = action.option_strings[-1] if action.option_strings else action.dest.upper()
    return names


def main(argv: list[str] | None = None) -> int:
    """Parse (options are validated here: a bad one exits 2 before any work), refuse an output path that is an
    input or another output (``cli_types.path_collisions``), run, and turn every user mistake into one line
    ``panorecon: error: ...`` with exit status 2, and Ctrl-C / SIGTERM into one line with exit 130 / 143
    (``interrupts``); only panorecon's own bugs leave a traceback."""
    import signal

    from . import interrupts

    old = {s: signal.getsignal(s) for s in interrupts.SIGNALS}
    interrupts.install()
    try:
        parser = build_parser()
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help (0) or a rejected option (2, its one line already printed)
        return e.code if isinstance(e.code, int) else 2
    except KeyboardInterrupt as e:
        e = e if isinstance(e, interrupts.Interrupted) else interrupts.Interrupted(signal.SIGINT)
        print(e.line(), file=sys.stderr)
        return e.exit_code
    finally:
        _restore(old)
    collision = T.path_collisions(vars(args), _option_names(parser))
    if collision:
        print(f"panorecon: error: {collision}", file=sys.stderr)
        return 2
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(name)s: %(message)s")
    interrupts.install()
    try:
        try:
            return args.fn(args)
        finally:  # inside the try below: a signal while the handlers are put back is one line too
            _restore(old)
            interrupts.end_at_exit()
    except KeyboardInterrupt as e:
        e = e if isinstance(e, interrupts.Interrupted) else interrupts.Interrupted(signal.SIGINT)
        print(e.line(), file=sys.stderr)
        return e.exit_code
    except PanoreconInputError as e:
        print(f"panorecon: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        if e.errno not in USER_OS_ERRORS:
            raise
        where = " -> ".join(str(f) for f in (e.filename, e.filename2) if f is not None)
        print(f"panorecon: error: {where + ': ' if where else ''}{e.strerror or e}", file=sys.stderr)
        return 2


def _restore(handlers: dict) -> None:
    """Put back the signal handlers main() found (in-process callers, e.g. tests, keep theirs)."""
    import signal

    if threading.current_thread() is threading.main_thread():
        for s, h in handlers.items():
            signal.signal(s, h)


if __name__ == "__main__":
    sys.exit(main())
