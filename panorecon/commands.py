"""What each ``panorecon`` command does, as functions of its typed config (``configs``); ``cli`` parses the
command line into the config and calls one of these, and ``demo`` calls several. Each imports only what it
needs. Bad input raises ``PanoreconInputError`` (one line, exit 2 from the CLI)."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import numpy as np

from . import configs as K
from .io import PanoreconInputError


def claim(out, command: str, inputs: dict, writes: tuple[str, ...], overwrite: bool) -> None:
    """The run-folder claim of ``out`` (see io.runs): another run's outputs there are refused unless ``overwrite``."""
    from .io.runs import claim_run

    claim_run(out, command, inputs, writes, overwrite)


# ---------------------------------------------------------------- scenes
def scenes_list(cfg: K.ScenesListConfig) -> int:
    from .scenes import list_scenes

    if cfg.root:
        from .scenes.datasets import list_root

        found = list_root(Path(cfg.root))
        for name, desc in found:
            print(f"{name}  ({desc.split(',')[0]})")
        print(f"{len(found)} panoramas with true depth under {cfg.root}")
        return 0
    rows = [(s.name, s.kind, "yes" if s.has_ground_truth else "no", s.description) for s in list_scenes()]
    w = max(len(r[0]) for r in rows)
    print(f"{'name':<{w}}  {'kind':<9}  {'truth':<5}  description")
    for name, kind, gt, desc in rows:
        print(f"{name:<{w}}  {kind:<9}  {gt:<5}  {desc}")
    return 0


def scenes_check(cfg: K.ScenesCheckConfig) -> int:
    from .io import write_json
    from .scenes.check import check_root, report_table, summary_line
    from .scenes.datasets import list_root

    if not Path(cfg.root).is_dir():
        raise PanoreconInputError(f"{cfg.root}: not a folder; expected a dataset folder")
    if not list_root(Path(cfg.root)):
        raise PanoreconInputError(
            f"{cfg.root}: no Stanford2D3D, Structured3D or Matterport3D panorama under it, and no poses.json "
            "(a posed-panoramas folder)"
        )
    report = check_root(Path(cfg.root), cfg.width)
    print(report_table(report))
    print(summary_line(report))
    if cfg.json:
        write_json(cfg.json, {"root": str(cfg.root), "width": cfg.width, **report.to_dict()})
    return 1 if report.flagged else 0


def render(cfg: K.RenderConfig, claimed: bool = False) -> int:
    """pano.png, mask.png, distance.npy, scene.json and the held-out views of a synthetic scene into cfg.out."""
    from .io import save_npy, write_image, write_json

    t0 = time.perf_counter()
    scene = cfg.scene.load()
    seconds = time.perf_counter() - t0
    out = Path(cfg.out)
    if not claimed:
        claim(out, "render", {**cfg.scene.identity(), "heldout": cfg.heldout}, K.RENDER_WRITES, cfg.overwrite)
    write_image(out / "pano.png", scene.rgb)
    mask = scene.valid if scene.distance is not None else ~scene.sky
    write_image(out / "mask.png", (mask * 255).astype(np.uint8))
    if scene.distance is not None:
        save_npy(out / "distance.npy", scene.distance.astype(np.float32))
    heldout_note, radius = "", None
    if scene.world is not None and cfg.heldout:
        # the true views `train` holds out, so that the folder trains and evaluates without Open3D
        from .scenes.rendered import RecordingWorld, save_heldout
        from .splat.labels import make_heldout_views

        train = K.TrainConfig()
        radius = scene.world.free_space_radius()
        for res in cfg.heldout_res:
            rec = RecordingWorld(scene.world)
            for seed in cfg.heldout_seeds:
                make_heldout_views(dataclasses.replace(scene, world=rec), cfg.heldout, res, train.fov_deg, seed)
            save_heldout(out, rec.cameras, rec.renders)
        seeds = f" for seed{'s' * (len(cfg.heldout_seeds) > 1)} {', '.join(map(str, cfg.heldout_seeds))}"
        heldout_note = f", {cfg.heldout} held-out views at {'/'.join(map(str, cfg.heldout_res))} px{seeds}"
    about = ("name", "kind", "description", "distance_kind", "meta")
    write_json(
        out / "scene.json",
        {
            **{k: getattr(scene, k) for k in about},
            "free_space_radius": radius,
            "heldout_seeds": list(cfg.heldout_seeds) if radius is not None else [],
        },
    )
    print(
        f"{scene.name}: {scene.width}x{scene.height} rendered in {seconds:.2f} s{heldout_note} -> {out}"
        + ("" if scene.distance is not None else " (no depth: distance.npy not written)")
    )
    return 0


