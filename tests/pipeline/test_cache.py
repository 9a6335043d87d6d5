import json

from panorecon.pipeline import Row, StageCache, code_digest, run_points, stage_key


def test_stage_key_depends_on_params_upstream_and_code():
    k = stage_key("points", {"a": 1}, (), ("geometry",))
    assert k == stage_key("points", {"a": 1}, (), ("geometry",))
    assert k != stage_key("points", {"a": 2}, (), ("geometry",))
    assert k != stage_key("points", {"a": 1}, ("up",), ("geometry",))
    assert k != stage_key("points", {"a": 1}, (), ("fusion",))
    assert code_digest(("geometry",)) != code_digest(("fusion",))


def test_rows_share_the_points_stage_but_not_training():
    a = Row("bedroom", 64, "fibonacci", "sim:clean", train={"iters": 5})
    b = Row("bedroom", 64, "fibonacci", "sim:clean", train={"iters": 6})
    assert a.points_key() == b.points_key() and a.train_key() != b.train_key()
    # a source that uses no teacher shares its points whatever the teacher (which only feeds training)
    r1, r2 = Row("bedroom", 64, "random", "sim:clean"), Row("bedroom", 64, "random", "sim:relative")
    assert r1.points_key() == r2.points_key()


def test_points_stage_is_computed_once_and_an_unfinished_folder_is_redone(tmp_path):
    cache = StageCache(tmp_path)
    row = Row("bedroom", 64, "fibonacci", "sim:clean")
    first = run_points(cache, row)
    assert not first["cached"] and first["points"] > 0
    again = run_points(cache, row)
    assert again["cached"] and again["report"] == json.loads(json.dumps(first["report"]))
    (cache.folder("points", row.points_key()) / "done.json").unlink()  # as if interrupted before finishing
    assert not run_points(cache, row)["cached"]


def test_finished_stage_records_content_hashes_and_a_corrupt_entry_is_recomputed_with_a_warning(tmp_path, caplog):
    from panorecon.geometry import PointCloud

    cache = StageCache(tmp_path)
    row = Row("bedroom", 64, "fibonacci", "sim:clean")
    first = run_points(cache, row)
    folder = cache.folder("points", row.points_key())
    assert set(first["files"]) == {"cloud.ply", "report.json"}
    cloud = (folder / "cloud.ply").read_bytes()
    # a cut-off cloud.ply (the case: trained on and reported as a normal row) is found and recomputed
    (folder / "cloud.ply").write_bytes(cloud[: len(cloud) // 3])
    with caplog.at_level("WARNING", logger="panorecon.cache"):
        again = run_points(cache, row)
    assert not again["cached"] and str(folder) in caplog.text and "cloud.ply" in caplog.text
    assert (folder / "cloud.ply").read_bytes() == cloud
    assert len(PointCloud.load_ply(folder / "cloud.ply")) == first["points"]
    # a cut done.json is a warning naming it, not a JSONDecodeError
    text = (folder / "done.json").read_text()
    for broken in (
        text[: len(text) // 2],
        json.dumps({"stage": "points", "key": "other", "files": {}}),
        json.dumps({k: v for k, v in json.loads(text).items() if k != "files"}),
    ):
        (folder / "done.json").write_text(broken)
        caplog.clear()
        with caplog.at_level("WARNING", logger="panorecon.cache"):
            assert cache.done("points", row.points_key()) is None
        assert "done.json" in caplog.text or "content hashes" in caplog.text
        assert not (folder / "done.json").exists()
    (folder / "report.json").unlink()
    assert not run_points(cache, row)["cached"] and run_points(cache, row)["cached"]


def test_the_stage_lock_is_exclusive_between_holders(tmp_path):
    import threading
    import time

    cache = StageCache(tmp_path)
    order = []

    def hold(name, seconds):
        with cache.lock("points", "k"):
            order.append(f"{name} in")
            time.sleep(seconds)
            order.append(f"{name} out")

    a = threading.Thread(target=hold, args=("a", 0.3))
    a.start()
    time.sleep(0.1)
    hold("b", 0)
    a.join()
    assert order == ["a in", "a out", "b in", "b out"]


def test_two_processes_on_one_cache_compute_a_stage_once(tmp_path):
    from concurrent.futures import ProcessPoolExecutor
    from multiprocessing import get_context

    row = Row("bedroom", 64, "fibonacci", "sim:clean")
    with ProcessPoolExecutor(2, mp_context=get_context("spawn")) as pool:
        results = list(pool.map(run_points, [StageCache(tmp_path)] * 2, [row] * 2))
    assert sorted(r["cached"] for r in results) == [False, True]
    assert results[0]["report"] == results[1]["report"]


def test_teacher_views_are_computed_once_per_scene_and_cameras(tmp_path, monkeypatch):
    """teacher_depth_fn with a cache folder: a second call (a later training with the same labels) reads the
    stored maps without loading the teacher; other cameras or another teacher compute again."""
    import numpy as np

    from panorecon.geometry import centred_camera
    from panorecon.pipeline import teacher_depth_fn
    from panorecon.scenes import load_scene
    from panorecon.teachers.sim import SimTeacher

    scene = load_scene("bedroom", 128)
    cams = [centred_camera(np.array(f, float), 24, 70.0) for f in ([1, 0, 0], [0, 1, 0])]
    calls = []
    real = SimTeacher.predict_views
    monkeypatch.setattr(SimTeacher, "predict_views", lambda self, s, c: calls.append(len(c)) or real(self, s, c))
    first = teacher_depth_fn(scene, "sim:relative", tmp_path)(cams)
    again = teacher_depth_fn(scene, "sim:relative", tmp_path)(cams)
    assert calls == [2] and len(list(tmp_path.glob("*.npz"))) == 1
    for a, b in zip(first, again):
        assert a.dtype == np.float32 and a.shape == (24, 24)
        np.testing.assert_array_equal(a, b)
    teacher_depth_fn(scene, "sim:relative", tmp_path)(cams[:1])
    teacher_depth_fn(scene, "sim:clean", tmp_path)(cams)
    assert calls == [2, 1, 2] and len(list(tmp_path.glob("*.npz"))) == 3
    uncached = teacher_depth_fn(scene, "sim:relative")(cams)
    np.testing.assert_array_equal(uncached[0], first[0])
