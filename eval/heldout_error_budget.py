"""Where a trained run's held-out error sits, and how much of the gap to the reprojection oracle each part of the
model holds. Prints one JSON object.

    python eval/heldout_error_budget.py RUN_DIR --scene bedroom --width 512

RUN_DIR is a ``panorecon train`` output folder (metrics.json and point_cloud.ply); the held-out views are rebuilt
from its config (count, resolution, field of view, seed; ``--heldout``/``--heldout-res`` override count and size)
and placed in the cloud's frame by its heldout_scale, as the trainer placed them. Two readings:

- shares: per held-out view, the share of the squared error in holes (pixels whose rendered alpha is below 0.9:
  what the centre never saw and nothing covers) and in pixels whose rendered depth is more than 5 % off the true
  depth (geometry, mostly at depth edges), and the mean PSNR with either share removed;
- ``classes``: the co-visible pixels split by what they show (within EDGE_PX of a true depth step of more than
  EDGE_STEP in ln depth; else textured, the true view's grey-level gradient above TEXTURE_GRAD per pixel; else
  smooth), each class's share of the pixels and of the render's squared error, the render's and the oracle's PSNR
  there and the gap; and ``distance_ratio_near_1``, the share of co-visible pixels whose true point is seen from
  the held-out camera within 0.75-1.33 x its distance from the centre (where the labels' scale is the view's);
- ``surface_offset``: how far along the centre's rays the trained Gaussians lie from the true surface (opacity-
  weighted median of |r - r_true| / r_true and the weight share beyond 5 %), beside the same for the cloud the run
  started from (RUN_DIR's ``<source>_cloud.ply``, as ``panorecon train`` writes it; n/a without one);
- ``swaps``: the held-out scores (all-pixel PSNR; the co-visible pixels' PSNR, the oracle's and the gap,
  ``splat/evaluate.oracle_scores``) of the trained Gaussians as they are and with one thing swapped for its truth
  or removed, no retraining (``SWAPS``);
- ``by_distance`` (``--by-distance``): the same scores on views drawn with the run's seed at DISTANCE_BANDS from
  the panorama centre, from the centre itself to the trainer's 30-70 % of the free-space radius.

``truth-views`` retrains the baseline with N true renders from off-centre positions beside its labels, an upper
bound on what off-centre labels could win (``truth_views``):

    python eval/heldout_error_budget.py truth-views OUT --scene bedroom --views 0 30 120

The budget table of docs/benchmarks.md trains, per scene, the baseline and each retrained variant (``RETRAINS``)
with ``panorecon train`` into OUT/<scene>/<variant>, reads every run on the baseline's held-out views, writes
OUT/budget.json and prints the table (markdown):

    python eval/heldout_error_budget.py table OUT --scenes bedroom beach --width 512 --res 64 --labels 240 \
        --iters 1500 --teacher sim:relative --heldout 24
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

FLOATER_REL = 0.05  # a Gaussian whose centre is nearer than (1 - this) x the true distance along its ray: a floater
EDGE_STEP = 0.05  # ln true depth between neighbouring pixels: a depth edge (or ground seen at a grazing angle)
EDGE_PX = 2  # pixels within this many of a depth edge are its class
TEXTURE_GRAD = 0.03  # grey-level gradient per pixel (central differences, [0, 1] images): texture
OFF_SURFACE = 0.05  # relative distance from the true surface counted as off it


def _rays(model):
    """(unit directions [N, 3] from the panorama centre to each Gaussian's mean, distances [N]) float64."""
    m = model.means.detach().double().numpy()
    r = np.linalg.norm(m, axis=1)
    return m / np.maximum(r, 1e-12)[:, None], r


def _true_distance(scene, u: np.ndarray, scale: float) -> np.ndarray:
    """The scene's true ray distance along unit directions ``u`` [N, 3] (bilinear ERP sample: a slanted surface's
    distance, not its pixel's steps), in the cloud's frame (truth / ``scale``); inf or NaN where the sample
    touches sky or unknown pixels."""
    from panorecon.geometry import sample_erp

    return sample_erp(scene.distance.astype(np.float32), u, "linear").astype(np.float64) / scale


def _replace(model, **params):
    """A copy of ``model`` (float32) with the given parameters [N, ...] replaced (numpy or torch)."""
    import torch

    from panorecon.splat.model import PARAM_NAMES, GaussianModel

    new = {
        n: torch.as_tensor(np.asarray(params[n]) if n in params else getattr(model, n).detach().numpy())
        for n in PARAM_NAMES
    }
    return GaussianModel(*[new[n].float().clone() for n in PARAM_NAMES])


def snap_to_surface(model, scene, scale: float, keep: float = 0.0):
    """Each Gaussian moved along its ray from the centre towards the true surface, to the distance
    D + ``keep`` (|mean| - D) (``keep`` 0: onto it; 0.5: half its depth error left), and scaled by the same factor,
    so the centre sees it as before (same direction, same angular size); Gaussians whose ray meets sky or no truth
    stay. With ``keep`` > 0 the Gaussians along one ray keep their order in depth."""
    u, r = _rays(model)
    d = _true_distance(scene, u, scale)
    with np.errstate(invalid="ignore"):  # sky: inf - inf
        f = (d + keep * (r - d)) / np.maximum(r, 1e-12)
    f = np.where(np.isfinite(f) & (f > 0), f, 1.0)
    means = model.means.detach().double().numpy() * f[:, None]
    return _replace(model, means=means, log_scales=model.log_scales.detach().double().numpy() + np.log(f)[:, None])


def clamp_along_ray(model):
    """Each Gaussian's extent along its ray from the centre clamped to its thinnest axis: Σ' = A Σ A with
    A = I + (k - 1) u uᵀ, k = min(1, s_min / sqrt(uᵀ Σ u)). A leaves the part of Σ across the ray as it was, so
    the centre sees the Gaussian as before (to first order); only the depth the centre cannot see shrinks."""
    from panorecon.splat.model import covariances, from_covariances

    u, _ = _rays(model)
    cov = covariances(model)
    radial = np.sqrt(np.einsum("ni,nij,nj->n", u, cov, u))
    k = np.minimum(1.0, np.exp(model.log_scales.detach().double().numpy()).min(1) / radial)
    A = np.eye(3) + (k - 1)[:, None, None] * np.einsum("ni,nj->nij", u, u)
    quats, log_scales = from_covariances(A @ cov @ A)
    keep = k >= 1  # already no deeper than thin: its own parameters, not their round trip
    quats[keep] = model.quats.detach().double().numpy()[keep]
    log_scales[keep] = model.log_scales.detach().double().numpy()[keep]
    return _replace(model, quats=quats, log_scales=log_scales)


def flatten_onto_surface(model, scene, scale: float, thickness: float | None = None):
    """A copy of ``model`` with every Gaussian sheared along its ray from the centre onto the true surface's
    tangent plane there (``splat/regularisers.flatten_onto_surface`` with the normals of the scene's true
    distance, ``geometry.erp_normals``; ``scale`` does not change a normal): the centre sees it as before, other
    positions see a disc on the true surface."""
    from panorecon.geometry import erp_normals
    from panorecon.splat.regularisers import FLAT_THICKNESS, flatten_frames
    from panorecon.splat.regularisers import flatten_onto_surface as flatten

    flat = _replace(model)
    frames = flatten_frames(erp_normals(scene.distance), flat.means.device)
    flatten(flat, frames, FLAT_THICKNESS if thickness is None else thickness)
    return flat


def zero_higher_sh(model):
    """The SH bands above degree 0 set to 0 (view-independent colour)."""
    return _replace(model, shN=np.zeros(tuple(model.shN.shape), np.float32))


def remove_floaters(model, scene, scale: float):
    """Without the Gaussians whose centre is nearer the panorama centre than (1 - FLOATER_REL) x the true
    distance along its ray (in front of the surface the centre sees; Gaussians behind it, the disocclusion
    fill's among them, stay)."""
    from panorecon.splat.model import PARAM_NAMES

    u, r = _rays(model)
    with np.errstate(invalid="ignore"):
        floater = r < (1 - FLOATER_REL) * _true_distance(scene, u, scale)  # NaN truth: never a floater
    return _replace(model, **{n: getattr(model, n).detach().numpy()[~floater] for n in PARAM_NAMES})


TRUE_SKY = "true sky behind the Gaussians"
# name -> the swap, (model, scene, scale) -> model; TRUE_SKY swaps the views' background instead
SWAPS = {
    "as trained": lambda m, scene, scale: m,
    "depth error along the centre's rays halved": lambda m, scene, scale: snap_to_surface(m, scene, scale, 0.5),
    "depth error along the centre's rays cut to 10 %": lambda m, scene, scale: snap_to_surface(m, scene, scale, 0.1),
    "centres on the true surface (depth order lost)": snap_to_surface,
    "extent along the centre's rays clamped": lambda m, scene, scale: clamp_along_ray(m),
    "depth error halved and extent clamped": lambda m, scene, scale: clamp_along_ray(
        snap_to_surface(m, scene, scale, 0.5)
    ),
    "flattened onto the true surface along the centre's rays": flatten_onto_surface,
    "depth error halved and flattened": lambda m, scene, scale: flatten_onto_surface(
        snap_to_surface(m, scene, scale, 0.5), scene, scale
    ),
    "SH bands above 0 zeroed": lambda m, scene, scale: zero_higher_sh(m),
    "floaters removed": remove_floaters,
    TRUE_SKY: lambda m, scene, scale: m,
}


def pixel_classes(view) -> dict:
    """{class: [h, w] bool} of a held-out ``view``'s co-visible pixels (module docstring, ``classes``)."""
    from scipy.ndimage import binary_dilation

    ln_depth = np.log(np.nan_to_num(view.depth, nan=1e9).astype(np.float64))  # sky: one far plane
    step = np.zeros(ln_depth.shape, bool)  # both pixels of every step
    rows = np.abs(np.diff(ln_depth, axis=0)) > EDGE_STEP
    step[:-1] |= rows
    step[1:] |= rows
    cols = np.abs(np.diff(ln_depth, axis=1)) > EDGE_STEP
    step[:, :-1] |= cols
    step[:, 1:] |= cols
    edge = binary_dilation(step, iterations=EDGE_PX)
    gy, gx = np.gradient(view.rgb.astype(np.float64).mean(-1))
    textured = np.hypot(gx, gy) > TEXTURE_GRAD
    cov = view.covisible
    return {"near a depth edge": cov & edge, "textured": cov & ~edge & textured, "smooth": cov & ~edge & ~textured}


def distance_ratio(view) -> np.ndarray:
    """[h, w]: each pixel's true point's distance from the held-out camera over its distance from the panorama
    centre (1: the centre's labels saw it at this view's scale)."""
    rays = view.camera.world_rays()
    dist = np.nan_to_num(view.depth, nan=np.inf).astype(np.float64) * view.camera.z_to_distance_factor()
    points = view.camera.position + rays * dist[..., None]
    with np.errstate(invalid="ignore"):
        return dist / np.linalg.norm(points, axis=-1)


def class_scores(kept: list) -> dict:
    """``classes`` of held-out views ``kept`` [(view, render [h, w, 3])] with an oracle (module docstring)."""
    sums = {}
    near_1 = total = 0
    for v, img in kept:
        if v.oracle is None:
            continue
        se_model = ((img.astype(np.float64) - v.rgb) ** 2).mean(-1)
        se_oracle = ((np.nan_to_num(v.oracle).astype(np.float64) - v.rgb) ** 2).mean(-1)
        for name, mask in pixel_classes(v).items():
            acc = sums.setdefault(name, [0, 0.0, 0.0])
            acc[0] += int(mask.sum())
            acc[1] += float(se_model[mask].sum())
            acc[2] += float(se_oracle[mask].sum())
        ratio = distance_ratio(v)[v.covisible]
        near_1 += int(((ratio >= 0.75) & (ratio <= 4 / 3)).sum())
        total += ratio.size
    pixels, error = sum(a[0] for a in sums.values()), sum(a[1] for a in sums.values())
    out = {}
    for name, (n, sm, so) in sums.items():
        model_psnr = 10 * np.log10(n / sm) if n else None
        oracle_psnr = 10 * np.log10(n / so) if n and so > 0 else None
        out[name] = {
            "pixel_share": n / pixels if pixels else None,
            "error_share": sm / error if error else None,
            "psnr": model_psnr,
            "oracle_psnr": oracle_psnr,
            "gap": None if model_psnr is None or oracle_psnr is None else oracle_psnr - model_psnr,
        }
    out["distance_ratio_near_1"] = near_1 / total if total else None
    return out


def surface_offset(xyz: np.ndarray, weights: np.ndarray, scene, scale: float) -> dict:
    """Weighted median of |r - r_true| / r_true of points ``xyz`` [N, 3] (the cloud's frame) along their rays
    from the centre and the weight share beyond OFF_SURFACE; points whose ray meets sky are left out."""
    r = np.linalg.norm(xyz, axis=1)
    truth = _true_distance(scene, xyz / np.maximum(r, 1e-12)[:, None], scale)
    ok = np.isfinite(truth) & (truth > 0)
    rel, w = np.abs(r[ok] - truth[ok]) / truth[ok], weights[ok]
    order = np.argsort(rel)
    cum = np.cumsum(w[order])
    median = float(rel[order][np.searchsorted(cum, cum[-1] / 2)])
    return {"median": median, "share_off": float(w[rel > OFF_SURFACE].sum() / w.sum()), "points": int(ok.sum())}


def scores(model, views, cfg) -> dict:
    """The trainer's held-out scores of ``model`` on ``views``: all-pixel PSNR (as ``splat/evaluate._evaluate``)
    and ``oracle_scores`` on the co-visible pixels."""
    import torch

    from panorecon.splat.evaluate import _render, oracle_scores, psnr

    ps, kept = [], []
    with torch.no_grad():
        for v in views:
            img = _render(model, [v], cfg, model.sh_degree, "cpu")[0][0].clamp(0, 1)
            ps.append(psnr(img, torch.from_numpy(v.rgb)))
            kept.append((v, img.numpy()))
    s = oracle_scores(kept)
    return {"psnr": float(np.mean(ps)), **{k: s[k] for k in ("covisible_psnr", "oracle_psnr", "oracle_gap")}}


def heldout_views(scene, metrics: dict, n: int | None = None, res: int | None = None, radius=(0.3, 0.7)) -> list:
    """The held-out views of a run (``metrics``: its metrics.json): its count, size, field of view and seed unless
    ``n`` / ``res`` are given, at ``radius`` (fractions of the free-space radius; the trainer's by default), in
    the cloud's frame, over the sky environment the run was trained in front of."""
    from panorecon.splat.initial import sky_environment, view_background
    from panorecon.splat.labels import in_cloud_frame, make_heldout_views

    c = metrics["config"]
    views = [
        in_cloud_frame(v, metrics["heldout_scale"])
        for v in make_heldout_views(scene, n or c["heldout"], res or c["res"], c["fov_deg"], c["seed"], radius)
    ]
    env = sky_environment(scene) if c["sky"] == "panorama" else None
    for v in views:
        v.background = view_background(env, v.camera)
    return views


def load_run(run: Path, res: int | None = None):
    """(metrics.json, the TrainConfig its renders are read with at ``res`` (default: the run's), the trained
    model) of a ``panorecon train`` folder."""
    from panorecon.splat.ply import load_ply
    from panorecon.splat.trainer import TrainConfig

    metrics = json.loads((run / "metrics.json").read_text())
    c = metrics["config"]
    cfg = TrainConfig(res=res or c["res"], fov_deg=c["fov_deg"], backend="cpu", antialiased=c.get("antialiased", False))
    return metrics, cfg, load_ply(run / "point_cloud.ply")


# fractions of the free-space radius at which ``by_distance`` places held-out cameras (the last: the trainer's)
DISTANCE_BANDS = ((0.0, 0.0), (0.02, 0.05), (0.1, 0.2), (0.3, 0.7))


def by_distance(run: Path, scene, n: int | None = None, res: int | None = None) -> list[dict]:
    """The held-out scores of a run on views drawn with its seed (same directions) at each of DISTANCE_BANDS from
    the panorama centre: how the gap grows as the views leave the centre (at 0 the oracle is the panorama itself
    resampled, so the gap there is the fit to the labels, not the view's position)."""
    metrics, cfg, model = load_run(run, res)
    return [
        {"radius": list(band), **scores(model, heldout_views(scene, metrics, n, res, band), cfg)}
        for band in DISTANCE_BANDS
    ]


def read_run(run: Path, scene, n: int | None = None, res: int | None = None) -> dict:
    """The budget of one run folder (module docstring)."""
    import dataclasses

    import torch

    from panorecon.splat.evaluate import _render

    metrics, cfg, model = load_run(run, res)
    views = heldout_views(scene, metrics, n, res)
    rows, kept = [], []  # kept: (view, render) for the class reading
    for v in views:
        with torch.no_grad():
            img, alpha, depth, _ = _render(model, [v], cfg, model.sh_degree, "cpu")
        kept.append((v, img[0].clamp(0, 1).numpy()))
        a = alpha[0, ..., 0].numpy()
        z = depth[0, ..., 0].numpy() / np.maximum(a, 1e-6)
        se = ((kept[-1][1].astype(np.float64) - v.rgb) ** 2).mean(-1)  # float64 sums
        hole = a < 0.9
        with np.errstate(invalid="ignore", divide="ignore"):
            off = ~hole & (np.abs(z - v.depth) > 0.05 * v.depth)  # sky (NaN truth) is never "off"
        rows.append(
            {
                "psnr": float(10 * np.log10(1 / se.mean())),
                "hole_pixels": float(hole.mean()),
                "hole_error_share": float(se[hole].sum() / se.sum()),
                "depth_off_pixels": float(off.mean()),
                "depth_off_error_share": float(se[off].sum() / se.sum()),
                "_mse": (float(se.mean()), float(se[hole].sum() / se.size), float(se[off].sum() / se.size)),
            }
        )
    mse = np.array([r.pop("_mse") for r in rows])
    scale = metrics["heldout_scale"]
    true_sky = [  # the true render's own colour behind the Gaussians where it is sky (NaN true depth)
        dataclasses.replace(v, background=np.where(np.isnan(v.depth)[..., None], v.rgb, v.background))
        if v.background is not None
        else v
        for v in views
    ]
    clouds = [p for p in run.glob("*_cloud.ply") if p.name != "point_cloud.ply"]
    offset = {
        "trained": surface_offset(
            model.means.detach().double().numpy(), model.opacities().detach().double().numpy(), scene, scale
        ),
        "initial cloud": "n/a: no <source>_cloud.ply in the run folder",
    }
    if clouds:
        from panorecon.geometry import PointCloud

        xyz = PointCloud.load_ply(clouds[0]).xyz.astype(np.float64)
        offset["initial cloud"] = surface_offset(xyz, np.ones(len(xyz)), scene, scale)
    swaps = {}
    for name, swap in SWAPS.items():
        swapped = swap(model, scene, scale)
        swaps[name] = scores(swapped, true_sky if name == TRUE_SKY else views, cfg)
        swaps[name]["gaussians"] = len(swapped)
    return {
        "run": str(run),
        "views": rows,
        "psnr": float(np.mean([r["psnr"] for r in rows])),
        "hole_error_share": float(mse[:, 1].sum() / mse[:, 0].sum()),
        "depth_off_error_share": float(mse[:, 2].sum() / mse[:, 0].sum()),
        "psnr_without_hole_error": float(np.mean(10 * np.log10(1 / (mse[:, 0] - mse[:, 1])))),
        "psnr_without_depth_off_error": float(np.mean(10 * np.log10(1 / (mse[:, 0] - mse[:, 2])))),
        "classes": class_scores(kept),
        "surface_offset": offset,
        "swaps": swaps,
    }


# name -> `panorecon train` options changed from the baseline (one thing retrained at a time)
RETRAINS = {
    "no disocclusion fill": lambda a: ["--disocclusion-fill-deg", "0"],
    "labels at 2x resolution": lambda a: ["--res", str(2 * a.res)],
    "near-true depth teacher (sim:clean)": lambda a: ["--teacher", "sim:clean"],
}


def _training_parser(description: str) -> argparse.ArgumentParser:
    """The options every retraining command shares: its output folder and the budget's training settings."""
    ap = argparse.ArgumentParser(description=description)
    ap.add_argument("out", type=Path)
    ap.add_argument("--width", type=int, default=512)
    ap.add_argument("--res", type=int, default=64)
    ap.add_argument("--labels", type=int, default=240)
    ap.add_argument("--iters", type=int, default=1500)
    ap.add_argument("--teacher", default="sim:relative")
    ap.add_argument("--heldout", type=int, default=24, help="held-out views every run is read on")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--flatten-every", type=int, default=None, help="every run's flatten_every (default: trainer's)")
    return ap


