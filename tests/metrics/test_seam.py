import numpy as np
import pytest

from panorecon.metrics.seam import seam_discontinuity


def test_a_periodic_image_has_no_seam_and_a_cut_one_does():
    x = np.linspace(0, 2 * np.pi, 256, endpoint=False)
    periodic = np.tile(np.sin(x) * 100 + 128, (64, 1))
    assert seam_discontinuity(periodic) == pytest.approx(1.0, rel=0.02)
    shifted = np.tile(np.sin(x * 0.8) * 100 + 128, (64, 1))  # not periodic: a jump at the wrap
    assert seam_discontinuity(shifted) > 10


def test_a_rolled_real_looking_image_moves_its_seam_inside():
    rng = np.random.default_rng(0)
    smooth = np.cumsum(rng.normal(size=(32, 200, 3)), axis=1)  # random walk along columns: no periodicity
    assert seam_discontinuity(smooth) > 3
    assert (
        seam_discontinuity(np.roll(smooth, 100, axis=1)) < 2
    )  # the wrap now joins two neighbouring columns of the walk


def test_too_narrow_is_refused():
    with pytest.raises(ValueError, match="expected"):
        seam_discontinuity(np.zeros((4, 10)), band=8)
