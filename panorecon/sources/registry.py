"""The point-source registry: every initialization is a named source returning the same ``PointCloud``.

In-tree sources register with ``@register_source(name, description)``; third-party packages add theirs
through the ``panorecon.sources`` entry-point group (the entry point loads a callable of the same
signature, registered under the entry point's name; a ``uses_teacher = False`` attribute on it says it needs
no depth teacher, a ``check`` attribute, ``check(scene)``, raises PanoreconInputError when it cannot run on that
scene (called before any work or output); the first line of its docstring is its description). The peer
methods in the top-level ``baselines`` package come in that way too. A plug-in that fails to import is still
listed; running it raises a PanoreconInputError naming the entry point and the import error, so one broken
plug-in breaks no other.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from importlib.metadata import entry_points

from ..io import PanoreconInputError


@dataclass(frozen=True)
class SourceSpec:
    """fn(scene, teacher, views, fusion_config, view_size) -> (PointCloud, stage_seconds dict, info dict);
    check(scene) raises PanoreconInputError when the source cannot run on the scene (None: it always can)."""

    name: str
    description: str
    fn: Callable
    uses_teacher: bool = True
    check: Callable | None = None


_SOURCES: dict[str, SourceSpec] = {}
_loaded_entry_points = False


def register_source(name: str, description: str, uses_teacher: bool = True):
    def deco(fn):
        if name in _SOURCES:
            raise ValueError(f"point source {name!r} is registered twice")
        _SOURCES[name] = SourceSpec(name, description, fn, uses_teacher)
        return fn

    return deco


def _load_entry_points() -> None:
    global _loaded_entry_points
    if _loaded_entry_points:
        return
    _loaded_entry_points = True
    for ep in entry_points(group="panorecon.sources"):
        if ep.name in _SOURCES:
            continue
        try:
            fn = ep.load()
        except Exception as e:  # noqa: BLE001  (any import failure of a third party's code)
            _SOURCES[ep.name] = SourceSpec(ep.name, f"(plug-in {ep.value} failed to load: {e})", _broken(ep, e), False)
            continue
        doc = (fn.__doc__ or "").strip().split("\n")[0] or f"plug-in from {ep.value}"
        _SOURCES[ep.name] = SourceSpec(ep.name, doc, fn, getattr(fn, "uses_teacher", True), getattr(fn, "check", None))


def _broken(ep, error: Exception) -> Callable:
    def fn(*args, **kwargs):
        raise PanoreconInputError(
            f"point source {ep.name!r}: its plug-in {ep.value} failed to load "
            f"({type(error).__name__}: {error}); reinstall the package that provides it"
        )

    return fn


def list_sources() -> list[SourceSpec]:
    from . import builtin  # noqa: F401  (registers the built-in sources)

    _load_entry_points()
    return list(_SOURCES.values())


def get_source(name: str) -> SourceSpec:
    names = {s.name: s for s in list_sources()}
    if name not in names:
        raise PanoreconInputError(f"unknown point source {name!r}; expected one of {', '.join(sorted(names))}")
    return names[name]