def _train_args(a) -> list[str]:
    """``panorecon train`` options of the settings ``a`` (``_training_parser``), fibonacci on the CPU."""
    base = ["--width", str(a.width), "--source", "fibonacci", "--teacher", a.teacher, "--res", str(a.res)]
    base += ["--labels", str(a.labels), "--iters", str(a.iters), "--seed", str(a.seed), "--heldout", str(a.heldout)]
    base += ["--checkpoint-every", "0", "--history-every", "0", "--backend", "cpu", "--device", "cpu", "--no-progress"]
    return base + ([] if a.flatten_every is None else ["--flatten-every", str(a.flatten_every)])


def table(argv=None) -> dict:
    from panorecon.cli import main as panorecon
    from panorecon.scenes import load_scene

    ap = _training_parser("the gap budget table (module docstring)")
    ap.add_argument("--scenes", nargs="+", required=True)
    a = ap.parse_args(argv)
    base = _train_args(a)
    out = {"settings": {k: v for k, v in vars(a).items() if k != "out"}, "scenes": {}}
    for name in a.scenes:
        scene = load_scene(name, a.width)
        runs = {}
        for variant, extra in {"baseline": lambda a: [], **RETRAINS}.items():
            folder = a.out / name / variant.split(" (")[0].replace(" ", "_")
            if not (folder / "metrics.json").is_file():  # a finished run is read again, not retrained
                if panorecon(["train", name, *base, *extra(a), "--out", str(folder), "--overwrite"]) != 0:
                    raise SystemExit(f"panorecon train failed for {name} / {variant}")
            runs[variant] = read_run(folder, scene, a.heldout, a.res)
        out["scenes"][name] = runs
    (a.out / "budget.json").write_text(json.dumps(out, indent=1))
    print(markdown(out))
    return out


