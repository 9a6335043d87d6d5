"""COLMAP SfM baselines on a synthetic scene from 3 panorama positions (512 x 256 ERP, 8 views of 128 px)."""

from __future__ import annotations

import numpy as np
import open3d as o3d
import pytest

from baselines.colmap_sfm import rig_directions, run_colmap_sfm, umeyama
from panorecon.io import PanoreconInputError
from panorecon.scenes import Scene
from panorecon.scenes.multiview import panorama_positions, render_positions
from panorecon.scenes.synthetic import build_scene

# median distance from the triangulated points to the true mesh: bedroom distances are 1-3 m and the views
# are 128 px at 90 degrees (about 1.3 cm per pixel at 2 m); we measure ~1 cm
SURFACE_TOL_M = 0.05


@pytest.fixture(scope="module")
def scene():
    return build_scene("bedroom", 512)


@pytest.fixture(scope="module")
def result(scene):
    return run_colmap_sfm(render_positions(scene, 3), n_views=8, view_size=128)


def surface_distance(scene, xyz: np.ndarray) -> np.ndarray:
    """Distance (metres) from each point [N, 3] to the scene's true mesh."""
    rc = o3d.t.geometry.RaycastingScene()
    rc.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(scene.world.mesh()))
    return rc.compute_distance(o3d.core.Tensor(xyz.astype(np.float32))).numpy()


def test_render_positions_ring_inside_free_space(scene):
    pans = render_positions(scene, 3, "ring", 0.3)
    r = 0.3 * scene.world.free_space_radius()
    assert len(pans) == 3
    for p, rgb, dist in pans:
        assert np.isclose(np.linalg.norm(p), r) and p[2] == 0
        assert rgb.shape == (256, 512, 3) and rgb.dtype == np.uint8 and dist.shape == (256, 512)
    rnd = panorama_positions(r, 5, "random", seed=1)
    assert (np.linalg.norm(rnd, axis=1) <= r + 1e-12).all()


def test_render_positions_needs_a_world(scene):
    real = Scene("x", "real", "", scene.rgb, None, scene.sky)
    with pytest.raises(PanoreconInputError, match="no world"):
        render_positions(real, 3)


def test_rig_directions():
    d = rig_directions(8)
    assert d.shape == (8, 3) and np.allclose(np.linalg.norm(d, axis=1), 1)
    with pytest.raises(PanoreconInputError, match="at least 6"):
        rig_directions(4)


def test_umeyama_coplanar():
    rng = np.random.default_rng(0)
    src = rng.normal(size=(3, 3)) * [1, 1, 0]  # planar, as a ring of panorama centres
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    R = o3d.geometry.get_rotation_matrix_from_quaternion(q)
    s, R2, t = umeyama(src, 2.5 * src @ R.T + [1, 2, 3])
    assert np.isclose(s, 2.5) and np.allclose(R2, R) and np.allclose(t, [1, 2, 3])


def test_triangulation_with_known_poses(scene, result):
    tri = result.report["triangulation"]
    assert tri["ran"] and tri["registered_images"] == 24 and tri["registered_frames"] == 3
    assert tri["points"] == len(result.cloud) >= 100
    assert tri["mean_reprojection_error_px"] < 1.0
    d = surface_distance(scene, result.cloud.xyz)
    assert np.median(d) < SURFACE_TOL_M, np.median(d)
    assert 0 <= result.cloud.rgb.min() and result.cloud.rgb.max() <= 1


def test_mapping_runs_or_reports(scene, result):
    m = result.report["mapping"]
    assert m["ran"]
    if m["aligned"]:
        assert m["centre_rms_m"] < 0.05
        assert np.median(surface_distance(scene, result.mapped.xyz)) < 2 * SURFACE_TOL_M
    else:
        assert result.mapped is None and m["reason"]


def test_needs_two_panoramas(scene):
    with pytest.raises(PanoreconInputError, match="at least 2"):
        run_colmap_sfm(render_positions(scene, 1))
