"""The method's own point sources: the Fibonacci fusion (the method), the other view layouts with the same
fusion, and random points. Peer methods (MoGe's merge, the teacher on the whole ERP, COLMAP) are plug-ins in
the top-level ``baselines`` package, registered through the ``panorecon.sources`` entry points."""

from __future__ import annotations

import time

import numpy as np

from ..fusion import FusionConfig, fuse_views
from ..geometry import PointCloud, back_project_erp, centred_camera, make_layout, sample_erp
from .registry import register_source


def default_view_size(erp_width: int) -> int:
    """Perspective view size for an ERP width: 512 at 2048 wide, scaled with the width, at least 32."""
    return int(max(32, min(512, round(erp_width / 4))))


def cloud_from_distance(scene, distance: np.ndarray, forwards: np.ndarray | None) -> PointCloud:
    """Back-project a fused ERP distance (in row bands, ``back_project_erp``); each point's view id is the view
    whose axis is closest to its ray."""
    keep = np.isfinite(distance) & (distance > 0) & ~scene.sky
    xyz, rgb, view_id = back_project_erp(distance, keep, scene.rgb, forwards)
    return PointCloud(xyz, rgb, None, view_id)


def _layout_source(layout_name: str, scene, teacher, views, fusion_config, view_size, fov_deg=None):
    t = time.perf_counter()
    layout = make_layout(layout_name, views, fov_deg)
    size = view_size or default_view_size(scene.width)
    cams = [centred_camera(d, size, layout.fov_deg) for d in layout.directions]
    seconds = {"views": time.perf_counter() - t}
    t = time.perf_counter()
    vds = teacher.predict_views(scene, cams)
    seconds["teacher"] = time.perf_counter() - t
    t = time.perf_counter()
    res = fuse_views(vds, scene.height, scene.width, fusion_config or FusionConfig(), guide=scene.rgb)
    seconds["fusion"] = time.perf_counter() - t
    t = time.perf_counter()
    pc = cloud_from_distance(scene, res.distance, layout.directions)
    seconds["points"] = time.perf_counter() - t
    info = {
        "views": layout.n_views,
        "fov_deg": layout.fov_deg,
        "view_size": size,
        "layout": layout.name,
        "fusion": res.report,
        "distance": res.distance,
        "view_depths": vds,
    }
    return pc, seconds, info


@register_source("fibonacci", "the method: N views on a Fibonacci lattice (default 20), log-depth least-squares fusion")
def fibonacci(scene, teacher, views=None, fusion_config=None, view_size=None):
    return _layout_source("fibonacci", scene, teacher, views or 20, fusion_config, view_size)


@register_source("icosahedral", "20 tangent views at the icosahedron's face centres, same fusion")
def icosahedral(scene, teacher, views=None, fusion_config=None, view_size=None):
    return _layout_source("icosahedral", scene, teacher, views, fusion_config, view_size)


@register_source("latlong", "a latitude-longitude grid of views (default 4 x 8), same fusion")
def latlong(scene, teacher, views=None, fusion_config=None, view_size=None):
    return _layout_source("latlong", scene, teacher, views, fusion_config, view_size)


@register_source("cube", "the six cube faces at 90 degrees, same fusion")
def cube(scene, teacher, views=None, fusion_config=None, view_size=None):
    return _layout_source("cube", scene, teacher, views, fusion_config, view_size)


@register_source("random", "uniform random points in a ball (the usual 3DGS random initialization)", uses_teacher=False)
def random_points(scene, teacher=None, views=None, fusion_config=None, view_size=None, n_points=100_000, seed=0):
    """Radius: the 90th percentile of the scene's finite distance when it has one (an oracle's bound on the
    scene size, as random initializations assume a known extent), else 10 m. Colours: the panorama's colour
    along each point's direction from the centre."""
    t = time.perf_counter()
    rng = np.random.default_rng(seed)
    radius = 10.0
    if scene.distance is not None and np.isfinite(scene.distance).any():
        radius = float(np.percentile(scene.distance[np.isfinite(scene.distance)], 90))
    d = rng.normal(size=(n_points, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = radius * rng.random(n_points) ** (1 / 3)
    rgb = sample_erp(scene.rgb, d, "linear").astype(np.float32) / 255.0
    pc = PointCloud(d * r[:, None], rgb)
    return pc, {"points": time.perf_counter() - t}, {"views": 0, "radius_m": radius, "distance": None}