TRUTH_SEED_OFFSET = 1000  # the true training views' seed is the run's plus this: never the held-out views' draw


def true_offcentre_views(scene, scale: float):
    """A stand-in for the trainer's ``offcentre_labels`` (same signature) that returns ``n`` true renders of
    ``scene`` from positions drawn like the held-out views' (``make_heldout_views`` with the run's seed plus
    TRUTH_SEED_OFFSET: other positions and directions), every pixel kept, in the cloud's frame (truth / ``scale``):
    off-centre information that no method working from the one panorama has, to bound what off-centre labels
    could win."""
    import dataclasses

    from panorecon.splat.labels import in_cloud_frame, make_heldout_views

    def views(rgb, point_cloud, n, size, fov_deg, radius, seed):
        true = make_heldout_views(scene, n, size, fov_deg, seed + TRUTH_SEED_OFFSET) if n else []
        return [
            dataclasses.replace(
                in_cloud_frame(v, scale), depth=None, mask=np.ones(v.rgb.shape[:2], bool), covisible=None, oracle=None
            )
            for v in true
        ]

    return views


def truth_views(argv=None) -> dict:
    """``truth-views OUT --scene S --views 0 30 120 ...``: the budget's baseline retrained with N true off-centre
    views beside its labels (``true_offcentre_views``, given to the trainer in place of ``offcentre_labels``), each
    read like the baseline (``read_run``); prints a markdown table of the changes against N = 0. An upper bound:
    what perfect off-centre labels would buy at these settings, and what they cost the centre's labels."""
    from unittest import mock

    import panorecon.splat.trainer as trainer
    from panorecon.cli import main as panorecon
    from panorecon.scenes import load_scene

    ap = _training_parser(truth_views.__doc__.splitlines()[0])
    ap.add_argument("--scene", required=True)
    ap.add_argument("--views", type=int, nargs="+", default=[0, 30, 120])
    a = ap.parse_args(argv)
    scene = load_scene(a.scene, a.width)
    base = _train_args(a)
    rows, scale = {}, None
    for n in sorted(set([0, *a.views])):
        folder = a.out / f"truth_views_{n}"
        if n and scale is None:  # the cloud's scale against the truth, as the baseline run measured it
            scale = json.loads((a.out / "truth_views_0" / "metrics.json").read_text())["heldout_scale"]
        if not (folder / "metrics.json").is_file():  # a finished run is read again, not retrained
            with mock.patch.object(trainer, "offcentre_labels", true_offcentre_views(scene, scale or 1.0)):
                argv_n = ["train", a.scene, *base, "--offcentre-labels", str(n), "--out", str(folder), "--overwrite"]
                if panorecon(argv_n) != 0:
                    raise SystemExit(f"panorecon train failed for {a.scene} with {n} true views")
        budget = read_run(folder, scene, a.heldout, a.res)
        metrics = json.loads((folder / "metrics.json").read_text())
        rows[n] = {
            "pseudo_label_psnr": metrics["pseudo-label"]["psnr"],
            **{k: budget["swaps"]["as trained"][k] for k in ("psnr", "oracle_gap")},
            "class_gaps": {k: v["gap"] for k, v in budget["classes"].items() if isinstance(v, dict)},
        }
    ref = rows[0]
    lines = ["| true off-centre views | pseudo-label PSNR (Δ) | held-out PSNR (Δ) | gap to oracle (Δ) | class gaps |"]
    lines.append("|---|---|---|---|---|")
    for n, r in rows.items():
        cells = [str(n)]
        for k in ("pseudo_label_psnr", "psnr", "oracle_gap"):
            if not isinstance(r[k], float) or not isinstance(ref[k], float):  # 'n/a: <reason>'
                cells.append(str(r[k]))
                continue
            cells.append(f"{r[k]:.2f}" + ("" if n == 0 else f" ({r[k] - ref[k]:+.2f})"))
        cells.append(", ".join(f"{k} {g:.2f}" for k, g in r["class_gaps"].items() if isinstance(g, float)))
        lines.append("| " + " | ".join(cells) + " |")
    print("\n".join(lines))
    out = {"settings": {k: v for k, v in vars(a).items() if k != "out"}, "rows": rows}
    (a.out / "truth_views.json").write_text(json.dumps(out, indent=1))
    return out


