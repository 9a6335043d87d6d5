"""The shared Gaussian trainer: every point source is judged through it (paper §2.3, §2.5)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from .. import checks as C
from .. import interrupts
from ..checks import opt
from ..device import device_record, reset_peak_memory, resolve_device, synchronize
from ..geometry import PointCloud
from ..io import peak_rss_mb, write_image, write_json
from ..io.depth import check_scene_scale
from . import footprint
from .checkpoint import checkpoint_inputs, load_checkpoint, save_checkpoint
from .evaluate import _cameras, _evaluate, _heldout_psnr, _render, best_heldout, heldout_plateau, psnr
from .initial import (
    disocclusion_fill,
    points_for_resolution,
    sky_environment,
    thin_by_detail,
    thin_cloud,
    view_background,
)
from .labels import (
    covisible_shortfall,
    in_cloud_frame,
    make_heldout_views,
    make_panorama_heldout_views,
    make_pseudo_labels,
)
from .losses import total_loss
from .model import PARAM_NAMES, GaussianModel, flatten_to_discs
from .offcentre import offcentre_labels
from .ply import save_ply
from .rasterize import BACKENDS, resolve_backend
from .regularisers import (
    FLAT_MIN_COHERENCE,
    anchor_height,
    depth_spread,
    flatten_frames,
    flatten_height,
    flatten_onto_surface,
    normal_coherence,
    render_depth_sq,
    surface_anchor,
    surface_distances,
    surface_normals,
)
from .strategy import STRATEGIES, edit_parameters

log = logging.getLogger("panorecon.train")


# The smallest half size that coarse steps render at: labels under 2 x COARSE_MIN_SIZE px train at full size
# throughout (at smaller sizes a coarse step saves little and the half-size targets lose detail; measured effects:
# docs/benchmarks.md).
COARSE_MIN_SIZE = 128
# the orders in which steps take the labels (TrainConfig.label_order)
LABEL_ORDERS = ("random", "shuffled")
# init_detail's coarse Gaussians start as discs on their region's plane, this thick over their radius
DISC_THICKNESS = 0.1


def _layouts() -> tuple[str, ...]:
    from ..geometry.layouts import LAYOUT_NAMES

    return LAYOUT_NAMES


@dataclass(frozen=True)
class TrainConfig:
    """The trainer's settings, checked when built (one ValueError naming the field and what was expected)."""

    iters: int = opt(3000, "optimisation steps (one pseudo-label view per step)", check=C.ITERS)
    res: int = opt(
        128, "held-out view size in pixels (square), and the pseudo-labels' unless label_res is set", check=C.LABEL_RES
    )
    labels: int = opt(240, "number of dense pseudo-label views (Table 5: 120-360)", check=C.LABELS)
    label_res: int = opt(
        0,
        "pseudo-label view size in pixels when it differs from the held-out views' `res` (the labels carry the "
        "panorama's detail up to its own angular resolution, ERP width / 360 px per degree); 0: res",
        check=C.int_in(0, 4096, "label view size"),
        neutral=0,
    )
    fov_deg: float = opt(60.0, "field of view of the label and held-out views (degrees)", check=C.FOV_DEG)
    layout: str = opt("fibonacci", "layout of the pseudo-label directions", choices=_layouts)
    label_order: str = opt(
        "random",
        "which label each step trains on: random (drawn with replacement) or shuffled (each pass over the labels a "
        "new permutation, as 3DGS's and gsplat's trainers take their cameras: every label is seen once per pass; "
        "measured effect: docs/benchmarks.md, time to quality)",
        choices=LABEL_ORDERS,
        neutral="random",
    )
    backend: str = opt(
        "auto",
        "rasterizer: auto (gsplat on CUDA, cpu on the CPU), torch (the reference), cpu (C++), gsplat (CUDA)",
        choices=BACKENDS,
    )
    sh_degree: int = opt(
        3,
        "SH degree of the model and its PLY (the 3DGS layout); bands above the active one stay 0",
        check=C.int_in(0, 3, "SH degree"),
    )
    sh_increase_every: int = opt(
        0,
        "steps between increases of the active SH degree, up to sh_degree (3DGS: 1000); 0: it stays 0. Every "
        "pseudo-label camera sits at the panorama centre, so all of them see a Gaussian along one direction: its "
        "higher bands add the same colour to every label as its DC band can, and only change what other positions "
        "see (measured effect: docs/benchmarks.md)",
        check=C.COUNT,
    )
    coarse_until: float = opt(
        0.2,
        "fraction of iters rendered at half the label size (res // 2, targets and teacher depth area-averaged, K "
        "scaled): coarse to fine, each such step about a third of a full one; 0: every step at full size (labels "
        "under 2 x COARSE_MIN_SIZE = 256 px always are)",
        check=C.FRACTION,
    )
    strategy: str = opt(
        "default", "densify/prune: default (3DGS) or adaptive (§2.5 contribution pruning)", choices=tuple(STRATEGIES)
    )
    densify_from: int = opt(
        100,
        "step of the first clone/split (then every 100 steps until densify_until; 3DGS: 500 of 30,000). An early "
        "start grows the model during the cheap coarse steps; a late one grows it at full size (measured effect: "
        "docs/benchmarks.md)",
        check=C.STEP,
    )
    densify_until: float = opt(
        0.5, "fraction of iters after which no Gaussian is cloned or split (0: never densify)", check=C.FRACTION
    )
    grad_threshold: float = opt(
        2e-4, "mean NDC 2D-mean gradient above which a Gaussian is cloned or split", check=C.POSITIVE_FLOAT
    )
    w_l1: float = opt(0.8, "weight of L1 (eq. 9)", check=C.LOSS_WEIGHT)
    w_ssim: float = opt(0.2, "weight of 1 - SSIM (eq. 12)", check=C.LOSS_WEIGHT)
    w_depth: float = opt(
        0.05, "weight of the Pearson depth term against the teacher's view depth (eq. 10-11)", check=C.LOSS_WEIGHT
    )
    w_spread: float = opt(
        0.0,
        "weight of the depth spread: the blending weights' depth variance along each ray over its squared mean depth "
        "(splat/regularisers.py), so no stack of Gaussians along a centre ray blends right only from the centre; one "
        "more render of each label view per step; 0: none",
        check=C.LOSS_WEIGHT,
        neutral=0.0,
    )
    w_anchor: float = opt(
        0.0,
        "weight of the surface anchor: each Gaussian held within ~10 % of the given cloud's surface along its ray "
        "from the centre, where no label sees it move (splat/regularisers.py); 0: none",
        check=C.LOSS_WEIGHT,
        neutral=0.0,
    )
    footprint_filter: float = opt(
        0.0,
        "variance of Mip-Splatting's 3D smoothing filter in squared label pixels (its 0.2): every Gaussian rendered "
        "no thinner than the finest label pixel that sees it (splat/footprint.py); 0: none",
        check=C.float_in(0.0, 100.0, "filter variance"),
        neutral=0.0,
    )
    antialiased: bool = opt(
        False,
        "Mip-Splatting's 2D mip filter (gsplat's antialiased mode) in training and every render: each Gaussian's "
        "opacity times sqrt(det S / det(S + 0.3 I)) of its 2D covariance S, so the 0.3 px^2 low-pass keeps what "
        "it covers instead of widening it, and a view that sees the surface smaller than the labels did sees "
        "it area-averaged, not aliased; its PLY is then meant for antialiased renderers",
        neutral=False,
    )
    flatten_every: int = opt(
        100,
        "steps between flattenings, and after the last: every Gaussian sheared along its ray from the centre onto "
        "the plane of the given cloud's surface there, a disc on the surface that the centre sees as before "
        "(splat/regularisers.py); 0: never",
        check=C.STEP,
        neutral=0,
    )
    offcentre_labels: int = opt(
        0,
        "masked pseudo-labels from positions off the panorama's centre, beside `labels`: the panorama through the "
        "initial cloud's geometry, co-visible pixels only (splat/offcentre.py); 0: none",
        check=C.COUNT,
        neutral=0,
    )
    offcentre_radius: float = opt(
        0.7,
        "positions of the off-centre labels: uniform in the ball of this fraction of the cloud's free-space radius "
        "(the distance of its nearest 1 % of points from the centre)",
        check=C.FRACTION,
        neutral=0.7,
    )
    lr_means: float = opt(1.6e-4, "initial means learning rate, times the scene extent")
    lr_means_final: float = opt(1.6e-6, "final means learning rate (exponential decay), times the extent")
    lr_quats: float = opt(1e-3, "quaternion learning rate")
    lr_scales: float = opt(5e-3, "log-scale learning rate")
    lr_opacities: float = opt(5e-2, "logit-opacity learning rate")
    lr_sh0: float = opt(2.5e-3, "DC colour learning rate")
    lr_shN: float = opt(2.5e-3 / 20, "higher SH bands learning rate")
    checkpoint_every: int = opt(500, "steps between checkpoints (OUT/ckpt.pt; 0: none)", check=C.STEP)
    heldout: int = opt(
        8,
        "held-out true views (synthetic scenes; dataset scenes with other posed panoramas)",
        check=C.int_in(0, 1000, "held-out view count"),
    )
    history_every: int = opt(100, "steps between history samples (training-view and held-out PSNR; 0: none)")
    eval_at: tuple[int, ...] = opt(
        (),
        "steps before the last at which the full evaluation (pseudo-label and held-out PSNR, SSIM, LPIPS) is also "
        "recorded, in metrics.json's 'budgets' beside the final step's: one run read at several training budgets",
        check=C.int_in(1, 10_000_000, "step"),
        many=True,
    )
    sky: str = opt(
        "panorama",
        "behind the Gaussians: panorama (its sky pixels, a fixed environment at infinity) or none",
        choices=("panorama", "none"),
    )
    init_opacity: float = opt(
        0.1,
        "opacity of every initial Gaussian, in (0, 1) (3DGS: 0.1), unless init_opacity_surface applies",
        check=C.float_in(0.0, 1.0, "opacity"),
    )
    init_opacity_surface: float = opt(
        0.3,
        "opacity of every initial Gaussian when the given cloud is a surface (its neighbouring normals agree, as "
        "flattening requires; not random points, which lie behind one another from the centre): one layer that "
        "0.3 makes opaque to the labels within about a hundred steps, where 0.1 leaves it translucent for hundreds "
        "(measured effect: docs/benchmarks.md, time to quality); 0: init_opacity for every cloud",
        check=C.float_in(0.0, 1.0, "opacity"),
        neutral=0.0,
    )
    disocclusion_fill_deg: float = opt(
        20.0,
        "degrees of background added behind each depth edge of the cloud, as seen from the centre, for views "
        "that look behind it (0: none; splat/initial.py)",
        check=C.float_in(0.0, 180.0, "degrees"),
    )
    disocclusion_fill_visits: float = opt(
        15.0,
        "label views that have seen each direction, on average, when the fill joins the model: the surface in "
        "front of it is opaque from the centre by then (init_opacity_surface), so it keeps its colour and opacity "
        "for the views that look behind (step 187 at 60 deg). A run that gets there only after half its steps "
        "takes the fill into its initial cloud instead (0: always there)",
    )
    disocclusion_opacity: float = opt(
        0.9,
        "opacity of fill Gaussians that join late: hidden from the centre, they keep about what they start with",
        check=C.float_in(0.0, 1.0, "opacity"),
    )
    init_pixels_per_point: float = opt(
        1.0,
        "label pixels per initial point over the sphere: the source's cloud is "
        "thinned to 4 pi / (fov / res)^2 / this points (0 keeps them all)",
    )
    init_detail: float = opt(
        0.005,
        "colour tolerance of the content-adaptive initial cloud: where the colour's standard deviation (in [0, 1]) "
        "and the relative distance from a plane (init_detail_depth) stay within it over a region, that region keeps "
        "fewer, larger Gaussians (down to one per 16 x 16 of the label-pixel spacing; splat/initial.thin_by_detail); "
        "0: the label resolution everywhere (the default's paired held-out difference: docs/benchmarks.md)",
        check=C.float_in(0.0, 1.0, "colour standard deviation"),
        neutral=0.0,
    )
    init_detail_depth: float = opt(
        0.01,
        "geometric tolerance of init_detail: RMS distance of a region's points from their plane over their mean "
        "distance",
        check=C.float_in(0.0, 1.0, "relative distance"),
        neutral=0.01,
    )
    seed: int = opt(0, "random seed", check=C.SEED)

    def __post_init__(self):
        object.__setattr__(self, "eval_at", tuple(self.eval_at))  # a suite's TOML list, a CLI's tuple
        C.validate(self)
        for name in ("init_opacity", "disocclusion_opacity"):  # a logit: 0 and 1 are out of reach
            if not 0 < getattr(self, name) < 1:
                raise ValueError(f"{name} = {getattr(self, name)!r}: expected an opacity in (0, 1)")
        if not 0 <= self.init_opacity_surface < 1:
            raise ValueError(
                f"init_opacity_surface = {self.init_opacity_surface!r}: expected 0 (off) or an opacity in (0, 1)"
            )

    def digest(self) -> str:
        return hashlib.sha256(json.dumps(dataclasses.asdict(self), sort_keys=True).encode()).hexdigest()[:16]


