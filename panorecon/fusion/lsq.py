"""The method's fusion (paper §2.4): per-view depth -> one panoramic ray-distance map by least squares in
log-distance, with gradient-matching (eq. 16) and Laplacian (eq. 17) terms.

Unknowns: x = log ray distance per ERP pixel, and s_i = log-scale per view (relative teachers).
Energy, with c_i(p) = cos^2 of the angle between pixel p's ray and view i's optical axis and a(p) = cos(lat)
the pixel's area weight::

    E(x, s) = w_grad * sum_i sum_(p,q) a c_i (x_q - x_p - (l_i(q) - l_i(p)))^2   horizontal (wrapping), vertical pairs
            + w_lap  * sum_i sum_p     a c_i (Lap x (p) - Lap l_i (p))^2        5-point Laplacian, taps seen by i
            + w_data * sum_i sum_p     a c_i (x_p - l_i(p) - s_i)^2                weak anchor: fixes the constant

Border of the sky: a view's pixels within ``border_px`` of a large invalid region (the sky; isolated dropped
pixels do not count) are flying pixels in every monocular teacher, which blends foreground and far background
there. They take part in no gradient or Laplacian equation and keep only a data anchor scaled by
``border_anchor``; where no view has a reliable value, the pixel is filled from its neighbours by Laplacian = 0
equations (linear continuation, weight w_lap * border_laplacian) and a weak membrane (gradient = 0, weight
w_grad * border_smooth). A connected region that no reliable observation reaches keeps its border values.

The gradient and Laplacian terms are invariant to each view's scale (a log-scale is an additive
constant), so per-view scale only enters the data term. Summing over views, each pair / pixel carries one
aggregated weight and target, so the system is H*W x H*W whatever the number of views. Its normal matrix
is sparse SPD (13-point stencil), solved coarse to fine: a direct solve at the coarsest level (assembled
sparse matrix), then Jacobi-preconditioned conjugate gradients on the matrix-free stencil operator
(``operators.StencilNormalOperator``: array shifts, no assembly; optionally pyamg smoothed-aggregation AMG on
the assembled matrix; with ``cg_device`` the same Jacobi-PCG runs in torch, on a GPU when asked), warm-started
from each pixel's data-weighted mean of its observations at the current per-view scales (the level's own fine
detail), the upsampled coarser solution where no view sees the pixel (``warm_start='coarse'``: that solution
everywhere, which leaves the CG to rebuild the detail the coarser grid could not hold: 36-39 iterations per
level instead of 5-11 on bench/fusion_moge.py's 2048 x 1024 inputs).
s is updated in closed form between solves (block coordinate descent), its gauge fixed by mean(s) = 0; metric
teachers keep s = 0. Systems are assembled and checked in float64: the Jacobi-PCG's stencil products run in
float32 (``cg_precision='mixed'``: half the memory traffic) with the residual recomputed in float64 and
refined until it meets ``tol`` there; the output is float32. Affine-invariant views (unknown scale and shift) are
first aligned to each other (``affine.py``). l_i is the view's log distance warped onto the level's ERP grid
(``warp.py``; ``FusionConfig.sampling``).
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .. import checks as C
from ..checks import opt
from ..geometry import ViewDepth, erp_pixel_to_lonlat, sample_erp
from .affine import GAUGES as AFFINE_GAUGES
from .affine import align_affine_views
from .connectivity import check_connectivity
from .operators import (
    StencilNormalOperator,
    TorchStencilOperator,
    laplacian_centres,
    stacked_operator,
    transpose_apply,
    vertical_pairs,
)
from .upsample import guided_upsample
from .warp import ErpObservation, warp_to_erp


@dataclass
class FusionConfig:
    """Weights and solver settings of ``fuse_views``."""

    w_grad: float = 1.0  # gradient-matching weight (eq. 16)
    w_lap: float = 0.25  # Laplacian weight (eq. 17)
    w_data: float = 0.02  # zero-order anchor weight
    levels: int | None = None  # pyramid levels; None: halve until the coarsest ERP height is <= 256
    tol: float = 1e-3  # relative residual at which CG stops on the finest level (1e-4 changed AbsRel by < 0.1 %)
    maxiter: int = 300  # CG iterations per level at most
    scale_iters: int = 2  # per-view scale updates per level (levels up to scale_max_height only)
    scale_max_height: int = 128  # finer levels keep the per-view scales of the coarser ones
    coarse_tol: float = 1e-3  # CG tolerance on every level but the finest
    preconditioner: str = "jacobi"  # "jacobi" or "amg" (pyamg smoothed aggregation: fewer, dearer iterations)
    area_weight: bool = True  # weight equations by cos(latitude), the ERP pixel's solid angle
    border_px: int = 4  # view pixels next to the sky whose depth is not used as evidence (0: use all)
    border_anchor: float = 1e-3  # data weight of a border pixel, relative to w_data
    border_smooth: float = 0.1  # membrane weight (gradient = 0) where a border pixel is filled, relative to w_grad
    border_laplacian: float = 1.0  # Laplacian = 0 weight where a border pixel is filled, relative to w_lap
    cg_device: str | None = None  # None: SciPy's CG; "cpu" / "cuda": the same Jacobi-PCG in torch float64 there
    cg_precision: str = "mixed"  # SciPy Jacobi-PCG: "mixed" (float32 products, float64 refinement) or "double"
    warm_start: str = "data"  # CG start: "data" (observations' mean; the coarser solution where none) or "coarse"
    sampling: str = "linear"  # warp: "linear" (edge-aware bilinear, footprint-averaged) or "nearest" (warp.py)
    supersample: int | None = None  # sub-rays per ERP pixel side, finest level, "linear"; None: from the footprint
    edge_log: float = 0.1  # "linear" leaves out taps further than this (log distance) from the nearest one
    # view pixels next to a depth edge above this (log distance; ln 1.5: a pixel put on the wrong side of, or
    # blended across, a smaller jump is less than 50 % off) are not observed, and the upsampling keeps to one side
    # of such an edge (warp.depth_edge_pixels, upsample.snap_to_side); None: off
    edge_jump: float | None = math.log(1.5)
    # view pixels within this many pixels of such an edge whose step to a neighbour is above half edge_jump are
    # part of it where flat pixels on both sides in the same window lie more than edge_jump apart: a teacher's blur
    # spreads a jump over a few pixels (sim:relative's 1.5 px: 3), a grazing surface keeps edge_jump's test
    # (warp.depth_edge_pixels); 0: edge_jump only
    edge_reach: int = 3
    affine_gauge: str = "reference"  # affine views' global shift (affine.py): "reference" or "mean-shift"
    resolution: str = "views"  # "views": solve up to the level the views resolve, then guided upsampling; "full"
    upsample_radius: int = 2  # guided upsampling window radius, solve-level pixels (upsample.py)
    upsample_eps: float = 1e-4  # guided upsampling regularisation, colour variance (colour in [0, 1])
    extra: dict = field(default_factory=dict)

    def check(self) -> None:
        for name in ("w_grad", "w_lap", "w_data", "border_anchor", "border_smooth", "border_laplacian"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"FusionConfig.{name}={v!r}: expected a finite weight >= 0")
        if not self.w_data > 0:
            raise ValueError(f"FusionConfig.w_data={self.w_data!r}: expected > 0 (it fixes the unknown constant)")
        if not (isinstance(self.border_px, int) and self.border_px >= 0):
            raise ValueError(f"FusionConfig.border_px={self.border_px!r}: expected an integer >= 0 (view pixels)")
        if self.border_px and not self.border_anchor > 0:
            raise ValueError(f"FusionConfig.border_anchor={self.border_anchor!r}: expected > 0 when border_px > 0")
        if self.sampling not in ("linear", "nearest"):
            raise ValueError(f"FusionConfig.sampling={self.sampling!r}: expected 'linear' or 'nearest'")
        if not (self.supersample is None or (isinstance(self.supersample, int) and 1 <= self.supersample <= 8)):
            raise ValueError(f"FusionConfig.supersample={self.supersample!r}: expected None or an integer in [1, 8]")
        if self.affine_gauge not in AFFINE_GAUGES:
            raise ValueError(
                f"FusionConfig.affine_gauge={self.affine_gauge!r}: expected one of {', '.join(AFFINE_GAUGES)}"
            )
        if self.resolution not in ("views", "full"):
            raise ValueError(f"FusionConfig.resolution={self.resolution!r}: expected 'views' or 'full'")
        if not (isinstance(self.upsample_radius, int) and self.upsample_radius >= 0 and self.upsample_eps > 0):
            raise ValueError(
                f"FusionConfig upsample_radius={self.upsample_radius!r}, upsample_eps={self.upsample_eps!r}: "
                "expected an integer >= 0 and a variance > 0"
            )
        if not self.edge_log > 0:
            raise ValueError(f"FusionConfig.edge_log={self.edge_log!r}: expected > 0 (log distance)")
        if self.edge_jump is not None and not (math.isfinite(self.edge_jump) and self.edge_jump > 0):
            raise ValueError(f"FusionConfig.edge_jump={self.edge_jump!r}: expected None or > 0 (log distance)")
        if not (isinstance(self.edge_reach, int) and self.edge_reach >= 0):
            raise ValueError(f"FusionConfig.edge_reach={self.edge_reach!r}: expected an integer >= 0 (view pixels)")
        if self.preconditioner not in ("amg", "jacobi"):
            raise ValueError(f"FusionConfig.preconditioner={self.preconditioner!r}: expected 'amg' or 'jacobi'")
        if self.warm_start not in ("data", "coarse"):
            raise ValueError(f"FusionConfig.warm_start={self.warm_start!r}: expected 'data' or 'coarse'")
        if self.cg_precision not in ("mixed", "double"):
            raise ValueError(f"FusionConfig.cg_precision={self.cg_precision!r}: expected 'mixed' or 'double'")
        if self.cg_device is not None and self.preconditioner != "jacobi":
            raise ValueError(
                f"FusionConfig.cg_device={self.cg_device!r}: the torch CG has the Jacobi preconditioner "
                f"only (preconditioner={self.preconditioner!r})"
            )
        if not (self.tol > 0 and self.maxiter >= 1):
            raise ValueError(f"FusionConfig tol={self.tol}, maxiter={self.maxiter}: expected tol > 0, maxiter >= 1")


@dataclass(frozen=True)
class FusionOptions:
    """The fusion settings a command line or a suite row sets (the rest of ``FusionConfig`` is the solver's and
    changes no result beyond its tolerance). Each declares the value at which it behaves as before it existed
    (``neutral``): a run that leaves it there keeps the identity it had then (``checks.identity``)."""

    edge_jump: float = opt(
        FusionConfig.edge_jump,
        "log-distance jump of a depth edge: view pixels next to one are not observed and the upsampling keeps to "
        "one side of it (FusionConfig.edge_jump; ln 1.5); 0: off",
        check=C.float_in(0.0, 10.0, "log distance"),
        neutral=0.0,
    )
    edge_reach: int = opt(
        FusionConfig.edge_reach,
        "view pixels within which steps over half edge_jump go with a depth edge (a teacher's blur spreads a jump "
        "over a few pixels); 0: edge_jump's test only",
        check=C.int_in(0, 64, "view pixels"),
        neutral=0,
    )
    affine_gauge: str = opt(
        FusionConfig.affine_gauge,
        "how affine-invariant views' global shift is fixed: 'reference' (the reference view's shift that the other "
        "views' overlaps fit best) or 'mean-shift' (the teacher's shifts average to zero; the first alignment)",
        choices=AFFINE_GAUGES,
        neutral="mean-shift",
    )

    def __post_init__(self):
        C.validate(self)

    def config(self, **solver) -> FusionConfig:
        """A ``FusionConfig`` with these settings and the solver's ``solver`` (e.g. ``cg_device``)."""
        return FusionConfig(
            edge_jump=self.edge_jump or None, edge_reach=self.edge_reach, affine_gauge=self.affine_gauge, **solver
        )


