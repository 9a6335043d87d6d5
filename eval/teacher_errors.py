"""Depth teachers measured the way the field measures them, side by side, on the Fibonacci fusion views.

    python eval/teacher_errors.py [--width 512] [--views 20] [--json out.json] [--md out.md]

Teachers: every ``sim:`` profile (seed 0), every learned model shipped in ``panorecon/teachers/weights``
(through ``onnx:``, as any user's model), and two controls: ``constant`` (one depth everywhere) and
``position prior`` (the mean training depth per pixel position: the learned teachers' training crops' z-depth,
each crop divided by its median, averaged per pixel in log depth -- a plain mean is pulled far by the few
distant outdoor pixels; it knows where a pixel lies in its view and nothing of the image). Scenes: the eight
table scenes at the tables' ERP width, the 20 Fibonacci views of ``points`` (square,
``default_view_size(width)`` pixels, the layout's 89.4 degree FOV); "seen" and "unseen" are the learned
teachers' training families and held-out families (the table scenes themselves are never trained on: training
uses variants ``@100`` and up).

Measures (z-depth of each view against the scene's true render; sky never counts):

- ``abs_rel``, ``delta1``: per view after the alignment the output allows -- scale only (median ratio) for
  relative outputs, least-squares scale and shift in the output's own space for affine ones (disparity: the
  depth capped at the view's farthest true depth, as in training's validation) -- mean over views and scenes;
- ``cross_view``: for every pair of views whose axes are less than the FOV apart, on the pixels both see (the
  first view's pixels whose ray lands inside the second, nearest pixel), mean |ln d_1 - ln d_2| of the two views'
  aligned ray distances; the truth gives 0 up to the nearest-pixel lookup (``truth`` row);
- framing: a second view turned (about its own vertical axis) by 0.7 x half the FOV puts the first view's
  central patch (the middle half of each axis) near its border, and a third along the same axis at 60 degrees
  (the labels' FOV) sees it at another scale: ``centre`` and ``border`` are the patch's AbsRel (each view's own
  alignment, over the whole view) in the first and second view, ``centre_vs_border`` and ``fov_60`` the mean
  |ln d_1 - ln d_2| on the patch between the first view and the second / third;
- ``shuffled``: a learned teacher's per-view AbsRel when each view's pixels are randomly permuted before the
  network sees them (its output aligned to the truth as usual): a network that reads the image gets worse.

Prints JSON, then a markdown table (means over the scenes of each split). Float64 statistics.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from panorecon.geometry import PinholeCamera, ViewDepth, centred_camera, erp_to_perspective, make_layout
from panorecon.io import json_text
from panorecon.learned.data import cached_crops
from panorecon.learned.loss import align_disparity
from panorecon.learned.train import DepthTrainConfig
from panorecon.scenes import load_scene
from panorecon.scenes.catalog import SYNTHETIC_SCENES
from panorecon.sources.builtin import default_view_size
from panorecon.teachers import PROFILES, get_teacher, shipped_models
from panorecon.teachers.base import true_view_distance

MIN_PIXELS = 100  # fewer valid pixels than this: the view / pair / patch is left out
TURN = 0.7  # the border view is turned by this x half the FOV
LABEL_FOV = 60.0  # TrainConfig.fov_deg


def aligned_z(v: ViewDepth, true_z: np.ndarray) -> np.ndarray:
    """A view's z-depth after the alignment its output allows [h, w] float64 (NaN: invalid or no truth)."""
    ok = v.valid & np.isfinite(true_z) & (true_z > 0)
    out = np.full(true_z.shape, np.nan)
    if ok.sum() < MIN_PIXELS:
        return out
    factor = v.camera.z_to_distance_factor()
    raw = v.depth.astype(np.float64)
    if v.affine and v.kind == "disparity":
        return align_disparity(raw, true_z, ok)
    if v.affine:  # z or distance up to scale and shift: least squares in the output's own space
        truth = true_z * factor if v.kind == "distance" else true_z
        A = np.stack([raw[ok], np.ones(ok.sum())], 1)
        (s, t), *_ = np.linalg.lstsq(A, truth[ok], rcond=None)
        fitted = s * raw + t
        z = fitted / factor if v.kind == "distance" else fitted
        z[~ok | ~(z > 0)] = np.nan
        return z
    z = {"z": raw, "distance": raw / factor, "disparity": 1.0 / raw}[v.kind]
    ok &= np.isfinite(z) & (z > 0)
    out[ok] = z[ok] * np.median(true_z[ok] / z[ok]) if not v.metric else z[ok]
    return out


