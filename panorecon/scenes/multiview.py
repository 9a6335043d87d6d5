"""Several panoramas of one synthetic scene from positions inside its free space (multi-view baselines)."""

from __future__ import annotations

import numpy as np

from ..io import PanoreconInputError
from .base import Scene

POSITION_LAYOUTS = ("ring", "random")


def panorama_positions(radius: float, k: int, layout: str = "ring", seed: int = 0) -> np.ndarray:
    """K camera centres [k, 3] (metres) within ``radius`` of the origin.

    ring: evenly spaced on the horizontal circle of ``radius`` (the first on +x);
    random: uniform in the ball of ``radius`` (seeded).
    """
    if k < 1:
        raise PanoreconInputError(f"k={k}: expected at least one panorama position")
    if layout == "ring":
        a = 2 * np.pi * np.arange(k) / k
        return radius * np.stack([np.cos(a), np.sin(a), np.zeros(k)], 1)
    if layout == "random":
        rng = np.random.default_rng(seed)
        d = rng.normal(size=(k, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        return d * (radius * rng.random(k) ** (1 / 3))[:, None]
    raise PanoreconInputError(f"layout {layout!r}: expected one of {', '.join(POSITION_LAYOUTS)}")


def require_world(scene: Scene) -> None:
    """PanoreconInputError ('n/a: ...') unless the scene has a world to render panoramas at new positions."""
    if scene.world is None:
        raise PanoreconInputError(
            f"n/a: scene {scene.name!r} has no world to render new positions from (synthetic scenes only)"
        )


def render_positions(
    scene: Scene, k: int, layout: str = "ring", radius_fraction: float = 0.3, seed: int = 0
) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Render K ERP panoramas of a synthetic scene at its own size from positions in its free space.

    The positions lie within ``radius_fraction`` x ``scene.world.free_space_radius()`` of the panorama
    centre (see ``panorama_positions``). Returns a list of (position [3] float64 metres, rgb [H, W, 3]
    uint8, ray distance [H, W] float32 metres with inf for sky).
    """
    require_world(scene)
    if not 0.0 <= radius_fraction <= 1.0:
        raise PanoreconInputError(f"radius_fraction={radius_fraction}: expected a value in [0, 1]")
    radius = radius_fraction * scene.world.free_space_radius()
    out = []
    for p in panorama_positions(radius, k, layout, seed):
        erp = scene.world.render_erp(scene.height, p)
        out.append((p, erp.rgb, erp.distance))
    return out