@dataclass
class FusionResult:
    """distance: [H, W] float32 ray distance (NaN where no view saw the pixel); seen: [H, W] bool;
    view_scale: [V] multiplicative factor applied to each view's distance; view_shift: [V] shift applied in
    the view's own space (affine views; 0 otherwise); report: solver statistics."""

    distance: np.ndarray
    seen: np.ndarray
    view_scale: np.ndarray
    view_shift: np.ndarray
    report: dict


def _check_views(views: Sequence[ViewDepth], height: int, width: int) -> None:
    if len(views) == 0:
        raise ValueError("fuse_views: no views given; expected at least one ViewDepth")
    if width != 2 * height or height < 2:
        raise ValueError(f"fuse_views: ERP size {width}x{height}: expected width = 2 x height >= 4")


def pyramid_heights(height: int, levels: int | None, coarsest: int = 256) -> list[int]:
    """ERP heights from coarsest to finest, each level half the next; ``levels`` of them, or (None) as many
    as it takes to bring the coarsest height to ``coarsest`` or below."""
    hs = [height]
    while (levels is None and hs[-1] > coarsest) or (levels is not None and len(hs) < levels):
        nxt = hs[-1] // 2
        if nxt < 4:
            break
        hs.append(nxt)
    return hs[::-1]


