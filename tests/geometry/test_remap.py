import math

import cv2
import numpy as np
import pytest

from panorecon.geometry import (
    PinholeCamera,
    centred_camera,
    erp_directions,
    erp_to_perspective,
    lonlat_to_direction,
    pad_erp,
    perspective_to_erp,
    sample_erp,
)

A = np.array([0.3, -0.5, 0.8])


def smooth_erp(h):
    """A smooth function on the sphere, f(d) = 0.5 + 0.4 * d.a (exactly linear in the direction)."""
    return (0.5 + 0.4 * erp_directions(h, 2 * h) @ A).astype(np.float32)


class TestSeamAndPoles:
    def test_pad_continues_across_the_pole(self):
        e = np.arange(4 * 8, dtype=np.float32).reshape(4, 8)
        p = pad_erp(e, 2)
        # the row above row 0 at column c is row 0 at column c + W/2
        np.testing.assert_array_equal(p[1, 2:10], np.roll(e[0], -4))
        np.testing.assert_array_equal(p[2:6, 0:2], e[:, -2:])

    @pytest.mark.parametrize("shape,pad", [((4, 8), 2), ((6, 12, 3), 3), ((5, 10), 5)])
    def test_pad_equals_the_whole_map_roll_and_concatenations(self, shape, pad):
        e = np.random.default_rng(0).uniform(size=shape).astype(np.float32)
        shifted = np.roll(e, shape[1] // 2, axis=1)  # the reference: whole-map roll, two concatenations
        tall = np.concatenate([shifted[:pad][::-1], e, shifted[-pad:][::-1]], axis=0)
        ref = np.concatenate([tall[:, -pad:], tall, tall[:, :pad]], axis=1)
        got = pad_erp(e, pad)
        assert got.dtype == e.dtype
        np.testing.assert_array_equal(got, ref)

    def test_sample_with_a_padded_map_given_equals_padding_inside(self):
        e = smooth_erp(32)
        d = erp_directions(16, 32) * 2.0
        np.testing.assert_array_equal(sample_erp(e, d, "nearest", padded=pad_erp(e)), sample_erp(e, d, "nearest"))

    @pytest.mark.parametrize(
        "lon,lat",
        [
            (math.pi, 0.1),
            (-math.pi + 1e-4, -0.3),
            (0.5, math.pi / 2 - 1e-3),
            (2.0, -math.pi / 2 + 1e-3),
            (math.pi - 1e-3, 1.4),
        ],
    )
    def test_samples_near_seam_and_poles_match_the_function(self, lon, lat):
        h = 64
        d = lonlat_to_direction(np.array([[lon]]), np.array([[lat]]))
        got = sample_erp(smooth_erp(h), d)[0, 0]
        # bilinear error of a smooth function is O(pixel^2); a clamped border would be off by O(pixel)
        assert got == pytest.approx(0.5 + 0.4 * d[0, 0] @ A, abs=2e-3)

    def test_perspective_view_across_the_seam_is_smooth(self):
        h = 128
        cam = centred_camera(lonlat_to_direction(np.float64(math.pi), np.float64(0.0)), 64, 90)
        view = erp_to_perspective(smooth_erp(h), cam)
        truth = 0.5 + 0.4 * cam.world_rays() @ A
        assert np.abs(view - truth).max() < 2e-3


class TestRoundTrip:
    @pytest.mark.parametrize("forward", [(1, 0, 0), (0, 0, 1), (-1, 0.2, -0.9), (-1, 0, 0)])
    def test_erp_to_perspective_to_erp(self, forward):
        h = 128
        e = smooth_erp(h)
        cam = centred_camera(np.array(forward, float), 128, 80)
        back, seen = perspective_to_erp(erp_to_perspective(e, cam), cam, h, 2 * h)
        assert seen.sum() > 100
        assert np.abs(back[seen] - e[seen]).max() < 3e-3
        assert (back[~seen] == 0).all()

    def test_multichannel_and_dtype_kept(self):
        img = (np.random.default_rng(0).random((32, 64, 3)) * 255).astype(np.uint8)
        out = erp_to_perspective(img, centred_camera(np.array([0, 1.0, 0]), 16, 60))
        assert out.shape == (16, 16, 3) and out.dtype == np.uint8

    def test_bad_interpolation_name(self):
        with pytest.raises(ValueError, match="interpolation"):
            sample_erp(smooth_erp(8), erp_directions(2, 4), "lanczos9")


class TestAgainstPy360convert:
    """py360convert's e2p is a test-only oracle. Mapping its conventions onto ours: its u/v angles are
    our longitude/latitude (same axes), and its output grid puts the first and last pixel *centres* on
    the FOV edges (np.linspace(-tan, tan, W)), i.e. f = (W - 1) / (2 tan(FOV / 2)) where ours uses W."""

    @pytest.mark.parametrize("fname", ["py360convert_demo_equirec.png", "hohonet_pano.png"])
    def test_e2p_agrees_on_real_panoramas(self, real_data, fname):
        py360convert = pytest.importorskip("py360convert")
        img = cv2.imread(str(real_data / fname))[..., ::-1].astype(np.float32) / 255
        for u, v, fov in [
            (0, 0, 90),
            (30, 20, 90),
            (-100, -40, 60),
            (179, 0, 90),
            (-170, 60, 100),
            (45, 85, 90),
            (0, -80, 75),
        ]:
            ref = py360convert.e2p(img, fov_deg=(fov, fov), u_deg=u, v_deg=v, out_hw=(256, 256), mode="bilinear")
            cam = centred_camera(lonlat_to_direction(np.radians(u), np.radians(v)), 256, fov)
            K = cam.K.copy()
            K[0, 0] = K[1, 1] = 255 / (2 * math.tan(math.radians(fov) / 2))
            cam = PinholeCamera(K, cam.viewmat, 256, 256)
            ours = erp_to_perspective(img, cam)
            mad = np.abs(ours - ref).mean()
            assert mad <= 1 / 255, f"{fname} u={u} v={v}: mean abs difference {mad * 255:.3f}/255"