def abs_rel_delta1(z: np.ndarray, true_z: np.ndarray, mask: np.ndarray | None = None) -> tuple[float, float]:
    ok = np.isfinite(z) & np.isfinite(true_z) & (true_z > 0) & (z > 0)
    if mask is not None:
        ok &= mask
    if ok.sum() < MIN_PIXELS:
        return float("nan"), float("nan")
    p, t = z[ok], true_z[ok]
    return float(np.mean(np.abs(p - t) / t)), float(np.mean(np.maximum(p / t, t / p) < 1.25))


def project(rays: np.ndarray, cam: PinholeCamera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World rays [..., 3] -> (row, col) int pixel of ``cam`` (nearest) and whether the ray lands in it."""
    c = rays @ cam.rotation_c2w  # world -> camera frame (rotation only: every view is at the centre)
    with np.errstate(divide="ignore", invalid="ignore"):
        u = cam.K[0, 0] * c[..., 0] / c[..., 2] + cam.K[0, 2]
        v = cam.K[1, 1] * c[..., 1] / c[..., 2] + cam.K[1, 2]
    inside = (c[..., 2] > 0) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    col = np.clip(np.nan_to_num(u), 0, cam.width - 1).astype(int)
    row = np.clip(np.nan_to_num(v), 0, cam.height - 1).astype(int)
    return row, col, inside


def log_disagreement(d1: np.ndarray, cam1: PinholeCamera, d2: np.ndarray, cam2: PinholeCamera, mask=None) -> float:
    """Mean |ln d1 - ln d2| of two views' ray distances on ``cam1``'s pixels (and ``mask``) whose rays land in
    ``cam2`` (nearest pixel); NaN with fewer than MIN_PIXELS."""
    row, col, inside = project(cam1.world_rays(), cam2)
    other = np.where(inside, d2[row, col], np.nan)
    ok = inside & np.isfinite(d1) & np.isfinite(other) & (d1 > 0) & (other > 0)
    if mask is not None:
        ok &= mask
    if ok.sum() < MIN_PIXELS:
        return float("nan")
    return float(np.mean(np.abs(np.log(d1[ok]) - np.log(other[ok]))))


def turned_camera(cam: PinholeCamera, angle_deg: float, size: int, fov_deg: float) -> PinholeCamera:
    """A view whose axis is ``cam``'s turned by ``angle_deg`` towards its right."""
    a = math.radians(angle_deg)
    right = cam.rotation_c2w[:, 0]
    return centred_camera(math.cos(a) * cam.forward + math.sin(a) * right, size, fov_deg)


class ControlTeacher:
    """A control: a relative z-depth that ignores the image -- ``constant`` ones, or ``prior`` [S, S] (the mean
    normalised training depth per pixel position, resized to the view)."""

    def __init__(self, name: str, prior: np.ndarray | None = None):
        self.name, self.prior = name, prior

    def predict_views(self, scene, cameras):
        import cv2

        views = []
        for cam in cameras:
            _, sky = true_view_distance(scene, cam)
            shape = (cam.height, cam.width)
            z = np.ones(shape, np.float32) if self.prior is None else cv2.resize(self.prior, shape[::-1])
            views.append(ViewDepth(cam, z.astype(np.float32), "z", ~sky))
        return views


def position_prior() -> tuple[np.ndarray, int]:
    """The mean training z-depth per pixel position ([S, S] float32; each crop over its median, averaged in log
    depth) and the crop count, from the learned teachers' (default config's) cached training crops."""
    crops = cached_crops(DepthTrainConfig().crop_specs()["train"])
    log_z = np.log(crops.depth.astype(np.float64))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # an all-sky crop has no median: it is left out as NaN
        log_z -= np.nanmedian(log_z.reshape(len(log_z), -1), axis=1)[:, None, None]
    return np.exp(np.nanmean(log_z, axis=0)).astype(np.float32), len(log_z)


def shuffled_abs_rel(teacher, scene, cams, truths, rng) -> float:
    """Mean per-view AbsRel of an ONNX teacher on views whose pixels were permuted (the same alignment)."""
    rels = []
    for cam, (true_z, sky) in zip(cams, truths):
        rgb = erp_to_perspective(scene.rgb, cam)
        flat = rgb.reshape(-1, 3)
        out = teacher.run(flat[rng.permutation(len(flat))].reshape(rgb.shape))
        v = ViewDepth(
            cam, out, teacher.config["output"], np.isfinite(out) & ~sky, affine=teacher.config["mode"] == "affine"
        )
        rels.append(abs_rel_delta1(aligned_z(v, true_z), true_z)[0])
    return float(np.nanmean(rels))


def measure(teacher, scene, cams, border, narrow, truths, half: np.ndarray) -> dict:
    """One teacher on one scene: every measure of the module doc (means over the views / pairs)."""
    n = len(cams)
    views = teacher.predict_views(scene, [*cams, *border, *narrow])  # one call: a sim: teacher's draws differ
    z = [aligned_z(v, t[0]) for v, t in zip(views, truths)]
    dist = [zi * v.camera.z_to_distance_factor() for zi, v in zip(z, views)]
    per_view = [abs_rel_delta1(z[i], truths[i][0]) for i in range(n)]
    fov = make_layout("fibonacci", n).fov_deg
    pairs = [
        (i, j)
        for i in range(n)
        for j in range(n)
        if i != j and math.degrees(math.acos(np.clip(cams[i].forward @ cams[j].forward, -1, 1))) < fov
    ]
    cross = [log_disagreement(dist[i], cams[i], dist[j], cams[j]) for i, j in pairs]
    centre, edge, c_vs_b, fov60 = [], [], [], []
    for i in range(n):
        b, c = n + i, 2 * n + i
        centre.append(abs_rel_delta1(z[i], truths[i][0], half)[0])
        row, col, inside = project(cams[i].world_rays(), border[i])
        patch_in_b = np.zeros(z[b].shape, bool)
        patch_in_b[row[half & inside], col[half & inside]] = True
        edge.append(abs_rel_delta1(z[b], truths[b][0], patch_in_b)[0])
        c_vs_b.append(log_disagreement(dist[i], cams[i], dist[b], border[i], half))
        fov60.append(log_disagreement(dist[i], cams[i], dist[c], narrow[i], half))
    return {
        "abs_rel": float(np.nanmean([r[0] for r in per_view])),
        "delta1": float(np.nanmean([r[1] for r in per_view])),
        "cross_view": float(np.nanmean(cross)),
        "centre": float(np.nanmean(centre)),
        "border": float(np.nanmean(edge)),
        "centre_vs_border": float(np.nanmean(c_vs_b)),
        "fov_60": float(np.nanmean(fov60)),
        "pairs": len(pairs),
    }


class TruthTeacher:
    """The true z-depth itself (the floor of every measure: the nearest-pixel lookups' own error)."""

    name = "truth"

    def predict_views(self, scene, cameras):
        out = []
        for cam in cameras:
            d, sky = true_view_distance(scene, cam)
            out.append(ViewDepth(cam, (d / cam.z_to_distance_factor()).astype(np.float32), "z", ~sky & np.isfinite(d)))
        return out


def measurement_views(width: int, views: int):
    """-> (layout, view size, the Fibonacci views, their border-turned twins, their 60-degree twins, the central
    patch mask [size, size]): what ``measure`` compares, at an ERP width."""
    layout = make_layout("fibonacci", views)
    size = default_view_size(width)
    cams = [centred_camera(d, size, layout.fov_deg) for d in layout.directions]
    border = [turned_camera(c, TURN * layout.fov_deg / 2, size, layout.fov_deg) for c in cams]
    narrow = [centred_camera(d, size, LABEL_FOV) for d in layout.directions]
    q = size // 4
    half = np.zeros((size, size), bool)
    half[q : size - q, q : size - q] = True
    return layout, size, cams, border, narrow, half


def view_truths(scene, cams) -> list[tuple[np.ndarray, np.ndarray]]:
    """(true z-depth with NaN on sky, sky) [h, w] of each camera."""
    truths = []
    for cam in cams:
        d, sky = true_view_distance(scene, cam)
        truths.append((np.where(sky, np.nan, d / cam.z_to_distance_factor()), sky))
    return truths


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--width", type=int, default=512, help="ERP width of the scenes (the tables': 512)")
    ap.add_argument("--views", type=int, default=20, help="Fibonacci views (the paper's 20)")
    ap.add_argument("--scenes", nargs="+", default=list(SYNTHETIC_SCENES), help="table scenes")
    ap.add_argument("--json", type=Path, help="also write the JSON here")
    ap.add_argument("--md", type=Path, help="also write the markdown table here")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    cfg = DepthTrainConfig()
    split = {s: ("seen" if s in cfg.families else "unseen") for s in SYNTHETIC_SCENES}
    prior, prior_crops = position_prior()
    teachers = [TruthTeacher()] + [get_teacher(f"sim:{p}", 0) for p in PROFILES]
    teachers += [get_teacher(f"onnx:{os.path.relpath(p)}") for p in shipped_models()]
    teachers += [ControlTeacher("constant"), ControlTeacher("position prior", prior)]
    learned = {t.name for t in teachers if t.name.startswith("onnx:")}
    layout, size, cams, border, narrow, half = measurement_views(args.width, args.views)
    results: dict = {t.name: {} for t in teachers}
    for name in args.scenes:
        scene = load_scene(name, args.width)
        truths = view_truths(scene, [*cams, *border, *narrow])
        for t in teachers:
            r = measure(t, scene, cams, border, narrow, truths, half)
            if t.name in learned:
                r["shuffled"] = shuffled_abs_rel(t, scene, cams, truths[: len(cams)], np.random.default_rng(0))
            results[t.name][name] = r
        print(f"{name}: done ({time.perf_counter() - t0:.0f} s)", file=sys.stderr, flush=True)
    measures = ("abs_rel", "delta1", "cross_view", "centre", "border", "centre_vs_border", "fov_60", "shuffled")
    summary = {
        t: {
            grp: {
                m: float(np.mean([r[m] for s, r in rows.items() if split[s] == grp and m in r]))
                for m in measures
                if any(m in r for s, r in rows.items() if split[s] == grp)
            }
            for grp in ("seen", "unseen")
        }
        for t, rows in results.items()
    }
    record = {
        "command": "python eval/teacher_errors.py " + " ".join(argv if argv is not None else sys.argv[1:]),
        "width": args.width,
        "views": args.views,
        "view_size": size,
        "fov_deg": layout.fov_deg,
        "seen_families": [s for s in args.scenes if split[s] == "seen"],
        "unseen_families": [s for s in args.scenes if split[s] == "unseen"],
        "position_prior_crops": prior_crops,
        "seconds": round(time.perf_counter() - t0, 1),
        "summary": summary,
        "per_scene": results,
    }
    text = json_text(json.loads(json.dumps(record), parse_constant=lambda c: None))
    print(text)
    md = markdown(summary)
    print(md)
    if args.json:
        args.json.write_text(text)
    if args.md:
        args.md.write_text(md)
    return 0


def markdown(summary: dict) -> str:
    """The table: one row per teacher, seen / unseen pairs per measure."""

    def cell(d, m, fmt):
        v = [d.get(g, {}).get(m) for g in ("seen", "unseen")]
        return " / ".join("–" if x is None or not math.isfinite(x) else format(x, fmt) for x in v)

    head = (
        "| teacher | AbsRel | δ1 | cross-view | centre AbsRel | border AbsRel | centre vs border | vs 60° FOV "
        "| shuffled AbsRel |\n|---|---|---|---|---|---|---|---|---|\n"
    )
    rows = [
        f"| `{t}` | {cell(d, 'abs_rel', '.3f')} | {cell(d, 'delta1', '.3f')} | {cell(d, 'cross_view', '.3f')} | "
        f"{cell(d, 'centre', '.3f')} | {cell(d, 'border', '.3f')} | {cell(d, 'centre_vs_border', '.3f')} | "
        f"{cell(d, 'fov_60', '.3f')} | {cell(d, 'shuffled', '.3f')} |"
        for t, d in summary.items()
    ]
    return head + "\n".join(rows) + "\n"


if __name__ == "__main__":
    sys.exit(main())