def label_order(kind: str, n_views: int, iters: int, seed: int) -> np.ndarray:
    """[iters] int64: the view each step trains on. ``random``: drawn with replacement; ``shuffled``: consecutive
    passes, each a new permutation of the ``n_views`` (the last one cut at ``iters``)."""
    gen = np.random.default_rng(seed)
    if kind == "random":
        return gen.integers(0, n_views, size=iters)
    if kind == "shuffled":
        passes = -(-iters // n_views)
        return np.concatenate([gen.permutation(n_views) for _ in range(passes)])[:iters]
    raise ValueError(f"label_order {kind!r}: expected one of {', '.join(LABEL_ORDERS)}")


def fill_join_step(cfg: TrainConfig) -> int:
    """The step at which the disocclusion fill joins the model: once each direction has been seen by
    ``cfg.disocclusion_fill_visits`` label views on average (one view per step, each covering the solid angle of
    a square ``fov_deg`` pinhole view, 4 asin(sin^2(fov / 2)) sr); 0, the initial cloud, when that step is not
    before half of ``cfg.iters`` or visits is 0."""
    half_fov = math.radians(cfg.fov_deg) / 2
    share = math.asin(math.sin(half_fov) ** 2) / math.pi  # the view's solid angle over 4 pi
    step = math.ceil(round(cfg.disocclusion_fill_visits / share, 6))  # rounded: sin(45 deg)^2 is 0.5 + 1 ulp
    return step if 0 < step < cfg.iters / 2 else 0


METRICS_MEANING = {
    "skipped": "stages this run left out because the scene or the settings do not need them: stage -> why. sky: "
    "no sky environment behind the Gaussians; disocclusion_fill: no points behind depth edges; depth_loss: no "
    "Pearson depth term; held-out: no held-out views; depth_metrics: no depth or point metrics against a truth "
    "(the points stage's report reads n/a); flatten: no flattening onto the starting cloud's surface",
    "seconds": "wall seconds per stage: backend (loading or building the rasterizer), labels (pseudo-labels, "
    "off-centre labels and held-out views), flatten_surface (the given cloud's surface normals, their coherence and "
    "each bin's plane for flattening, once, before training; absent when neither flatten_every nor "
    "init_opacity_surface asks for them), train (the steps, "
    "without the held-out history samples), flatten (the flattenings within train: flatten / train is their "
    "share), history, eval, total",
    "initial_opacity": "the opacity every initial Gaussian started at: init_opacity_surface where the given "
    "cloud is a surface (normal coherence at least FLAT_MIN_COHERENCE), else init_opacity",
    "initial_thinning": "the initial cloud after thinning to the label resolution (splat/initial.thin_by_detail): "
    "points kept, and per level (0: the label-pixel spacing; l: sites 2^l times further apart, kept where colour "
    "and geometry are smooth within init_detail and init_detail_depth)",
}


def skipped_stages(
    scene, cfg: TrainConfig, env, fill_points: int, heldout: list, has_teacher: bool, coherence: float | None = None
) -> dict:
    """{stage: why} for each stage ``train`` left out (``METRICS_MEANING['skipped']``): ``env`` the sky environment
    (None: none), ``fill_points`` the disocclusion fill's size, ``heldout`` the held-out views, ``has_teacher``
    whether the labels carry teacher depth, ``coherence`` the starting cloud's ``normal_coherence`` (None: not
    computed, flattening off)."""
    skipped = {}
    if not cfg.flatten_every:
        skipped["flatten"] = "flatten_every = 0"
    elif coherence is not None and coherence < FLAT_MIN_COHERENCE:
        skipped["flatten"] = (
            f"the starting cloud has no surface to flatten onto: {coherence:.0%} of its neighbouring normals agree "
            f"(< {FLAT_MIN_COHERENCE:.0%})"
        )
    if cfg.sky == "none":
        skipped["sky"] = "sky = none"
    elif env is None:
        skipped["sky"] = "the panorama has no sky pixel"
    if not cfg.disocclusion_fill_deg:
        skipped["disocclusion_fill"] = "disocclusion_fill_deg = 0"
    elif not fill_points:
        skipped["disocclusion_fill"] = "the cloud has no depth edge as seen from the centre"
    if not has_teacher:
        skipped["depth_loss"] = "no teacher depth for the labels"
    elif not cfg.w_depth:
        skipped["depth_loss"] = "w_depth = 0"
    if not heldout:
        skipped["held-out"] = (
            "heldout = 0"
            if not cfg.heldout
            else scene.meta.get("heldout_note", "n/a: scene has no ground-truth world").removeprefix("n/a: ")
        )
    if not scene.has_ground_truth:
        skipped["depth_metrics"] = f"scene {scene.name!r} has no true depth"
    return skipped


def _adam(model: GaussianModel, groups) -> torch.optim.Adam:
    """One Adam group per parameter (named, for the strategies' edits), eps 1e-15 as in 3DGS; the fused
    kernel (one pass per tensor, ~3x faster than the per-tensor loop at 100k+ Gaussians on CPU)."""
    return torch.optim.Adam(
        [{"params": [getattr(model, n)], "lr": lr, "name": n} for n, lr in groups], eps=1e-15, fused=True
    )


def train(
    scene,
    point_cloud,
    config: TrainConfig,
    out_dir,
    depth_fn=None,
    progress: bool = True,
    inputs: dict | None = None,
    device: str | torch.device = "auto",
    heldout_scale: float = 1.0,
) -> dict:
    """Fit Gaussians initialised from ``point_cloud`` to pseudo-labels of ``scene``; writes point_cloud.ply
    (3DGS layout), cameras.json (pseudo-label and held-out cameras: viewmat, K, size), renders/, metrics.json and
    ckpt.pt, resumed (on any device) when present and written for the same scene, width, config, cloud and
    ``inputs`` (e.g. source and teacher names; see ``checkpoint.py``). The model, labels, losses, optimizer and
    strategy live on ``device`` ('auto': CUDA when present); the step loop reads nothing back to the host except
    every ``history_every`` steps. ``heldout_scale``: the cloud's scale against the truth (truth = scale x cloud,
    the source's median depth alignment; 1 for metric clouds): held-out cameras are placed at their true positions
    divided by it, so a scale-ambiguous cloud is judged in its own frame (a similarity alignment), not on its
    arbitrary global scale."""
    from tqdm import tqdm

    cfg = config
    check_scene_scale(np.linalg.norm(point_cloud.xyz, axis=1), "the point cloud to train from")
    given_cloud = point_cloud  # the checkpoint's key: the cloud as given (thinning by detail may drop a change)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    seconds = {}
    dev = resolve_device(device)
    reset_peak_memory(dev)
    backend = resolve_backend(cfg.backend, dev.type == "cuda")  # on first use this loads (or builds) the C++ backend
    seconds["backend"] = time.perf_counter() - t0
    t = time.perf_counter()
    lres = cfg.label_res or cfg.res  # the labels' size; held-out views are res
    labels = make_pseudo_labels(scene, cfg.labels, lres, cfg.fov_deg, cfg.layout, depth_fn)
    heldout = []
    if cfg.heldout and scene.world is not None:
        heldout = make_heldout_views(scene, cfg.heldout, cfg.res, cfg.fov_deg, cfg.seed)
    elif cfg.heldout and scene.has_ground_truth and scene.meta.get("others"):  # a dataset space's other panoramas
        from ..scenes.datasets import heldout_panoramas

        pans = heldout_panoramas(scene)
        heldout = make_panorama_heldout_views(scene, pans, cfg.heldout, cfg.res, cfg.fov_deg, cfg.seed) if pans else []
    if not (np.isfinite(heldout_scale) and heldout_scale > 0):
        raise ValueError(f"heldout_scale={heldout_scale!r}: expected a finite scale > 0 (truth / cloud)")
    heldout = [in_cloud_frame(v, heldout_scale) for v in heldout]
    heldout_na = covisible_shortfall(heldout)  # other panoramas that see too little: no held-out number at all
    env = sky_environment(scene) if cfg.sky == "panorama" else None
    # the panorama seen from elsewhere through the cloud as given (no fill: the centre never saw behind edges)
    offcentre = offcentre_labels(
        scene.rgb, point_cloud, cfg.offcentre_labels, lres, cfg.fov_deg, cfg.offcentre_radius, cfg.seed
    )
    for v in (*labels, *offcentre, *heldout):
        v.background = view_background(env, v.camera)
    seconds["labels"] = time.perf_counter() - t
    fill, fill_points = None, 0  # the fill's points: joined to the cloud now, or to the model at fill_step
    fill_step = fill_join_step(cfg)
    if cfg.disocclusion_fill_deg:
        fill = disocclusion_fill(point_cloud, *scene.rgb.shape[:2], cfg.disocclusion_fill_deg)
        fill_points = len(fill)
        log.info("disocclusion fill: %d points behind depth edges", fill_points)
        if not fill_step or not fill_points:
            point_cloud, fill = (
                PointCloud(np.concatenate([point_cloud.xyz, fill.xyz]), np.concatenate([point_cloud.rgb, fill.rgb])),
                None,
            )
    thinning = {"points": len(point_cloud), "points_per_level": {}}
    if cfg.init_pixels_per_point:
        n_points = points_for_resolution(lres, cfg.fov_deg, cfg.init_pixels_per_point)
        before = len(point_cloud)
        point_cloud, thinning = thin_by_detail(point_cloud, n_points, cfg.init_detail, cfg.init_detail_depth, cfg.seed)
        if fill is not None and len(point_cloud) < before:  # the late fill thinned as the cloud was
            fill = thin_cloud(fill, max(1, round(len(fill) * len(point_cloud) / before)), cfg.seed)
            fill_points = len(fill)
    # the given cloud's surface seen from the centre, in bins it fills: whether it is one (its normals agree)
    normals, coherence = None, None
    if cfg.flatten_every or cfg.init_opacity_surface:
        tf = time.perf_counter()
        normals = surface_normals(given_cloud.xyz, flatten_height(len(given_cloud.xyz), lres, cfg.fov_deg))
        coherence = normal_coherence(normals)
        seconds["flatten_surface"] = time.perf_counter() - tf
    is_surface = coherence is not None and coherence >= FLAT_MIN_COHERENCE
    init_opacity = cfg.init_opacity_surface if cfg.init_opacity_surface and is_surface else cfg.init_opacity
    model = GaussianModel.from_point_cloud(point_cloud, cfg.sh_degree, init_opacity)
    if cfg.init_detail and point_cloud.normals is not None:  # thin_by_detail's coarse points: discs on their plane
        flatten_to_discs(model, point_cloud.normals, DISC_THICKNESS)
    model = model.to(dev)
    fill_step = fill_step if fill is not None else -1
    late_fill = (
        None if fill is None else GaussianModel.from_point_cloud(fill, cfg.sh_degree, cfg.disocclusion_opacity).to(dev)
    )
    extent = float(np.percentile(np.linalg.norm(point_cloud.xyz, axis=1), 90)) or 1.0
    groups = [
        ("means", cfg.lr_means * extent),
        ("quats", cfg.lr_quats),
        ("log_scales", cfg.lr_scales),
        ("logit_opacities", cfg.lr_opacities),
        ("sh0", cfg.lr_sh0),
        ("shN", cfg.lr_shN),
    ]
    opt = _adam(model, groups)
    strategy = STRATEGIES[cfg.strategy](
        refine_start=cfg.densify_from, refine_stop=int(cfg.densify_until * cfg.iters), grad_threshold=cfg.grad_threshold
    )
    start, history, budgets = 0, [], []
    ckpt = out / "ckpt.pt"
    keys = checkpoint_inputs(scene, given_cloud, cfg.digest(), {**(inputs or {}), "heldout_scale": heldout_scale})
    state = load_checkpoint(ckpt, keys, cfg.iters)
    torch.manual_seed(cfg.seed)  # split sampling; a resumed run continues the stored generator states
    if state is not None:
        model = GaussianModel(*[state["model"][n] for n in PARAM_NAMES]).to(dev)
        opt = _adam(model, groups)
        opt.load_state_dict(state["optimizer"])
        start, history = state["iteration"], state["history"]
        budgets = state.get("budgets", [])
        if state.get("footprint") is not None:
            model.footprint = (state["footprint"].to(dev), cfg.footprint_filter)
        strategy.load_state_dict(state["strategy"])
        torch.set_rng_state(state["rng"])
        if dev.type == "cuda" and "cuda_rng" in state:
            torch.cuda.set_rng_state(state["cuda_rng"], dev)
        log.info("resuming %s at step %d of %d", ckpt, start, cfg.iters)
    surface = None  # the given cloud's surface seen from the centre, in label-pixel bins (the anchor's target)
    if cfg.w_anchor:
        surface = torch.from_numpy(surface_distances(given_cloud.xyz, anchor_height(lres, cfg.fov_deg))).to(dev)
    frames = None  # the given cloud's surface planes per bin
    if cfg.flatten_every and is_surface:
        tf = time.perf_counter()
        frames = flatten_frames(normals, dev)
        seconds["flatten_surface"] += time.perf_counter() - tf
    elif cfg.flatten_every:
        log.info("flattening skipped: %.0f %% of the cloud's neighbouring normals agree", 100 * coherence)
    # every label's target, teacher depth and camera on the device once (no host-to-device copy per step)
    views = labels + offcentre  # the views trained on: teacher depth for the centre's, masks for the others'
    targets = torch.from_numpy(np.stack([v.rgb for v in views])).to(dev)
    teachers = None if labels[0].depth is None else torch.from_numpy(np.stack([v.depth for v in labels])).to(dev)
    masks = None if not offcentre else torch.from_numpy(np.stack([v.mask for v in offcentre])).to(dev)
    viewmats, Ks = _cameras(views, dev)
    backgrounds = (
        None if labels[0].background is None else torch.from_numpy(np.stack([v.background for v in views])).to(dev)
    )
    # coarse to fine: the same labels at res // 2 (area means; pixel centres at i + 0.5, so K scales with the size)
    coarse_steps = int(cfg.coarse_until * cfg.iters) if lres // 2 >= COARSE_MIN_SIZE else 0
    coarse = None  # (size, targets, teacher depths, masks, Ks, backgrounds) of the coarse steps, if any are left
    if coarse_steps > start:
        small = lres // 2
        area = lambda x: None if x is None else F.interpolate(x.movedim(-1, 1), size=small, mode="area").movedim(1, -1)  # noqa: E731
        teachers_small = None if teachers is None else area(teachers[..., None])[..., 0]
        Ks_small = Ks * torch.tensor([[small / lres], [small / lres], [1.0]], device=dev)
        masks_small = None if masks is None else area(masks[..., None].float())[..., 0] > 0.999
        coarse = (small, area(targets), teachers_small, masks_small, Ks_small, area(backgrounds))
    first_bad = torch.full((), -1, dtype=torch.long, device=dev)  # first iteration with a non-finite loss
    synchronize(dev)
    t = time.perf_counter()
    # training seconds exclude the held-out history samples; a resumed run continues from its last sample
    history_s, clock0 = 0.0, (history[-1].get("seconds", 0.0) if history else 0.0)
    seconds["flatten"] = 0.0  # within seconds["train"]
    order = label_order(cfg.label_order, len(views), cfg.iters, cfg.seed)
    bar = tqdm(range(start, cfg.iters), initial=start, total=cfg.iters, disable=not progress, desc="train")

    def checkpoint(iteration: int) -> str:
        """ckpt.pt after ``iteration`` steps (model, optimizer, strategy, history, generator states) -> its path."""
        rng = {"rng": torch.get_rng_state()}
        if dev.type == "cuda":
            rng["cuda_rng"] = torch.cuda.get_rng_state(dev)
        state = {
            "iteration": iteration,
            "history": history,
            "budgets": budgets,
            "optimizer": opt.state_dict(),
            "strategy": strategy.state_dict(),
            **rng,
            "model": {n: p.detach() for n, p in model.named_parameters()},
            "footprint": None if model.footprint is None else model.footprint[0],  # refreshed every 100 steps
        }
        save_checkpoint(ckpt, keys, state)
        return str(ckpt)

    # Ctrl-C / SIGTERM wait for a step boundary, where a checkpoint is written to resume from (see interrupts)
    for it in interrupts.at_step_boundaries(bar, cfg.iters, checkpoint):
        if it == fill_step:  # behind a surface that is opaque by now: the centre's labels no longer see it
            keep = torch.ones(len(model), dtype=torch.bool, device=dev)
            edit_parameters(model, opt, keep, {n: getattr(late_fill, n).detach() for n in PARAM_NAMES})
        lr = cfg.lr_means * extent * (cfg.lr_means_final / cfg.lr_means) ** (it / max(cfg.iters - 1, 1))
        opt.param_groups[0]["lr"] = lr
        k = int(order[it])
        deg = min(cfg.sh_degree, it // cfg.sh_increase_every) if cfg.sh_increase_every else 0
        footprint.refresh(model, cfg.footprint_filter, viewmats, Ks, lres)  # a new or resized model
        res, targets_it, teachers_it, masks_it, Ks_it, backgrounds_it = (
            coarse if it < coarse_steps else (lres, targets, teachers, masks, Ks, backgrounds)
        )
        img, alpha, depth, meta = _render(
            model,
            [views[k]],
            cfg,
            deg,
            backend,
            strategy.needs_contrib,
            (viewmats[k : k + 1], Ks_it[k : k + 1]),
            None if backgrounds_it is None else backgrounds_it[k : k + 1],
            res,
        )
        meta["means2d"].retain_grad()
        target = targets_it[k : k + 1]
        if k >= len(labels):  # an off-centre label: its masked pixels give no loss (the render is their target)
            target = torch.where(masks_it[k - len(labels), None, ..., None], target, img.detach())
        teacher = None if teachers_it is None or k >= len(labels) else teachers_it[k]
        expected_z = (depth / alpha.clamp_min(1e-6))[0, ..., 0]
        loss = total_loss(
            img,
            target,
            expected_z,
            teacher,
            alpha[0, ..., 0].detach() > 0.5,
            cfg.w_l1,
            cfg.w_ssim,
            cfg.w_depth if teacher is not None else 0.0,
        )
        if cfg.w_anchor:
            loss = loss + cfg.w_anchor * surface_anchor(model.means, surface)
        if cfg.w_spread:
            s2 = render_depth_sq(model, viewmats[k : k + 1], Ks_it[k : k + 1], res, res, backend, cfg.antialiased)
            loss = loss + cfg.w_spread * depth_spread(alpha[..., 0], depth[..., 0], s2)
        # recorded on the device and checked where the loop syncs anyway (history, checkpoints, the end)
        first_bad = torch.where((first_bad < 0) & ~torch.isfinite(loss.detach()), it, first_bad)
        loss.backward()
        strategy.observe(model, meta, res, res)
        opt.step()
        opt.zero_grad(set_to_none=True)
        strategy.step(model, opt, it + 1, extent)
        if frames is not None and ((it + 1) % cfg.flatten_every == 0 or it + 1 == cfg.iters):
            tf = time.perf_counter()
            flatten_onto_surface(model, frames)
            synchronize(dev)
            seconds["flatten"] += time.perf_counter() - tf
        footprint.refresh(model, cfg.footprint_filter, viewmats, Ks, lres, it + 1)
        sync_now = (
            (cfg.history_every and (it + 1) % cfg.history_every == 0)
            or it + 1 == cfg.iters
            or (cfg.checkpoint_every and (it + 1) % cfg.checkpoint_every == 0)
        )
        if sync_now and int(first_bad) >= 0:
            raise FloatingPointError(
                f"non-finite loss at iteration {int(first_bad)}: check the point cloud and learning rates"
            )
        if cfg.history_every and (it + 1) % cfg.history_every == 0:
            te = time.perf_counter()
            seen = slice(None) if k < len(labels) else masks_it[k - len(labels)]  # the pixels the step scored
            history.append(
                {
                    "iteration": it + 1,
                    "seconds": clock0 + te - t - history_s,
                    "psnr": psnr(img.detach().clamp(0, 1)[0][seen], target[0][seen]),
                    "gaussians": len(model),
                }
            )
            if heldout and heldout_na is None:
                history[-1]["heldout_psnr"] = _heldout_psnr(model, heldout, cfg, backend)
            history_s += time.perf_counter() - te
            bar.set_postfix(psnr=f"{history[-1]['psnr']:.2f}", n=len(model))
        if it + 1 in cfg.eval_at and it + 1 < cfg.iters:
            te = time.perf_counter()
            budgets.append(
                {
                    "iteration": it + 1,
                    "seconds": clock0 + te - t - history_s,
                    "gaussians": len(model),
                    "pseudo-label": _evaluate(model, labels, cfg, backend),
                    "held-out": _evaluate(model, heldout, cfg, backend) if heldout else None,
                }
            )
            history_s += time.perf_counter() - te
        if cfg.checkpoint_every and (it + 1) % cfg.checkpoint_every == 0 and it + 1 < cfg.iters:
            checkpoint(it + 1)
    synchronize(dev)
    seconds["train"] = time.perf_counter() - t - history_s
    seconds["history"] = history_s
    t = time.perf_counter()
    metrics = {
        "pseudo-label": _evaluate(model, labels, cfg, backend),
        "held-out": _evaluate(model, heldout, cfg, backend)
        if heldout
        else scene.meta.get("heldout_note", "n/a: scene has no ground-truth world"),
    }
    seconds["eval"] = time.perf_counter() - t
    budgets.append(
        {
            "iteration": cfg.iters,
            "seconds": clock0 + seconds["train"],
            "gaussians": len(model),
            "pseudo-label": metrics["pseudo-label"],
            "held-out": metrics["held-out"] if heldout else None,
        }
    )
    save_ply(model, out / "point_cloud.ply")
    if env is not None:  # the sky the Gaussians were trained in front of, for viewers of the .ply
        write_image(out / "sky.png", (env * 255).round().astype(np.uint8))
    write_json(
        out / "cameras.json",
        {
            name: [
                {
                    "viewmat": v.camera.viewmat.tolist(),
                    "K": v.camera.K.tolist(),
                    "width": v.camera.width,
                    "height": v.camera.height,
                }
                for v in views
            ]
            for name, views in (("pseudo-label", labels), ("held-out", heldout))
        },
    )
    with torch.no_grad():
        for name, views in (("label", labels[:3]), ("heldout", heldout[:3])):
            for k, v in enumerate(views):
                img = _render(model, [v], cfg, model.sh_degree, backend)[0][0].clamp(0, 1).cpu().numpy()
                write_image(
                    out / "renders" / f"{name}_{k}.png",
                    (np.concatenate([img, v.rgb], 1) * 255).round().astype(np.uint8),
                )
    seconds["total"] = time.perf_counter() - t0
    metrics.update(
        seconds=seconds,
        iterations=cfg.iters,
        gaussians=len(model),
        initial_gaussians=len(point_cloud),
        initial_opacity=init_opacity,
        disocclusion_points=fill_points,
        disocclusion_step=max(fill_step, 0),
        backend=backend,
        strategy=cfg.strategy,
        peak_rss_mb=peak_rss_mb(),
        **device_record(dev),
        history=history,
        budgets=budgets,
        heldout_best=best_heldout(history, heldout_na),
        heldout_plateau=heldout_plateau(history, heldout_na),
        heldout_scale=heldout_scale,
        initial_thinning=thinning,
        skipped=skipped_stages(scene, cfg, env, fill_points, heldout, labels[0].depth is not None, coherence),
        meaning=METRICS_MEANING,
        config=dataclasses.asdict(cfg),
    )
    write_json(out / "metrics.json", metrics)
    ckpt.unlink(missing_ok=True)
    return metrics
