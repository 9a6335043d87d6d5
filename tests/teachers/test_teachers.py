import json

import numpy as np
import pytest

from panorecon.geometry import centred_camera, fibonacci_directions
from panorecon.io import PanoreconInputError
from panorecon.scenes import load_scene
from panorecon.teachers import get_teacher, list_teachers
from panorecon.teachers.base import true_view_distance


@pytest.fixture(scope="module")
def bedroom():
    return load_scene("bedroom", 256)


@pytest.fixture(scope="module")
def cams():
    return [centred_camera(f, 48, 80) for f in fibonacci_directions(6)]


def test_listed_and_named_sim(bedroom):
    specs = [s for s, _ in list_teachers()]
    assert {"sim:clean", "sim:relative", "sim:affine-disparity"} <= set(specs)
    assert all(s.startswith(("sim:", "onnx:", "file:", "hf:", "moge:", "  ")) for s in specs)  # "  ": output kinds
    with pytest.raises(PanoreconInputError, match="unknown simulated profile"):
        get_teacher("sim:depth-anything")
    with pytest.raises(PanoreconInputError, match="expected sim:"):
        get_teacher("midas")


def test_sim_is_deterministic_and_severity_increases(bedroom, cams):
    errs = []
    for name in ["clean", "relative", "affine-disparity", "network"]:
        t = get_teacher(f"sim:{name}")
        a, b = t.predict_views(bedroom, cams), t.predict_views(bedroom, cams)
        for x, y in zip(a, b):
            np.testing.assert_array_equal(x.depth, y.depth)
            assert not x.valid[~np.isfinite(x.depth)].any()
        # severity measured in inverse depth after a per-view least-squares affine fit (fair to all kinds)
        rel = []
        for v in a:
            d, _ = true_view_distance(bedroom, v.camera)
            z = d / v.camera.z_to_distance_factor()
            target = 1 / z if v.kind == "disparity" else z
            ok = v.valid
            A = np.stack([v.depth[ok], np.ones(ok.sum())], 1)
            coef = np.linalg.lstsq(A, target[ok], rcond=None)[0]
            rel.append(np.mean(np.abs(A @ coef - target[ok]) / target[ok]))
        errs.append(np.median(rel))
    assert errs[0] < errs[1] < errs[2] < errs[3], errs


class TestNetworkProfile:
    """sim:network: affine-disparity's errors plus errors that follow the view's content and framing."""

    def _z_and_sky(self, scene, cam):
        d, sky = true_view_distance(scene, cam)
        return d / cam.z_to_distance_factor(), sky

    def test_the_other_profiles_do_not_read_the_image(self, bedroom, cams):
        """Profiles without content or framing errors ignore the image and draw the same random numbers as
        before sim:network existed (the committed tables' sim: rows stay reproducible)."""
        from panorecon.teachers.sim import PROFILES, SimTeacher

        z, sky = self._z_and_sky(bedroom, cams[0])
        for name in ("clean", "relative", "affine-disparity"):
            t = SimTeacher(PROFILES[name], 0)
            assert not PROFILES[name].reads_image
            plain = t._corrupt(z, sky, t._rng("bedroom", 0))[0]
            given = t._corrupt(z, sky, t._rng("bedroom", 0), rgb=np.zeros((*z.shape, 3)))[0]
            np.testing.assert_array_equal(plain, given)

    def test_errors_follow_the_image(self, bedroom, cams):
        """The same depth under another image gives another output: the luminance is copied into the depth."""
        from panorecon.teachers.sim import PROFILES, SimTeacher

        t = SimTeacher(PROFILES["network"], 0)
        z, sky = self._z_and_sky(bedroom, cams[0])
        rng = np.random.default_rng(0)
        a = t._corrupt(z, sky, t._rng("bedroom", 0), rgb=rng.random((*z.shape, 3)))[0]
        b = t._corrupt(z, sky, t._rng("bedroom", 0), rgb=rng.random((*z.shape, 3)))[0]
        flat = t._corrupt(z, sky, t._rng("bedroom", 0), rgb=np.full((*z.shape, 3), 0.5))[0]
        ok = np.isfinite(a) & np.isfinite(b) & np.isfinite(flat)
        assert np.mean(np.abs(np.log(a[ok] / b[ok]))) > 0.01
        assert not np.allclose(a[ok], flat[ok])

    def test_the_same_depth_reads_otherwise_at_the_border(self):
        """A fronto-parallel wall (z constant) under a flat image: the output bends with the framing, by rho
        between the centre and the corners (in log depth, before the disparity's scale and shift)."""
        from panorecon.teachers.sim import PROFILES, SimTeacher

        p = PROFILES["network"]
        t = SimTeacher(p, 0)
        z = np.full((64, 64), 3.0)
        log_z = _network_log_depth(t, z)
        bend = log_z[0, 0] - log_z[32, 32]
        assert bend == pytest.approx(p.bend * 2.0, rel=0.05)

    def test_the_range_is_compressed_to_the_median(self):
        """Depth ratios within a view shrink to the power gamma."""
        from panorecon.teachers.sim import PROFILES, SimTeacher

        p = PROFILES["network"]
        t = SimTeacher(p, 0)
        z = np.tile(np.geomspace(1.0, 8.0, 64), (64, 1))
        log_z = _network_log_depth(t, z)
        centre = 32
        ratio = (log_z[centre, -1] - log_z[centre, 0]) / np.log(8.0)
        assert ratio == pytest.approx(p.compress, rel=0.05)


