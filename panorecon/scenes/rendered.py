"""A scene saved by ``panorecon render`` loaded back, with its truth, without Open3D.

The folder holds pano.png (ERP RGB), distance.npy (float32 ray distance in metres, inf = sky, nan = unknown),
scene.json (name, kind, description, distance_kind, meta, free_space_radius) and, for synthetic scenes,
heldout_<res>.npz: the true held-out views that ``splat.labels.make_heldout_views`` asks for at that
resolution (cameras, RGB, z-depth, sky), rendered by the real world when the folder was written. The loaded
scene's ``RecordedWorld`` replays them, so a machine without Open3D trains and evaluates it exactly as the
synthetic scene; a camera that was not recorded is refused with the command that records it (simulated
teachers then read the truth from distance.npy, see ``teachers.base.true_view_distance``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry import PinholeCamera
from ..io import PanoreconInputError, atomic_write, read_image
from .base import ErpRender, Scene, ViewRender

HELDOUT_FILE = "heldout_{res}.npz"


@dataclass
class RecordedWorld:
    """The ``World`` of a rendered folder: the free-space radius and a set of recorded true views."""

    folder: Path
    radius: float
    views: dict = field(default_factory=dict)  # res -> dict of arrays (see ``save_heldout``), loaded lazily

    def free_space_radius(self) -> float:
        return self.radius

    def _recorded(self, res: int) -> dict | None:
        if res not in self.views:
            path = self.folder / HELDOUT_FILE.format(res=res)
            self.views[res] = dict(np.load(path)) if path.is_file() else None
        return self.views[res]

    def _find(self, camera: PinholeCamera) -> tuple[dict, int] | None:
        rec = self._recorded(camera.width) if camera.width == camera.height else None
        if rec is None:
            return None
        same = (np.abs(rec["viewmats"] - camera.viewmat).max((1, 2)) < 1e-9) & (
            np.abs(rec["Ks"] - camera.K).max((1, 2)) < 1e-9
        )
        hit = np.flatnonzero(same)
        return (rec, int(hit[0])) if len(hit) else None

    def can_render(self, camera: PinholeCamera) -> bool:
        """Whether ``camera``'s view was recorded."""
        return self._find(camera) is not None

    def render_view(self, camera: PinholeCamera) -> ViewRender:
        """The recorded view whose camera equals ``camera`` (viewmat and K within 1e-9)."""
        found = self._find(camera)
        if found is not None:
            rec, k = found
            return ViewRender(rec["rgb"][k], rec["distance"][k], rec["depth_z"][k], rec["sky"][k])
        raise PanoreconInputError(
            f"{self.folder}: no recorded true view for a {camera.width}x{camera.height} camera at "
            f"{np.round(camera.position, 3).tolist()}; write the folder again with "
            f"`panorecon render <scene> --out {self.folder} --heldout-res {camera.width}` (and the same --heldout, "
            "fov and seed as the training)"
        )

    def render_erp(self, height: int, position: np.ndarray | None = None) -> ErpRender:
        raise PanoreconInputError(f"{self.folder}: a rendered folder holds no world to render new panoramas from")

    def mesh(self):
        raise PanoreconInputError(f"{self.folder}: a rendered folder holds no mesh")


def save_heldout(folder: Path, cameras: list[PinholeCamera], renders: list[ViewRender]) -> Path:
    """Write true views of one square size (their cameras and renders) as heldout_<res>.npz -> its path."""
    res = cameras[0].width
    if any(c.width != res or c.height != res for c in cameras):
        raise ValueError("save_heldout: every camera must be square and of one size")
    arrays = {"viewmats": np.stack([c.viewmat for c in cameras]), "Ks": np.stack([c.K for c in cameras])}
    for key in ("rgb", "distance", "depth_z", "sky"):
        arrays[key] = np.stack([getattr(r, key) for r in renders])
    path = Path(folder) / HELDOUT_FILE.format(res=res)
    with atomic_write(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
    return path


class RecordingWorld:
    """Wraps a world and keeps every (camera, render) that ``render_view`` served, for ``save_heldout``."""

    def __init__(self, world):
        self.world, self.cameras, self.renders = world, [], []

    def free_space_radius(self) -> float:
        return self.world.free_space_radius()

    def render_view(self, camera: PinholeCamera) -> ViewRender:
        r = self.world.render_view(camera)
        self.cameras.append(camera)
        self.renders.append(r)
        return r


def load_rendered(folder: Path, width: int | None = None) -> Scene:
    """The scene in a folder written by ``panorecon render`` (``width`` must be None or the stored width)."""
    info_path = folder / "scene.json"
    if not info_path.is_file():
        raise PanoreconInputError(f"{folder}: not a folder written by `panorecon render` (no scene.json)")
    try:
        info = json.loads(info_path.read_text())
        name, kind, distance_kind = info["name"], info["kind"], info["distance_kind"]
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        raise PanoreconInputError(
            f"{info_path}: unreadable ({type(e).__name__}: {e}); write the folder again"
        ) from None
    rgb = read_image(folder / "pano.png", erp=True)
    if width is not None and width != rgb.shape[1]:
        raise PanoreconInputError(
            f"--width {width}: {folder} was rendered at width {rgb.shape[1]}; render it again "
            "at that width or leave --width out"
        )
    distance = None
    dpath = folder / "distance.npy"
    if dpath.is_file():
        distance = np.load(dpath)
        if distance.shape != rgb.shape[:2] or distance.dtype != np.float32:
            raise PanoreconInputError(
                f"{dpath}: expected float32 {rgb.shape[:2]} ray distance, got {distance.dtype} {distance.shape}"
            )
    elif distance_kind != "none":
        raise PanoreconInputError(
            f"{folder}: scene.json says distance_kind={distance_kind!r} but distance.npy is missing"
        )
    sky = np.isposinf(distance) if distance is not None else np.zeros(rgb.shape[:2], bool)
    radius = info.get("free_space_radius")
    world = RecordedWorld(folder, float(radius)) if radius is not None else None
    return Scene(
        name=name,
        kind=kind,
        description=info.get("description", ""),
        rgb=rgb,
        distance=distance,
        sky=sky,
        distance_kind=distance_kind,
        world=world,
        meta={**info.get("meta", {}), "rendered_from": str(folder)},
    )
