"""Run one point source on one scene with one teacher, timed, and measured against the truth."""

from __future__ import annotations

import inspect
import math
import time

import numpy as np

from ..geometry import back_project_erp, thin_on_sphere
from ..io import PanoreconInputError, peak_rss_mb
from ..metrics import depth_metrics, edge_depth_metrics, point_flying_share, point_metrics, ws_depth_metrics
from ..teachers import get_teacher, seeded_teacher
from ..teachers.base import require_truth, true_view_distance
from .registry import get_source

# metrics on fewer valid pixels / points than these read "n/a: <reason>": a handful of samples measures nothing
MIN_METRIC_PIXELS = 100
MIN_METRIC_POINTS = 100


def _per_view_abs_rel(scene, view_depths) -> float:
    """Median over views of each view's own AbsRel against its true distance: median-aligned per view for
    scale-only views; for affine views after a per-view least-squares scale+shift fit to the truth in the
    view's own space (the best one view can do)."""
    rels = []
    for v in view_depths:
        true_d, sky = true_view_distance(scene, v.camera)
        if v.affine:
            truth_raw = true_d / v.camera.z_to_distance_factor() if v.kind == "z" else true_d
            if v.kind == "disparity":
                truth_raw = v.camera.z_to_distance_factor() / true_d
            ok = v.valid & np.isfinite(truth_raw) & ~sky
            if ok.sum() < 2:
                continue
            A = np.stack([v.depth[ok], np.ones(ok.sum())], 1).astype(np.float64)
            a, b = np.linalg.lstsq(A, truth_raw[ok].astype(np.float64), rcond=None)[0]
            fitted = np.full(v.depth.shape, np.nan)
            fitted[ok] = a * v.depth[ok] + b
            pred = (
                fitted
                if v.kind == "distance"
                else (
                    fitted * v.camera.z_to_distance_factor()
                    if v.kind == "z"
                    else v.camera.z_to_distance_factor() / fitted
                )
            )
            m = depth_metrics(pred, true_d, "none", ~sky)
        else:
            m = depth_metrics(v.to_distance(), true_d, "none" if v.metric else "median", ~sky)
        if m["pixels"]:
            rels.append(m["abs_rel"])
    return float(np.median(rels)) if rels else float("nan")


class EmptyCloudError(PanoreconInputError):
    """A source ran on a scene and gave no point (e.g. COLMAP triangulating nothing): one line for a command,
    and the run's recorded outcome ("failed: ...") in an ablation table."""


POINT_METRIC_SAMPLE = 200_000  # points of each cloud the point metrics compare (point_metrics' default)


