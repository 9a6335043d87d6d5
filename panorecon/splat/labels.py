"""Dense perspective pseudo-labels from a panorama (paper §2.3) and held-out true views: renders of a synthetic
scene's world, or the other real panoramas of the same space (dataset scenes with poses).

Pseudo-labels: views at the panorama centre looking along a dense layout (Fibonacci by default; Table 5
uses 120-360), their RGB resampled from the ERP and their depth from a teacher. Held-out views: true
renders from positions away from the centre (inside the scene's free space), never trained on.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..geometry import (
    PinholeCamera,
    centred_camera,
    erp_to_perspective,
    intrinsics_from_fov,
    look_at_rotation,
    make_layout,
    sample_erp,
    viewmat_from_pose,
)


@dataclass
class LabelView:
    """camera; rgb [h, w, 3] float32 in [0, 1]; depth [h, w] float32 z-depth (metres or the teacher's units,
    NaN unknown) or None; mask [h, w] bool: the pixels a score may use (None: all); background [h, w, 3] float32
    in [0, 1] composited behind the Gaussians (the sky environment, see splat/initial.py) or None; covisible
    [h, w] bool or None: for a held-out view, the pixels whose true 3D point the training panorama also sees
    (``reprojection_oracle``; a real panorama's ``mask`` itself); oracle [h, w, 3] float32 in [0, 1], NaN
    outside ``covisible``, or None: the training panorama's colour at each co-visible pixel's true 3D point (the
    best any reconstruction from that panorama can show there, its capture's exposure included)."""

    camera: PinholeCamera
    rgb: np.ndarray
    depth: np.ndarray | None = None
    mask: np.ndarray | None = None
    background: np.ndarray | None = None
    covisible: np.ndarray | None = None
    oracle: np.ndarray | None = None


def make_pseudo_labels(
    scene,
    n_views: int,
    size: int,
    fov_deg: float = 60.0,
    layout: str = "fibonacci",
    depth_fn: Callable[[Sequence[PinholeCamera]], Sequence[np.ndarray]] | None = None,
) -> list[LabelView]:
    """``n_views`` perspective labels of ``size``² pixels at the panorama centre; ``depth_fn(cameras)`` returns
    one z-depth map per camera (or None to train on colour alone)."""
    if n_views < 1 or size < 8:
        raise ValueError(f"make_pseudo_labels: n_views={n_views}, size={size}: expected n_views >= 1 and size >= 8")
    dirs = make_layout(layout, n_views if layout in ("fibonacci", "latlong") else None).directions
    cams = [centred_camera(d, size, fov_deg) for d in dirs]
    depths = list(depth_fn(cams)) if depth_fn is not None else [None] * len(cams)
    if len(depths) != len(cams):
        raise ValueError(f"depth_fn returned {len(depths)} maps for {len(cams)} cameras")
    return [
        LabelView(
            c,
            erp_to_perspective(scene.rgb, c).astype(np.float32) / 255.0,
            None if d is None else np.asarray(d, np.float32),
        )
        for c, d in zip(cams, depths)
    ]


# A pixel's true 3D point X counts as seen by the training panorama when |X| (its distance from the panorama
# centre) is within this fraction of the panorama's true distance along X's direction.
COVISIBLE_REL_TOL = 0.05
# A held-out view is scored on its co-visible pixels only when it has at least this many
# (a PSNR over fewer is noise: the relative error of a mean squared error over n pixels is about sqrt(2 / n),
# 0.09 = 0.4 dB at 256); with no such view the held-out score reads n/a (``covisible_shortfall``).
MIN_COVISIBLE_PIXELS = 256


def reprojection_oracle(
    scene, origin: np.ndarray, rays: np.ndarray, distance: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """What the training panorama shows of the points a held-out camera sees: the camera at ``origin`` [3]
    (metres, the scene's frame: the panorama centre at 0) sees along unit ``rays`` [h, w, 3] the true points at
    ray distance ``distance`` [h, w] (metres; ``inf`` for sky, NaN unknown).

    Returns (covisible [h, w] bool, oracle [h, w, 3] float32 in [0, 1], NaN outside ``covisible``). A finite
    point X is co-visible when the scene's true distance (``scene.distance``, nearest ERP sample) along X / |X|
    is within COVISIBLE_REL_TOL x |X| of |X| (otherwise something nearer the centre hides it, or the panorama
    does not know it); a point at infinity (sky) when the panorama also sees infinity along the same ray. The
    oracle is the panorama's colour (``scene.rgb``, bilinear) along that direction from its centre."""
    rays = np.asarray(rays, np.float64)
    d = np.asarray(distance, np.float64)
    with np.errstate(invalid="ignore"):
        x = np.asarray(origin, np.float64) + rays * d[..., None]
    far = np.isposinf(d)
    r = np.where(far, np.inf, np.linalg.norm(np.where(far[..., None], 0.0, x), axis=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        direction = np.where(far[..., None], rays, x / r[..., None])
    ok = np.isfinite(direction).all(-1) & (r > 0)
    seen = np.full(d.shape, np.nan)
    seen[ok] = sample_erp(scene.distance.astype(np.float32), direction[ok], "nearest")
    with np.errstate(invalid="ignore"):
        near = np.isfinite(d) & np.isfinite(seen) & (np.abs(seen - r) <= COVISIBLE_REL_TOL * r)
    covisible = ok & (near | (far & np.isposinf(seen)))
    oracle = np.full((*d.shape, 3), np.nan, np.float32)
    oracle[covisible] = sample_erp(scene.rgb, direction[covisible], "linear").astype(np.float32) / 255.0
    return covisible, oracle


def make_heldout_views(
    scene, n_views: int, size: int, fov_deg: float = 60.0, seed: int = 0, radius: tuple[float, float] = (0.3, 0.7)
) -> list[LabelView]:
    """True renders from random positions at ``radius`` (fractions, default 30-70 %) of the free-space radius from
    the panorama centre, looking in random directions within 30 degrees of the horizon, with their true z-depth;
    on a scene with a true distance, their co-visible pixels and reprojection oracle too (``reprojection_oracle``).
    The same seed draws the same directions whatever ``radius`` is."""
    if scene.world is None:
        raise ValueError(f"scene {scene.name!r} has no ground-truth world: held-out views need a synthetic scene")
    lo, hi = radius
    if not 0 <= lo <= hi <= 1:
        raise ValueError(f"make_heldout_views: radius {radius!r}: expected fractions 0 <= lo <= hi <= 1")
    rng = np.random.default_rng(seed)
    free = scene.world.free_space_radius()
    K = intrinsics_from_fov(size, size, fov_deg)
    views = []
    for _ in range(n_views):
        p = rng.normal(size=3)
        p *= rng.uniform(lo, hi) * free / np.linalg.norm(p)
        az, el = rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi / 6, np.pi / 6)
        forward = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cam = PinholeCamera(K, viewmat_from_pose(look_at_rotation(forward), p), size, size)
        r = scene.world.render_view(cam)
        covisible, oracle = (None, None) if scene.distance is None else _true_oracle(scene, cam, r)
        views.append(
            LabelView(
                cam,
                r.rgb.astype(np.float32) / 255.0,
                np.where(r.sky, np.nan, r.depth_z).astype(np.float32),
                covisible=covisible,
                oracle=oracle,
            )
        )
    return views


def _true_oracle(scene, cam: PinholeCamera, render) -> tuple[np.ndarray, np.ndarray]:
    """``reprojection_oracle`` of a true render (``World.render_view``) of ``cam``: its ray distance, inf for sky."""
    return reprojection_oracle(scene, cam.position, cam.world_rays(), np.where(render.sky, np.inf, render.distance))


def in_cloud_frame(view: LabelView, scale: float) -> LabelView:
    """A held-out view moved into a cloud that is the truth divided by ``scale``: the camera at position / scale
    (same rotation and intrinsics) sees that cloud exactly as the true camera sees the truth; z-depth / scale."""
    if scale == 1.0:
        return view
    viewmat = view.camera.viewmat.copy()
    viewmat[:3, 3] /= scale
    cam = dataclasses.replace(view.camera, viewmat=viewmat)
    depth = None if view.depth is None else (view.depth / scale).astype(np.float32)
    return dataclasses.replace(view, camera=cam, depth=depth)


def make_panorama_heldout_views(
    scene, panoramas, n_views: int, size: int, fov_deg: float = 60.0, seed: int = 0
) -> list[LabelView]:
    """Held-out views on a real scene from its other panoramas (true images taken elsewhere in the same space).

    ``panoramas``: [(offset [3] metres of that panorama's centre in the scene's frame, rotation [3, 3] taking a
    scene-frame direction to that panorama's own frame, rgb [H, W, 3] uint8, ray distance [H, W] float32 metres,
    NaN unknown)] (``scenes.datasets.heldout_panoramas``). View i stands at panorama i mod K looking in a random
    direction within 30 degrees of the horizon (scene frame); its rgb and z-depth are sampled from that panorama
    along the rotated rays. Its mask (and ``covisible``) keeps the pixels the training panorama sees too, and
    its oracle is the training panorama's colour there (``reprojection_oracle`` of the true 3D points X from the
    held-out panorama's depth; a pixel without a finite depth is never co-visible). The scene needs a true
    distance."""
    if scene.distance is None or not panoramas:
        raise ValueError(f"scene {scene.name!r}: held-out panoramas need the scene's true depth and other panoramas")
    rng = np.random.default_rng(seed)
    K = intrinsics_from_fov(size, size, fov_deg)
    views = []
    for i in range(n_views):
        offset, rotation, rgb, dist = panoramas[i % len(panoramas)]
        az, el = rng.uniform(-np.pi, np.pi), rng.uniform(-np.pi / 6, np.pi / 6)
        forward = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        cam = PinholeCamera(K, viewmat_from_pose(look_at_rotation(forward), np.asarray(offset, float)), size, size)
        rays = cam.world_rays()
        local = rays @ np.asarray(rotation, np.float64).T  # the same rays in that panorama's frame
        d = sample_erp(dist.astype(np.float32), local, "nearest").astype(np.float64)
        d[~np.isfinite(d)] = np.nan  # a real panorama's depth never says "sky": unknown, never co-visible
        mask, oracle = reprojection_oracle(scene, offset, rays, d)
        img = sample_erp(rgb, local, "linear").astype(np.float32) / 255.0
        z = np.where(mask, d / cam.z_to_distance_factor(), np.nan).astype(np.float32)
        views.append(LabelView(cam, img, z, mask, covisible=mask, oracle=oracle))
    return views


def covisible_shortfall(views: Sequence[LabelView]) -> str | None:
    """For masked held-out views (other panoramas): 'n/a: <reason>' when no view has MIN_COVISIBLE_PIXELS
    co-visible pixels (nothing to score on), else None. Unmasked views (true renders) always score."""
    if not views or all(v.mask is None for v in views):
        return None
    counts = [int(v.mask.sum()) for v in views if v.mask is not None]
    if max(counts) >= MIN_COVISIBLE_PIXELS:
        return None
    return (
        f"n/a: no held-out view has {MIN_COVISIBLE_PIXELS} co-visible pixels (most: {max(counts)} of "
        f"{views[0].mask.size}; the other panoramas see little of what the training panorama sees)"
    )