def gt_cloud(cfg: K.GtCloudConfig) -> int:
    scene = cfg.scene.load()
    if scene.distance is None:
        raise PanoreconInputError(f"scene {scene.name!r} has no depth, so it has no ground-truth cloud")
    if not scene.has_ground_truth:
        print(f"note: {scene.name}'s depth is {scene.meta.get('depth_from', scene.distance_kind)}, not ground truth")
    pc = scene.point_cloud()
    pc.save_ply(cfg.out)
    print(f"{scene.name}: {len(pc)} points -> {cfg.out}")
    return 0


def inspect_cloud(cfg: K.InspectConfig) -> int:
    from .geometry.pointcloud import PointCloud
    from .viz import screenshot, show

    path = Path(cfg.cloud)
    pc = PointCloud.load_ply(path)
    if cfg.clip_z is not None and not (pc.xyz[:, 2] <= cfg.clip_z).any():
        raise PanoreconInputError(
            f"--clip-z {cfg.clip_z:g} hides every point of {path} (its heights run from "
            f"{pc.xyz[:, 2].min():.3g} to {pc.xyz[:, 2].max():.3g} m)"
        )
    if cfg.screenshot:
        screenshot(pc, cfg.screenshot, cfg.color, cfg.point_size, cfg.clip_z)
        print(f"{path}: {len(pc)} points -> {cfg.screenshot}")
    else:
        show(pc, cfg.color, cfg.point_size, cfg.clip_z)
    return 0


# ---------------------------------------------------------------- teachers, sources, points
def teachers_list(cfg: K.ListConfig) -> int:
    from .teachers import list_teachers

    for spec, desc in list_teachers():
        print(f"{spec:<34}  {desc}")
    return 0


def teachers_train(cfg: K.TeachersTrainConfig) -> int:
    """Train (or resume) the learned teacher into cfg.out and export it (learned.train.train_teacher)."""
    import shlex

    from . import checks as C
    from .learned.train import train_teacher

    claim(cfg.out, "teachers-train", {"config": cfg.train.digest()}, K.TEACHER_TRAIN_WRITES, cfg.overwrite)
    words = ["panorecon", "teachers", "train"]
    for s in C.settings(type(cfg.train)):  # the options that differ from their defaults: the command that remakes it
        value = getattr(cfg.train, s.name)
        if value != s.default:
            words += [f"--{s.name.replace('_', '-')}", *map(str, value if isinstance(value, tuple) else [value])]
    r = train_teacher(cfg.train, cfg.out, shlex.join([*words, "--out", str(cfg.out)]), progress=not cfg.no_progress)
    f = r["final"]
    print(
        f"{cfg.train.name}: {r['parameters']} parameters, {cfg.train.steps} steps in {r['train_seconds']:.0f} s; "
        f"val seen AbsRel {f['seen_abs_rel']:.4f} d1 {f['seen_delta1']:.3f}, unseen AbsRel {f['unseen_abs_rel']:.4f} "
        f"d1 {f['unseen_delta1']:.3f} -> {Path(cfg.out) / (cfg.train.name + '.onnx')}"
    )
    return 0


def sources_list(cfg: K.ListConfig) -> int:
    from .sources import list_sources

    for s in list_sources():
        print(f"{s.name:<12}  {s.description}")
    return 0


def check_source(src: K.SourceArgs, views: int | None) -> None:
    """The source's name and the view count it is given, checked before any work."""
    from .geometry.layouts import LAYOUT_NAMES, make_layout
    from .sources import get_source

    get_source(src.source)
    if src.source in LAYOUT_NAMES and views is not None:
        try:
            make_layout(src.source, views)
        except ValueError as e:
            raise PanoreconInputError(f"--views {views}: {e}") from None