def view_supported_height(views: Sequence[ViewDepth], heights: Sequence[int]) -> tuple[int, dict]:
    """The finest of ``heights`` (a pyramid, coarsest first) whose ERP pixel (pi / h radians) is no smaller than
    the finest view's central pixel (1 / f radians, f its focal length in pixels), rounded to the nearest level:
    h <= sqrt(2) pi f (a 512 px, 89 degree view: f = 259 px, h <= 1150 rows). Finer levels would solve for
    detail no view holds. -> (height, why: the numbers the choice came from)."""
    f = max(float(v.camera.K[0, 0]) for v in views)
    limit = math.sqrt(2.0) * math.pi * f
    fits = [h for h in heights if h <= limit]
    h = fits[-1] if fits else heights[0]
    return h, {
        "view_focal_px": f,
        "view_pixel_deg": math.degrees(1.0 / f),
        "max_height": limit,
        "erp_pixel_deg": 180.0 / h,
        "reason": f"views resolve {math.degrees(1.0 / f):.4f} deg per pixel: ERP levels up to sqrt(2) pi f = "
        f"{limit:.0f} rows are observed; {h} rows solved",
    }


@dataclass
class _Level:
    height: int
    width: int
    obs: list[ErpObservation]
    seen: np.ndarray  # [N] bool


