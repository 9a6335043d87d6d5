"""Fusion on equal inputs: MoGe's own ``merge_panorama_depth`` (the ``dlr-moge`` package) and panorecon's
``fuse_views`` fed the same views.

A scene's true ERP ray distance is split by MoGe's own ``split_panorama_image`` (bilinear) into MoGe's 12
icosahedron-vertex views of 90 degrees, 512 px; each condition perturbs every view the same way for both
methods: ``exact`` (as split), ``scale`` (times a random per-view scale in [0.7, 1.4]), ``scale+noise``
(and times 1 + 0.02 N(0, 1) per view pixel). Both outputs are compared with the truth at the ERP size
(AbsRel after median alignment). ``fibonacci-own`` is panorecon on its own default views (20 Fibonacci
views, ``default_view_size``) split the same way, under ``scale+noise``.

    python -m panorecon.bench.fusion_moge [--widths 1024 2048] [--variants nearest linear-1 linear-2]
        [--repeats N] [--out result.json]

Needs the ``moge`` extra (``dlr-moge`` and ``dlr-utils3d``; see scripts/setup.sh). Every run is a fresh
process: ``peak_mb`` is that run's peak resident memory (VmHWM: imports, truth and views included,
``rss_before_mb`` of it before the merge started). ``seconds`` is wall time, ``cpu_seconds`` the process's
CPU time; on a shared machine set OMP_NUM_THREADS=1 (recorded in ``thread_env``) so that BLAS threads of
either method do not fight other work. MoGe's ERP has its seam at panorecon's lon 0 (columns rolled by W/2); the
benchmark rolls its input and output accordingly.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .. import checks as C
from ..checks import opt
from ..evaluation.environment import emit, environment, in_fresh_process

CONDITIONS = ("exact", "scale", "scale+noise")
METHODS = ("moge", "fuse_views")
NOISE = 0.02
VIEW_SIZE = 512


def require_moge():
    """MoGe's panorama module, or PanoreconInputError saying what to install."""
    try:
        from moge.utils import panorama
    except ImportError as e:
        from ..io import PanoreconInputError

        raise PanoreconInputError(
            f"MoGe's merge is not installed ({e}); install the moge extra: "
            "pip install --no-deps dlr-moge==2.0.0 dlr-utils3d==1.3"
        ) from None
    return panorama


def panorecon_views_as_moge(cameras):
    """(extrinsics [V, 4, 4], normalised intrinsics list) for panorecon cameras (same OpenCV axes)."""
    ext = np.stack([c.viewmat for c in cameras]).astype(np.float32)
    ints = [c.K / np.array([[c.width], [c.height], [1.0]]) for c in cameras]
    return ext, ints


