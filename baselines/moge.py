"""``moge-merge``: MoGe's own panorama merge, ``merge_panorama_depth`` from the ``dlr-moge`` package (MIT,
microsoft/MoGe's ``moge/utils/panorama.py``, with its ``dlr-utils3d``), on MoGe's own 12 icosahedron-vertex
views of 90 degrees. The merge imports only numpy, scipy, OpenCV, tqdm and utils3d's numpy part, so the
``moge`` extra is installed without dependencies (see scripts/setup.sh): the package's full list (gradio,
torchvision, trimesh, ...) is for its model and demos.

MoGe's ERP puts its seam where panorecon's longitude 0 is: its columns are panorecon's rolled by W / 2. Its
cameras are in the same world frame and OpenCV axes as panorecon's, so views pass through unchanged.
"""

from __future__ import annotations

import time

import numpy as np
from scipy import ndimage

from panorecon.fusion import FusionConfig
from panorecon.fusion.affine import align_affine_views
from panorecon.fusion.connectivity import check_connectivity
from panorecon.geometry import PinholeCamera, ViewDepth
from panorecon.io import PanoreconInputError
from panorecon.sources.builtin import cloud_from_distance, default_view_size

from . import BaselineUnavailableError

INSTALL = "pip install --no-deps dlr-moge==2.0.0 dlr-utils3d==1.3 (the moge extra)"

# MoGe's merge_panorama_depth keeps, at its finest level (the panorama's own size), full-size float64 ray
# directions, per view its gradient, Laplacian and mask maps (all 12 kept, then stacked), and a sparse
# least-squares system of about 9 non-zeros per pixel with LSMR's vectors: its peak grows with the ERP's pixels.
# Peak resident memory above the scene (VmHWM less the RSS before the row), through run_source on the bedroom with
# sim:relative: 1024 x 512: 338 MB (45.6 s merging), 2048 x 1024: 1595 MB (91 s), 4096 x 2048: 6870 MB (still in
# its finest LSMR after 6.5 min of CPU when stopped). Per ERP megapixel: 645, 761, 820 MB; the largest is used.
MERGE_MB_PER_MEGAPIXEL = 820.0
MERGE_MEASURED = "measured 338 / 1595 / 6870 MB at 1024 / 2048 / 4096 px wide, extrapolated linearly"


def merge_memory_mb(height: int, width: int) -> float:
    """The peak memory (MB) MoGe's merge is expected to take on a height x width ERP: MERGE_MB_PER_MEGAPIXEL times
    its megapixels (the measurements above, extrapolated linearly)."""
    return MERGE_MB_PER_MEGAPIXEL * height * width / 1e6


def check_memory(scene) -> None:
    """BaselineUnavailableError ('n/a: ...', before any work) when MoGe's merge on this scene's ERP would need more
    memory than ``io.memory_budget_mb`` (MemAvailable, or $PANORECON_MEMORY_BUDGET_MB) leaves: MoGe's own code is
    run as it is, never re-implemented or run on a smaller panorama than asked."""
    from panorecon.io import memory_budget_mb

    need, budget = merge_memory_mb(scene.height, scene.width), memory_budget_mb()
    if budget is not None and need > budget:
        raise BaselineUnavailableError(
            f"n/a: moge-merge at {scene.width} x {scene.height}: MoGe's merge_panorama_depth would need about "
            f"{need / 1024:.1f} GB ({MERGE_MB_PER_MEGAPIXEL:.0f} MB per ERP megapixel, {MERGE_MEASURED}), more "
            f"than the {budget / 1024:.1f} GB available (io.memory_budget_mb)"
        )


def moge_panorama():
    """MoGe's ``moge.utils.panorama`` module, or BaselineUnavailableError saying what to install."""
    try:
        from moge.utils import panorama
    except ImportError as e:
        raise BaselineUnavailableError(f"n/a: moge-merge needs MoGe's code ({e}); {INSTALL}") from None
    return panorama