def markdown(budget: dict) -> str:
    """The budget table: per scene, each swap's and retrained variant's held-out PSNR (all pixels) and gap to the
    oracle on the co-visible pixels, each with its change against the baseline as trained."""
    scenes = list(budget["scenes"])
    head = ["what is swapped for its truth or removed"]
    for s in scenes:
        head += [f"{s}: held-out PSNR (Δ)", f"{s}: gap to oracle (Δ)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    rows = [("baseline", n) for n in SWAPS] + [(v, "as trained") for v in RETRAINS]
    ref = {s: budget["scenes"][s]["baseline"]["swaps"]["as trained"] for s in scenes}
    for run, swap in rows:
        label = swap if run == "baseline" else f"retrained: {run}"
        cells = [label]
        for s in scenes:
            r = budget["scenes"][s][run]["swaps"][swap]
            for key in ("psnr", "oracle_gap"):
                d = r[key] - ref[s][key]
                cells.append(
                    f"{r[key]:.2f}" if (run, swap) == ("baseline", "as trained") else f"{r[key]:.2f} ({d:+.2f})"
                )
        lines.append("| " + " | ".join(cells) + " |")
    oracle = ", ".join(
        f"{s} {ref[s]['oracle_psnr']:.2f} dB against the Gaussians' {ref[s]['covisible_psnr']:.2f} dB" for s in scenes
    )
    return "\n".join(lines) + f"\n\nOn the co-visible pixels, as trained: oracle {oracle}."


def main(argv=None) -> dict:
    import sys

    argv = sys.argv[1:] if argv is None else argv
    if argv and argv[0] == "table":
        return table(argv[1:])
    if argv and argv[0] == "truth-views":
        return truth_views(argv[1:])
    from panorecon.scenes import load_scene

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--scene", required=True)
    ap.add_argument("--width", type=int, required=True)
    ap.add_argument("--heldout", type=int, default=None, help="held-out views (default: the run's)")
    ap.add_argument("--heldout-res", type=int, default=None, help="their size in pixels (default: the run's)")
    ap.add_argument("--by-distance", action="store_true", help="also read the run at DISTANCE_BANDS (by_distance)")
    args = ap.parse_args(argv)
    scene = load_scene(args.scene, args.width)
    out = read_run(args.run, scene, args.heldout, args.heldout_res)
    if args.by_distance:
        out["by_distance"] = by_distance(args.run, scene, args.heldout, args.heldout_res)
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
