"""Stress benchmark: extreme panoramas through the points stage (every source) and a short training (the method's
source), error against run time for each case.

    python eval/stress.py [--quick] [--cases NAME,...] [--sources NAME,...] [--width 512]
                          [--train-iters 100] [--out benchmarks/stress.json] [--table docs/stress_table.md]

Cases (``CASES``, one list; each builds a ``Scene`` at a width): depth scales 1e-3 and 1e3 (the bedroom's true
distances times the factor), near/far cliffs of ratio 10 to 1e4, a jump at the ERP's left/right seam, ramps over
two and four decades, all sky, no sky (the bedroom), content only near the poles, a textureless panorama, 64 px and
8K widths, and the real panoramas (hohonet with its predicted depth as a ``file:`` teacher; py360-demo has no
depth, so no teacher runs on it offline). Scenes with truth use the ``sim:relative`` teacher (which samples the
truth), scenes without it get n/a depth columns.

Per case and source (``sources.run_source``, the points stage): AbsRel, delta1 (from its report), the median
relative error and the share of flying points (more than 50 % off their true distance after the report's one
median scale), each also WS-weighted (cos-latitude row weights, ``metrics.panorama.erp_row_weights``), points,
seconds and the process's peak resident MB during the row (VmHWM reset before it, ``io.reset_peak_rss``). Per
case, the method's source trained for a short budget (``--train-iters`` steps at ``--train-res`` px, ``--labels``
labels, no held-out views, ``--init-detail``; ``splat.trainer.train``): pseudo-label PSNR, Gaussians, seconds,
peak MB. A case a source cannot run, or runs and gets no point from (all sky), is a row with its reason.
``--quick``: four cases at 64 px, two sources, 5 training steps (seconds; the test's mode). Prints JSON (machine,
versions, commit), a markdown table of every case and source (``table``) and one line per case (``summary``: the
method's columns beside the worst over the sources).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from panorecon.metrics.depth import FLYING_REL

LAYOUTS = ("fibonacci", "icosahedral", "latlong", "cube")  # the fused view layouts; the method is the first
SOURCES = (*LAYOUTS, "erp-direct", "moge-merge")
TEACHER = "sim:relative"


@dataclass(frozen=True)
class Case:
    """A stress case: ``build(width)`` -> Scene; ``width`` overrides the run's width (64 px, 8K); ``teacher``
    None: the default for scenes with truth."""

    name: str
    what: str
    build: Callable
    width: int | None = None
    teacher: str | None = None


def _texture(lon: np.ndarray, lat: np.ndarray, palette: int = 0) -> np.ndarray:
    """[H, W, 3] uint8: a smooth colour field with 10-degree checks, so a teacher and the labels have detail."""
    check = (np.floor(lon / np.radians(10)) + np.floor(lat / np.radians(10))) % 2
    base = np.stack([0.5 + 0.3 * np.sin(lon + palette), 0.5 + 0.3 * np.cos(2 * lat + palette), 0.4 + 0.2 * check], -1)
    return np.clip(base * 255, 0, 255).round().astype(np.uint8)


def _grid(width: int) -> tuple[np.ndarray, np.ndarray]:
    from panorecon.geometry import erp_pixel_to_lonlat

    h = width // 2
    rr, cc = np.meshgrid(np.arange(h, dtype=np.float64), np.arange(width, dtype=np.float64), indexing="ij")
    return erp_pixel_to_lonlat(rr, cc, h, width)


def erp_case(name: str, distance: np.ndarray, rgb: np.ndarray, sky: np.ndarray | None = None):
    """A Scene with true ERP ``distance`` [H, W] (metres, inf on sky), ``rgb`` [H, W, 3] uint8 and no world: a
    simulated teacher samples the truth; there are no held-out views."""
    from panorecon.scenes.base import Scene

    sky = np.zeros(distance.shape, bool) if sky is None else sky
    return Scene(name, "synthetic", name, rgb, np.where(sky, np.inf, distance).astype(np.float32), sky, "truth")


def scaled_bedroom(scale: float) -> Callable:
    def build(width):
        from panorecon.scenes import load_scene

        s = load_scene("bedroom", width)
        return erp_case(f"bedroom x{scale:g}", s.distance * scale, s.rgb, s.sky)

    return build


def cliff(ratio: float) -> Callable:
    """A near wall (1 m) over longitudes -60..60 deg and latitudes -45..45 deg in front of a far sphere at
    ``ratio`` m."""

    def build(width):
        lon, lat = _grid(width)
        near = (np.abs(lon) < np.radians(60)) & (np.abs(lat) < np.radians(45))
        rgb = np.where(near[..., None], _texture(lon, lat, 0), _texture(lon, lat, 2))
        return erp_case(f"cliff 1:{ratio:g}", np.where(near, 1.0, ratio), rgb)

    return build


def ramp(decades: float) -> Callable:
    """Distance 0.1 m at the south pole rising log-linearly with latitude over ``decades`` decades."""

    def build(width):
        lon, lat = _grid(width)
        return erp_case(f"ramp {decades:g} decades", 0.1 * 10.0 ** (decades * (lat / np.pi + 0.5)), _texture(lon, lat))

    return build


def all_sky(width):
    lon, lat = _grid(width)
    return erp_case("all sky", np.full(lon.shape, np.inf), _texture(lon, lat), np.ones(lon.shape, bool))


def poles_only(width):
    """A 3 m sphere, textured only above 60 deg of latitude (north and south), one grey elsewhere."""
    lon, lat = _grid(width)
    polar = np.abs(lat) > np.radians(60)
    rgb = np.where(polar[..., None], _texture(lon, lat), np.uint8(128))
    return erp_case("poles only", np.full(lon.shape, 3.0), rgb)


def textureless(width):
    """One grey on a 3 m sphere."""
    lon, _ = _grid(width)
    return erp_case("textureless", np.full(lon.shape, 3.0), np.full((*lon.shape, 3), 128, np.uint8))


def stress_scene(name: str) -> Callable:
    """A case of ``panorecon.scenes.stress.CASES`` (the scenes the fusion's tests share)."""

    def build(width):
        from panorecon.scenes.stress import CASES

        return CASES[name](width)

    return build


def named_scene(name: str) -> Callable:
    def build(width):
        from panorecon.scenes import load_scene

        return load_scene(name, width)

    return build


def _real(name: str) -> str:
    from panorecon.scenes.real import real_data_dir

    return str(real_data_dir() / name)


CASES = [
    Case("scale-1e-3", "the bedroom's distances x 1e-3", scaled_bedroom(1e-3)),
    Case("scale-1e3", "the bedroom's distances x 1e3", scaled_bedroom(1e3)),
    Case("cliff-10", "near wall 1 m before a far sphere, 1:10", cliff(10)),
    Case("cliff-100", "near wall before a far sphere, 1:100", cliff(100)),
    Case("cliff-1e4", "near wall before a far sphere, 1:1e4", cliff(1e4)),
    Case("seam-jump", "1 m to 10 m across the left/right seam", stress_scene("seam-jump")),
    Case("ramp-2", "distance over 2 decades with latitude", ramp(2)),
    Case("ramp-4", "distance over 4 decades with latitude", ramp(4)),
    Case("all-sky", "every pixel sky", all_sky),
    Case("no-sky", "the bedroom (indoor, no sky pixel)", named_scene("bedroom")),
    Case("poles-only", "texture only above 60 deg latitude", poles_only),
    Case("textureless", "one grey on a 3 m sphere", textureless),
    Case("tiny-64", "the bedroom at 64 px wide", named_scene("bedroom"), width=64),
    Case("real-hohonet", "real indoor, HoHoNet's predicted depth as file: teacher", named_scene("hohonet"), teacher=""),
    Case("real-py360", "real indoor, no depth: no teacher offline", named_scene("py360-demo"), teacher=""),
    Case("8k", "the bedroom at 8192 px wide", named_scene("bedroom"), width=8192),
]
QUICK_CASES = ("textureless", "cliff-100", "seam-jump", "all-sky")


def _teacher(case: Case) -> str | None:
    """The teacher spec of a case: sim:relative for scenes with truth; hohonet's own predicted depth; None where
    no teacher can run offline."""
    if case.teacher is None:
        return TEACHER
    if case.name == "real-hohonet":
        return f"file:{_real('hohonet_pano.pred_depth_mm.png')}?scale=0.001"
    return None


SHARE_CHUNK = 1 << 22  # pixels per chunk of error_shares' float64 temporaries


def error_shares(pred: np.ndarray, truth: np.ndarray, scale: float, mask: np.ndarray) -> dict:
    """Median relative error and share of flying points (relative error > metrics.depth's FLYING_REL) of
    ``pred`` x ``scale`` against ``truth`` ([H, W] ERP distances) over ``mask`` & both finite and positive, plain
    and WS-weighted (row weights cos latitude; the weighted median is the first error whose cumulative weight, in
    increasing error, reaches half). NaN with no pixel. Float64 errors; the full-size arrays are the errors
    (float64), their sort order (int64) and each error's row (int32), everything else is made ``SHARE_CHUNK``
    pixels or rows at a time (an 8K map has 33.5M pixels: 268 MB per float64 copy)."""
    from panorecon.metrics.panorama import erp_row_weights

    H, W = truth.shape
    weights = erp_row_weights(H)
    n_row = np.zeros(H, np.int64)
    band = max(1, SHARE_CHUNK // max(W, 1))
    oks = []
    for r in range(0, H, band):
        with np.errstate(invalid="ignore"):
            p, t = pred[r : r + band], truth[r : r + band]
            ok = mask[r : r + band] & np.isfinite(p) & np.isfinite(t) & (p > 0) & (t > 0)
        n_row[r : r + band] = ok.sum(1)
        oks.append(ok)
    n = int(n_row.sum())
    if not n:
        return {k: math.nan for k in ("median_rel", "flying", "ws_median_rel", "ws_flying")}
    rel = np.empty(n, np.float64)
    at, fly_row = 0, np.zeros(H, np.int64)
    for r, ok in zip(range(0, H, band), oks):
        t = truth[r : r + band][ok].astype(np.float64)
        e = np.abs(pred[r : r + band][ok].astype(np.float64) * scale - t) / t
        rel[at : at + len(e)] = e
        at += len(e)
        per_row = n_row[r : r + band]
        fly_row[r : r + band] = np.bincount(np.repeat(np.arange(len(per_row)), per_row), e > FLYING_REL, len(per_row))
    del oks
    rows = np.repeat(np.arange(H, dtype=np.int32), n_row)  # the row of each error (row-major, as rel)
    order = np.argsort(rel)
    # the cumulative weight in increasing error, as one sequential sum (np.cumsum's), carried from chunk to chunk
    total, acc = 0.0, 0.0
    for i in range(0, n, SHARE_CHUNK):
        w = weights[rows[order[i : i + SHARE_CHUNK]]]
        w[0] += total
        total = float(np.cumsum(w)[-1])
    half, ws_median = 0.5 * total, math.nan
    for i in range(0, n, SHARE_CHUNK):
        w = weights[rows[order[i : i + SHARE_CHUNK]]]
        w[0] += acc
        cw = np.cumsum(w)
        if cw[-1] >= half:
            ws_median = float(rel[order[i + int(np.searchsorted(cw, half))]])
            break
        acc = float(cw[-1])
    del rows, order
    return {
        "median_rel": float(np.median(rel, overwrite_input=True)),
        "flying": int(fly_row.sum()) / n,
        "ws_median_rel": ws_median,
        "ws_flying": float(np.sum(weights * fly_row) / np.sum(weights * n_row)),
    }


def points_row(scene, source: str, teacher: str | None) -> dict:
    """One source on one scene (``run_source``): errors, points, seconds, peak MB; or its reason."""
    from panorecon.io import PanoreconInputError, reset_peak_rss, window_peak_rss_mb
    from panorecon.sources import run_source

    reset_peak_rss()
    t = time.perf_counter()
    try:
        pc, report = run_source(scene, source, teacher)
    except PanoreconInputError as e:
        return {"unavailable": str(e), "seconds": time.perf_counter() - t, "peak_mb": window_peak_rss_mb()}
    row = {"points": len(pc), "seconds": time.perf_counter() - t, "peak_mb": window_peak_rss_mb()}
    depth = report.get("depth")
    if isinstance(depth, dict) and "erp_distance" in pc.meta:
        row.update({k: depth.get(k) for k in ("abs_rel", "delta1", "ws_abs_rel", "ws_delta1")})
        row.update(error_shares(pc.meta["erp_distance"], scene.distance, depth["scale"], ~scene.sky))
    else:
        row["depth"] = depth if isinstance(depth, str) else "n/a: no depth map"
    return row


def train_row(scene, teacher: str | None, iters: int, res: int, labels: int, **settings) -> dict:
    """The method's source, then ``iters`` training steps at ``res`` px with ``labels`` labels and ``settings``
    (other TrainConfig fields; the trainer's defaults otherwise, no held-out views): pseudo-label PSNR,
    Gaussians, seconds, peak MB; or its reason."""
    from panorecon.io import PanoreconInputError, reset_peak_rss, window_peak_rss_mb
    from panorecon.pipeline import teacher_depth_fn
    from panorecon.sources import run_source
    from panorecon.splat.trainer import TrainConfig, train

    reset_peak_rss()
    t = time.perf_counter()
    try:
        pc, _ = run_source(scene, "fibonacci", teacher)
    except PanoreconInputError as e:
        return {"unavailable": str(e)}
    cfg = TrainConfig(iters=iters, res=res, labels=labels, heldout=0, checkpoint_every=0, history_every=0, **settings)
    with tempfile.TemporaryDirectory() as tmp:
        m = train(scene, pc, cfg, tmp, teacher_depth_fn(scene, teacher), progress=False)
    return {
        "psnr": m["pseudo-label"]["psnr"],
        "gaussians": m["gaussians"],
        "initial_gaussians": m["initial_gaussians"],
        "skipped": m["skipped"],
        "seconds": time.perf_counter() - t,
        "train_seconds": m["seconds"]["train"],
        "peak_mb": window_peak_rss_mb(),
    }


def run_case(case: Case, width: int, sources: tuple[str, ...], train: dict) -> dict:
    """Every source's points row and the training row of one case."""
    w = case.width or width
    t = time.perf_counter()
    scene = case.build(w)
    scene_s = time.perf_counter() - t
    teacher = _teacher(case)
    out = {"case": case.name, "what": case.what, "width": w, "teacher": teacher, "scene_seconds": scene_s}
    if teacher is None:
        reason = f"n/a: scene {scene.name!r} has no depth and no teacher runs offline (hf:/onnx: need weights)"
        out["points"] = {s: {"unavailable": reason} for s in sources}
        out["train"] = {"unavailable": reason}
        return out
    out["points"] = {}
    for s in sources:  # one line each, so a run the system stops (memory) says how far it got
        out["points"][s] = points_row(scene, s, teacher)
        print(f"{case.name} {s}: {out['points'][s]}", flush=True, file=sys.stderr)
    out["train"] = train_row(scene, teacher, **train)
    return out


def _fmt(v, spec: str) -> str:
    return format(v, spec) if isinstance(v, (int, float)) and math.isfinite(v) else "n/a"


def summary(rows: list[dict]) -> str:
    """Markdown, one line per case: the method's (fibonacci) errors, flying % and WS flying %, its seconds and peak
    MB, AbsRel's range over every source that ran, the worst flying % over the layouts, erp-direct's and
    moge-merge's flying %, and the training row; a case no source ran on gives its reason."""
    head = (
        "| case | method AbsRel | δ1 | flying % | WS flying % | AbsRel over sources (min–max) | flying % over "
        "layouts (max) | flying % erp-direct / moge-merge | points s (method) | peak MB | PSNR (train) | Gaussians "
        "| train s |\n" + "|---" * 13 + "|\n"
    )

    def pct(p: dict | None) -> str:
        return _fmt(100 * p["flying"], ".3f") if p and "flying" in p else "n/a"

    lines = []
    for r in rows:
        pts, tr = r["points"], r["train"]
        ran = {s: p for s, p in pts.items() if "unavailable" not in p}
        m = pts.get("fibonacci", {})
        name = f"{r['case']} ({r['width']} px)"
        if "unavailable" in m:
            lines.append(f"| {name} | {m['unavailable'][:90]} |" + " |" * 11)
            continue
        if "flying" not in m:  # ran, but no truth to measure against
            errors = [m.get("depth", "n/a")[:60]] + [""] * 7
        else:
            rel = [p["abs_rel"] for p in ran.values() if p.get("abs_rel") is not None]
            layouts = [100 * ran[s]["flying"] for s in LAYOUTS if s in ran and "flying" in ran[s]]
            errors = [
                _fmt(m["abs_rel"], ".3f"),
                _fmt(m["delta1"], ".3f"),
                pct(m),
                _fmt(100 * m["ws_flying"], ".3f"),
                f"{min(rel):.3f}–{max(rel):.3f}",
                _fmt(max(layouts), ".3f"),
                f"{pct(pts.get('erp-direct'))} / {pct(pts.get('moge-merge'))}",
            ]
        train = (
            [_fmt(tr.get("psnr"), ".2f"), f"{tr['gaussians']:,}", _fmt(tr.get("train_seconds"), ".1f")]
            if "unavailable" not in tr
            else ["", "", ""]
        )
        cells = [name, *errors, _fmt(m["seconds"], ".1f"), _fmt(m["peak_mb"], ".0f"), *train]
        lines.append("| " + " | ".join(cells) + " |")
    return head + "\n".join(lines) + "\n"


def table(rows: list[dict]) -> str:
    """Markdown: one line per case and source (points columns), the training columns on the method's line."""
    head = (
        "| case | source | AbsRel | δ1 | med. rel | flying | WS AbsRel | WS δ1 | WS med. rel | WS flying | points "
        "| s | peak MB | PSNR (train) | Gaussians | train s | train peak MB |\n" + "|---" * 17 + "|\n"
    )
    lines = []
    for r in rows:
        for s, p in r["points"].items():
            tr = r["train"] if s == "fibonacci" else {}
            if "unavailable" in p:
                cells = [p["unavailable"][:70]] + [""] * 10
            else:
                cells = [
                    _fmt(p.get(k), ".3f")
                    for k in (
                        "abs_rel",
                        "delta1",
                        "median_rel",
                        "flying",
                        "ws_abs_rel",
                        "ws_delta1",
                        "ws_median_rel",
                        "ws_flying",
                    )
                ]
                cells += [str(p["points"]), _fmt(p["seconds"], ".1f"), _fmt(p["peak_mb"], ".0f")]
            train_cells = (
                [_fmt(tr.get("psnr"), ".2f"), str(tr.get("gaussians", "")), _fmt(tr.get("seconds"), ".1f")]
                + [_fmt(tr.get("peak_mb"), ".0f")]
                if tr and "unavailable" not in tr
                else ["", "", "", ""]
            )
            lines.append("| " + " | ".join([f"{r['case']} ({r['width']} px)", s, *cells, *train_cells]) + " |")
    return head + "\n".join(lines) + "\n"


def main(argv=None) -> dict:
    from panorecon.evaluation.environment import emit, environment
    from panorecon.io import atomic_write
    from panorecon.splat.trainer import TrainConfig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="four cases at 64 px, two sources, 5 steps (seconds)")
    ap.add_argument("--cases", default="", help="comma-separated case names (default: all, or the quick ones)")
    ap.add_argument("--sources", default="", help=f"comma-separated sources (default: {','.join(SOURCES)})")
    ap.add_argument("--width", type=int, default=512, help="ERP width of the cases without their own")
    ap.add_argument("--train-iters", type=int, default=100)
    ap.add_argument("--train-res", type=int, default=32, help="label size of the training rows (px)")
    ap.add_argument("--labels", type=int, default=40, help="pseudo-label views of the training rows")
    ap.add_argument("--init-detail", type=float, default=None, help="TrainConfig.init_detail (default: its default)")
    ap.add_argument("--out", default=None, help="write the JSON here too")
    ap.add_argument("--table", default=None, help="write the markdown table here")
    args = ap.parse_args(argv)
    names = [c for c in args.cases.split(",") if c] or (list(QUICK_CASES) if args.quick else [c.name for c in CASES])
    known = {c.name: c for c in CASES}
    bad = [n for n in names if n not in known]
    if bad:
        ap.error(f"--cases {','.join(bad)}: unknown; expected some of {', '.join(known)}")
    sources = tuple(s for s in args.sources.split(",") if s) or (("fibonacci", "erp-direct") if args.quick else SOURCES)
    env = environment()  # the code that runs, recorded before it runs
    width = 64 if args.quick else args.width
    train = {
        "iters": 5 if args.quick else args.train_iters,
        "res": 16 if args.quick else args.train_res,
        "labels": args.labels,
        **({} if args.init_detail is None else {"init_detail": args.init_detail}),
    }

    def result(rows: list[dict], complete: bool) -> dict:
        return {
            "benchmark": "stress",
            **env,
            "complete": complete,
            "quick": args.quick,
            "width": width,
            "teacher": TEACHER,
            "train_budget": {**train, "heldout": 0, "source": "fibonacci", "config": "TrainConfig defaults otherwise"},
            "init_detail": TrainConfig(**train).init_detail,
            "flying_threshold": FLYING_REL,
            "rows": rows,
            "summary": summary(rows),
            "table": table(rows),
        }

    rows = []
    for name in names:
        case = known[name]
        if args.quick and case.width:
            case = Case(case.name, case.what, case.build, None, case.teacher)
        load = os.getloadavg()[0]
        row = run_case(case, width, sources, train)
        row["load_average_before"] = round(load, 2)
        print(f"{name}: done, load {load:.1f}", flush=True, file=sys.stderr)
        rows.append(row)
        if args.out and len(rows) < len(names):  # the cases so far, should a long grid be stopped
            with atomic_write(Path(args.out)) as tmp:
                Path(tmp).write_text(json.dumps(result(rows, False), indent=2) + "\n")
    done = result(rows, True)
    if args.table:
        with atomic_write(Path(args.table)) as tmp:
            Path(tmp).write_text(done["table"])
    return emit(done, args.out)


if __name__ == "__main__":
    main()
