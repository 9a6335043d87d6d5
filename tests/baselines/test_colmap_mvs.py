"""COLMAP MVS: a clear 'n/a' without a CUDA build of pycolmap; a small fused cloud with one."""

from __future__ import annotations

import pycolmap
import pytest

from baselines import BaselineUnavailableError
from baselines.colmap_mvs import run_colmap_mvs
from baselines.sources import colmap_mvs
from panorecon.scenes.multiview import render_positions
from panorecon.scenes.synthetic import build_scene


@pytest.mark.skipif(pycolmap.has_cuda, reason="pycolmap has CUDA: the n/a path does not apply")
def test_na_without_cuda():
    with pytest.raises(BaselineUnavailableError, match=r"^n/a: needs a CUDA build of pycolmap"):
        run_colmap_mvs([])
    with pytest.raises(BaselineUnavailableError, match=r"^n/a: needs a CUDA build of pycolmap"):
        colmap_mvs(build_scene("bedroom", 64))


@pytest.mark.skipif(not pycolmap.has_cuda, reason="PatchMatch stereo needs a CUDA build of pycolmap")
def test_fused_cloud_with_cuda():
    scene = build_scene("bedroom", 512)
    cloud, report = run_colmap_mvs(render_positions(scene, 3), view_size=128)
    assert report["fused_points"] == len(cloud) > 0
