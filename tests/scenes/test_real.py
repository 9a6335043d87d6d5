import numpy as np
import pytest

from panorecon.geometry import erp_directions
from panorecon.io import PanoreconInputError
from panorecon.scenes import list_scenes, load_scene


def test_real_scenes_are_listed():
    real = {s.name: s for s in list_scenes() if s.kind == "real"}
    assert {"hohonet", "py360-demo"} <= set(real)
    assert not real["hohonet"].has_ground_truth


def test_hohonet_depth_is_predicted_ray_distance(real_data):
    s = load_scene("hohonet")
    assert s.rgb.shape == (512, 1024, 3) and s.distance_kind == "predicted" and not s.has_ground_truth
    d = s.distance
    assert np.isfinite(d).all() and 0.5 < d.min() and d.max() < 20
    # ray distance: the floor height d * sin(lat) is nearly constant below the horizon; read as horizontal
    # (cylindrical) distance, d * tan(lat) would spread far more. Measured: 0.14 vs 7.5 relative spread.
    lat = np.arcsin(erp_directions(512, 1024)[..., 2])
    floor = lat < np.radians(-70)
    as_ray = d[floor] * np.sin(lat[floor])
    as_horizontal = d[floor] * np.tan(lat[floor])
    spread_ray = np.std(as_ray) / abs(np.median(as_ray))
    assert spread_ray < 0.2
    assert spread_ray < 0.1 * np.std(as_horizontal) / abs(np.median(as_horizontal))


def test_resize_and_point_cloud(real_data):
    s = load_scene("hohonet", width=256)
    assert s.rgb.shape == (128, 256, 3) and s.distance.shape == (128, 256)
    pc = s.point_cloud()
    assert len(pc) == 128 * 256
    np.testing.assert_allclose(np.linalg.norm(pc.xyz, axis=1), s.distance.ravel(), rtol=1e-5)


def test_scene_without_depth(real_data):
    s = load_scene("py360-demo", width=64)
    assert s.distance is None and not s.valid.any()
    with pytest.raises(ValueError, match="no depth"):
        s.point_cloud()


@pytest.mark.parametrize("bad", ["no-such-scene", "missing.png"])
def test_unknown_scene_or_missing_file(bad):
    with pytest.raises(PanoreconInputError, match=bad.split(".")[0]):
        load_scene(bad)


@pytest.mark.parametrize("w", [3, 7, 20000])
def test_bad_width(w):
    with pytest.raises(PanoreconInputError, match="--width"):
        load_scene("py360-demo", w)


def test_a_depth_file_given_for_a_builtin_real_scene_is_truth(real_data):
    from panorecon.scenes.real import DepthSpec

    s = load_scene("hohonet", 128, DepthSpec(real_data / "hohonet_pano.pred_depth_mm.png", 1e-3))
    assert s.distance_kind == "truth" and s.has_ground_truth and s.distance.shape == (64, 128)
    assert load_scene("hohonet", 128).distance_kind == "predicted"