def initial_cloud(scene, src: K.SourceArgs, views, cloud_path, report_path, device="auto", **options):
    """Run the point source, write its cloud (and report, and ``distance_out``) and print one summary line ->
    (PointCloud, report). ``options``: view_size, max_points, distance_out (a path for the fused ERP distance).
    The outputs are written together (``atomic_write_all``): an error or a Ctrl-C/SIGTERM before they are all
    written leaves none of them (files already at those paths are kept), one during the final renames leaves all
    of them whole."""
    from .device import resolve_device
    from .io import atomic_write_all, json_text
    from .pipeline.stages import fusion_config_for
    from .sources import run_source

    fusion = fusion_config_for(resolve_device(device), src.fusion)
    pc, report = run_source(
        scene,
        src.source,
        src.teacher,
        views,
        fusion,
        view_size=options.get("view_size"),
        max_points=options.get("max_points"),
    )
    distance_out = options.get("distance_out")
    if distance_out and pc.meta.get("erp_distance") is None:
        raise PanoreconInputError(f"--distance-out {distance_out}: source {src.source!r} gives no ERP distance")
    outputs = [p for p in (cloud_path, distance_out, report_path) if p]
    with atomic_write_all(outputs) as tmps:
        written = dict(zip(outputs, tmps))
        pc.save_ply(written[cloud_path])
        if distance_out:
            with open(written[distance_out], "wb") as f:  # a file object: np.save adds no ".npy" to the name
                np.save(f, pc.meta["erp_distance"])
        if report_path:
            written[report_path].write_text(json_text(report))
    _print_points(scene, src, pc, report, cloud_path)
    return pc, report


def _print_points(scene, src, pc, report, cloud_path) -> None:
    depth = report.get("depth")
    d = (
        f"AbsRel {depth['abs_rel']:.4f}, delta1 {depth['delta1']:.3f}"
        if isinstance(depth, dict) and isinstance(depth.get("abs_rel"), float)
        else str(depth)
    )
    pts = report["points"]
    chamfer = f"{pts['chamfer']:.4f} m" if isinstance(pts.get("chamfer"), float) else pts.get("chamfer")
    flying = f", flying {100 * pts['flying']:.3f} %" if isinstance(pts.get("flying"), float) else ""
    thin = report.get("thinning")
    if thin and thin.get("thinned"):
        print(
            f"thinned to {thin['points']} points, {thin['spacing_deg']:.3f} deg apart "
            f"({thin['points_per_sr']:.0f} per sr)"
        )
    print(
        f"{scene.name} / {src.source} / {report['teacher']}: {len(pc)} points, depth {d}, chamfer {chamfer}{flying}, "
        f"{report['seconds']['total']:.2f} s, peak {report['peak_rss_mb']:.0f} MB -> {cloud_path}"
    )
    for warning in report.get("warnings", []):
        print(f"WARNING: {warning}")


def points(cfg: K.PointsConfig) -> int:
    from .device import resolve_device

    resolve_device(cfg.device)  # --device cuda without CUDA: refused before any work
    check_source(cfg.source, cfg.source.views)  # before the scene is rendered
    options = dict(view_size=cfg.view_size, max_points=cfg.max_points, distance_out=cfg.distance_out)
    initial_cloud(cfg.scene.load(), cfg.source, cfg.source.views, cfg.out, cfg.report, cfg.device, **options)
    return 0


def check_backend(backend: str, device) -> None:
    """A backend that cannot render on ``device`` is bad input: one line, before any work."""
    from .splat.rasterize import cpu_backend, gsplat_backend

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


def train(cfg: K.TrainCommandConfig, claimed: bool = False) -> int:
    """The point source's cloud, then Gaussians trained from it (splat.trainer.train) into cfg.out."""
    from . import sources
    from .device import resolve_device
    from .pipeline import teacher_depth_fn
    from .sources import cloud_scale
    from .splat.evaluate import heldout_summary
    from .splat.trainer import train as fit

    device = resolve_device(cfg.device)
    check_backend(cfg.train.backend, device)
    views, src = cfg.views(), cfg.source
    check_source(src, views)
    scene = cfg.scene.load()
    sources.check_source(scene, src.source, src.teacher)  # what the source needs of this scene: before the claim
    if not claimed:
        inputs = {"source": src.source, "teacher": src.teacher, "views": views, "config": cfg.train.digest()}
        claim(cfg.out, "train", {**cfg.scene.identity(), **inputs}, K.TRAIN_WRITES, cfg.overwrite)
    out = Path(cfg.out)
    cloud, report = initial_cloud(
        scene, src, views, out / f"{src.source}_cloud.ply", out / f"{src.source}_report.json", cfg.device
    )
    m = fit(
        scene,
        cloud,
        cfg.train,
        cfg.out,
        teacher_depth_fn(scene, src.teacher),
        progress=not cfg.no_progress,
        inputs={"source": src.source, "teacher": src.teacher, "views": views, "depth": cfg.scene.depth},
        device=device,
        heldout_scale=cloud_scale(report),
    )
    lp = m["pseudo-label"]["lpips"]
    lp_txt = f"{lp:.3f}" if isinstance(lp, float) else lp
    print(
        f"{scene.name} / {src.source}: pseudo-label PSNR {m['pseudo-label']['psnr']:.2f} dB, SSIM "
        f"{m['pseudo-label']['ssim']:.3f}, LPIPS {lp_txt}; {heldout_summary(m['held-out'])}; "
        f"{m['gaussians']} Gaussians; "
        f"{m['seconds']['total']:.1f} s ({m['seconds']['train']:.1f} s training); peak {m['peak_rss_mb']:.0f} MB; "
        f"{m['backend']} on {m['device_name']} -> {cfg.out}"
    )
    return 0


