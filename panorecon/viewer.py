"""``panorecon view PATH``: a viser server (the viewer of nerfstudio and gsplat's examples) in the browser.

A 3DGS ``point_cloud.ply`` is shown with viser's Gaussian-splat node, any other PLY as points. A run folder
(``panorecon train`` / ``demo`` output) shows its Gaussians, its initial cloud(s), the point source's
perspective views of the panorama (Fibonacci / icosahedral ... layout, from ``*_report.json``) and, from
``cameras.json``, the pseudo-label and held-out cameras as frustums. viser is the ``view`` extra.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .io import PanoreconInputError

COLOURS = {"source": (230, 120, 20), "pseudo-label": (40, 110, 230), "held-out": (220, 30, 60)}


@dataclass
class Frustum:
    """A camera to draw: world-to-camera ``viewmat`` [4, 4] (OpenCV axes), vertical FOV (radians), W/H."""

    viewmat: np.ndarray
    fov_y: float
    aspect: float


@dataclass
class ViewItems:
    """What ``serve`` shows: Gaussian PLYs, point-cloud PLYs and frustum groups by name."""

    gaussians: list[Path] = field(default_factory=list)
    clouds: list[Path] = field(default_factory=list)
    frustums: dict[str, list[Frustum]] = field(default_factory=dict)


def is_gaussian_ply(path: Path) -> bool:
    """True when the PLY header has the 3DGS properties (f_dc_0, opacity, scale_0, rot_0)."""
    head = path.open("rb").read(4096).split(b"end_header")[0]
    return all(b"property float " + p in head for p in (b"f_dc_0", b"opacity", b"scale_0", b"rot_0"))


def _frustum(viewmat, K, width, height) -> Frustum:
    K = np.asarray(K, float)
    return Frustum(np.asarray(viewmat, float), 2 * np.arctan(0.5 * height / K[1, 1]), width / height)


def collect(path: str | Path) -> ViewItems:
    """The items of a PLY file or a run folder; a bad path raises PanoreconInputError."""
    path = Path(path)
    items = ViewItems()
    if path.is_file():
        if path.suffix.lower() != ".ply":
            raise PanoreconInputError(f"{path}: expected a .ply file or a run folder")
        (items.gaussians if is_gaussian_ply(path) else items.clouds).append(path)
        return items
    if not path.is_dir():
        raise PanoreconInputError(f"{path}: no such file or folder")
    for ply in sorted(path.glob("*.ply")):
        (items.gaussians if is_gaussian_ply(ply) else items.clouds).append(ply)
    from .geometry import LAYOUT_NAMES, centred_camera, make_layout

    for rep in sorted(path.glob("*_report.json")):
        r = json.loads(rep.read_text())
        if r.get("source") in LAYOUT_NAMES and r.get("fov_deg") and r.get("view_size"):
            lay = make_layout(r["source"], r.get("views") if r["source"] in ("fibonacci", "latlong") else None)
            cams = [centred_camera(d, r["view_size"], r["fov_deg"]) for d in lay.directions]
            items.frustums[f"{r['source']} views"] = [_frustum(c.viewmat, c.K, c.width, c.height) for c in cams]
    if (path / "cameras.json").is_file():
        for name, cams in json.loads((path / "cameras.json").read_text()).items():
            items.frustums[name] = [_frustum(c["viewmat"], c["K"], c["width"], c["height"]) for c in cams]
    if not items.gaussians and not items.clouds:
        raise PanoreconInputError(f"{path}: no .ply in this folder (expected point_cloud.ply or a *_cloud.ply)")
    return items


def gaussian_arrays(path: Path) -> dict[str, np.ndarray]:
    """A 3DGS PLY as viser wants it: centers [N,3], covariances [N,3,3] = R diag(s^2) R^T (metres^2),
    rgbs [N,3] in [0, 1] (the DC colour), opacities [N,1]; float32."""
    import torch

    from .splat.ply import load_ply
    from .splat.rasterize import quat_to_rotmat
    from .splat.rasterize.sh import C0

    m = load_ply(path)
    with torch.no_grad():
        M = quat_to_rotmat(m.quats) * m.scales()[:, None, :]  # R diag(s)
        cov = M @ M.transpose(1, 2)
        rgb = (0.5 + C0 * m.sh0[:, 0]).clamp(0, 1)
        return {
            "centers": m.means.numpy(),
            "covariances": cov.numpy(),
            "rgbs": rgb.numpy(),
            "opacities": m.opacities()[:, None].numpy(),
        }


def _wxyz(rotation: np.ndarray) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    x, y, z, w = Rotation.from_matrix(rotation).as_quat()
    return np.array([w, x, y, z])


def serve(path: str | Path, port: int = 8080, host: str = "0.0.0.0", point_size: float = 0.02):
    """Start a viser server showing ``path`` (see the module doc) and return it (it serves from a thread)."""
    items = collect(path)
    try:
        import viser
    except ImportError:
        raise PanoreconInputError("`panorecon view` needs viser: pip install 'panorecon[view]'") from None
    from .geometry import PointCloud

    server = viser.ViserServer(host=host, port=port, verbose=False)
    server.scene.set_up_direction("+z")
    # start inside, near the panorama centre, looking along +x (the panorama's middle column)
    server.initial_camera.position = (-0.8, 0.0, 0.3)
    server.initial_camera.look_at = (1.0, 0.0, 0.0)
    server.initial_camera.up = (0.0, 0.0, 1.0)
    for p in items.gaussians:
        server.scene.add_gaussian_splats(f"/gaussians/{p.stem}", **gaussian_arrays(p))
    for p in items.clouds:
        pc = PointCloud.load_ply(p)
        server.scene.add_point_cloud(
            f"/clouds/{p.stem}",
            pc.xyz,
            (np.clip(pc.rgb, 0, 1) * 255).astype(np.uint8),
            point_size=point_size,
            visible=not items.gaussians,
        )
    for group, frustums in items.frustums.items():
        colour = next((c for k, c in COLOURS.items() if k in group), COLOURS["source"])
        for k, f in enumerate(frustums):
            c2w = f.viewmat[:3, :3].T
            # the dense pseudo-label cameras (120+) would hide the scene: listed, off until ticked in the tree
            server.scene.add_camera_frustum(
                f"/cameras/{group.replace(' ', '_')}/{k}",
                fov=f.fov_y,
                aspect=f.aspect,
                scale=0.12,
                thickness=0.004,
                color=colour,
                wxyz=_wxyz(c2w),
                position=-c2w @ f.viewmat[:3, 3],
                visible=group != "pseudo-label",
            )
    return server


def cmd_view(cfg) -> int:
    """``panorecon view`` (a ``configs.ViewConfig``): serve until Ctrl-C."""
    server = serve(cfg.path, cfg.port, cfg.host)
    host = "localhost" if cfg.host in ("0.0.0.0", "::") else cfg.host
    print(f"panorecon view: {cfg.path} at http://{host}:{server.get_port()} (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        server.stop()
    return 0
