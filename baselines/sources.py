"""The multi-view baselines as point sources: fn(scene, teacher, views, fusion_config, view_size) ->
(PointCloud, stage seconds, info). They need no teacher (``fn.uses_teacher`` is False) and a synthetic
scene (``fn.check``, before any work): K panoramas are rendered from positions around the panorama centre
(``render_positions``).

``views`` is the number of 90-degree views each panorama is split into (default 8); ``view_size`` their
side in pixels (default: ERP width / 4, which keeps the panorama's resolution). The info dict holds
views, fov_deg, view_size, layout, panoramas (K), distance (None: these sources give no ERP depth map)
and the baseline's own report under ``baseline``.
"""

from __future__ import annotations

import time

from panorecon.scenes.multiview import render_positions, require_world
from panorecon.sources.builtin import default_view_size

from .colmap_mvs import require_cuda, run_colmap_mvs
from .colmap_sfm import run_colmap_sfm

PANORAMAS = 3
VIEWS = 8


def _render(scene, panoramas: int, layout: str, radius_fraction: float, seed: int):
    t = time.perf_counter()
    pans = render_positions(scene, panoramas, layout, radius_fraction, seed)
    return pans, {"render": time.perf_counter() - t}


def _info(views: int, size: int, layout: str, panoramas: int, report: dict) -> dict:
    return {
        "views": views,
        "fov_deg": 90.0,
        "view_size": size,
        "layout": f"rig-{views}/{layout}",
        "panoramas": panoramas,
        "distance": None,
        "baseline": report,
    }


def colmap_sfm(
    scene,
    teacher=None,
    views=None,
    fusion_config=None,
    view_size=None,
    panoramas=PANORAMAS,
    layout="ring",
    radius_fraction=0.3,
    seed=0,
):
    """COLMAP SIFT + exhaustive matching on K panoramas' perspective rigs, triangulated with the known poses;
    incremental mapping also runs and its registration stats and alignment are in info['baseline']['mapping']."""
    n, size = views or VIEWS, view_size or default_view_size(scene.width)
    pans, seconds = _render(scene, panoramas, layout, radius_fraction, seed)
    res = run_colmap_sfm(pans, n, size, mapping=True, seed=seed)
    seconds.update(res.report.pop("seconds"))
    return res.cloud, seconds, _info(n, size, layout, panoramas, res.report)


def colmap_mvs(
    scene,
    teacher=None,
    views=None,
    fusion_config=None,
    view_size=None,
    panoramas=PANORAMAS,
    layout="ring",
    radius_fraction=0.3,
    seed=0,
):
    """COLMAP PatchMatch stereo + fusion on K panoramas' rigs with the known poses (CUDA builds of pycolmap only:
    elsewhere raises BaselineUnavailableError 'n/a: needs a CUDA build of pycolmap ...' before rendering)."""
    require_cuda()
    n, size = views or VIEWS, view_size or default_view_size(scene.width)
    pans, seconds = _render(scene, panoramas, layout, radius_fraction, seed)
    cloud, report = run_colmap_mvs(pans, n, size, seed=seed)
    seconds.update(report.pop("seconds"))
    return cloud, seconds, _info(n, size, layout, panoramas, report)


def _check_mvs(scene) -> None:
    require_cuda()
    require_world(scene)


for _fn, _check in ((colmap_sfm, require_world), (colmap_mvs, _check_mvs)):
    _fn.uses_teacher = False
    _fn.check = _check  # before any work: `train` claims its --out folder only after this
