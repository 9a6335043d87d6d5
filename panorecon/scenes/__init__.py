"""Scenes with ground truth (procedural synthetic) and real panoramas, behind one ``Scene`` type."""

from .base import ErpRender, Scene, ViewRender, World
from .registry import DEFAULT_SCENE, SceneSpec, list_scenes, load_scene, register_scene

__all__ = [
    "Scene",
    "World",
    "ErpRender",
    "ViewRender",
    "SceneSpec",
    "DEFAULT_SCENE",
    "list_scenes",
    "load_scene",
    "register_scene",
]
