"""Scene registry: every scene by name, synthetic and real, plus any ERP image given by path."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ..io import PanoreconInputError
from .base import Scene

DEFAULT_SCENE = "bedroom"


@dataclass(frozen=True)
class SceneSpec:
    """A named scene and how to build it at a given ERP width (None: the scene's native size)."""

    name: str
    kind: str  # "synthetic" | "real"
    has_ground_truth: bool
    description: str
    build: Callable[[int | None], Scene]


_SCENES: dict[str, SceneSpec] = {}


def register_scene(spec: SceneSpec) -> SceneSpec:
    if spec.name in _SCENES:
        raise ValueError(f"scene {spec.name!r} is registered twice")
    _SCENES[spec.name] = spec
    return spec


def _ensure_builtin() -> None:
    # importing the modules registers their scenes
    from . import real, synthetic  # noqa: F401


def list_scenes() -> list[SceneSpec]:
    _ensure_builtin()
    return list(_SCENES.values())


def load_scene(name: str, width: int | None = None) -> Scene:
    """A scene by registered name, or an equirectangular image given by path (no depth)."""
    _ensure_builtin()
    if width is not None and (width < 4 or width % 2 or width > 16384):
        raise PanoreconInputError(f"--width {width}: expected an even width between 4 and 16384 pixels")
    if name in _SCENES:
        return _SCENES[name].build(width)
    if Path(name).suffix.lower() in (".png", ".jpg", ".jpeg", ".webp", ".tif", ".tiff", ".exr"):
        from .real import scene_from_image

        return scene_from_image(Path(name), width)
    raise PanoreconInputError(
        f"unknown scene {name!r}: expected one of {', '.join(sorted(_SCENES))}, or the path of an equirectangular image"
    )
