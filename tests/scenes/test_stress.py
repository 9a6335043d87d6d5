"""The stress scenes (scenes/stress.py): their depth ranges and edges are what their names say."""

import numpy as np
import pytest

from panorecon.scenes.stress import CASES, cliff, horizon, ramp, scaled, seam_jump


@pytest.mark.parametrize("ratio", [10.0, 1e4])
def test_a_cliff_jumps_by_its_ratio_between_the_front_and_back_halves(ratio):
    s = cliff(ratio, 128, near_m=0.5)
    d = s.distance.astype(np.float64)
    assert s.has_ground_truth and s.valid.all() and s.rgb.shape == (64, 128, 3)
    front, back = d[:, 32:96], np.concatenate([d[:, :32], d[:, 96:]], 1)
    assert front.min() == pytest.approx(0.5, rel=1e-3) and front.max() <= 0.5 * np.sqrt(3) * (1 + 1e-6)
    assert back.min() == pytest.approx(0.5 * ratio, rel=1e-3)
    jump = np.log(d[:, 32] / d[:, 31])  # across the edge at longitude -90 degrees
    np.testing.assert_allclose(jump, -np.log(ratio), atol=0.05)
    colour_step = np.abs(s.rgb[:, 32].astype(int) - s.rgb[:, 31].astype(int)).sum(-1)
    assert (colour_step > 100).all()  # the colour edge is where the depth edge is


def test_a_seam_jump_rises_with_longitude_and_jumps_by_its_ratio_across_the_seam():
    s = seam_jump(10.0, 128, near_m=0.5)
    d = s.distance.astype(np.float64)
    assert s.has_ground_truth and s.valid.all() and s.rgb.shape == (64, 128, 3)
    assert (d == d[:1]).all() and (np.diff(d, axis=1) > 0).all()  # the same in every row, rising left to right
    assert d[:, 0] == pytest.approx(0.5 * (1 + 9 * 0.5 / 128)) and d[:, -1] == pytest.approx(0.5 * (10 - 9 * 0.5 / 128))
    assert np.log(d[:, -1] / d[:, 0]) == pytest.approx(np.log(10.0), abs=0.1)  # across the seam, wrapping
    colour_step = np.abs(s.rgb[:, 0].astype(int) - s.rgb[:, -1].astype(int)).sum(-1)
    assert (colour_step > 50).all()  # the checker changes cell at the seam
    np.testing.assert_array_equal(CASES["seam-jump"](128).distance, seam_jump(10.0, 128).distance)


def test_a_ramp_and_a_horizon_span_their_decades_monotonically_in_latitude():
    cube = cliff(1.0, 128).distance[:, 0].astype(np.float64)  # ratio 1: the ramp's cube of half-size 1 m
    for s, decades, base in ((ramp(4.0, 128), 4.0, cube), (horizon(3.0, 128), 3.0, 1.0)):
        col = s.distance[:, 0].astype(np.float64) / base
        assert np.all(np.diff(col) <= 1e-6 * col[1:])  # rows run from the zenith down: distance falls
        assert np.log10(col.max() / col.min()) == pytest.approx(decades, abs=0.3)
        assert np.isfinite(s.distance).all()


def test_scaled_multiplies_every_distance_and_keeps_the_rest():
    s = CASES["cliff-1e2"](64)
    t = scaled(s, 1e-3)
    np.testing.assert_allclose(t.distance, s.distance * 1e-3, rtol=1e-6)
    assert np.array_equal(t.rgb, s.rgb) and t.name == s.name and t.meta["scaled"] == 1e-3 and t.has_ground_truth
    with pytest.raises(ValueError, match="factor"):
        scaled(s, 0.0)


@pytest.mark.parametrize(
    "build", [lambda: cliff(0.5), lambda: seam_jump(0.5), lambda: ramp(-1.0), lambda: horizon(2.0, height_m=0.0)]
)
def test_bad_parameters_are_refused(build):
    with pytest.raises(ValueError):
        build()
