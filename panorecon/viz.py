"""Point-cloud inspection with pyvista: off-screen screenshots, or an interactive window."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .geometry.pointcloud import PointCloud
from .io import PanoreconInputError, atomic_write, quiet_native_stderr


def point_scalars(pc: PointCloud) -> dict[str, np.ndarray]:
    """Per-point scalars a cloud carries ([N] float arrays): view_id and any extra PLY property."""
    out = {}
    if pc.view_id is not None:
        out["view_id"] = pc.view_id.astype(np.float32)
    for k, v in pc.meta.get("scalars", {}).items():
        out[k] = np.asarray(v, np.float32).reshape(len(pc), -1)[:, 0]
    return out


def _headless_gl() -> None:
    """Without a display, have VTK open an EGL window when libEGL is there (instead of trying X first and
    printing "bad X server connection"); an explicit $VTK_DEFAULT_OPENGL_WINDOW wins."""
    import ctypes.util

    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY") and ctypes.util.find_library("EGL"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def _plotter(
    pc: PointCloud,
    scalar: str | None,
    point_size: float,
    off_screen: bool,
    clip_z: float | None = None,
    window_size=(1280, 800),
):
    if off_screen:
        _headless_gl()
    import pyvista as pv

    if clip_z is not None:  # drop a ceiling so a room can be seen from above
        pc = pc.subset(pc.xyz[:, 2] <= clip_z)

    cloud = pv.PolyData(pc.xyz.astype(np.float64))
    plotter = pv.Plotter(off_screen=off_screen, window_size=list(window_size))
    if scalar is None:
        cloud["rgb"] = (np.clip(pc.rgb, 0, 1) * 255).astype(np.uint8)
        plotter.add_mesh(cloud, scalars="rgb", rgb=True, point_size=point_size, render_points_as_spheres=False)
    else:
        scalars = point_scalars(pc)
        if scalar not in scalars:
            raise PanoreconInputError(
                f"--color {scalar!r}: the cloud has no such per-point scalar; it has {sorted(scalars) or 'none'}"
            )
        cloud[scalar] = scalars[scalar]
        plotter.add_mesh(cloud, scalars=scalar, cmap="viridis", point_size=point_size, show_scalar_bar=True)
    plotter.set_background("white")
    # look from above and outside the panorama centre, down the scene (+z up)
    centre = np.median(pc.xyz, axis=0)
    extent = np.percentile(np.linalg.norm(pc.xyz - centre, axis=1), 90) if len(pc) else 1.0
    plotter.camera_position = [tuple(centre + extent * np.array([-1.5, 1.1, 2.6])), tuple(centre), (0, 0, 1)]
    return plotter


def screenshot(
    pc: PointCloud,
    out: str | os.PathLike,
    scalar: str | None = None,
    point_size: float = 2.0,
    clip_z: float | None = None,
    window_size=(1280, 800),
) -> Path:
    """Render the cloud off-screen to a PNG of ``window_size`` (width, height) pixels (atomically); colour by RGB
    or by the named scalar; points above ``clip_z`` (metres) are not drawn."""
    if len(pc) == 0:
        raise PanoreconInputError("the point cloud is empty: nothing to show")
    out = Path(out)
    with quiet_native_stderr():  # VTK's "bad X server connection" noise: off-screen rendering needs no display
        plotter = _plotter(pc, scalar, point_size, off_screen=True, clip_z=clip_z, window_size=window_size)
        try:
            with atomic_write(out, suffix=".png") as tmp:
                plotter.screenshot(str(tmp))
                if tmp.stat().st_size == 0:
                    raise OSError(f"could not render a screenshot to {out} (VTK wrote nothing)")
        finally:
            plotter.close()
    return out


def show(pc: PointCloud, scalar: str | None = None, point_size: float = 2.0, clip_z: float | None = None) -> None:
    """Open an interactive window (needs a display)."""
    if not os.environ.get("DISPLAY") and not os.environ.get("WAYLAND_DISPLAY"):
        raise PanoreconInputError("no display found for an interactive window: pass --screenshot OUT.png instead")
    _plotter(pc, scalar, point_size, off_screen=False, clip_z=clip_z).show()