@functools.lru_cache(maxsize=2)
def _erp_rays(height: int) -> np.ndarray:
    """Unit ERP directions [H*2H, 3] of one size (``erp_directions``' values), computed once (read-only):
    trigonometry per row and per column only, combined by outer products."""
    width = 2 * height
    lon, lat = erp_pixel_to_lonlat(np.arange(height, dtype=float), np.arange(width, dtype=float), height, width)
    cl = np.cos(lat)[:, None]
    d = np.empty((height, width, 3))
    d[..., 0], d[..., 1], d[..., 2] = cl * np.cos(lon)[None], -cl * np.sin(lon)[None], np.sin(lat)[:, None]
    d = d.reshape(-1, 3)
    d.flags.writeable = False
    return d


def _observe(views, dists, height, border_px: int = 0, cfg: FusionConfig | None = None, finest: bool = True) -> _Level:
    """The views warped onto one pyramid level; ``cfg``'s sampling (coarser levels, which only start the next
    one, read one bilinear ray per pixel); without ``cfg`` nearest-neighbour."""
    width = 2 * height
    dirs = _erp_rays(height)
    warp = (
        {}
        if cfg is None
        else {
            "sampling": cfg.sampling,
            "supersample": cfg.supersample if finest else 1,
            "edge_log": cfg.edge_log,
            "edge_jump": cfg.edge_jump,
            "edge_reach": cfg.edge_reach,
        }
    )
    obs = [warp_to_erp(v, height, width, dirs, d, border_px, **warp) for v, d in zip(views, dists)]
    seen = np.zeros(height * width, bool)
    for o in obs:
        seen[o.index] = True
    return _Level(height, width, obs, seen)


def _row_area(height: int, width: int, on: bool) -> np.ndarray:
    lat = (0.5 - (np.arange(height) + 0.5) / height) * np.pi
    a = np.cos(lat) if on else np.ones(height)
    return np.repeat(a, width)


