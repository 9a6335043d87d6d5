"""COLMAP dense multi-view stereo on K panoramas: the known-pose sparse model of ``colmap_sfm``, then
``pycolmap.undistort_images`` (a COLMAP MVS workspace), ``patch_match_stereo`` (photometric + geometric
consistency) and ``stereo_fusion`` into one fused cloud in the scene frame (metres).

PatchMatch stereo exists only in CUDA builds of COLMAP; elsewhere ``run_colmap_mvs`` raises
``BaselineUnavailableError`` before doing any work.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

from panorecon.geometry import PointCloud

from . import BaselineUnavailableError
from .colmap_sfm import quiet_colmap, run_colmap_sfm


def require_cuda() -> None:
    """Raise BaselineUnavailableError unless pycolmap was built with CUDA."""
    import pycolmap

    if not pycolmap.has_cuda:
        raise BaselineUnavailableError(
            f"n/a: needs a CUDA build of pycolmap (installed pycolmap {pycolmap.__version__} has has_cuda=False); "
            "COLMAP's PatchMatch stereo runs only on CUDA GPUs"
        )


def run_colmap_mvs(
    panoramas,
    n_views: int = 8,
    view_size: int = 128,
    threads: int = 2,
    seed: int = 0,
    workdir: str | Path | None = None,
) -> tuple[PointCloud, dict]:
    """Panoramas [(position [3] metres, ERP rgb [H, W, 3] uint8, ...), ...] -> (fused PointCloud, report with
    the sparse model's report, fused point count and per-stage seconds). ``workdir`` keeps the workspace."""
    require_cuda()
    import pycolmap

    with tempfile.TemporaryDirectory(prefix="colmap-mvs-") as tmp:
        root = Path(workdir) if workdir else Path(tmp)
        sparse = run_colmap_sfm(
            panoramas, n_views, view_size, mapping=False, threads=threads, seed=seed, workdir=root / "sparse"
        )
        seconds = dict(sparse.report.pop("seconds"))
        with quiet_colmap():
            t = time.perf_counter()
            dense = root / "dense"
            pycolmap.undistort_images(dense, root / "sparse" / "triangulated", root / "sparse" / "images")
            pycolmap.patch_match_stereo(dense)
            seconds["patch_match"] = time.perf_counter() - t
            t = time.perf_counter()
            fused = root / "fused.ply"
            fusion = pycolmap.StereoFusionOptions()
            fusion.num_threads = threads
            pycolmap.stereo_fusion(fused, dense, options=fusion, output_type="PLY")
            cloud = PointCloud.load_ply(fused)
            seconds["fusion"] = time.perf_counter() - t
    return cloud, {"sparse": sparse.report, "fused_points": len(cloud), "seconds": seconds}
