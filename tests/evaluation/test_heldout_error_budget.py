"""eval/heldout_error_budget.py on a short run: its mean PSNR is the trainer's held-out PSNR (same views, same
frame), shares are fractions, and removing a share's error can only raise the PSNR."""

import importlib.util
from pathlib import Path

import pytest

from panorecon.scenes import load_scene
from panorecon.sources import cloud_scale, run_source
from panorecon.splat.trainer import TrainConfig, train

spec = importlib.util.spec_from_file_location(
    "heldout_error_budget", Path(__file__).parents[2] / "eval" / "heldout_error_budget.py"
)
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("budget")
    scene = load_scene("bedroom", 128)
    pc, report = run_source(scene, "fibonacci", "sim:relative")
    cfg = TrainConfig(iters=30, res=32, labels=16, heldout=4, checkpoint_every=0, history_every=0, backend="cpu")
    metrics = train(scene, pc, cfg, out, progress=False, device="cpu", heldout_scale=cloud_scale(report))
    return out, metrics


def test_budget_reads_the_trainers_heldout_views(run):
    out, metrics = run
    budget = script.main([str(out), "--scene", "bedroom", "--width", "128"])
    assert len(budget["views"]) == 4
    assert budget["psnr"] == pytest.approx(metrics["held-out"]["psnr"], abs=1e-3)
    for key in ("hole_error_share", "depth_off_error_share"):
        assert 0 <= budget[key] <= 1
    assert budget["psnr_without_hole_error"] >= budget["psnr"]
    assert budget["psnr_without_depth_off_error"] >= budget["psnr"]
    assert any(v["depth_off_pixels"] > 0 for v in budget["views"])  # 30 steps at 32² leave geometry to fix


def test_as_trained_reads_the_trainers_gap(run):
    out, metrics = run
    budget = script.main([str(out), "--scene", "bedroom", "--width", "128"])
    held, as_trained = metrics["held-out"], budget["swaps"]["as trained"]
    for key in ("psnr", "covisible_psnr", "oracle_psnr", "oracle_gap"):
        assert as_trained[key] == pytest.approx(held[key], abs=1e-3), key
    assert set(budget["swaps"]) == set(script.SWAPS)
    # the oracle is the scene's, whatever is swapped in the model
    assert len({round(s["oracle_psnr"], 9) for s in budget["swaps"].values()}) == 1


def _model(means, scales, quats=None):
    import torch

    from panorecon.splat.model import GaussianModel

    n = len(means)
    q = torch.tensor([[1.0, 0, 0, 0]] * n) if quats is None else torch.as_tensor(quats, dtype=torch.float32)
    return GaussianModel(
        torch.as_tensor(means, dtype=torch.float32),
        q,
        torch.log(torch.as_tensor(scales, dtype=torch.float32)),
        torch.zeros(n),
        torch.rand(n, 1, 3),
        torch.rand(n, 15, 3),
    )


def test_clamp_keeps_what_the_centre_sees_and_thins_the_depth():
    import numpy as np
    from scipy.spatial.transform import Rotation

    from panorecon.splat.model import covariances, from_covariances

    rng = np.random.default_rng(0)
    n = 64
    means = rng.normal(size=(n, 3)) * 3
    quats = Rotation.random(n, random_state=1).as_quat()[:, [3, 0, 1, 2]]
    m = _model(means, rng.uniform(0.01, 0.5, (n, 3)), quats)
    cov = covariances(m)
    q, ls = from_covariances(cov)  # the round trip the clamp goes through
    np.testing.assert_allclose(covariances(_model(means, np.exp(ls), q)), cov, atol=1e-6)
    c = script.clamp_along_ray(m)
    cov2 = covariances(c)
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    P = np.eye(3) - np.einsum("ni,nj->nij", u, u)
    np.testing.assert_allclose(P @ cov2 @ P, P @ cov @ P, atol=1e-6)  # across the ray: unchanged
    s_min = np.exp(m.log_scales.detach().double().numpy()).min(1)
    radial = np.einsum("ni,nij,nj->n", u, cov2, u)
    assert (radial <= s_min**2 * (1 + 1e-4)).all()  # along the ray: no deeper than the thinnest axis
    was = np.einsum("ni,nij,nj->n", u, cov, u)
    np.testing.assert_allclose(radial, np.minimum(was, s_min**2), rtol=1e-4)


