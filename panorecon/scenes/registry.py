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


def load_scene(name: str, width: int | None = None, depth=None) -> Scene:
    """A scene by registered name, a dataset panorama (``stanford2d3d:``, ``structured3d:``, ``matterport3d:``,
    see ``datasets.py``), or an equirectangular image given by path. ``depth``: a ``real.DepthSpec``, the true
    depth of a real panorama (refused for synthetic and dataset scenes, which carry their own)."""
    _ensure_builtin()
    from .datasets import is_dataset_name, load_dataset_scene
    from .real import scene_from_image, with_depth

    if width is not None and (width < 4 or width % 2 or width > 16384):
        raise PanoreconInputError(f"--width {width}: expected an even width between 4 and 16384 pixels")
    if is_dataset_name(name):
        if depth is not None:
            raise PanoreconInputError(f"--depth {depth.path}: scene {name!r} is a dataset panorama with its own depth")
        return load_dataset_scene(name, width)
    if name in _SCENES:
        scene = _SCENES[name].build(width)
        return scene if depth is None else with_depth(scene, depth)
    if Path(name).suffix.lower() in (".png", ".jpg", ".jpeg", ".webp", ".tif", ".tiff", ".exr"):
        if Path(name).suffix.lower() == ".exr":
            raise PanoreconInputError(f"{name}: an .exr is read as a depth file (--depth), not as the panorama; "
                                      "expected the colour image (.png, .jpg, ...)")
        return scene_from_image(Path(name), width, depth=depth)
    raise PanoreconInputError(
        f"unknown scene {name!r}: expected one of {', '.join(sorted(_SCENES))}, a dataset panorama "
        "(stanford2d3d:, structured3d:, matterport3d:), or the path of an equirectangular image"
    )


def scene_from_args(args) -> Scene:
    """``load_scene`` from a command's parsed options: scene, width and the --depth options (absent: none)."""
    depth = None
    if getattr(args, "depth", None):
        from .real import DepthSpec

        depth = DepthSpec(Path(args.depth), getattr(args, "depth_scale", None),
                          getattr(args, "depth_kind", None) or "distance")
    elif getattr(args, "depth_scale", None) is not None or getattr(args, "depth_kind", None) is not None:
        raise PanoreconInputError("--depth-scale/--depth-kind without --depth: expected a depth file to read")
    return load_scene(args.scene, getattr(args, "width", None), depth)