def _assemble(level: _Level, cfg: FusionConfig, sparse: bool):
    """Normal matrix A and the scale-independent part of b, plus per-view data weights. A is a scipy sparse
    matrix when ``sparse`` (direct solves, AMG), else the matrix-free ``StencilNormalOperator`` (the same A)."""
    H, W = level.height, level.width
    N = H * W
    area = _row_area(H, W, cfg.area_weight)
    vp, vq = vertical_pairs(H, W)
    lc = laplacian_centres(H, W)
    wgx, tgx = np.zeros(N), np.zeros(N)
    wgy, tgy = np.zeros(len(vp)), np.zeros(len(vp))
    wl, tl = np.zeros(H * W), np.zeros(H * W)  # indexed by the centre pixel
    data_w = []
    reliable, border = _trust_border_only_regions(level)
    for o in level.obs:
        if len(o.index) == 0:
            data_w.append(np.zeros(0))
            continue
        # work on the band of rows the view touches (plus one row each side): full width keeps the seam wrap
        r0, r1 = max(o.index.min() // W - 1, 0), min(o.index.max() // W + 1, H - 1)
        band = slice(r0 * W, (r1 + 1) * W)
        hb = r1 - r0 + 1
        # dense band arrays: log distance (0 where unused) and confidence (0 where unused; > 0 where used), so an
        # equation's weight, the smallest confidence of its taps, is 0 exactly where a tap is missing
        L, C = np.zeros((hb, W)), np.zeros((hb, W))
        use = ~o.border  # border values enter no difference equation
        L.ravel()[o.index[use] - r0 * W] = o.log_distance[use]
        C.ravel()[o.index[use] - r0 * W] = o.confidence[use]
        Lr, Cr = np.roll(L, -1, axis=1), np.roll(C, -1, axis=1)
        cx = np.minimum(C, Cr)
        _accumulate(wgx[band], tgx[band], Lr - L, cx)
        if hb > 1:
            _accumulate(wgy[r0 * W : r1 * W], tgy[r0 * W : r1 * W], L[1:] - L[:-1], np.minimum(C[1:], C[:-1]))
        if hb > 2:
            # a Laplacian row carries its centre's confidence when all five taps are used
            whole = np.minimum(np.minimum(cx, np.roll(cx, 1, axis=1))[1:-1], np.minimum(C[:-2], C[2:])) > 0
            lv = (Lr + np.roll(L, 1, axis=1) - 4 * L)[1:-1] + L[:-2] + L[2:]
            _accumulate(wl[(r0 + 1) * W : r1 * W], tl[(r0 + 1) * W : r1 * W], lv, np.where(whole, C[1:-1], 0.0))
        data_w.append(cfg.w_data * o.confidence * area[o.index] * np.where(o.border, cfg.border_anchor, 1.0))
    _add_fill(border & ~reliable, level.seen, H, W, wgx, wgy, wl, cfg.border_smooth, cfg.border_laplacian)
    # Laplacian rows exist for interior rows only
    wl, tl = wl[lc], tl[lc]
    area_v = 0.5 * (area[vp] + area[vq])
    diag = np.zeros(N)
    for o, w in zip(level.obs, data_w):
        diag += np.bincount(o.index, w, minlength=N)
    diag[~level.seen] = 1.0  # unseen pixels carry no equation: decouple them (x = 0 there, reported as NaN)
    gx, gy, gl = cfg.w_grad * wgx * area, cfg.w_grad * wgy * area_v, cfg.w_lap * wl * area[lc]
    b0 = transpose_apply(H, W, cfg.w_grad * tgx * area, cfg.w_grad * tgy * area_v, cfg.w_lap * tl * area[lc]).ravel()
    if not sparse:
        return StencilNormalOperator(H, W, gx, gy, gl, diag), b0, data_w
    # A = (R B)^T (R B) for the stacked operator B = [Dx; Dy; Lap; I] and row weights R^2 = (gradient, Laplacian,
    # data) weights: one sparse product on a cached structure
    B, row_of_entry = stacked_operator(H, W)
    w_rows = np.concatenate([gx, gy, gl, diag])
    Bw = sp.csr_matrix((B.data * np.sqrt(w_rows)[row_of_entry], B.indices, B.indptr), shape=B.shape)
    A = (Bw.T @ Bw).tocsr()
    return A, b0, data_w


def _trust_border_only_regions(level: _Level) -> tuple[np.ndarray, np.ndarray]:
    """Border observations in a connected region of seen pixels (4-neighbour, wrapping at the seam) that no
    reliable observation reaches are the only evidence there (a thin ridge or pole against the sky): they are
    made ordinary observations again (``border`` cleared in place). -> (reliable, border-only) [H*W] bool."""
    from scipy import ndimage
    from scipy.sparse.csgraph import connected_components

    H, W, N = level.height, level.width, level.height * level.width
    reliable, border = np.zeros(N, bool), np.zeros(N, bool)
    for o in level.obs:
        reliable[o.index[~o.border]] = True
        border[o.index[o.border]] = True
    if not (border & ~reliable).any():
        return reliable, border & ~reliable
    labels, n = ndimage.label(level.seen.reshape(H, W))
    wrap = (labels[:, 0] > 0) & (labels[:, -1] > 0)  # regions that continue across the seam are one region
    graph = sp.coo_matrix((np.ones(wrap.sum()), (labels[wrap, 0], labels[wrap, -1])), shape=(n + 1, n + 1))
    region = connected_components(graph, directed=False)[1][labels.ravel()]
    supported = np.bincount(region, reliable, minlength=region.max() + 1) > 0
    for o in level.obs:
        o.border &= supported[region[o.index]]
    reliable[border & ~supported[region]] = True
    return reliable, border & ~reliable


def _add_fill(
    fill: np.ndarray, seen: np.ndarray, H: int, W: int, wgx, wgy, wl, membrane: float, laplacian: float
) -> None:
    """Equations with target 0 for the pixels ``fill`` [H*W] that only border observations reach, added in place
    to the summed confidences (which later take the w_grad / w_lap factors): ``laplacian`` on a Laplacian row
    centred on every interior pixel whose stencil touches a fill pixel and lies in ``seen``, ``membrane`` on
    every seen gradient pair with a fill pixel in it."""
    if not fill.any():
        return
    F, S = fill.reshape(H, W), seen.reshape(H, W)
    right = lambda a: np.roll(a, -1, axis=1)  # noqa: E731
    left = lambda a: np.roll(a, 1, axis=1)  # noqa: E731
    wgx += membrane * ((F | right(F)) & S & right(S)).ravel()
    wgy += membrane * ((F[1:] | F[:-1]) & S[1:] & S[:-1]).ravel()
    touch = (F | left(F) | right(F))[1:-1] | F[:-2] | F[2:]
    inside = (S & left(S) & right(S))[1:-1] & S[:-2] & S[2:]
    wl[W : (H - 1) * W] += laplacian * (touch & inside).ravel()


def _accumulate(weight_sum: np.ndarray, target_sum: np.ndarray, value: np.ndarray, conf: np.ndarray) -> None:
    """weight_sum += conf, target_sum += conf * value (in place, flat views; ``value`` is finite, and arbitrary
    where ``conf`` is 0)."""
    weight_sum += conf.ravel()
    target_sum += (conf * value).ravel()


def _data_rhs(level: _Level, data_w, s: np.ndarray) -> np.ndarray:
    N = level.height * level.width
    b = np.zeros(N)
    for o, w, si in zip(level.obs, data_w, s):
        b += np.bincount(o.index, w * (o.log_distance + si), minlength=N)
    return b


def _data_mean(level: _Level, data_w, data_rhs: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """[H*W] the data-weighted mean of each pixel's observations l_i + s_i (the level's own detail, at the current
    per-view log-scales; ``data_rhs`` = ``_data_rhs`` at those scales), ``fallback`` where no view observes the
    pixel: the CG's warm start."""
    wsum = sum(np.bincount(o.index, w, minlength=len(fallback)) for o, w in zip(level.obs, data_w))
    return np.where(wsum > 0, data_rhs / np.maximum(wsum, 1e-300), fallback)


def _update_scales(level: _Level, data_w, x: np.ndarray, metric: bool) -> np.ndarray:
    """Closed-form s_i = weighted mean of (x - l_i) over view i's pixels; gauge mean(s) = 0."""
    V = len(level.obs)
    if metric:
        return np.zeros(V)
    s = np.zeros(V)
    has = np.zeros(V, bool)
    for i, (o, w) in enumerate(zip(level.obs, data_w)):
        if w.sum() > 0:
            s[i] = np.sum(w * (x[o.index] - o.log_distance)) / w.sum()
            has[i] = True
    if has.any():
        s[has] -= s[has].mean()
    return s


def _initial_scales(level: _Level, metric: bool) -> np.ndarray:
    """Per-view log-scales from pairwise overlaps: s_i - s_j = median(l_j - l_i) in least squares, mean(s) = 0."""
    V = len(level.obs)
    if metric or V == 1:
        return np.zeros(V)
    N = level.height * level.width
    dense = [o.dense(N) for o in level.obs]
    rows, rhs = [], []
    for i in range(V):
        for j in range(i + 1, V):
            both = np.isfinite(dense[i]) & np.isfinite(dense[j])
            if both.sum() >= 4:
                rows.append((i, j))
                rhs.append(np.median(dense[j][both] - dense[i][both]))
    M = np.zeros((len(rows) + 1, V))
    for k, (i, j) in enumerate(rows):
        M[k, i], M[k, j] = 1.0, -1.0
    M[-1] = 1.0  # gauge: mean(s) = 0
    s = np.linalg.lstsq(M, np.array(rhs + [0.0]), rcond=None)[0]
    return s


def _preconditioner(A, cfg: FusionConfig):
    if cfg.preconditioner == "amg":
        import pyamg

        ml = pyamg.smoothed_aggregation_solver(
            A, symmetry="symmetric", max_coarse=400, coarse_solver="splu", smooth=None
        )
        return ml.aspreconditioner(cycle="V")
    return sp.diags(1.0 / A.diagonal())


def _solve(A, b, x0, tol: float, maxiter: int, M):
    """Solve A x = b (M: preconditioner, or None for a direct solve); returns (x, iterations, relative residual)."""
    bn = np.linalg.norm(b) or 1.0
    if M is None:
        x = spla.spsolve(A.tocsc(), b)
        return x, 0, float(np.linalg.norm(A @ x - b) / bn)
    its = [0]

    def count(_):
        its[0] += 1

    x, _info = spla.cg(A, b, x0=x0, rtol=tol, atol=0.0, maxiter=maxiter, M=M, callback=count)
    return x, its[0], float(np.linalg.norm(A @ x - b) / bn)


def _solve_mixed(A: StencilNormalOperator, b, x0, tol: float, maxiter: int):
    """``_solve`` with the Jacobi-PCG run on the float32 operator (half the memory traffic per iteration), then
    checked in float64: while the float64 relative residual is above ``tol``, the float32 CG solves for the
    correction (iterative refinement, at most 3 rounds; then float64 CG from there). Same stopping rule as the
    float64 solve: ||A x - b|| <= tol ||b|| in float64. -> (x float64, iterations, relative residual)."""
    bn = np.linalg.norm(b) or 1.0
    A32 = A.astype(np.float32)
    inv_diag = 1.0 / A.diagonal()  # the Jacobi preconditioner of both precisions
    M32 = sp.diags(inv_diag.astype(np.float32))
    x = np.asarray(x0, np.float64).copy()
    r = b - A @ x
    its = 0
    for _ in range(3):
        rn = np.linalg.norm(r)
        if rn <= tol * bn or its >= maxiter:
            return x, its, float(rn / bn)
        # the correction e solves A e = r to the tolerance that brings ||r - A e|| to tol ||b||
        e, k, _ = _solve(
            A32, r.astype(np.float32), np.zeros_like(r, np.float32), min(0.5, tol * bn / rn), maxiter - its, M32
        )
        x += e
        r = b - A @ x
        its += k
    if np.linalg.norm(r) > tol * bn and its < maxiter:
        x, k, _ = _solve(A, b, x, tol, maxiter - its, sp.diags(inv_diag))
        its += k
    return x, its, float(np.linalg.norm(A @ x - b) / bn)


def _solve_torch(A: StencilNormalOperator, b, x0, tol: float, maxiter: int, device):
    """``_solve``'s Jacobi-PCG in torch float64 on ``device`` (same stopping rule as SciPy: ||r|| <= tol ||b||,
    at most ``maxiter`` iterations) -> (x as NumPy, iterations, relative residual)."""
    import torch

    op = TorchStencilOperator(A, device)
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a), dtype=torch.float64, device=device)  # noqa: E731
    b_t, x = t(b), t(x0).clone()
    inv_diag = 1.0 / t(A.diagonal())
    bn = float(torch.linalg.vector_norm(b_t)) or 1.0
    r = b_t - op @ x
    its = 0
    if float(torch.linalg.vector_norm(r)) > tol * bn:
        z = inv_diag * r
        p = z.clone()
        rz = torch.dot(r, z)
        while its < maxiter:
            Ap = op @ p
            alpha = rz / torch.dot(p, Ap)
            x += alpha * p
            r -= alpha * Ap
            its += 1
            if float(torch.linalg.vector_norm(r)) <= tol * bn:  # one scalar read per iteration
                break
            z = inv_diag * r
            rz_new = torch.dot(r, z)
            p = z + (rz_new / rz) * p
            rz = rz_new
    resid = float(torch.linalg.vector_norm(b_t - op @ x)) / bn
    return x.cpu().numpy(), its, resid


