"""Fusion benchmark: the method's fusion (20 Fibonacci views) against MoGe's own merge (``merge_panorama_depth``
of the ``dlr-moge`` package on its 12 icosahedron-vertex views at 90 degrees), each on its own default views,
measured in the same run, on a box room whose true ray distance is known, with per-view random scales in
[0.7, 1.4] and 2 % multiplicative noise. (Equal inputs for both: ``bench.fusion_moge``.)

    python -m panorecon.bench.fusion [--quick] [--repeats N] [--out result.json]

Prints JSON: machine, versions, commit, and per size the median seconds, AbsRel and peak RSS of each
method (each repeat in a fresh process, so the peak is that run's own; it includes the ~0.3 GB of imports)
and the speed ratio reference / method.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from dataclasses import dataclass

import numpy as np

from .. import checks as C
from ..checks import opt
from ..evaluation.environment import emit, environment, in_fresh_process


def box_distance(d):
    lo, hi = np.array([-3.0, -4.0, -1.6]), np.array([2.0, 3.5, 1.1])
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, hi / d, np.where(d < 0, lo / d, np.inf))
    return t.min(-1)


def one_run(method: str, height: int, view_size: int, seed: int) -> dict:
    from panorecon.fusion import fuse_views
    from panorecon.geometry import ViewDepth, centred_camera, erp_directions, make_layout
    from panorecon.metrics import depth_metrics

    from .fusion_moge import moge_cameras, moge_merge_maps, panorecon_views_as_moge

    if method == "fibonacci-lsq":
        layout = make_layout("fibonacci", 20)
        cams = [centred_camera(f, view_size, layout.fov_deg) for f in layout.directions]
    else:
        cams = moge_cameras(view_size)
    rng = np.random.default_rng(seed)
    maps = [
        (
            box_distance(c.world_rays()) * rng.uniform(0.7, 1.4) * (1 + 0.02 * rng.standard_normal((c.height, c.width)))
        ).astype(np.float32)
        for c in cams
    ]
    if method == "fibonacci-lsq":
        views = [ViewDepth(c, m, "distance", np.ones(m.shape, bool)) for c, m in zip(cams, maps)]
        fuse_views(views[:2], 16, 32)  # warm-up: lazy imports and first-call costs stay out of the timing
        t = time.perf_counter()
        r = fuse_views(views, height, 2 * height)
        seconds, pred, its = time.perf_counter() - t, r.distance, r.report["iterations"]
    else:
        ext, ints = panorecon_views_as_moge(cams)
        moge_merge_maps(maps[:2], ext[:2], ints[:2], 16, 32)
        t = time.perf_counter()
        pred = moge_merge_maps(maps, ext, ints, height, 2 * height)
        seconds, its = time.perf_counter() - t, None
    m = depth_metrics(pred, box_distance(erp_directions(height, 2 * height)))
    return {"seconds": seconds, "abs_rel": m["abs_rel"], "iterations": its}


@dataclass(frozen=True)
class BenchFusionConfig:
    quick: bool = opt(False, "one small size (CI)")
    repeats: int | None = opt(None, "fresh-process runs per size (default 3)", check=C.int_in(1, None, "repeat count"))
    out: str | None = opt(None, "also write the result JSON here", role="out-file")


def main(argv=None) -> dict:
    from ..cli_types import parse_config

    cfg = parse_config(BenchFusionConfig, argv, __doc__.splitlines()[0])
    # (ERP height, view size); quick: 512 x 256, large enough that the ratio is not dominated by fixed costs
    sizes = [(256, 128)] if cfg.quick else [(480, 512), (1024, 512)]
    repeats = cfg.repeats or 3
    results = []
    for height, view_size in sizes:
        row = {"erp": f"{2 * height}x{height}", "view_size": view_size, "repeats": repeats}
        for method in ("fibonacci-lsq", "moge-reference"):
            runs = [in_fresh_process(one_run, method, height, view_size, k) for k in range(repeats)]
            row[method] = {
                "median_seconds": statistics.median(r["seconds"] for r in runs),
                "median_abs_rel": statistics.median(r["abs_rel"] for r in runs),
                "peak_rss_mb": max(r["peak_rss_mb"] for r in runs),
                "iterations": runs[0]["iterations"],
            }
        row["speedup_vs_reference"] = row["moge-reference"]["median_seconds"] / row["fibonacci-lsq"]["median_seconds"]
        results.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    return emit({"benchmark": "fusion", **environment(), "results": results}, cfg.out)


if __name__ == "__main__":
    main()