def moge_cameras(size: int) -> list[PinholeCamera]:
    """MoGe's 12 panorama cameras (``get_panorama_cameras``) as panorecon cameras of size x size pixels."""
    extrinsics, intrinsics = moge_panorama().get_panorama_cameras()
    scale = np.array([[size], [size], [1.0]])
    return [
        PinholeCamera(np.asarray(k, np.float64) * scale, np.asarray(e, np.float64), size, size)
        for e, k in zip(extrinsics, intrinsics)
    ]


def merge_views(views, height: int, width: int) -> np.ndarray:
    """MoGe's ``merge_panorama_depth`` on panorecon views (scale-only) -> ERP ray distance [H, W] float32 in
    panorecon's ERP convention, NaN where no view's valid pixel lands. Invalid view pixels are filled with
    their nearest valid value first (MoGe's merge reads its maps bilinearly and masks afterwards, so a NaN
    would spread); a view without any valid pixel is left out."""
    pano = moge_panorama()
    maps, masks, ext, ints = [], [], [], []
    for v in views:
        d = v.to_distance()
        ok = np.isfinite(d) & (d > 0)
        if not ok.any():
            continue
        idx = ndimage.distance_transform_edt(~ok, return_distances=False, return_indices=True)
        maps.append(d[idx[0], idx[1]].astype(np.float32))
        masks.append(ok)
        ext.append(v.camera.viewmat.astype(np.float32))
        ints.append(v.camera.K / np.array([[v.camera.width], [v.camera.height], [1.0]]))
    if not maps:
        raise PanoreconInputError("moge-merge: no view has a valid depth pixel; expected at least one")
    depth, mask = pano.merge_panorama_depth(width, height, maps, masks, np.stack(ext), ints)
    depth = np.where(mask, depth, np.nan).astype(np.float32)
    depth = np.roll(depth, -(width // 2), axis=1)
    if not np.isfinite(depth[np.roll(mask, -(width // 2), axis=1)]).all():
        raise ValueError("moge-merge: MoGe's merge returned non-finite distances")
    return depth


def moge_merge(scene, teacher, views=None, fusion_config=None, view_size=None):
    """MoGe's own merge_panorama_depth (dlr-moge) on its 12 icosahedron-vertex views at 90 degrees"""
    if views not in (None, 12):
        raise PanoreconInputError(f"moge-merge: views={views}; MoGe's merge uses its own 12 views (leave it unset)")
    t = time.perf_counter()
    size = view_size or default_view_size(scene.width)
    cams = moge_cameras(size)
    seconds = {"views": time.perf_counter() - t}
    t = time.perf_counter()
    vds = teacher.predict_views(scene, cams)
    seconds["teacher"] = time.perf_counter() - t
    t = time.perf_counter()
    if any(v.affine for v in vds):  # MoGe's merge takes scale-only views: align the shifts first
        dists, _, _ = align_affine_views(vds, gauge=(fusion_config or FusionConfig()).affine_gauge)
        vds = [ViewDepth(v.camera, d, "distance", np.isfinite(d)) for v, d in zip(vds, dists)]
    distance = merge_views(vds, scene.height, scene.width)
    seconds["fusion"] = time.perf_counter() - t
    t = time.perf_counter()
    forwards = np.stack([c.forward for c in cams])
    pc = cloud_from_distance(scene, distance, forwards)
    seconds["points"] = time.perf_counter() - t
    info = {
        "views": len(cams),
        "fov_deg": 90.0,
        "view_size": size,
        "layout": "moge-icosahedron-vertices",
        "fusion": {
            "solver": "MoGe merge_panorama_depth (dlr-moge): LSMR, coarse to fine",
            "connectivity": check_connectivity(vds),
        },
        "distance": distance,
        "view_depths": vds,
    }
    return pc, seconds, info


moge_merge.check = check_memory  # before any work (sources.check_source)