def _upsample(x: np.ndarray, seen: np.ndarray, h: int, H: int) -> np.ndarray:
    """Bilinear resampling of a coarse ERP solution onto a finer ERP grid, continuous across seam and poles."""
    grid = x.reshape(h, 2 * h).copy()
    if (~seen).any() and seen.any():
        grid[~seen.reshape(h, 2 * h)] = np.median(x[seen])
    return sample_erp(grid, _erp_rays(H), "linear").ravel()


def fuse_views(
    views: Sequence[ViewDepth],
    height: int,
    width: int,
    config: FusionConfig | None = None,
    guide: np.ndarray | None = None,
) -> FusionResult:
    """Fuse per-view depth maps into one ERP ray-distance map (the §2.4 solve; see the module docstring).

    views: perspective depths at the panorama centre (camera positions are ignored: the panorama's rays
    all start at the origin). With ``resolution='views'`` the pyramid stops at the level the views resolve
    (``view_supported_height``) and the result is brought to height x width by ``upsample.guided_upsample``,
    guided by ``guide`` (the panorama [height, width, 3], uint8 or float in [0, 1]; None: bilinear in log
    distance); ``'full'`` solves every level up to height (the reference). Returns a ``FusionResult`` whose
    ``report`` lists the levels solved and skipped (and why), per-level sizes, CG iterations, relative
    residuals and seconds.
    """
    cfg = config or FusionConfig()
    cfg.check()
    _check_views(views, height, width)
    t0 = time.perf_counter()
    metric = all(v.metric for v in views)
    affine = any(v.affine for v in views)
    if affine:
        dists, view_shift, affine_report = align_affine_views(views, gauge=cfg.affine_gauge)
    else:
        dists, view_shift, affine_report = [v.to_distance() for v in views], np.zeros(len(views)), None
    solver = f"pcg+{cfg.preconditioner}" + (
        f" (torch, {cfg.cg_device})"
        if cfg.cg_device is not None
        else " (float32 products, float64 refinement)"
        if cfg.preconditioner == "jacobi" and cfg.cg_precision == "mixed"
        else ""
    )
    report = {
        "solver": f"{solver}, coarse-to-fine",
        "levels": [],
        "affine_alignment": affine_report,
        "connectivity": check_connectivity(views),
    }
    if guide is not None and guide.shape[:2] != (height, width):
        raise ValueError(f"fuse_views: guide {guide.shape}: expected the panorama's size {height}x{width}")
    heights = pyramid_heights(height, cfg.levels)
    if cfg.resolution == "views":
        top, why = view_supported_height(views, heights)
        report["resolution"] = {
            **why,
            "solved": [h for h in heights if h <= top],
            "skipped": heights[heights.index(top) + 1 :],
        }
        heights = heights[: heights.index(top) + 1]
    else:
        report["resolution"] = {"solved": heights, "skipped": [], "reason": "resolution='full': every level"}
    x = None
    s = None
    prev_h = None
    prev_seen = None
    for li, h in enumerate(heights):
        tl = time.perf_counter()
        level = _observe(views, dists, h, cfg.border_px, cfg, h == heights[-1])
        direct = li == 0 and h * 2 * h <= 40_000
        A, b0, data_w = _assemble(level, cfg, sparse=direct or cfg.preconditioner == "amg")
        if s is None:
            s = _initial_scales(level, metric)
        coarse = np.zeros(h * 2 * h) if x is None else _upsample(x, prev_seen, prev_h, h)
        data_rhs = _data_rhs(level, data_w, s)  # at the current scales: the first solve's and the warm start's
        x = coarse if x is not None and cfg.warm_start == "coarse" else _data_mean(level, data_w, data_rhs, coarse)
        its_total, resid = 0, float("nan")
        torch_cg = cfg.cg_device is not None and not direct
        mixed = not (direct or torch_cg) and cfg.preconditioner == "jacobi" and cfg.cg_precision == "mixed"
        M = None if direct or torch_cg or mixed else _preconditioner(A, cfg)
        tol = cfg.tol if h == heights[-1] else max(cfg.tol, cfg.coarse_tol)
        for _ in range(max(1, cfg.scale_iters) if (h <= cfg.scale_max_height or li == 0) else 1):
            rhs = b0 + data_rhs
            if torch_cg:
                x, its, resid = _solve_torch(A, rhs, x, tol, cfg.maxiter, cfg.cg_device)
            elif mixed:
                x, its, resid = _solve_mixed(A, rhs, x, tol, cfg.maxiter)
            else:
                x, its, resid = _solve(A, rhs, x, tol, cfg.maxiter, M)
            its_total += its
            if h > cfg.scale_max_height and li > 0:
                break
            s_new = _update_scales(level, data_w, x, metric)
            converged = np.abs(s_new - s).max() < 1e-4
            s = s_new
            if converged:
                break
            data_rhs = _data_rhs(level, data_w, s)
        report["levels"].append(
            {
                "height": h,
                "width": 2 * h,
                "unknowns": h * 2 * h,
                "iterations": its_total,
                "residual": resid,
                "seconds": time.perf_counter() - tl,
                "direct": direct,
            }
        )
        prev_h, prev_seen = h, level.seen
    h = heights[-1]
    seen = prev_seen.reshape(h, 2 * h)
    xs = x.reshape(h, 2 * h)
    if not np.isfinite(xs[seen]).all():
        raise ValueError(
            "fuse_views: the solve produced non-finite log-distances; check the weights and the teacher's depth range"
        )
    if h == height:
        distance = np.full((height, width), np.nan, np.float32)
        with np.errstate(over="ignore"):
            distance[seen] = np.exp(xs[seen]).astype(np.float32)
    else:
        tu = time.perf_counter()
        with np.errstate(over="ignore"):
            distance = guided_upsample(
                np.where(seen, xs, np.nan), guide, height, width, cfg.upsample_radius, cfg.upsample_eps, cfg.edge_jump
            )
        seen = np.isfinite(distance) | np.isinf(distance)
        report["upsample"] = {
            "from": [2 * h, h],
            "to": [width, height],
            "method": "guided filter (panorama colour)" if guide is not None else "bilinear in log distance (no guide)",
            "radius": cfg.upsample_radius,
            "eps": cfg.upsample_eps,
            "seconds": time.perf_counter() - tu,
        }
    if not np.isfinite(distance[seen]).all():
        raise ValueError(
            "fuse_views: fused distances overflow float32 (log-distance beyond 88); check the teacher's depth range"
        )
    report.update(
        iterations=[lv["iterations"] for lv in report["levels"]],
        residual=report["levels"][-1]["residual"],
        seconds=time.perf_counter() - t0,
        views=len(views),
        metric=metric,
        affine=affine,
    )
    return FusionResult(distance, seen, np.exp(s), view_shift, report)
