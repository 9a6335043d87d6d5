"""Scene registry: every scene by name, synthetic and real, the variants of the synthetic scenes (``bedroom@3``,
see ``synthetic.py``), plus any ERP image given by path and any folder written by ``panorecon render``
(``rendered:<dir>`` or the folder's path). Only a synthetic scene's build imports Open3D."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..io import PanoreconInputError
from .base import Scene
from .catalog import VARIANT_PATTERN, VARIANT_SEP, split_variant

DEFAULT_SCENE = "bedroom"


@dataclass(frozen=True)
class SceneSpec:
    """A named scene and how to build it at a given ERP width (None: the scene's native size)."""

    name: str
    kind: str  # "synthetic" | "real" | "variant" (the NAME@K pattern: listed, never built under that name)
    has_ground_truth: bool
    description: str
    build: Callable[[int | None], Scene]


_SCENES: dict[str, SceneSpec] = {}


def register_scene(spec: SceneSpec) -> SceneSpec:
    if spec.name in _SCENES:
        raise ValueError(f"scene {spec.name!r} is registered twice")
    _SCENES[spec.name] = spec
    return spec


def _build_synthetic(name: str, width: int | None) -> Scene:
    from .synthetic import build_scene  # Open3D: imported only when a synthetic scene is built

    return build_scene(name, width)


def _ensure_builtin() -> None:
    # importing the module registers the real scenes; the synthetic ones come from the Open3D-free catalog
    from . import real  # noqa: F401
    from .catalog import SYNTHETIC_SCENES

    for name, description in SYNTHETIC_SCENES.items():
        if name not in _SCENES:
            register_scene(
                SceneSpec(name, "synthetic", True, description, lambda width, _n=name: _build_synthetic(_n, width))
            )


def _pattern_build(width: int | None) -> Scene:
    raise PanoreconInputError(f"scene {VARIANT_PATTERN!r} is a pattern: expected a variant such as bedroom@3")


VARIANTS_SPEC = SceneSpec(
    VARIANT_PATTERN,
    "variant",
    True,
    "variant K >= 1 of a synthetic scene above (bedroom@3): room size, layout, materials, light and sky drawn "
    "from (NAME, K); a suite names a population as bedroom@1..10",
    _pattern_build,
)


def list_scenes() -> list[SceneSpec]:
    """The registered scenes, then one entry standing for all variants of the synthetic scenes (``NAME@K``)."""
    _ensure_builtin()
    return [*_SCENES.values(), VARIANTS_SPEC]


def parse_variant(name: str) -> tuple[str, int]:
    """``"bedroom@3"`` -> ("bedroom", 3). A malformed variant name (``bedroom@0``, ``bedroom@x``, ``nosuch@2``,
    ``photo.png@2``) raises PanoreconInputError naming it and what was expected."""
    if VARIANT_SEP not in name:
        raise PanoreconInputError(f"scene {name!r}: expected a variant {VARIANT_PATTERN}, e.g. bedroom@3")
    try:
        base, k = split_variant(name)
    except ValueError as e:
        raise PanoreconInputError(f"scene {name!r}: {e}") from None
    return base, k


def load_scene(name: str, width: int | None = None, depth=None) -> Scene:
    """A scene by registered name, a dataset panorama (``stanford2d3d:``, ``structured3d:``, ``matterport3d:``,
    ``panoramas:``, see ``datasets.py``), or an equirectangular image given by path. ``depth``: a
    ``real.DepthSpec``, the true depth of a real panorama (refused for synthetic and dataset scenes, which carry
    their own)."""
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
    if name.startswith("rendered:") or Path(name).is_dir():
        from .rendered import load_rendered

        if depth is not None:
            raise PanoreconInputError(
                f"--depth {depth.path}: {name!r} is a `panorecon render` folder with its own depth"
            )
        return load_rendered(Path(name.removeprefix("rendered:")), width)
    if Path(name).suffix.lower() in (".png", ".jpg", ".jpeg", ".webp", ".tif", ".tiff", ".exr"):
        if Path(name).suffix.lower() == ".exr":
            raise PanoreconInputError(
                f"{name}: an .exr is read as a depth file (--depth), not as the panorama; "
                "expected the colour image (.png, .jpg, ...)"
            )
        return scene_from_image(Path(name), width, depth=depth)
    if VARIANT_SEP in name:
        parse_variant(name)
        if depth is not None:
            raise PanoreconInputError(
                f"--depth {depth.path}: scene {name!r} is synthetic and already has its true depth; "
                "--depth is for real panoramas"
            )
        return _build_synthetic(name, width)
    raise PanoreconInputError(
        f"unknown scene {name!r}: expected one of {', '.join(sorted(_SCENES))}, a variant {VARIANT_PATTERN} "
        "(bedroom@3), a dataset panorama "
        "(stanford2d3d:, structured3d:, matterport3d:, panoramas:), the path of an equirectangular image, "
        "or a folder written by `panorecon render`"
    )
