"""Simulated teachers: the true depth of each view through a declared error profile.

They stand in for real monocular models on scenes whose truth is known and are always named ``sim:...``,
never as the model they imitate. Each error is deterministic from (profile, scene, view index, seed).

| profile | output | unknowns per view | smooth warp | edge blur | noise | dropped / NaN |
|---|---|---|---|---|---|---|
| `sim:clean` | z-depth | scale in [0.5, 2] | none | none | 0.5 % | none |
| `sim:relative` | z-depth | scale in [0.5, 2] | ±8 % (log amplitude 0.08) | σ = 1.5 px | 2 % | 1 % dropped |
| `sim:affine-disparity` | disparity | scale [0.5, 2], shift ±10 % of median | ±10 % | σ = 2 px | 3 % | 3 %; 1 % NaN |
| `sim:network` | disparity | scale [0.5, 2], shift ±10 % of median | ±10 % | σ = 2 px | 3 % | 3 %; 1 % NaN |

``sim:network`` adds errors that follow the view's content and framing, as a network's do
(docs/benchmarks.md, "Learned depth teachers"), with ``affine-disparity``'s output and noise: in log z-depth,
(1) the depth range compressed towards the view's median, ln z <- m + gamma (ln z - m), m the median over the
view, so that one surface reads another depth in another crop; (2) the image copied into the depth,
+ kappa * (L - mean L) / std L, L the view's luminance blurred by 2 px (texture read as relief); (3) a bend with the
framing, + rho * ((u^2 + v^2) - mean), u, v in [-1, 1] across the view (the same wall deeper at a crop's border than
at its centre). gamma, kappa and rho are calibrated on the learned teacher learned-w16
(``eval/calibrate_sim_network.py``). On the whole ERP (``predict_erp``) there is no framing: (2) and (1) only.

"Relative" outputs are known up to scale; "affine" outputs up to scale and shift (as MiDaS-style models).
The smooth warp multiplies depth by exp(a * w(u, v)), w a sum of four random low-frequency cosines with
unit peak; the edge blur is a Gaussian blur of the depth map that mixes foreground and background
across depth edges; noise is multiplicative and Gaussian. Sky pixels are never valid.
"""

from __future__ import annotations

import dataclasses
import zlib
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from ..geometry import PinholeCamera, ViewDepth, erp_to_perspective
from ..io import PanoreconInputError
from .base import ErpDepth, true_view_distance


@dataclass(frozen=True)
class SimProfile:
    name: str
    description: str
    output: str  # "z" | "disparity"
    affine: bool = False
    scale_range: tuple[float, float] = (0.5, 2.0)
    shift_frac: float = 0.0
    warp: float = 0.0
    edge_blur_px: float = 0.0
    noise: float = 0.0
    drop: float = 0.0
    nan: float = 0.0
    compress: float = 1.0  # gamma: ln z -> m + gamma (ln z - m), m the view's median ln z (1: none)
    texture: float = 0.0  # kappa: ln z += kappa x the view's blurred luminance, standardised
    bend: float = 0.0  # rho: ln z += rho x (u^2 + v^2 - its mean), u, v in [-1, 1] across the view

    @property
    def reads_image(self) -> bool:
        return self.compress != 1.0 or self.texture != 0.0 or self.bend != 0.0


# sim:network's (gamma, kappa, rho): eval/calibrate_sim_network.py's choice, closest to learned-w16's seen-family
# per-view AbsRel, cross-view disagreement and centre-vs-border disagreement (docs/benchmarks.md)
NETWORK = (0.95, 0.15, 0.05)

ARG = "<profile>"  # the spec's argument (teachers/spec.py)
OPTIONS: dict = {}  # a profile takes no options

PROFILES = {
    p.name: p
    for p in [
        SimProfile("clean", "relative z-depth: unknown scale, 0.5 % noise", "z", noise=0.005),
        SimProfile(
            "relative",
            "relative z-depth: scale, smooth ±8 % warp, edge blur 1.5 px, 2 % noise, 1 % dropped",
            "z",
            warp=0.08,
            edge_blur_px=1.5,
            noise=0.02,
            drop=0.01,
        ),
        SimProfile(
            "affine-disparity",
            "affine-invariant disparity: scale and shift, ±10 % warp, edge blur 2 px, 3 % noise, 3 % dropped, 1 % NaN",
            "disparity",
            affine=True,
            shift_frac=0.1,
            warp=0.1,
            edge_blur_px=2.0,
            noise=0.03,
            drop=0.03,
            nan=0.01,
        ),
    ]
}
PROFILES["network"] = dataclasses.replace(
    PROFILES["affine-disparity"],
    name="network",
    description="affine-invariant disparity with a network's errors: affine-disparity's, plus depth range compressed "
    f"to the view's median (gamma {NETWORK[0]}), luminance copied into depth (kappa {NETWORK[1]}), a bend with the "
    f"framing (rho {NETWORK[2]}); calibrated on learned-w16",
    compress=NETWORK[0],
    texture=NETWORK[1],
    bend=NETWORK[2],
)


