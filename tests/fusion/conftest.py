"""Analytic scenes for fusion tests: a box room whose ray distance is known in closed form."""

import numpy as np
import pytest

from panorecon.geometry import ViewDepth, centred_camera, erp_directions, make_layout

BOX_LO = np.array([-3.0, -4.0, -1.6])
BOX_HI = np.array([2.0, 3.5, 1.1])


def box_distance(d: np.ndarray, lo=BOX_LO, hi=BOX_HI) -> np.ndarray:
    """Ray distance from the origin to the inside of the box [lo, hi] along unit directions [..., 3]."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(d > 0, hi / d, np.where(d < 0, lo / d, np.inf))
    return t.min(-1)


def make_views(layout, size, rng, noise=0.0, scale=(0.7, 1.4), field=box_distance):
    views = []
    for f in layout.directions:
        cam = centred_camera(f, size, layout.fov_deg)
        d = field(cam.world_rays())
        z = d / cam.z_to_distance_factor() * rng.uniform(*scale) * (1 + noise * rng.standard_normal(d.shape))
        views.append(ViewDepth(cam, z.astype(np.float32), "z", np.isfinite(z)))
    return views


@pytest.fixture
def box_truth():
    def truth(h):
        return box_distance(erp_directions(h, 2 * h))

    return truth


@pytest.fixture
def fib20():
    return make_layout("fibonacci", 20)