def equal_views(truth: np.ndarray, layout: str, condition: str, seed: int, size: int | None = None):
    """Split panorecon-frame ERP truth [H, W] with MoGe's split into the views of ``layout`` ("moge": its 12
    icosahedral views; "fibonacci": panorecon's default 20) and perturb them. -> (distance maps [V] of
    [size, size] float32 (size: VIEW_SIZE unless given), extrinsics [V, 4, 4], normalised intrinsics [V])."""
    pano = require_moge()
    size = size or VIEW_SIZE
    if layout == "moge":
        ext, ints = pano.get_panorama_cameras()
    else:
        from ..geometry import centred_camera, make_layout

        lay = make_layout("fibonacci", 20)
        ext, ints = panorecon_views_as_moge([centred_camera(d, size, lay.fov_deg) for d in lay.directions])
    moge_frame = np.roll(truth.astype(np.float32), truth.shape[1] // 2, axis=1)
    maps = pano.split_panorama_image(moge_frame, ext, ints, size)
    rng = np.random.default_rng(seed)
    out = []
    for m in maps:
        f = rng.uniform(0.7, 1.4) if condition != "exact" else 1.0
        noise = 1 + NOISE * rng.standard_normal(m.shape) if condition == "scale+noise" else 1.0
        out.append((m * f * noise).astype(np.float32))
    return out, ext, ints


def moge_cameras(size: int):
    """MoGe's 12 panorama cameras (``get_panorama_cameras``) as panorecon ``PinholeCamera``s of size^2 px."""
    from ..geometry import PinholeCamera

    ext, ints = require_moge().get_panorama_cameras()
    return [
        PinholeCamera(
            np.asarray(k, np.float64) * np.array([[size], [size], [1.0]]), np.asarray(e, np.float64), size, size
        )
        for e, k in zip(ext, ints)
    ]


def moge_merge_maps(maps, ext, ints, height: int, width: int) -> np.ndarray:
    """MoGe's ``merge_panorama_depth`` on finite distance maps -> [H, W] float32 in panorecon's ERP columns."""
    depth, _ = require_moge().merge_panorama_depth(width, height, maps, [np.isfinite(m) for m in maps], ext, ints)
    return np.roll(depth, -(width // 2), axis=1)


def _view_depths(maps, ext, ints):
    from ..geometry import PinholeCamera, ViewDepth

    vds = []
    for m, e, k in zip(maps, ext, ints):
        h, w = m.shape
        K = np.asarray(k, np.float64) * np.array([[w], [h], [1.0]])
        vds.append(ViewDepth(PinholeCamera(K, np.asarray(e, np.float64), w, h), m, "distance", np.isfinite(m)))
    return vds


def _status_mb(field: str) -> float:
    """A memory line of /proc/self/status in MB: VmRSS (now) or VmHWM (this process image's peak since exec;
    unlike getrusage's ru_maxrss it does not carry the parent's RSS at fork)."""
    with open("/proc/self/status") as f:
        line = next(ln for ln in f if ln.startswith(field + ":"))
    return int(line.split()[1]) / 1024.0


def one_run(method: str, truth_path: str, layout: str, condition: str, seed: int, config: dict | None = None) -> dict:
    """One merge in this process: -> seconds (wall), cpu_seconds (this process's CPU time: less disturbed than
    wall time by other work on a shared machine), abs_rel (median-aligned, against the truth), rss_before_mb."""
    from ..fusion import FusionConfig, fuse_views
    from ..metrics import depth_metrics

    truth = np.load(truth_path)
    H, W = truth.shape
    maps, ext, ints = equal_views(truth, layout, condition, seed)
    if method == "moge":
        pano = require_moge()
        pano.merge_panorama_depth(32, 16, maps[:2], [np.ones_like(m, bool) for m in maps[:2]], ext[:2], ints[:2])
        rss = _status_mb("VmRSS")
        t, c = time.perf_counter(), time.process_time()
        pred = moge_merge_maps(maps, ext, ints, H, W)
        seconds, cpu = time.perf_counter() - t, time.process_time() - c
        extra = {}
    else:
        vds = _view_depths(maps, ext, ints)
        fuse_views(vds[:2], 16, 32)  # warm-up: lazy imports stay out of the timing
        rss = _status_mb("VmRSS")
        t, c = time.perf_counter(), time.process_time()
        res = fuse_views(vds, H, W, FusionConfig(**(config or {})))
        seconds, cpu = time.perf_counter() - t, time.process_time() - c
        pred = res.distance
        extra = {"iterations": res.report["iterations"]}
    m = depth_metrics(pred, truth)
    return {
        "seconds": seconds,
        "cpu_seconds": cpu,
        "abs_rel": m["abs_rel"],
        "pixels": m["pixels"],
        "rss_before_mb": rss,
        "peak_mb": _status_mb("VmHWM"),
        **extra,
    }


VARIANTS = {
    "nearest": {"sampling": "nearest"},
    "linear-1": {"supersample": 1},
    "linear-2": {"supersample": 2},
    "float64-cg": {"cg_precision": "double"},  # the CG before mixed precision
    "coarse-start": {"warm_start": "coarse"},  # each level's CG started from the coarser solution only
}


def run(scene: str, widths, conditions, seed: int, variants=(), log=sys.stderr, repeats: int = 1) -> list[dict]:
    """All rows: per width, condition and method (equal inputs), plus fibonacci-own per width, plus
    ``fuse_views[variant]`` (``VARIANTS``: one FusionConfig change each) on the equal inputs under
    scale+noise. Each row runs ``repeats`` times, each in a fresh process: ``seconds`` and ``cpu_seconds`` are
    the medians (every run's in ``*_runs``), ``peak_mb`` the largest."""
    from ..scenes import load_scene

    require_moge()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for width in widths:
            path = str(Path(tmp) / f"truth{width}.npy")
            np.save(path, load_scene(scene, width).distance.astype(np.float32))
            jobs = [(m, "moge", c, None) for c in conditions for m in METHODS]
            jobs += [("fuse_views", "fibonacci", "scale+noise", None)]
            jobs += [("fuse_views", "moge", "scale+noise", v) for v in variants]
            for method, layout, condition, variant in jobs:
                runs = [
                    in_fresh_process(one_run, method, path, layout, condition, seed, VARIANTS.get(variant))
                    for _ in range(repeats)
                ]
                r = dict(runs[0])  # abs_rel, pixels and iterations are the same in every run (deterministic)
                r.pop("peak_rss_mb", None)  # getrusage's peak counts the parent's RSS at fork: peak_mb is the run's own
                for key in ("seconds", "cpu_seconds"):
                    r[key] = float(np.median([x[key] for x in runs]))
                    r[key + "_runs"] = [x[key] for x in runs]
                r["peak_mb"] = max(x["peak_mb"] for x in runs)
                name = "fibonacci-own" if layout == "fibonacci" else f"{method}[{variant}]" if variant else method
                row = {
                    "erp": f"{width}x{width // 2}",
                    "condition": condition,
                    "method": name,
                    "views": 12 if layout == "moge" else 20,
                    **r,
                }
                print(json.dumps(row), file=log, flush=True)
                rows.append(row)
    for row in rows:
        if row["method"] != "moge":
            ref = next(
                (
                    r
                    for r in rows
                    if r["method"] == "moge" and r["erp"] == row["erp"] and r["condition"] == row["condition"]
                ),
                None,
            )
            if ref is None:
                continue
            row["speedup_vs_moge"] = ref["seconds"] / row["seconds"]
            row["cpu_speedup_vs_moge"] = ref["cpu_seconds"] / row["cpu_seconds"]
            row["abs_rel_ratio_vs_moge"] = row["abs_rel"] / ref["abs_rel"]
    return rows


@dataclass(frozen=True)
class BenchFusionMogeConfig:
    scene: str = opt("bedroom", "scene name (see `panorecon scenes list`)")
    widths: tuple[int, ...] = opt((1024, 2048), "ERP widths", check=C.ERP_WIDTH, many=True)
    conditions: tuple[str, ...] = opt(tuple(CONDITIONS), "input conditions", choices=tuple(CONDITIONS), many=True)
    seed: int = opt(0, "random seed", check=C.SEED)
    variants: tuple[str, ...] = opt(
        (),
        "also fuse_views with one setting changed (scale+noise): the levers measured alone",
        choices=tuple(sorted(VARIANTS)),
        many=True,
    )
    repeats: int = opt(1, "fresh-process runs per row (seconds: their median)", check=C.int_in(1, None, "repeat count"))
    out: str | None = opt(None, "also write the result JSON here", role="out-file")


def main(argv=None) -> dict:
    from ..cli_types import parse_config

    cfg = parse_config(BenchFusionMogeConfig, argv, __doc__.splitlines()[0])
    with open("/proc/loadavg") as f:
        load_before = f.read().split()[:3]
    rows = run(cfg.scene, cfg.widths, cfg.conditions, cfg.seed, cfg.variants, repeats=cfg.repeats)
    from importlib.metadata import version

    env = environment()
    env["versions"]["dlr-moge"] = version("dlr-moge")
    env["versions"]["dlr-utils3d"] = version("dlr-utils3d")
    with open("/proc/loadavg") as f:
        load = f.read().split()[:3]
    threads = {k: os.environ[k] for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS") if k in os.environ}
    return emit(
        {
            "benchmark": "fusion-vs-moge-equal-inputs",
            "scene": cfg.scene,
            "view_size": VIEW_SIZE,
            "noise": NOISE,
            "seed": cfg.seed,
            "repeats": cfg.repeats,
            "loadavg_before": load_before,
            "loadavg_after": load,
            "thread_env": threads,
            **env,
            "results": rows,
        },
        cfg.out,
    )


if __name__ == "__main__":
    main()
