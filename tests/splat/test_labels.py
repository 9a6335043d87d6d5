import numpy as np
import pytest

from panorecon.scenes import load_scene
from panorecon.splat.labels import make_heldout_views, make_pseudo_labels
from panorecon.teachers import get_teacher


@pytest.fixture(scope="module")
def bedroom():
    return load_scene("bedroom", 256)


def test_pseudo_labels_are_views_of_the_panorama_with_teacher_depth(bedroom):
    teacher = get_teacher("sim:relative")
    labels = make_pseudo_labels(
        bedroom, 120, 32, 60.0, depth_fn=lambda cams: [v.depth for v in teacher.predict_views(bedroom, cams)]
    )
    assert len(labels) == 120
    fw = np.stack([lv.camera.forward for lv in labels])
    assert np.allclose(np.linalg.norm(fw, axis=1), 1) and np.abs(fw.mean(0)).max() < 0.05  # spread over the sphere
    lv = labels[7]
    assert lv.rgb.shape == (32, 32, 3) and 0 <= lv.rgb.min() and lv.rgb.max() <= 1
    # the label's colour is the true view's colour up to ERP resampling
    true = bedroom.world.render_view(lv.camera).rgb / 255.0
    assert np.abs(lv.rgb - true).mean() < 0.08
    assert lv.depth.shape == (32, 32) and np.isfinite(lv.depth).mean() > 0.9


def test_heldout_views_are_off_centre_true_renders(bedroom):
    views = make_heldout_views(bedroom, 4, 24, seed=3)
    r = bedroom.world.free_space_radius()
    for v in views:
        d = np.linalg.norm(v.camera.position)
        assert 0.3 * r - 1e-9 <= d <= 0.7 * r + 1e-9
        assert np.isfinite(v.depth).all() and v.rgb.shape == (24, 24, 3)
    a, b = make_heldout_views(bedroom, 2, 24, seed=3), make_heldout_views(bedroom, 2, 24, seed=3)
    np.testing.assert_array_equal(a[1].rgb, b[1].rgb)


def test_errors(real_data, bedroom):
    with pytest.raises(ValueError, match="ground-truth world"):
        make_heldout_views(load_scene("py360-demo", 64), 2, 16)
    with pytest.raises(ValueError, match="n_views"):
        make_pseudo_labels(bedroom, 0, 32)