def _metric_samples(scene, pred: np.ndarray, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """The predicted and true points ``point_metrics(pred, scene.point_cloud().xyz, max_points=n, seed=seed)``
    would subsample to (the same draws: the prediction's first, then the truth's valid pixels in row-major
    order) -> ([<= n, 3], [<= n, 3] float32); neither the full true cloud nor a scaled copy of the prediction is
    built."""
    rng = np.random.default_rng(seed)
    if len(pred) > n:
        pred = pred[rng.choice(len(pred), n, replace=False)]
    flat = np.flatnonzero(scene.valid)
    if len(flat) > n:
        flat = flat[rng.choice(len(flat), n, replace=False)]
    keep = np.zeros(scene.valid.shape, bool)
    keep.ravel()[flat] = True
    xyz = back_project_erp(scene.distance, keep, scene.rgb)[0]
    order = np.argsort(np.argsort(flat))  # back_project_erp returns row-major order: back to the draw's order
    return pred, xyz[order]


def _finite_or_na(d: dict, reason: str) -> dict:
    return {k: (v if not (isinstance(v, float) and not math.isfinite(v)) else f"n/a: {reason}") for k, v in d.items()}


def _takes_seed(fn) -> bool:
    try:
        return "seed" in inspect.signature(fn).parameters
    except (TypeError, ValueError):  # a callable without a signature
        return False


def uses_seed(source_name: str, teacher_spec: str | None) -> bool:
    """Whether ``run_source(..., seed=s)`` depends on ``s``: the source draws random numbers itself (its function
    takes ``seed``), or it runs a teacher whose errors are seeded (``sim:``)."""
    spec = get_source(source_name)
    return _takes_seed(spec.fn) or (spec.uses_teacher and seeded_teacher(teacher_spec))


def check_source(scene, source_name: str, teacher_spec: str | None) -> None:
    """What is known to fail before any work: an unknown source, a missing teacher where the source needs one, a
    simulated teacher on a scene without truth (``require_truth``), and the source's own ``check(scene)`` (e.g.
    the multi-view baselines need a synthetic scene). Raises PanoreconInputError; ``run_source`` calls it first,
    and a command calls it before it claims or writes anything."""
    spec = get_source(source_name)
    if spec.uses_teacher and not teacher_spec:
        raise PanoreconInputError(f"source {source_name!r} needs --teacher (see `panorecon teachers list`)")
    if spec.uses_teacher and teacher_spec.partition(":")[0] == "sim":
        require_truth(scene)
    if spec.check is not None:
        spec.check(scene)


def run_source(
    scene,
    source_name: str,
    teacher_spec: str | None,
    views: int | None = None,
    fusion_config=None,
    view_size: int | None = None,
    seed: int = 0,
    max_points: int | None = None,
):
    """-> (PointCloud, report dict). The report: source, teacher, scene, views, seconds per stage and total,
    peak_rss_mb (process peak so far), fusion solver report, depth and point metrics against the truth
    (median-aligned unless the teacher is metric; the cloud is scaled by the same factor before point
    metrics) or 'n/a: <reason>', and the median per-view teacher AbsRel; for affine-invariant teachers also
    ``depth_inverse_affine`` (the fused map aligned by scale and shift in inverse distance). ``depth["flying"]``
    and ``points["flying"]``: the share of pixels / points more than 50 % off their true distance after the same
    alignment (``metrics.depth.FLYING_REL``; the points' on their ray from the centre, ``point_flying_share``).
    The fused ERP ray distance the metrics are computed from ([H, W] float32 metres, NaN unknown) is kept in
    ``pc.meta["erp_distance"]`` when the source gives one. ``seed`` seeds the teacher (``get_teacher``) and a
    source that takes a ``seed`` (random points); see :func:`uses_seed`. ``max_points``: the cloud thinned evenly
    over the sphere to at most that many points (``thin_on_sphere``; ``report["thinning"]`` gives the density)
    before it is measured. The report's ``depth_edges`` is the fused map's AbsRel near true depth discontinuities."""
    t_total = time.perf_counter()
    check_source(scene, source_name, teacher_spec)
    spec = get_source(source_name)
    teacher = get_teacher(teacher_spec, seed) if spec.uses_teacher else None
    extra = {"seed": seed} if _takes_seed(spec.fn) else {}
    pc, seconds, info = spec.fn(scene, teacher, views, fusion_config, view_size, **extra)
    if len(pc) == 0:
        why = (
            "no valid fused depth; at small widths try a larger --width or --view-size"
            if spec.uses_teacher
            else "it reconstructed nothing from this scene's views"
        )
        raise EmptyCloudError(
            f"source {source_name!r} with teacher {teacher_spec!r} gave no point on scene {scene.name!r} ({why})"
        )
    if max_points is not None:
        t = time.perf_counter()
        pc, thinning = thin_on_sphere(pc, max_points)
        seconds["thinning"] = time.perf_counter() - t
    t = time.perf_counter()
    report = {
        "source": source_name,
        "teacher": teacher.name if teacher else None,
        "scene": scene.name,
        "erp": [scene.width, scene.height],
        "views": info.get("views"),
        "view_size": info.get("view_size"),
        "fov_deg": info.get("fov_deg"),
    }
    if max_points is not None:
        report["thinning"] = {"max_points": max_points, **thinning}
    for key in ("fusion", "panoramas", "baseline"):  # solver statistics; multi-view baselines' inputs and report
        if key in info:
            report[key] = info[key]
    conn = (info.get("fusion") or {}).get("connectivity")
    if conn is not None:  # every fusion reports which views its equations tie together
        report["view_components"] = conn["components"]
        if conn.get("warning"):
            report["warnings"] = [conn["warning"]]
    metric = bool(info.get("view_depths") and all(v.metric for v in info["view_depths"]))
    distance = info.get("distance")
    if distance is not None:
        pc.meta["erp_distance"] = np.asarray(distance, np.float32)
    if not scene.has_ground_truth:
        reason = f"scene {scene.name!r} has no ground truth"
        report["depth"] = f"n/a: {reason}"
        report["points"] = {
            "count": len(pc),
            **{k: f"n/a: {reason}" for k in ("accuracy", "completeness", "chamfer", "fscore")},
        }
    else:
        scale = 1.0
        if distance is not None:
            dm = depth_metrics(distance, scene.distance, "none" if metric else "median", ~scene.sky)
            few = dm["pixels"] < MIN_METRIC_PIXELS
            scale = dm["scale"] if math.isfinite(dm["scale"]) and not few else 1.0
            if not few:  # the same comparison with each ERP pixel weighted by its solid angle (cos latitude)
                dm.update(ws_depth_metrics(distance, scene.distance, dm["scale"], ~scene.sky))
            report["depth"] = (
                f"n/a: {dm['pixels']} pixels with both prediction and truth (fewer than {MIN_METRIC_PIXELS})"
                if few
                else _finite_or_na(dm, "no pixel with both prediction and truth")
            )
            report["depth_edges"] = _finite_or_na(
                edge_depth_metrics(distance, scene.distance, scale, ~scene.sky), "no pixel near a true depth edge"
            )
            if any(v.affine for v in info.get("view_depths") or ()):
                # affine views fix the fused map only up to a global scale and (nearly) a shift in inverse
                # distance: measured as well after that alignment, the protocol of the per-view number
                report["depth_inverse_affine"] = _finite_or_na(
                    depth_metrics(distance, scene.distance, "inverse-affine", ~scene.sky), "no pixel to compare"
                )
        else:
            report["depth"] = "n/a: the source gives no depth map"
        pred, truth = _metric_samples(scene, pc.xyz, POINT_METRIC_SAMPLE)
        if min(len(pred), len(truth)) < MIN_METRIC_POINTS:
            reason = f"n/a: {len(pc)} points against {len(truth)} true points (fewer than {MIN_METRIC_POINTS})"
            report["points"] = {
                "count": len(pc),
                **{k: reason for k in ("accuracy", "completeness", "chamfer", "fscore")},
            }
        else:
            report["points"] = {**point_metrics(pred * scale, truth, max_points=POINT_METRIC_SAMPLE), "count": len(pc)}
            flying, compared = point_flying_share(pred, scene.distance, scale)
            report["points"]["flying"] = (
                flying
                if compared >= MIN_METRIC_POINTS
                else (f"n/a: {compared} points on a ray with a true distance (fewer than {MIN_METRIC_POINTS})")
            )
        report["points"]["scale_applied"] = scale
        if info.get("view_depths"):
            report["teacher_per_view_abs_rel_median"] = _per_view_abs_rel(scene, info["view_depths"])
    seconds["metrics"] = time.perf_counter() - t
    seconds["total"] = time.perf_counter() - t_total
    report["seconds"] = seconds
    report["peak_rss_mb"] = peak_rss_mb()
    return pc, report


def cloud_scale(report: dict) -> float:
    """truth / cloud: the scale a source's report measured by aligning its depth to the truth (median
    alignment; 1 for metric teachers, for clouds without a depth map and for scenes without truth)."""
    depth = report.get("depth")
    scale = depth.get("scale") if isinstance(depth, dict) else None
    return float(scale) if isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0 else 1.0