def test_snap_and_floaters_follow_the_true_distance():
    import numpy as np

    from panorecon.scenes import load_scene

    scene = load_scene("bedroom", 128)
    rng = np.random.default_rng(2)
    u = rng.normal(size=(50, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    scale = 2.0  # the cloud is the truth / 2
    truth = script._true_distance(scene, u, scale)
    assert np.isfinite(truth).all()  # a room: every ray meets a wall
    r = truth * rng.choice([0.5, 0.9, 1.0, 1.2], size=50)
    m = _model(u * r[:, None], np.full((50, 3), 0.02))
    snapped = script.snap_to_surface(m, scene, scale)
    got = snapped.means.detach().double().numpy()
    np.testing.assert_allclose(np.linalg.norm(got, axis=1), truth, rtol=1e-5)
    np.testing.assert_allclose(got / np.linalg.norm(got, axis=1, keepdims=True), u, atol=1e-6)
    np.testing.assert_allclose(np.exp(snapped.log_scales.detach().double().numpy())[:, 0], 0.02 * truth / r, rtol=1e-5)
    half = script.snap_to_surface(m, scene, scale, keep=0.5).means.detach().double().numpy()
    np.testing.assert_allclose(np.linalg.norm(half, axis=1), (truth + r) / 2, rtol=1e-5)
    kept = script.remove_floaters(m, scene, scale)
    assert (
        len(kept) == int((r >= (1 - script.FLOATER_REL) * truth).sum()) == int((r / truth > 0.99).sum())
    )  # 0.5, 0.9 gone


def test_pixel_classes_partition_the_covisible_pixels_and_the_gap_is_read_per_class(run):
    out, metrics = run
    budget = script.main([str(out), "--scene", "bedroom", "--width", "128"])
    classes = budget["classes"]
    names = ("near a depth edge", "textured", "smooth")
    assert sum(classes[n]["pixel_share"] for n in names) == pytest.approx(1.0)
    assert sum(classes[n]["error_share"] for n in names) == pytest.approx(1.0)
    for n in names:
        if classes[n]["pixel_share"]:
            assert classes[n]["gap"] == pytest.approx(classes[n]["oracle_psnr"] - classes[n]["psnr"])
    assert 0 <= classes["distance_ratio_near_1"] <= 1
    views = script.heldout_views(load_scene("bedroom", 128), metrics)
    for v in views:
        masks = list(script.pixel_classes(v).values())
        assert (sum(m.astype(int) for m in masks) == v.covisible.astype(int)).all()  # disjoint, covering


def test_distance_ratio_of_a_camera_moved_towards_a_wall():
    """A camera 0.5 m along +x looking at a wall at x = 2 sees its centre 1.5 m away, 2 m from the panorama
    centre: ratio 0.75; a camera at the centre reads 1 everywhere."""
    import numpy as np

    from panorecon.geometry import centred_camera
    from panorecon.splat.labels import LabelView

    for position, expect in (((0.5, 0.0, 0.0), 0.75), ((0.0, 0.0, 0.0), 1.0)):
        cam = centred_camera(np.array([1.0, 0, 0]), 9, 60.0, position)
        z = np.full((9, 9), 2.0 - position[0], np.float32)  # a wall at x = 2: the same z-depth at every pixel
        ratio = script.distance_ratio(LabelView(cam, np.zeros((9, 9, 3), np.float32), z))
        assert ratio[4, 4] == pytest.approx(expect, rel=1e-6)
        if expect == 1.0:
            np.testing.assert_allclose(ratio, 1.0, rtol=1e-6)


def test_surface_offset_of_points_on_and_off_the_true_surface():
    import numpy as np

    from panorecon.geometry import erp_directions

    scene = load_scene("bedroom", 128)
    d = erp_directions(64, 128).reshape(-1, 3)
    t = script._true_distance(scene, d, 1.0)
    ok = np.isfinite(t)
    on = d[ok] * t[ok, None]
    exact = script.surface_offset(on, np.ones(len(on)), scene, 1.0)
    assert exact["median"] < 1e-5 and exact["share_off"] == 0
    off = script.surface_offset(on * 1.1, np.ones(len(on)), scene, 1.0)
    assert off["median"] == pytest.approx(0.1, rel=1e-4) and off["share_off"] == 1.0
    # in the cloud's frame: truth = scale x cloud
    assert script.surface_offset(on / 2.0, np.ones(len(on)), scene, 2.0)["median"] < 1e-5


def test_surface_offset_reads_the_starting_cloud_when_the_run_has_it(run, tmp_path):
    import shutil

    from panorecon.sources import run_source

    out, _ = run
    budget = script.main([str(out), "--scene", "bedroom", "--width", "128"])
    assert budget["surface_offset"]["initial cloud"].startswith("n/a")
    assert 0 <= budget["surface_offset"]["trained"]["median"] < 1
    copy = tmp_path / "run"
    shutil.copytree(out, copy)
    pc, _ = run_source(load_scene("bedroom", 128), "fibonacci", "sim:relative")
    pc.save_ply(copy / "fibonacci_cloud.ply")
    cloud = script.main([str(copy), "--scene", "bedroom", "--width", "128"])["surface_offset"]["initial cloud"]
    assert 0 <= cloud["median"] < 0.05 and cloud["points"] > 0


def test_an_antialiased_run_is_read_as_it_was_trained(tmp_path):
    """The budget renders a run with the 2D mip filter when the run trained with it: its 'as trained' reading is
    the trainer's own held-out score."""
    scene = load_scene("bedroom", 128)
    pc, report = run_source(scene, "fibonacci", "sim:relative")
    cfg = TrainConfig(
        iters=20, res=24, label_res=32, labels=12, heldout=3, checkpoint_every=0, history_every=0, antialiased=True
    )
    metrics = train(scene, pc, cfg, tmp_path, progress=False, device="cpu", heldout_scale=cloud_scale(report))
    as_trained = script.main([str(tmp_path), "--scene", "bedroom", "--width", "128"])["swaps"]["as trained"]
    for key in ("psnr", "oracle_gap"):
        assert as_trained[key] == pytest.approx(metrics["held-out"][key], abs=1e-3), key


def test_true_normals_of_a_room_are_its_walls_and_floor():
    """bedroom is built of boxes and quads: the normals of its ERP are axis-aligned almost everywhere (a wrong
    cross product or a swapped difference leaves them oblique)."""
    import numpy as np

    from panorecon.geometry import erp_normals

    n = erp_normals(load_scene("bedroom", 128).distance)
    finite = np.isfinite(n).all(-1)
    assert finite.mean() > 0.8
    np.testing.assert_allclose(np.linalg.norm(n[finite], axis=-1), 1.0, atol=1e-5)
    assert (np.abs(n[finite]).max(-1) > 0.99).mean() > 0.85


def test_flatten_keeps_what_the_centre_sees_and_lays_each_gaussian_on_the_true_surface():
    import numpy as np
    from scipy.spatial.transform import Rotation

    from panorecon.geometry import erp_normals, sample_erp
    from panorecon.splat.model import covariances

    scene = load_scene("bedroom", 128)
    rng = np.random.default_rng(3)
    u = rng.normal(size=(200, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    scale = 2.0
    means = u * script._true_distance(scene, u, scale)[:, None]
    quats = Rotation.random(200, random_state=4).as_quat()[:, [3, 0, 1, 2]]
    m = _model(means, rng.uniform(0.005, 0.05, (200, 3)), quats)
    normals = sample_erp(erp_normals(scene.distance), u, "nearest").astype(np.float64)
    cos = np.abs(np.einsum("ni,ni->n", np.nan_to_num(normals), u))
    flat = np.isfinite(normals).all(1) & (cos >= 0.2)
    assert 0.5 < flat.mean() < 1  # most lie on a surface seen squarely enough; some are left as they are
    cov, cov2 = covariances(m), covariances(script.flatten_onto_surface(m, scene, scale, thickness=0))
    P = np.eye(3) - np.einsum("ni,nj->nij", u, u)
    np.testing.assert_allclose(P @ cov2 @ P, P @ cov @ P, atol=1e-7)  # across the centre's ray: as before
    thin = np.einsum("ni,nij,nj->n", normals[flat], cov2[flat], normals[flat])
    assert (thin < 1e-6 * np.linalg.eigvalsh(cov2[flat])[:, -1]).all()  # nothing left along the true normal
    np.testing.assert_allclose(cov2[~flat], cov[~flat], atol=1e-7)
    thick = covariances(script.flatten_onto_surface(m, scene, scale, thickness=0.1))
    ratio = np.einsum("ni,nij,nj->n", normals[flat], thick[flat], normals[flat]) / (
        np.trace(cov2[flat], axis1=1, axis2=2) / 2
    )
    np.testing.assert_allclose(ratio, 0.01, rtol=1e-3)


def test_by_distance_draws_the_same_views_nearer_the_centre(run):
    out, metrics = run
    scene = load_scene("bedroom", 128)
    rows = script.by_distance(out, scene)
    assert [tuple(r["radius"]) for r in rows] == list(script.DISTANCE_BANDS)
    trained = script.read_run(out, scene)["swaps"]["as trained"]
    for key in ("psnr", "oracle_gap"):  # the last band is the trainer's own held-out draw
        assert rows[-1][key] == pytest.approx(trained[key], abs=1e-9)
    assert rows[0]["oracle_psnr"] != pytest.approx(rows[-1]["oracle_psnr"])


def test_true_offcentre_views_are_true_renders_elsewhere_in_the_cloud_frame():
    import numpy as np

    from panorecon.splat.labels import make_heldout_views

    scene = load_scene("bedroom", 128)
    views = script.true_offcentre_views(scene, 2.0)(scene.rgb, None, 3, 16, 60.0, 0.7, 5)
    truth = make_heldout_views(scene, 3, 16, 60.0, 5 + script.TRUTH_SEED_OFFSET)
    heldout = make_heldout_views(scene, 3, 16, 60.0, 5)
    assert script.true_offcentre_views(scene, 2.0)(scene.rgb, None, 0, 16, 60.0, 0.7, 5) == []
    for v, t, h in zip(views, truth, heldout):
        np.testing.assert_allclose(v.camera.position, t.camera.position / 2.0, atol=1e-12)
        assert not np.allclose(t.camera.position, h.camera.position)  # never the held-out views themselves
        np.testing.assert_array_equal(v.rgb, t.rgb)
        assert v.mask.all() and v.depth is None and v.oracle is None


def test_truth_views_trains_with_the_true_views_in_place_of_the_warped_ones(tmp_path, monkeypatch):
    import panorecon.splat.trainer as trainer

    def refuse(rgb, point_cloud, n, *args):
        assert n == 0, "the warped off-centre labels were asked for: the true views did not reach the trainer"
        return []

    monkeypatch.setattr(trainer, "offcentre_labels", refuse)
    args = ["--width", "128", "--res", "32", "--labels", "8", "--iters", "6", "--heldout", "2", "--views", "4"]
    out = script.truth_views([str(tmp_path), "--scene", "bedroom", *args])
    assert set(out["rows"]) == {0, 4}
    assert (tmp_path / "truth_views.json").is_file()
    assert out["rows"][4]["psnr"] != out["rows"][0]["psnr"]  # the four true views changed the training