def _smooth_field(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Sum of four random low-frequency cosines over the image, peak magnitude 1, [h, w]."""
    v, u = np.meshgrid(np.linspace(0, 1, h), np.linspace(0, 1, w), indexing="ij")
    f = np.zeros((h, w))
    for _ in range(4):
        fu, fv = rng.uniform(-1.5, 1.5, 2)
        f += rng.uniform(0.5, 1.0) * np.cos(2 * np.pi * (fu * u + fv * v) + rng.uniform(0, 2 * np.pi))
    return f / max(np.abs(f).max(), 1e-12)


def _content_and_framing(log_z: np.ndarray, valid: np.ndarray, rgb, p: SimProfile, framed: bool) -> np.ndarray:
    """sim:network's errors in log depth [h, w] (module docstring): compression to the view's median, luminance
    copied in, the framing's bend."""
    m = np.median(log_z[valid])
    out = m + p.compress * (log_z - m)
    if p.texture:
        if rgb is None:
            raise ValueError(f"sim:{p.name} reads the view's image: expected rgb")
        img = np.asarray(rgb, np.float64)
        img = img / 255.0 if np.asarray(rgb).dtype == np.uint8 else img
        lum = cv2.GaussianBlur(img @ np.array([0.299, 0.587, 0.114]), (0, 0), 2.0)
        sd = lum[valid].std()
        if sd > 1e-6:  # a flat image copies nothing
            out = out + p.texture * (lum - lum[valid].mean()) / sd
    if p.bend and framed:
        h, w = log_z.shape
        v, u = np.meshgrid(np.linspace(-1, 1, h), np.linspace(-1, 1, w), indexing="ij")
        r2 = u**2 + v**2
        out = out + p.bend * (r2 - r2.mean())
    return out


class SimTeacher:
    def __init__(self, profile: SimProfile, seed: int = 0):
        self.profile = profile
        self.seed = seed
        self.name = f"sim:{profile.name}"

    def _rng(self, scene_name: str, index: int) -> np.random.Generator:
        return np.random.default_rng([self.seed, index, zlib.crc32(f"{self.name}/{scene_name}".encode())])

    def _corrupt(
        self,
        z: np.ndarray,
        sky: np.ndarray,
        rng: np.random.Generator,
        rgb: np.ndarray | None = None,
        framed: bool = True,
    ):
        """z: true depth [h, w] (inf on sky); rgb: the view's image [h, w, 3] (float in [0, 1] or uint8; for a
        profile that reads it); framed: a perspective view (the bend applies) -> (output in the profile's kind,
        valid). Float64 inside."""
        p = self.profile
        valid = ~sky & np.isfinite(z) & (z > 0)
        zf = np.where(valid, z, np.nan).astype(np.float64)
        if not valid.any():
            return np.full(z.shape, np.nan, np.float32), valid
        fill = np.nanmax(zf)
        zf = np.where(valid, zf, fill)  # sky as far background for the blur
        if p.reads_image:
            zf = np.exp(_content_and_framing(np.log(zf), valid, rgb, p, framed))
        if p.warp:
            zf = zf * np.exp(p.warp * _smooth_field(*z.shape, rng))
        if p.edge_blur_px:
            zf = cv2.GaussianBlur(zf, (0, 0), p.edge_blur_px)
        if p.noise:
            zf = zf * (1 + p.noise * rng.standard_normal(z.shape))
        out = 1.0 / np.maximum(zf, 1e-12) if p.output == "disparity" else zf
        out = out * rng.uniform(*p.scale_range)
        if p.affine:
            out = out + p.shift_frac * rng.uniform(-1, 1) * np.median(out[valid])
        if p.drop:
            valid &= rng.random(z.shape) >= p.drop
        out = out.astype(np.float32)
        if p.nan:
            out[rng.random(z.shape) < p.nan] = np.nan
        valid &= np.isfinite(out)
        out[~valid] = np.nan
        return out, valid

    def predict_views(self, scene, cameras: Sequence[PinholeCamera]) -> list[ViewDepth]:
        views = []
        for i, cam in enumerate(cameras):
            dist, sky = true_view_distance(scene, cam)
            z = dist / cam.z_to_distance_factor()
            rgb = erp_to_perspective(scene.rgb, cam) if self.profile.reads_image else None
            out, valid = self._corrupt(z, sky, self._rng(scene.name, i), rgb)
            views.append(ViewDepth(cam, out, self.profile.output, valid, affine=self.profile.affine))
        return views

    def predict_erp(self, scene) -> ErpDepth:
        if scene.distance is None or scene.distance_kind != "truth":
            raise PanoreconInputError(
                f"scene {scene.name!r} has no true depth; simulated teachers need a synthetic "
                "scene or a real one with --depth"
            )
        out, valid = self._corrupt(scene.distance, scene.sky, self._rng(scene.name, 1_000_000), scene.rgb, framed=False)
        kind = "disparity" if self.profile.output == "disparity" else "distance"
        return ErpDepth(out, kind, valid, affine=self.profile.affine)