# ---------------------------------------------------------------- evaluation
def ablate(cfg: K.AblateConfig) -> int:
    from .device import resolve_device
    from .evaluation.ablate import run_suites, suite_out_dirs
    from .evaluation.report import average_table
    from .evaluation.suite import load_suite, parse_override

    if cfg.from_csv:
        return _ablate_from_csv(cfg)
    if not cfg.suite:
        raise PanoreconInputError("ablate: give a suite file (e.g. eval/suites/quick.toml) or --from-csv results.csv")
    resolve_device(cfg.device)
    if cfg.scheduler and cfg.engine != "dask":
        raise PanoreconInputError(f"--scheduler {cfg.scheduler}: a scheduler is used only with --engine dask")
    if cfg.root is not None and not Path(cfg.root).is_dir():
        raise PanoreconInputError(f"--root {cfg.root}: no such folder (expected a dataset root)")
    overrides = dict(parse_override(t) for t in cfg.set)
    suites = [load_suite(s, cfg.root, overrides, cfg.scene_dir, cfg.max_runs, cfg.unpinned) for s in cfg.suite]
    stems = [s.name for s in suites]
    if len(set(stems)) != len(stems):
        raise PanoreconInputError(f"ablate: suites {', '.join(cfg.suite)} share a file name; rename one")
    runs = {r.run_id() for s in suites for r in s.rows}
    if len(runs) > cfg.max_runs:
        raise PanoreconInputError(
            f"suite {' '.join(cfg.suite)} expands to {len(runs)} runs, more than --max-runs {cfg.max_runs}; "
            "pass a larger --max-runs to run it"
        )
    if cfg.engine == "dask" and cfg.scheduler:
        from .evaluation.ablate import check_scheduler

        check_scheduler(cfg.scheduler)
    if cfg.verify:
        from .evaluation.verify import verify_suites

        for text in verify_suites(suites, cfg.out, cfg.verify, cfg.jobs, cfg.threads, cfg.device, cfg.cache):
            print(text)
        return 0
    for s in suites:
        print(f"{s.title}: {len(s.rows)} runs")
    frames = run_suites(
        suites,
        cfg.out,
        jobs=cfg.jobs,
        engine=cfg.engine,
        scheduler=cfg.scheduler,
        cache_dir=cfg.cache,
        progress=not cfg.no_progress,
        device=cfg.device,
        threads=cfg.threads,
        retry_unavailable=cfg.retry_unavailable,
    )
    for suite, frame, o in zip(suites, frames, suite_out_dirs(suites, Path(cfg.out))):
        cols = [c for c in ("psnr_pl", "psnr_ho", "abs_rel", "chamfer", "sec_total", "peak_mb") if c in frame]
        print(suite.title)
        print(average_table(frame)[cols].to_string(float_format=lambda v: f"{v:.4g}"))
        if "warning" in frame:
            for _, r in frame[frame["warning"].fillna("").astype(str) != ""].iterrows():
                print(f"WARNING ({r['label']}, {r['scene']}): {r['warning']}")
        print(f"-> {o / 'results.csv'}, results.md, pareto.png, report.html")
    return 0


def _ablate_from_csv(cfg: K.AblateConfig) -> int:
    """``ablate --from-csv CSV [SUITE] --out DIR``: tables, report and plots from a results.csv, nothing run."""
    from .evaluation.rerender import rerender
    from .evaluation.suite import load_suite

    if len(cfg.suite) > 1:
        raise PanoreconInputError(f"ablate --from-csv: give at most one suite (got {len(cfg.suite)})")
    suite = load_suite(cfg.suite[0], cfg.root) if cfg.suite else None
    frame = rerender(cfg.from_csv, cfg.out, suite)
    print(f"{len(frame)} runs from {cfg.from_csv} -> {Path(cfg.out) / 'results.md'}, report.html, pareto.png")
    return 0


def bench(cfg: K.BenchConfig) -> int:
    from .bench.command import run_bench

    return run_bench(
        cfg.suite, cfg.baseline, cfg.out, quick=cfg.quick, update_baseline=cfg.update_baseline, device=cfg.device
    )