def _network_log_depth(t, z):
    """sim:network's content and framing errors alone (no warp, blur, noise, scale or shift), flat grey image."""
    from panorecon.teachers.sim import _content_and_framing

    return _content_and_framing(np.log(z), np.ones(z.shape, bool), np.full((*z.shape, 3), 0.5), t.profile, True)


def test_sky_is_never_valid():
    plaza = load_scene("city-plaza", 128)
    for v in get_teacher("sim:relative").predict_views(plaza, [centred_camera(np.array([0.3, 0.2, 0.6]), 32, 90)]):
        d, sky = true_view_distance(plaza, v.camera)
        assert sky.any() and not v.valid[sky].any()


def test_sim_needs_truth(real_data, cams):
    with pytest.raises(PanoreconInputError, match="has no true depth.*with --depth"):
        get_teacher("sim:clean").predict_views(load_scene("hohonet", 128), cams)


class TestFileTeacher:
    def test_hohonet_prediction_in_views_and_erp(self, real_data, cams):
        spec = f"file:{real_data / 'hohonet_pano.pred_depth_mm.png'}?scale=0.001"
        t = get_teacher(spec)
        scene = load_scene("hohonet", 256)
        erp = t.predict_erp(scene)
        assert erp.depth.shape == (128, 256) and np.nanmax(erp.depth) < 20
        views = t.predict_views(scene, cams)
        assert all(v.kind == "distance" and v.valid.mean() > 0.99 for v in views)
        # each view pixel holds the file's value (mm x 0.001) at the ERP pixel its ray falls in, read here directly
        import cv2

        from panorecon.geometry import direction_to_erp_pixel

        raw = cv2.imread(str(real_data / "hohonet_pano.pred_depth_mm.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)
        for v in views:
            r, c = direction_to_erp_pixel(v.camera.world_rays(), *raw.shape)
            rows = np.clip(np.rint(r).astype(int), 0, raw.shape[0] - 1)
            cols = np.rint(c).astype(int) % raw.shape[1]
            expected = raw[rows, cols] * 0.001
            ok = v.valid & (expected > 0)
            assert ok.mean() > 0.99
            np.testing.assert_allclose(v.depth[ok], expected[ok], rtol=1e-6)

    @pytest.mark.parametrize(
        "spec,needle",
        [
            ("file:/nope.png", "no such file"),
            ("file:x.png?scale=-1", "positive"),
            ("file:x.png?bogus=1", "unknown option"),
        ],
    )
    def test_bad_specs(self, spec, needle):
        with pytest.raises(PanoreconInputError, match=needle):
            get_teacher(spec)

    @pytest.mark.parametrize("fill", [0.0, np.nan, np.inf, -1.0], ids=["zero", "nan", "inf", "negative"])
    def test_a_map_with_no_valid_depth_is_one_input_error(self, tmp_path, fill):
        np.save(tmp_path / "d.npy", np.full((8, 16), fill, np.float32))
        with pytest.raises(PanoreconInputError, match="d.npy: holds no valid depth"):
            get_teacher(f"file:{tmp_path / 'd.npy'}")

    def test_an_empty_scale_is_refused_not_read_as_1(self, tmp_path):
        np.save(tmp_path / "d.npy", np.ones((8, 16), np.float32))
        with pytest.raises(PanoreconInputError, match="scale='' is not a number"):
            get_teacher(f"file:{tmp_path / 'd.npy'}?scale=")

    def test_npy_must_be_2_to_1(self, tmp_path):
        np.save(tmp_path / "d.npy", np.ones((10, 10), np.float32))
        with pytest.raises(PanoreconInputError, match="not an equirectangular"):
            get_teacher(f"file:{tmp_path / 'd.npy'}")


class TestOnnxTeacher:
    def _model(self, tmp_path, config):
        """A tiny ONNX net the test builds: output = 2 * mean over channels of the normalised input + 1."""
        onnx = pytest.importorskip("onnx")
        from onnx import TensorProto, helper

        x = helper.make_tensor_value_info("image", TensorProto.FLOAT, [1, 3, 8, 12])
        y = helper.make_tensor_value_info("depth", TensorProto.FLOAT, [1, 1, 8, 12])
        axes = helper.make_tensor("axes", TensorProto.INT64, [1], [1])
        two = helper.make_tensor("two", TensorProto.FLOAT, [], [2.0])
        one = helper.make_tensor("one", TensorProto.FLOAT, [], [1.0])
        nodes = [
            helper.make_node("ReduceMean", ["image", "axes"], ["m"], keepdims=1),
            helper.make_node("Mul", ["m", "two"], ["m2"]),
            helper.make_node("Add", ["m2", "one"], ["depth"]),
        ]
        graph = helper.make_graph(nodes, "tiny", [x], [y], initializer=[axes, two, one])
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
        model.ir_version = 9
        path = tmp_path / "tiny.onnx"
        onnx.save(model, path)
        (tmp_path / "tiny.json").write_text(json.dumps(config))
        return path

    def test_pre_and_post_processing(self, tmp_path, cams):
        pytest.importorskip("onnxruntime")
        path = self._model(
            tmp_path,
            {"input_size": [8, 12], "mean": [0.5, 0.5, 0.5], "std": [0.5, 0.5, 0.5], "output": "z", "mode": "relative"},
        )
        scene = load_scene("bedroom", 128)
        t = get_teacher(f"onnx:{path}")
        flat = np.full((16, 24, 3), 191, np.uint8)  # (0.749 - 0.5) / 0.5 = 0.498 -> 2 * 0.498 + 1
        np.testing.assert_allclose(t.run(flat), 1.996, atol=2e-3)
        assert t.run(flat).shape == (16, 24)
        views = t.predict_views(scene, cams[:2])
        assert views[0].depth.shape == (48, 48) and views[0].kind == "z" and not views[0].affine
        erp = t.predict_erp(scene)
        assert erp.kind == "distance" and erp.depth.shape == (64, 128)

    def test_config_errors(self, tmp_path):
        pytest.importorskip("onnxruntime")
        path = self._model(tmp_path, {"input_size": [8, 12], "output": "inverse", "mode": "relative"})
        with pytest.raises(PanoreconInputError, match="'output' must be one of"):
            get_teacher(f"onnx:{path}")
        (tmp_path / "tiny.json").unlink()
        with pytest.raises(PanoreconInputError, match="expected its config"):
            get_teacher(f"onnx:{path}")
        with pytest.raises(PanoreconInputError, match="no such ONNX"):
            get_teacher("onnx:/missing.onnx")


def test_fingerprint_follows_the_model_files(tmp_path):
    """Stage keys use teacher_fingerprint: a changed model folder or file recomputes; sim specs are unchanged."""
    from panorecon.pipeline import Row
    from panorecon.teachers import teacher_fingerprint

    assert teacher_fingerprint("sim:relative") == "sim:relative" and teacher_fingerprint(None) is None
    assert teacher_fingerprint("hf:no-such-org/no-such-model") == "hf:no-such-org/no-such-model"
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "config.json").write_text("{}")
    spec = f"hf:{tmp_path / 'm'}"
    first = teacher_fingerprint(spec)
    row = lambda: Row("bedroom", 128, "fibonacci", spec)  # noqa: E731
    keys = (row().points_key(), row().train_key())
    assert first.startswith(spec + "#") and teacher_fingerprint(spec) == first
    (tmp_path / "m" / "model.safetensors").write_bytes(b"weights")
    assert teacher_fingerprint(spec) != first
    assert row().points_key() != keys[0] and row().train_key() != keys[1]
    npy = tmp_path / "d.npy"
    np.save(npy, np.ones((4, 8), np.float32))
    before = teacher_fingerprint(f"file:{npy}?scale=2")
    np.save(npy, np.ones((8, 16), np.float32))
    assert teacher_fingerprint(f"file:{npy}?scale=2") != before


def test_fingerprint_is_the_same_on_a_fresh_copy(tmp_path):
    """A clone or a copy touches every file's modification time; the run identity of a table under an onnx:
    teacher must not move with it (the committed tables under learned teachers)."""
    import os

    from panorecon.teachers import teacher_fingerprint

    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "m.onnx").write_bytes(b"weights")
        (tmp_path / name / "m.json").write_text("{}")
    os.utime(tmp_path / "b" / "m.onnx", (1, 1))
    fa, fb = (teacher_fingerprint(f"onnx:{tmp_path / n / 'm.onnx'}") for n in ("a", "b"))
    assert fa.split("#")[1] == fb.split("#")[1]
    (tmp_path / "b" / "m.onnx").write_bytes(b"other weights")
    assert teacher_fingerprint(f"onnx:{tmp_path / 'b' / 'm.onnx'}").split("#")[1] != fa.split("#")[1]
