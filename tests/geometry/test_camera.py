import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from panorecon.geometry import (
    PinholeCamera,
    centred_camera,
    intrinsics_from_fov,
    look_at_rotation,
    look_at_viewmat,
    viewmat_from_pose,
)

unit_vectors = st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 1e-3)


class TestIntrinsics:
    def test_ninety_degrees_gives_half_width_focal(self):
        K = intrinsics_from_fov(512, 256, 90.0)
        assert K[0, 0] == pytest.approx(256.0) and K[1, 1] == pytest.approx(256.0)
        assert (K[0, 2], K[1, 2]) == (256.0, 128.0)

    def test_separate_vertical_fov(self):
        K = intrinsics_from_fov(400, 200, 90.0, 60.0)
        assert K[1, 1] == pytest.approx(100 / math.tan(math.radians(30)))

    @pytest.mark.parametrize("fov", [0.0, -5.0, 180.0, 200.0, float("nan")])
    def test_bad_fov_is_refused(self, fov):
        with pytest.raises(ValueError, match="fov"):
            intrinsics_from_fov(64, 64, fov)

    def test_extreme_fovs_stay_finite(self):
        for fov in (1e-3, 1.0, 179.0, 179.999):
            assert np.isfinite(intrinsics_from_fov(64, 64, fov)).all()


class TestLookAt:
    @given(unit_vectors)
    def test_rotation_is_proper_and_looks_forward(self, f):
        R = look_at_rotation(np.array(f))
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-9)
        assert np.linalg.det(R) == pytest.approx(1.0)
        np.testing.assert_allclose(R[:, 2], np.array(f) / np.linalg.norm(f), atol=1e-9)

    def test_image_down_is_world_down_for_horizontal_views(self):
        R = look_at_rotation(np.array([0.3, -0.8, 0.0]))
        assert R[2, 1] == pytest.approx(-1.0)  # camera +y (down) is world -z

    @pytest.mark.parametrize("f", [(0, 0, 1), (0, 0, -1), (0, 0, 5.0)])
    def test_poles_are_defined(self, f):
        R = look_at_rotation(np.array(f, float))
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)

    def test_zero_forward_is_refused(self):
        with pytest.raises(ValueError, match="zero length"):
            look_at_rotation(np.zeros(3))

    def test_viewmat_maps_target_onto_optical_axis(self):
        V = look_at_viewmat([1.0, 2.0, 0.5], [4.0, -1.0, 0.0])
        p = V @ np.array([4.0, -1.0, 0.0, 1.0])
        assert abs(p[0]) < 1e-9 and abs(p[1]) < 1e-9 and p[2] > 0
        cam = PinholeCamera(np.eye(3), V, 4, 4)
        np.testing.assert_allclose(cam.position, [1.0, 2.0, 0.5], atol=1e-12)


def test_world_rays_through_centre_and_corners():
    cam = centred_camera(np.array([1.0, 0, 0]), 64, 90.0)
    rays = cam.world_rays()
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1, atol=1e-12)
    centre = rays[31:33, 31:33].mean((0, 1))
    assert centre[0] > 0.999
    # the left/right image edges are 45 degrees off axis at 90 deg FOV (pixel centres half a pixel in)
    edge_angle = math.degrees(math.atan((32 - 0.5) / 32))
    assert math.degrees(math.acos(rays[32, 0] @ [1, 0, 0] / np.linalg.norm(rays[32, 0]))) == pytest.approx(
        edge_angle, abs=0.5
    )
    # right of the image is -y in the world when looking along +x
    assert rays[32, -1, 1] < 0


def test_z_to_distance_factor():
    cam = PinholeCamera(intrinsics_from_fov(8, 8, 90), viewmat_from_pose(np.eye(3), np.zeros(3)), 8, 8)
    f = cam.z_to_distance_factor()
    assert f.min() >= 1.0 and f.max() < math.sqrt(3)
