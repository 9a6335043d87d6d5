"""Stress scenes: small synthetic panoramas with their true ray distance, built for the cases that break a
depth fusion or a trainer, and a scene's copy at another scale.

- ``cliff(ratio)``: the front half of the panorama (|longitude| < 90 degrees) is the inside of a cube of
  half-size ``near_m`` around the centre, the back half the same cube ``ratio`` times larger: two vertical depth
  edges, pole to pole, across which the distance jumps by ``ratio`` (10 to 1e4: a wall at arm's length beside
  a view kilometres deep).
- ``seam_jump(ratio)``: distance rising linearly with longitude from ``near_m`` at the left edge of the ERP to
  ``ratio`` times that at the right edge: one depth edge, along the seam (the left/right wrap every ERP operator
  must cut like any other edge), pole to pole, where it meets every distance of the slope.
- ``ramp(decades)``: the inside of a cube of half-size ``near_m`` whose distance is multiplied by
  10^(decades * t(latitude)), t rising smoothly (cosine) from 0 at ``band_deg`` below the horizon to 1 at
  ``band_deg`` above: no edge at all, a log-distance slope of ``decades * ln 10`` over 2 ``band_deg`` (a ground
  plane seen to the horizon).
- ``scaled(scene, factor)``: the same panorama with every true distance times ``factor`` (a 5 m room as 5 mm).

Colour: a lon/lat checker (16 x 8 cells) in a hue of its own on each side of every depth edge, so the
panorama's colour edges are where its depth edges are, as in a photograph. No sky, no world: the scenes carry
their truth as a real panorama with ``--depth`` does (the simulated teachers sample it, ``true_view_distance``),
and are built in milliseconds without Open3D. ``CASES`` names the cases the tests and the stress benchmark share.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..geometry import erp_directions
from .base import Scene


def _cube_distance(height: int, width: int, half: float) -> np.ndarray:
    """Ray distance [H, W] float64 from the centre of a cube of half-size ``half`` to its faces."""
    d = erp_directions(height, width)
    return half / np.abs(d).max(-1)


def _checker_rgb(height: int, width: int, side: np.ndarray) -> np.ndarray:
    """[H, W, 3] uint8: a 16 x 8 lon/lat checker, a warm hue where ``side`` [H, W] is 0, a cool one where 1."""
    r, c = np.mgrid[0:height, 0:width]
    cell = ((r * 8 // height) + (c * 16 // width)) % 2
    warm, cool = np.array([200, 120, 60]), np.array([60, 130, 210])
    base = np.where(side[..., None] > 0.5, cool, warm) * (0.6 + 0.4 * cell[..., None])
    return np.clip(base, 0, 255).astype(np.uint8)


def _scene(name: str, description: str, rgb: np.ndarray, distance: np.ndarray, meta: dict) -> Scene:
    return Scene(
        name=name,
        kind="synthetic",
        description=description,
        rgb=rgb,
        distance=distance.astype(np.float32),
        sky=np.zeros(distance.shape, bool),
        distance_kind="truth",
        meta={"stress": meta},
    )


def cliff(ratio: float, width: int = 512, near_m: float = 1.0) -> Scene:
    """The near/far cliff (module docstring): ERP ``width`` x ``width // 2``; distances ``near_m`` to
    ``near_m * sqrt(3)`` in front, ``ratio`` times that behind."""
    if not (np.isfinite(ratio) and ratio >= 1 and np.isfinite(near_m) and near_m > 0):
        raise ValueError(f"cliff: ratio={ratio!r}, near_m={near_m!r}: expected ratio >= 1 and near_m > 0")
    height = width // 2
    lon = (np.arange(width) + 0.5) / width * 2 * np.pi - np.pi
    back = np.broadcast_to(np.abs(lon) >= np.pi / 2, (height, width))
    distance = _cube_distance(height, width, near_m) * np.where(back, ratio, 1.0)
    return _scene(
        f"cliff-{ratio:g}",
        f"near/far cliff: a cube of {near_m:g} m in front, {ratio:g} times farther behind",
        _checker_rgb(height, width, back),
        distance,
        {"case": "cliff", "ratio": float(ratio), "near_m": near_m},
    )


def seam_jump(ratio: float = 10.0, width: int = 512, near_m: float = 1.0) -> Scene:
    """The seam jump (module docstring): ERP ``width`` x ``width // 2``, distance ``near_m * (1 + (ratio - 1) *
    (lon + pi) / (2 pi))`` at each pixel centre's longitude, a jump of about ``ratio`` across the seam; one hue,
    whose checker changes cell at the seam (cells 15 and 0), so the colour has its edge there too."""
    if not (np.isfinite(ratio) and ratio >= 1 and np.isfinite(near_m) and near_m > 0):
        raise ValueError(f"seam_jump: ratio={ratio!r}, near_m={near_m!r}: expected ratio >= 1 and near_m > 0")
    height = width // 2
    u = (np.arange(width) + 0.5) / width  # (lon + pi) / (2 pi) at the pixel centres
    distance = np.broadcast_to(near_m * (1.0 + (ratio - 1.0) * u), (height, width))
    return _scene(
        f"seam-jump-{ratio:g}",
        f"seam jump: {near_m:g} m at the left edge rising with longitude to {ratio:g} times that at the right",
        _checker_rgb(height, width, np.zeros((height, width))),
        distance,
        {"case": "seam-jump", "ratio": float(ratio), "near_m": near_m},
    )


def ramp(decades: float, width: int = 512, near_m: float = 1.0, band_deg: float = 5.0) -> Scene:
    """The multi-decade ramp (module docstring): distance ``near_m`` (cube) below the band, ``10**decades``
    times that above it, rising smoothly over the ``band_deg`` either side of the horizon."""
    if not (np.isfinite(decades) and decades >= 0 and near_m > 0 and 0 < band_deg < 90):
        raise ValueError(f"ramp: decades={decades!r}, near_m={near_m!r}, band_deg={band_deg!r}: out of range")
    height = width // 2
    lat = 90.0 - (np.arange(height) + 0.5) / height * 180.0
    t = 0.5 - 0.5 * np.cos(np.pi * np.clip((lat + band_deg) / (2 * band_deg), 0.0, 1.0))
    distance = _cube_distance(height, width, near_m) * 10.0 ** (decades * t)[:, None]
    return _scene(
        f"ramp-{decades:g}",
        f"multi-decade ramp: distance x 10^{decades:g} over +-{band_deg:g} degrees around the horizon",
        _checker_rgb(height, width, np.broadcast_to((lat > 0)[:, None], (height, width))),
        distance,
        {"case": "ramp", "decades": float(decades), "near_m": near_m, "band_deg": band_deg},
    )


def horizon(decades: float, width: int = 512, height_m: float = 1.0) -> Scene:
    """A ground plane ``height_m`` below the centre, seen to the horizon: distance ``height_m / sin(-latitude)``
    below it, capped at ``height_m * 10**decades``, the cap's dome above it (the module docstring's ramp as a
    real ground plane: the last rows before the horizon multiply the distance by 2-3 per row, then the dome)."""
    if not (np.isfinite(decades) and decades >= 0 and np.isfinite(height_m) and height_m > 0):
        raise ValueError(f"horizon: decades={decades!r}, height_m={height_m!r}: out of range")
    height = width // 2
    lat = (0.5 - (np.arange(height) + 0.5) / height) * np.pi
    far = height_m * 10.0**decades
    with np.errstate(divide="ignore"):
        ground = np.where(lat < 0, height_m / np.sin(np.minimum(-lat, np.pi / 2)), np.inf)
    row = np.minimum(ground, far)
    distance = np.broadcast_to(row[:, None], (height, width))
    return _scene(
        f"horizon-{decades:g}",
        f"ground plane {height_m:g} m below, seen to the horizon, capped at 10^{decades:g} times that",
        _checker_rgb(height, width, np.broadcast_to((lat > 0)[:, None], (height, width))),
        distance,
        {"case": "horizon", "decades": float(decades), "height_m": height_m},
    )


def scaled(scene: Scene, factor: float) -> Scene:
    """``scene`` with its true distance times ``factor`` (colour, sky, masks and name unchanged, so a simulated
    teacher draws the same errors; no world: a world renders at its own scale). ``meta["scaled"]`` says the
    factor."""
    if not (np.isfinite(factor) and factor > 0):
        raise ValueError(f"scaled: factor={factor!r}: expected a finite factor > 0")
    if scene.distance is None:
        raise ValueError(f"scaled: scene {scene.name!r} has no distance to scale")
    distance = (scene.distance.astype(np.float64) * factor).astype(np.float32)
    return dataclasses.replace(scene, distance=distance, world=None, meta={**scene.meta, "scaled": factor})


# the named cases shared by the tests and the stress benchmark: name -> builder(width) -> Scene
CASES = {
    "cliff-10": lambda width=512: cliff(10.0, width),
    "cliff-1e2": lambda width=512: cliff(1e2, width),
    "cliff-1e3": lambda width=512: cliff(1e3, width),
    "cliff-1e4": lambda width=512: cliff(1e4, width),
    "seam-jump": lambda width=512: seam_jump(10.0, width),
    "ramp-4": lambda width=512: ramp(4.0, width, band_deg=3.0),
    "ramp-6": lambda width=512: ramp(6.0, width),
    "horizon-4": lambda width=512: horizon(4.0, width),
}
