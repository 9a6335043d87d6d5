import dataclasses
import json
import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from panorecon.io import PanoreconInputError
from panorecon.metrics.lpips import lpips_or_reason
from panorecon.scenes import load_scene
from panorecon.sources import run_source
from panorecon.splat import evaluate as evaluate_mod
from panorecon.splat import trainer as trainer_mod
from panorecon.splat.initial import points_for_resolution
from panorecon.splat.model import GaussianModel
from panorecon.splat.ply import load_ply
from panorecon.splat.rasterize import resolve_backend
from panorecon.splat.strategy import DefaultStrategy, edit_parameters
from panorecon.splat.trainer import LABEL_ORDERS, TrainConfig, fill_join_step, label_order, train
from panorecon.teachers import get_teacher


@pytest.fixture(scope="module")
def setup():
    scene = load_scene("bedroom", 128)
    pc, _ = run_source(scene, "fibonacci", "sim:clean")
    teacher = get_teacher("sim:clean")
    depth_fn = lambda cams: [v.depth for v in teacher.predict_views(scene, cams)]  # noqa: E731
    return scene, pc.subset(slice(None, None, 4)), depth_fn


def cfg(**kw):
    base = dict(
        iters=60, res=32, labels=24, heldout=2, checkpoint_every=20, history_every=20, sh_degree=1, sh_increase_every=30
    )
    base.update(kw)
    return TrainConfig(**base)


def test_training_improves_and_writes_outputs(setup, tmp_path):
    scene, pc, depth_fn = setup
    before = train(scene, pc, cfg(iters=1), tmp_path / "a", depth_fn, progress=False)
    after = train(scene, pc, cfg(), tmp_path / "b", depth_fn, progress=False)
    assert after["pseudo-label"]["psnr"] > before["pseudo-label"]["psnr"] + 2
    assert isinstance(after["held-out"]["psnr"], float)
    m = json.loads((tmp_path / "b" / "metrics.json").read_text())
    # beside the all-pixel headline: the co-visible pixels' PSNR, the reprojection oracle's and the gap, explained
    held = m["held-out"]
    assert held["oracle_gap"] == pytest.approx(held["oracle_psnr"] - held["covisible_psnr"])
    assert 0 < held["covisible_fraction"] < 1 and held["oracle_gap_views"] >= 1
    assert set(held["meaning"]) >= {"psnr", "covisible_psnr", "oracle_psnr", "oracle_gap", "covisible_fraction"}
    assert "meaning" not in m["pseudo-label"] and "oracle_gap" not in m["pseudo-label"]
    net = lpips_or_reason()  # a number where setup.sh converted the weights, else the reason, never a stand-in
    if isinstance(net, str):
        assert after["pseudo-label"]["lpips"] == net == m["pseudo-label"]["lpips"]
    else:
        assert 0 < after["pseudo-label"]["lpips"] < 1 and m["pseudo-label"]["lpips"] == after["pseudo-label"]["lpips"]
    assert {"seconds", "iterations", "gaussians", "peak_rss_mb", "history"} <= set(m)
    assert {"backend", "labels", "train", "eval", "total"} <= set(m["seconds"])
    assert sum(m["seconds"][k] for k in ("backend", "labels", "train", "eval")) <= m["seconds"]["total"]
    assert (tmp_path / "b" / "renders" / "label_0.png").is_file() and not (tmp_path / "b" / "ckpt.pt").exists()
    assert len(load_ply(tmp_path / "b" / "point_cloud.ply")) == after["gaussians"]
    # every history sample carries the training seconds so far and the held-out PSNR (quality against time)
    hist = m["history"]
    assert [h["iteration"] for h in hist] == [20, 40, 60]
    assert all(isinstance(h["heldout_psnr"], float) and h["heldout_psnr"] > 5 for h in hist)
    assert 0 < hist[0]["seconds"] < hist[1]["seconds"] < hist[2]["seconds"] <= m["seconds"]["train"] + 1e-6
    assert hist[-1]["heldout_psnr"] == pytest.approx(after["held-out"]["psnr"], abs=1e-4)
    best = max(hist, key=lambda h: h["heldout_psnr"])
    assert m["heldout_best"] == {k: best[k] for k in ("iteration", "seconds", "gaussians", "heldout_psnr")}
    assert trainer_mod.best_heldout([{"iteration": 1, "psnr": 3.0}]).startswith("n/a")
    late = [h["heldout_psnr"] for h in hist[1:]]  # iterations 40 and 60: past half of the last sample's 60
    assert m["heldout_plateau"] == pytest.approx(
        {
            "from_iteration": 40,
            "samples": 2,
            "mean": np.mean(late),
            "sd": np.std(late, ddof=1),
            "min": min(late),
            "max": max(late),
        }
    )
    assert trainer_mod.heldout_plateau(hist[:2]).startswith("n/a")  # 40 > 20 only: one sample past the half

    cams = json.loads((tmp_path / "b" / "cameras.json").read_text())
    assert len(cams["pseudo-label"]) == cfg().labels and len(cams["held-out"]) == cfg().heldout
    assert np.asarray(cams["held-out"][0]["viewmat"]).shape == (4, 4)


def test_every_source_trains_in_front_of_the_panorama_sky(tmp_path):
    """Outdoors the cloud has no sky points; the sky environment fills the sky in held-out views."""
    scene = load_scene("beach", 128)
    pc, _ = run_source(scene, "fibonacci", "sim:clean")
    c = dict(iters=1, res=32, labels=8, heldout=4, checkpoint_every=0, history_every=0, sh_degree=0)
    sky = train(scene, pc, TrainConfig(**c), tmp_path / "sky", progress=False)
    bare = train(scene, pc, TrainConfig(**c, sky="none"), tmp_path / "bare", progress=False)
    assert sky["held-out"]["psnr"] > bare["held-out"]["psnr"] + 1.0
    assert (tmp_path / "sky" / "sky.png").is_file() and not (tmp_path / "bare" / "sky.png").exists()
    with pytest.raises(ValueError, match="sky = .*expected one of panorama, none"):
        train(scene, pc, TrainConfig(**c, sky="blue"), tmp_path / "bad", progress=False)


@pytest.mark.parametrize(
    "field, value",
    [
        ("densify_until", 1.5),
        ("densify_until", -0.1),
        ("densify_from", -1),
        ("densify_from", 1.5),
        ("grad_threshold", 0.0),
        ("init_opacity", 1.0),
        ("init_opacity", 0.0),
        ("disocclusion_fill_deg", -1.0),
        ("disocclusion_fill_deg", float("nan")),
        ("disocclusion_fill_visits", -1.0),
        ("disocclusion_fill_visits", float("inf")),
        ("disocclusion_opacity", 0.0),
        ("w_depth", -0.1),
        ("w_depth", float("nan")),
        ("w_ssim", float("inf")),
        ("w_l1", -1.0),
    ],
)
def test_bad_trainer_settings_are_one_clear_error_before_anything_is_written(setup, tmp_path, field, value):
    scene, pc, _ = setup
    with pytest.raises(ValueError, match=f"{field} = "):
        train(scene, pc, TrainConfig(iters=1, res=16, labels=4, **{field: value}), tmp_path / "bad", progress=False)
    assert not (tmp_path / "bad").exists()


def test_the_initial_cloud_follows_the_training_resolution(setup, tmp_path):
    scene, pc, depth_fn = setup
    c = dict(
        iters=1,
        res=16,
        labels=4,
        heldout=0,
        checkpoint_every=0,
        history_every=0,
        sh_degree=0,
        init_pixels_per_point=4.0,
        init_detail=0.0,  # the label resolution everywhere
    )
    n = points_for_resolution(16, 60.0, 4.0)
    assert n < len(pc)
    assert train(scene, pc, TrainConfig(**c), tmp_path / "a", progress=False)["initial_gaussians"] == n
    by_content = train(scene, pc, TrainConfig(**{**c, "init_detail": 0.05}), tmp_path / "d", progress=False)
    assert by_content["initial_gaussians"] < n  # the bedroom's smooth walls need fewer
    assert by_content["initial_thinning"]["points"] == by_content["initial_gaussians"]
    early = {**c, "init_pixels_per_point": 0, "disocclusion_fill_visits": 0.0}  # the fill in the initial cloud
    kept = train(scene, pc, TrainConfig(**early), tmp_path / "b", progress=False)
    assert kept["disocclusion_points"] > 0  # the bedroom's furniture has depth edges
    assert kept["initial_gaussians"] == len(pc) + kept["disocclusion_points"]
    bare = TrainConfig(**{**early, "disocclusion_fill_deg": 0})
    m = train(scene, pc, bare, tmp_path / "c", progress=False)
    assert m["initial_gaussians"] == len(pc) and m["disocclusion_points"] == 0


def test_label_orders():
    """random: the run's generator's draws with replacement (the order every committed run took); shuffled: each
    pass of n steps a permutation of the n views, the last pass cut at iters."""
    drawn = label_order("random", 240, 3000, 7)
    assert np.array_equal(drawn, np.random.default_rng(7).integers(0, 240, size=3000))
    assert np.bincount(drawn[:240], minlength=240).max() > 1  # with replacement: some label twice in one pass
    passes = label_order("shuffled", 240, 3000, 7)
    assert len(passes) == 3000 and passes.dtype.kind == "i"
    for k in range(12):
        assert sorted(passes[240 * k : 240 * (k + 1)]) == list(range(240))
    assert set(passes[2880:]) <= set(range(240)) and len(set(passes[2880:])) == 120  # the 13th pass, cut
    assert not np.array_equal(passes[:240], passes[240:480])  # a new permutation each pass
    assert np.array_equal(passes, label_order("shuffled", 240, 3000, 7))  # the seed fixes it
    assert set(LABEL_ORDERS) == {"random", "shuffled"}
    with pytest.raises(ValueError, match="label_order 'sorted'"):
        label_order("sorted", 240, 10, 0)


def test_the_fill_joins_once_each_direction_has_been_seen_enough_and_short_runs_start_with_it():
    """15 visits (the default) of 60-degree views (each 4 asin(1/4) sr of the sphere): step 187; 40 visits: step
    498; at 300 steps 187 is past half the run, so the fill is in the initial cloud (step 0), as with visits 0."""
    assert fill_join_step(TrainConfig(iters=3000)) == math.ceil(15 * math.pi / math.asin(0.25)) == 187
    visits40 = dict(disocclusion_fill_visits=40.0)
    assert fill_join_step(TrainConfig(iters=3000, **visits40)) == math.ceil(40 * math.pi / math.asin(0.25)) == 498
    assert fill_join_step(TrainConfig(iters=997, **visits40)) == 498
    assert fill_join_step(TrainConfig(iters=996, **visits40)) == 0
    assert fill_join_step(TrainConfig(iters=375)) == 187 and fill_join_step(TrainConfig(iters=374)) == 0
    assert fill_join_step(TrainConfig(iters=300)) == 0
    assert fill_join_step(TrainConfig(iters=3000, disocclusion_fill_visits=0)) == 0
    wide = TrainConfig(iters=3000, fov_deg=90.0)  # a 90-degree view covers 4 asin(1/2) = 2.09 sr
    assert fill_join_step(wide) == math.ceil(15 * math.pi / math.asin(0.5))


def test_a_late_fill_joins_the_model_at_its_step_with_its_opacity(setup, tmp_path, monkeypatch):
    """Visits 0.8 of 24 steps joins at step 10 (no densification this early): the model grows by the fill's
    points there, the fill Gaussians start at disocclusion_opacity, and thinning thins the fill in proportion."""
    scene, pc, depth_fn = setup
    seen = []
    real = trainer_mod.edit_parameters

    def spy(model, opt, keep, new):
        seen.append((len(model), {k: v.detach().clone() for k, v in new.items()}))
        return real(model, opt, keep, new)

    monkeypatch.setattr(trainer_mod, "edit_parameters", spy)
    c = dict(iters=24, res=16, labels=4, heldout=0, checkpoint_every=0, history_every=5, sh_degree=0)
    c["disocclusion_fill_visits"] = 0.8
    late = TrainConfig(**c, init_pixels_per_point=0, disocclusion_opacity=0.7)
    assert fill_join_step(late) == 10
    m = train(scene, pc, late, tmp_path / "late", depth_fn, progress=False)
    n_fill = m["disocclusion_points"]
    assert n_fill > 0 and m["disocclusion_step"] == 10 and m["initial_gaussians"] == len(pc)
    sizes = {h["iteration"]: h["gaussians"] for h in m["history"]}
    assert sizes[5] == sizes[10] == len(pc) and sizes[15] == sizes[20] == len(pc) + n_fill
    ((before, new),) = seen
    assert before == len(pc) and len(new["means"]) == n_fill
    torch.testing.assert_close(torch.sigmoid(new["logit_opacities"]), torch.full((n_fill,), 0.7))
    thinned = train(scene, pc, TrainConfig(**c, init_pixels_per_point=4.0), tmp_path / "thin", progress=False)
    ratio = thinned["initial_gaussians"] / len(pc)
    assert thinned["disocclusion_points"] == max(1, round(n_fill * ratio))


def interrupt_training(monkeypatch, run, at_step: int = 45) -> None:
    """Run ``run()`` with the loss raising KeyboardInterrupt at step ``at_step`` (after a checkpoint)."""
    real, calls = trainer_mod.total_loss, {"n": 0}

    def interrupt(*a, **k):
        calls["n"] += 1
        if calls["n"] == at_step:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(trainer_mod, "total_loss", interrupt)
    with pytest.raises(KeyboardInterrupt):
        run()
    monkeypatch.setattr(trainer_mod, "total_loss", real)


def test_an_interrupted_run_resumes_to_the_same_state(setup, tmp_path, monkeypatch):
    scene, pc, depth_fn = setup
    full = train(scene, pc, cfg(), tmp_path / "full", depth_fn, progress=False)
    interrupt_training(monkeypatch, lambda: train(scene, pc, cfg(), tmp_path / "resumed", depth_fn, progress=False))
    assert (tmp_path / "resumed" / "ckpt.pt").exists()
    # a checkpoint written for other inputs (here: another teacher, another cloud) is refused, not resumed
    with pytest.raises(PanoreconInputError, match="different run.*teacher"):
        train(scene, pc, cfg(), tmp_path / "resumed", depth_fn, progress=False, inputs={"teacher": "sim:other"})
    with pytest.raises(PanoreconInputError, match="different run.*cloud"):
        train(scene, pc.subset(slice(1, None)), cfg(), tmp_path / "resumed", depth_fn, progress=False)
    resumed = train(scene, pc, cfg(), tmp_path / "resumed", depth_fn, progress=False)
    a, b = load_ply(tmp_path / "full" / "point_cloud.ply"), load_ply(tmp_path / "resumed" / "point_cloud.ply")
    for x, y in zip(a.parameters(), b.parameters()):
        torch.testing.assert_close(x, y, atol=1e-6, rtol=1e-5)
    assert resumed["pseudo-label"]["psnr"] == pytest.approx(full["pseudo-label"]["psnr"], abs=1e-4)


def test_the_footprint_filter_is_resumed_exactly_and_baked_into_the_ply(setup, tmp_path, monkeypatch):
    scene, pc, depth_fn = setup
    c = cfg(footprint_filter=0.5)
    saved = {}
    real_save = trainer_mod.save_ply
    monkeypatch.setattr(trainer_mod, "save_ply", lambda m, p: (saved.setdefault(str(p), m), real_save(m, p)))
    full = train(scene, pc, c, tmp_path / "full", depth_fn, progress=False)
    model = saved[str(tmp_path / "full" / "point_cloud.ply")]
    scales, opacities = model.rendered()
    assert (scales > model.scales()).all() and (opacities < model.opacities()).all()
    # the PLY holds the Gaussians as rendered: a 3DGS viewer (no filter) sees what was trained and scored
    ply = load_ply(tmp_path / "full" / "point_cloud.ply")
    torch.testing.assert_close(ply.scales(), scales.detach(), rtol=1e-5, atol=0)
    torch.testing.assert_close(ply.opacities(), opacities.detach(), rtol=1e-4, atol=1e-7)
    # the variances travel in the checkpoint (recomputed at the resume step, they would differ from the run's)
    interrupt_training(monkeypatch, lambda: train(scene, pc, c, tmp_path / "resumed", depth_fn, progress=False))
    resumed = train(scene, pc, c, tmp_path / "resumed", depth_fn, progress=False)
    b = load_ply(tmp_path / "resumed" / "point_cloud.ply")
    for x, y in zip(ply.parameters(), b.parameters()):
        torch.testing.assert_close(x, y, atol=1e-6, rtol=1e-5)
    assert resumed["pseudo-label"]["psnr"] == pytest.approx(full["pseudo-label"]["psnr"], abs=1e-4)
    assert full["pseudo-label"]["psnr"] != pytest.approx(
        train(scene, pc, cfg(), tmp_path / "off", depth_fn, progress=False)["pseudo-label"]["psnr"], abs=1e-3
    )


def test_strategy_clones_splits_prunes_and_keeps_adam_aligned():
    from panorecon.geometry import PointCloud

    pc = PointCloud(np.random.default_rng(0).normal(size=(6, 3)) + [3, 0, 0], np.full((6, 3), 0.5))
    model = GaussianModel.from_point_cloud(pc, sh_degree=1)
    with torch.no_grad():
        model.log_scales[:3] = np.log(0.001)  # small: cloned
        model.log_scales[3:] = np.log(1.0)  # large: split
        model.logit_opacities[5] = -10.0  # transparent: pruned
    from panorecon.splat.trainer import _adam

    opt = _adam(model, [(n, 1e-3) for n in ("means", "quats", "log_scales", "logit_opacities", "sh0", "shN")])
    (
        model.means.sum() + model.sh().sum() + model.opacities().sum() + model.scales().sum() + model.quats.sum()
    ).backward()
    opt.step()
    s = DefaultStrategy(refine_start=0, refine_every=1)
    s.grad_sum = torch.tensor([1.0, 1.0, 0.0, 1.0, 1.0, 0.0])
    s.count = torch.ones(6)
    out = s.step(model, opt, 1, extent=1.0)
    assert out == {"cloned": 2, "split": 2, "pruned": 1, "reset": False}
    # 6 - 2 split - 1 pruned + 2 clones + 2 x 2 split halves
    assert len(model) == 9
    for group in opt.param_groups:
        p = group["params"][0]
        assert p is getattr(model, group["name"]) and opt.state[p]["exp_avg"].shape == p.shape
    edit_parameters(model, opt, torch.ones(len(model), dtype=torch.bool))
    assert len(model) == 9
    before = model.means.detach().clone()
    model.means.sum().backward()
    opt.step()  # the (fused) optimizer takes the edited parameters and moments
    assert torch.isfinite(model.means).all() and not torch.equal(model.means, before)


def _stack_scene():
    """Gaussians along the camera's optical axis: a large opaque wall at 3 m, a tiny opaque detail in front of
    it at 2.5 m, and an internal Gaussian hidden 0.2 m behind the wall."""
    from panorecon.geometry import PointCloud

    xyz = np.array([[3.0, 0, 0], [2.5, 0.3, 0.2], [3.2, 0, 0]])
    model = GaussianModel.from_point_cloud(PointCloud(xyz, np.full((3, 3), 0.5)), sh_degree=0)
    with torch.no_grad():
        model.log_scales[:] = torch.log(torch.tensor([[0.01, 2.0, 2.0], [0.004, 0.004, 0.004], [0.01, 0.3, 0.3]]))
        model.logit_opacities[:] = 5.0
        model.quats[:] = torch.tensor([1.0, 0, 0, 0])
    return model


def _observe_views(strategy, model, n_views=6):
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
    from panorecon.splat.rasterize import rasterize

    K = torch.tensor(intrinsics_from_fov(64, 64, 60.0), dtype=torch.float32)[None]
    for k in range(n_views):
        eye = [0.0, 0.05 * k, 0.0]
        V = torch.tensor(look_at_viewmat(eye, [3.0, 0.05 * k, 0.0]), dtype=torch.float32)[None]
        img, alpha, depth, meta = rasterize(
            model.means,
            model.quats,
            model.scales(),
            model.opacities(),
            model.sh()[:, 0] * 0 + 0.5,
            V,
            K,
            64,
            64,
            return_contrib=True,
        )
        meta["means2d"].retain_grad()
        img.sum().backward()
        strategy.observe(model, meta, 64, 64)


def test_adaptive_strategy_prunes_hidden_gaussians_and_protects_surface_detail():
    from panorecon.splat.strategy import AdaptiveStrategy

    model = _stack_scene()
    opt = torch.optim.Adam(
        [
            {"params": [getattr(model, n)], "lr": 0.0, "name": n}
            for n in ("means", "quats", "log_scales", "logit_opacities", "sh0", "shN")
        ]
    )
    s = AdaptiveStrategy(
        refine_start=0,
        refine_stop=100,
        refine_every=10,
        grad_threshold=1e9,
        threshold_start=10.0,
        threshold_end=20.0,
        relax_fraction=0.5,
        reference_size=64,  # the views' own pixels
    )
    _observe_views(s, model)
    score = s.top_contrib.mean(1)
    at_256 = AdaptiveStrategy(reference_size=256)
    _observe_views(at_256, _stack_scene())
    torch.testing.assert_close(at_256.top_contrib.mean(1), score * 16)  # in pixels of a 256² view
    # the wall contributes thousands of pixels; the detail a few; the hidden one only what leaks through the wall
    assert score[0] > 1000 and score[1] < 5.0 and score[2] < 10.0
    assert s.trans_max[1] > 0.9 and s.trans_max[2] < 0.2  # < surface_transmittance 0.5
    assert s.threshold(40) == 0.0, "relaxation stage: no contribution pruning"
    assert 10.0 <= s.threshold(60) < s.threshold(150) <= 20.0
    out = s.step(model, opt, 150, extent=1.0)
    assert out["pruned"] == 1 and len(model) == 2
    # the internal Gaussian went; the wall and the surface detail (small footprint, high transmittance) stay
    np.testing.assert_allclose(model.means.detach().numpy()[:, 0], [3.0, 2.5], atol=1e-6)


def test_adaptive_strategy_in_the_relaxation_stage_prunes_nothing():
    from panorecon.splat.strategy import AdaptiveStrategy

    model = _stack_scene()
    opt = torch.optim.Adam(
        [
            {"params": [getattr(model, n)], "lr": 0.0, "name": n}
            for n in ("means", "quats", "log_scales", "logit_opacities", "sh0", "shN")
        ]
    )
    s = AdaptiveStrategy(
        refine_start=0, refine_stop=100, refine_every=10, grad_threshold=1e9, relax_fraction=0.5, reference_size=64
    )
    _observe_views(s, model)
    assert s.step(model, opt, 20, extent=1.0)["pruned"] == 0 and len(model) == 3


def test_adaptive_training_resumes_exactly(setup, tmp_path, monkeypatch):
    scene, pc, depth_fn = setup
    c = cfg(strategy="adaptive")
    full = train(scene, pc, c, tmp_path / "full", depth_fn, progress=False)
    assert full["strategy"] == "adaptive"
    interrupt_training(monkeypatch, lambda: train(scene, pc, c, tmp_path / "resumed", depth_fn, progress=False))
    train(scene, pc, c, tmp_path / "resumed", depth_fn, progress=False)
    a, b = load_ply(tmp_path / "full" / "point_cloud.ply"), load_ply(tmp_path / "resumed" / "point_cloud.ply")
    assert len(a) == len(b)
    for x, y in zip(a.parameters(), b.parameters()):
        torch.testing.assert_close(x, y, atol=1e-6, rtol=1e-5)


def test_held_out_views_are_judged_in_the_clouds_own_scale(setup, tmp_path):
    """A cloud known up to scale (the sim teachers' per-view scales) is judged in its own frame: moved into a
    cloud that is the truth / s, a held-out camera at position / s sees it as the true camera sees the truth
    (pinhole projection is scale-invariant), so the held-out score does not depend on the arbitrary scale."""
    from panorecon.geometry import PointCloud
    from panorecon.splat.labels import in_cloud_frame, make_heldout_views
    from panorecon.splat.rasterize import rasterize

    scene, pc, depth_fn = setup
    g = torch.Generator().manual_seed(0)
    n = 500
    means = torch.randn(n, 3, generator=g) * 1.5
    quats, scales = torch.randn(n, 4, generator=g), torch.rand(n, 3, generator=g) * 0.1 + 0.02
    opac, cols = torch.rand(n, generator=g) * 0.8 + 0.1, torch.rand(n, 3, generator=g)
    (v,) = make_heldout_views(scene, 1, 32)
    s = 2.5
    moved = in_cloud_frame(v, s)
    np.testing.assert_allclose(moved.camera.position, v.camera.position / s, atol=1e-12)

    def render(view, k):
        V = torch.tensor(view.camera.viewmat[None], dtype=torch.float32)
        K = torch.tensor(view.camera.K[None], dtype=torch.float32)
        return rasterize(means / k, quats, scales / k, opac, cols, V, K, 32, 32, backend="torch")[0]

    torch.testing.assert_close(render(moved, s), render(v, 1.0), atol=1e-5, rtol=1e-4)
    # the trainer: a cloud halved and told so scores (nearly) as the metric cloud; told nothing, it does not
    c = dict(iters=20, heldout=4, checkpoint_every=0, history_every=0, sh_degree=0, init_pixels_per_point=0)
    half = PointCloud(pc.xyz / 2, pc.rgb)
    full = train(scene, pc, cfg(**c), tmp_path / "full", depth_fn, progress=False)["held-out"]["psnr"]
    aligned = train(scene, half, cfg(**c), tmp_path / "a", depth_fn, progress=False, heldout_scale=2.0)
    blind = train(scene, half, cfg(**c), tmp_path / "b", depth_fn, progress=False)["held-out"]["psnr"]
    assert abs(aligned["held-out"]["psnr"] - full) < 0.3 and aligned["heldout_scale"] == 2.0
    assert blind < aligned["held-out"]["psnr"] - 0.1
    with pytest.raises(ValueError, match="heldout_scale"):
        train(scene, pc, cfg(**c), tmp_path / "bad", depth_fn, progress=False, heldout_scale=0.0)


def test_the_first_clone_or_split_is_at_densify_from(setup, tmp_path):
    """densify_from is the strategy's first refinement step (then every 100 steps): with a gradient threshold every
    visible Gaussian passes, the model first grows at the first multiple of 100 at or after densify_from."""
    scene, pc, depth_fn = setup
    for start, first_growth in ((100, 100), (150, 200)):
        c = cfg(iters=250, res=16, labels=8, heldout=0, history_every=50, checkpoint_every=0)
        c = dataclasses.replace(c, densify_from=start, densify_until=1.0, grad_threshold=1e-12)
        m = train(scene, pc, c, tmp_path / str(start), depth_fn, progress=False)
        counts = {h["iteration"]: h["gaussians"] for h in m["history"]}
        assert all(counts[i] == m["initial_gaussians"] for i in counts if i < first_growth), counts
        assert counts[first_growth] > m["initial_gaussians"], counts


def test_the_higher_sh_bands_stay_zero_until_the_active_degree_rises(setup, tmp_path):
    """Label cameras share the panorama centre, so by default (sh_increase_every = 0) only the DC band is fit and
    the PLY's higher bands are exact zeros; with the 3DGS schedule they are fit once the degree rises."""
    scene, pc, depth_fn = setup
    c = cfg(iters=40, res=16, labels=8, heldout=0, checkpoint_every=0, history_every=0)
    fixed = train(scene, pc, dataclasses.replace(c, sh_increase_every=0), tmp_path / "dc", depth_fn, progress=False)
    rising = train(scene, pc, dataclasses.replace(c, sh_increase_every=20), tmp_path / "up", depth_fn, progress=False)
    assert fixed["iterations"] == rising["iterations"] == 40
    assert TrainConfig().sh_increase_every == 0
    dc, up = load_ply(tmp_path / "dc" / "point_cloud.ply"), load_ply(tmp_path / "up" / "point_cloud.ply")
    assert dc.shN.shape[1] == up.shN.shape[1] == 3 and not dc.shN.any()
    assert up.shN.abs().amax() > 1e-4


def test_coarse_steps_render_at_half_resolution_then_full(setup, tmp_path, monkeypatch):
    """coarse_until: its fraction of the steps renders at res // 2 against area-averaged targets, the rest at res;
    the history's held-out samples are always at full resolution. Fractions outside [0, 1] are refused."""
    scene, pc, depth_fn = setup
    sizes = []
    real = evaluate_mod.rasterize  # the trainer's _render (splat/evaluate.py) calls it

    def spy(*a, **k):
        sizes.append((a[7], torch.is_grad_enabled()))
        return real(*a, **k)

    monkeypatch.setattr(evaluate_mod, "rasterize", spy)
    monkeypatch.setattr(trainer_mod, "COARSE_MIN_SIZE", 16)  # tiny labels stand for 256 px ones here
    m = train(scene, pc, cfg(iters=6, coarse_until=0.7, history_every=3), tmp_path / "c", depth_fn, progress=False)
    steps = [w for w, grad in sizes if grad]  # the training steps (the evaluation renders run without grad)
    assert steps == [16] * 4 + [32] * 2
    assert all(w == 32 for w, grad in sizes if not grad)
    assert [h["iteration"] for h in m["history"]] == [3, 6] and m["history"][0]["psnr"] > 5  # coarse target
    sizes.clear()
    train(scene, pc, cfg(iters=4, res=33, coarse_until=0.5), tmp_path / "odd", depth_fn, progress=False)
    assert [w for w, grad in sizes if grad] == [16, 16, 33, 33]
    sizes.clear()  # a half size under COARSE_MIN_SIZE: full size throughout
    train(scene, pc, cfg(iters=2, res=30, coarse_until=1.0), tmp_path / "small", depth_fn, progress=False)
    assert [w for w, grad in sizes if grad] == [30, 30]
    for bad in (dict(coarse_until=-0.1), dict(coarse_until=1.5)):
        with pytest.raises(ValueError, match="coarse_until = "):
            train(scene, pc, cfg(**bad), tmp_path / "bad", depth_fn, progress=False)


def test_a_half_resolution_render_is_the_2x2_mean_of_the_full_one():
    """The coarse steps' camera (K halved: pixel centres at i + 0.5) against the reference, the full-resolution
    render averaged 2x2: the same image to within the finer sampling's blur, and the same centroid; a K off by a
    quarter pixel (the convention with pixel centres at integers) moves it by that quarter pixel."""
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
    from panorecon.splat.rasterize import rasterize

    g = torch.Generator().manual_seed(0)
    n = 400
    means = torch.randn(n, 3, generator=g) * torch.tensor([0.6, 0.6, 0.2]) + torch.tensor([0.0, 0.0, 4.0])
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.15 + 0.15
    opac, cols = torch.rand(n, generator=g) * 0.5 + 0.3, torch.rand(n, 3, generator=g)
    V = torch.tensor(look_at_viewmat([0, 0, 0], [0, 0, 1]), dtype=torch.float32)[None]
    K = torch.tensor(intrinsics_from_fov(64, 64, 60.0), dtype=torch.float32)[None]

    def render(KK, size):
        return rasterize(means, quats, scales, opac, cols, V, KK, size, size, backend="torch")[0][0]

    def centroid(img):  # intensity-weighted pixel position (x, y), pixel centres at i + 0.5
        w = img.sum(-1)
        c = torch.arange(img.shape[0], dtype=torch.float32) + 0.5
        return torch.stack([(w * c[None, :]).sum(), (w * c[:, None]).sum()]) / w.sum()

    ref = F.avg_pool2d(render(K, 64).movedim(-1, 0)[None], 2)[0].movedim(0, -1)
    half = K * torch.tensor([[0.5], [0.5], [1.0]])
    shifted = half.clone()
    shifted[0, :2, 2] -= 0.25  # the convention with pixel centres at integers
    assert (render(half, 32) - ref).abs().mean() < 0.01  # the finer sampling's blur only
    assert (centroid(render(half, 32)) - centroid(ref)).abs().max() < 0.03  # in pixels of the half-size view
    assert (centroid(render(shifted, 32)) - centroid(ref)).abs().min() > 0.2


def test_labels_at_their_own_size_and_antialiased_rendering_reach_every_render(setup, tmp_path, monkeypatch):
    """label_res: the training steps and the pseudo-label evaluation render at the labels' size, the held-out views
    at res; antialiased: every render, trained or evaluated, takes the 2D mip filter."""
    scene, pc, depth_fn = setup
    calls = []
    real = evaluate_mod.rasterize

    def spy(*a, **k):
        calls.append((a[7], torch.is_grad_enabled(), k.get("antialiased")))
        return real(*a, **k)

    monkeypatch.setattr(evaluate_mod, "rasterize", spy)
    c = cfg(iters=4, res=16, label_res=24, labels=6, heldout=2, coarse_until=0, antialiased=True, history_every=0)
    m = train(scene, pc, c, tmp_path / "lr", depth_fn, progress=False)
    assert [w for w, grad, _ in calls if grad] == [24] * 4
    evaluated = [w for w, grad, _ in calls if not grad]
    assert evaluated.count(24) >= 6 and evaluated.count(16) >= 2 and set(evaluated) == {16, 24}
    assert all(aa is True for *_, aa in calls)
    assert m["config"]["label_res"] == 24 and np.isfinite(m["pseudo-label"]["psnr"])
    flat = dict(iters=1, labels=4, heldout=0, checkpoint_every=0, history_every=0, init_pixels_per_point=4.0)
    flat["init_detail"] = 0.0  # the label resolution everywhere: the cloud follows the labels' size, not res
    got = train(scene, pc, cfg(**flat, res=16, label_res=24), tmp_path / "n", progress=False)["initial_gaussians"]
    assert got == points_for_resolution(24, 60.0, 4.0) > points_for_resolution(16, 60.0, 4.0)
    with pytest.raises(ValueError, match="label_res"):
        cfg(label_res=-1)


def test_the_depth_weight_pulls_the_rendered_depth_toward_the_teachers(setup, tmp_path):
    """TrainConfig.w_depth reaches the loss: against a teacher whose depth maps are upside down (so the photometric
    terms disagree with it), a run with a strong depth weight renders depth that correlates with the teacher's
    more than a run without the term."""
    scene, pc, depth_fn = setup
    flipped = lambda cams: [np.ascontiguousarray(d[::-1]) for d in depth_fn(cams)]  # noqa: E731

    def correlation(w_depth: float) -> float:
        c = cfg(iters=40, res=16, labels=12, heldout=0, checkpoint_every=0, history_every=0, w_depth=w_depth)
        train(scene, pc, c, tmp_path / f"w{w_depth}", flipped, progress=False)
        model = load_ply(tmp_path / f"w{w_depth}" / "point_cloud.ply")
        views = trainer_mod.make_pseudo_labels(scene, c.labels, c.res, c.fov_deg, c.layout, flipped)
        rs = []
        with torch.no_grad():
            for v in views:
                _, alpha, depth, _ = trainer_mod._render(model, [v], c, 0, resolve_backend(c.backend, False))
                z = (depth / alpha.clamp_min(1e-6))[0, ..., 0].flatten().double()
                t = torch.from_numpy(v.depth).flatten().double()
                rs.append(float(torch.corrcoef(torch.stack([z, t]))[0, 1]))
        return float(np.mean(rs))

    without, strong = correlation(0.0), correlation(2.0)
    assert strong > without + 0.05, (without, strong)


def test_the_surface_anchor_holds_the_gaussians_on_the_clouds_surface(setup, tmp_path):
    """TrainConfig.w_anchor reaches the loss: after training, the Gaussians of a run with a strong anchor lie
    nearer the given cloud's surface along their rays (median |ln(r / D)|) than those of a run without it."""
    from panorecon.splat.regularisers import anchor_height, surface_anchor, surface_distances

    scene, pc, depth_fn = setup

    def off_surface(w_anchor: float) -> float:
        c = cfg(iters=150, res=16, labels=12, heldout=0, checkpoint_every=0, history_every=0, w_anchor=w_anchor)
        c = dataclasses.replace(c, lr_means=1.6e-2, lr_means_final=1.6e-3)  # moves enough in few steps
        train(scene, pc, c, tmp_path / f"a{w_anchor}", depth_fn, progress=False)
        means = load_ply(tmp_path / f"a{w_anchor}" / "point_cloud.ply").means.detach()
        surface = torch.from_numpy(surface_distances(pc.xyz, anchor_height(c.res, c.fov_deg)))
        return float(surface_anchor(means, surface))

    without, anchored = off_surface(0.0), off_surface(1000.0)
    assert anchored < 0.6 * without, (without, anchored)


def test_the_depth_spread_weight_reaches_the_loss(setup, tmp_path, monkeypatch):
    """TrainConfig.w_spread: each training step adds the spread of its own render (one more render, of z^2);
    with the weight 0 nothing extra is rendered."""
    scene, pc, depth_fn = setup
    calls = []
    real = trainer_mod.depth_spread

    def spy(*a):
        calls.append(a[0].shape)
        return real(*a)

    monkeypatch.setattr(trainer_mod, "depth_spread", spy)
    c = cfg(iters=3, res=16, labels=4, heldout=0, checkpoint_every=0, history_every=0)
    train(scene, pc, c, tmp_path / "none", depth_fn, progress=False)
    assert calls == []
    m = train(scene, pc, dataclasses.replace(c, w_spread=1.0), tmp_path / "on", depth_fn, progress=False)
    assert calls == [(1, 16, 16)] * 3 and np.isfinite(m["pseudo-label"]["psnr"])


@pytest.fixture(scope="module")
def psnr_at_scale(tmp_path_factory):
    """Pseudo-label PSNR of a short training on bedroom (128 px) given at its true size times ``s``: the true
    distance scaled (``scenes.stress.scaled``, same teacher errors), the same fusion and training."""
    from panorecon.scenes.stress import scaled

    base = load_scene("bedroom", 128)
    teacher = get_teacher("sim:clean")
    done = {}

    def run(s: float) -> float:
        if s not in done:
            scene = scaled(base, s)
            pc, rep = run_source(scene, "fibonacci", "sim:clean")
            depth_fn = lambda cams: [v.depth for v in teacher.predict_views(scene, cams)]  # noqa: E731
            out = tmp_path_factory.mktemp(f"scale{s:g}")
            m = train(scene, pc.subset(slice(None, None, 4)), cfg(heldout=0, iters=60), out, depth_fn, progress=False)
            done[s] = (m["pseudo-label"]["psnr"], rep["depth"]["abs_rel"])
        return done[s]

    return run


@pytest.mark.parametrize("s", [1e-3, 1e3], ids=["at_scale_1e-3", "at_scale_1e3"])
def test_training_gives_the_same_psnr_and_depth_error(psnr_at_scale, s):
    """A 5 mm room (every surface inside a fixed 0.01 m near plane) or a 5 km one trains as the 5 m room does."""
    psnr, abs_rel = psnr_at_scale(s)
    psnr1, abs_rel1 = psnr_at_scale(1.0)
    assert psnr1 > 15 and abs(psnr - psnr1) < 0.3
    assert abs_rel == pytest.approx(abs_rel1, rel=1e-3, abs=1e-5)


@pytest.mark.parametrize("s", [1e-9, 1e9], ids=["at_scale_1e-9", "at_scale_1e9"])
def test_a_scene_too_small_or_too_large_for_float32_is_refused_naming_its_median(setup, tmp_path, s):
    scene, pc, depth_fn = setup
    far = type(pc)(pc.xyz * s, pc.rgb)
    with pytest.raises(PanoreconInputError, match=r"median distance .* m is outside the 0.0001 to 1e\+07 m"):
        train(scene, far, cfg(), tmp_path / "x", depth_fn, progress=False)
    assert not (tmp_path / "x").exists()


def test_flatten_every_lays_the_saved_gaussians_on_the_clouds_surface(setup, tmp_path, monkeypatch):
    """TrainConfig.flatten_every: the trainer flattens every k steps and after the last, so the saved Gaussians
    are discs on the given cloud's surface (the normal's variance is the thickness term's); never with 0."""
    from panorecon.splat.model import covariances
    from panorecon.splat.regularisers import FLAT_THICKNESS, _erp_bins, flatten_height, surface_normals

    scene, pc, depth_fn = setup
    steps = []
    real = trainer_mod.flatten_onto_surface

    def counted(model, frames):
        steps.append(len(steps))
        return real(model, frames)

    monkeypatch.setattr(trainer_mod, "flatten_onto_surface", counted)
    c = cfg(iters=25, res=16, labels=12, heldout=0, checkpoint_every=0, history_every=0, flatten_every=10)
    m = train(scene, pc, c, tmp_path / "f", depth_fn, progress=False)
    assert len(steps) == 3  # after steps 10, 20 and the last, 25
    assert 0 < m["seconds"]["flatten"] < m["seconds"]["train"] and m["seconds"]["flatten_surface"] > 0
    assert "flatten" in m["meaning"]["seconds"]
    model = load_ply(tmp_path / "f" / "point_cloud.ply")
    normals = surface_normals(pc.xyz, flatten_height(len(pc.xyz), c.res, c.fov_deg))
    means = model.means.detach().double().numpy()
    u = means / np.linalg.norm(means, axis=1, keepdims=True)
    n = normals[_erp_bins(u, normals.shape[0])].astype(np.float64)
    flat = np.isfinite(n).all(1) & (np.abs(np.einsum("ni,ni->n", np.nan_to_num(n), u)) >= 0.2)
    assert flat.mean() > 0.5
    cov = covariances(model)[flat]
    along_n = np.einsum("ni,nij,nj->n", n[flat], cov, n[flat])
    in_plane = (np.trace(cov, axis1=1, axis2=2) - along_n) / 2
    np.testing.assert_allclose(along_n / in_plane, FLAT_THICKNESS**2, rtol=1e-2)
    steps.clear()
    c_off = dataclasses.replace(c, flatten_every=0, init_opacity_surface=0.0)  # nothing asks for the surface
    off = train(scene, pc, c_off, tmp_path / "g", depth_fn, progress=False)
    assert steps == [] and off["seconds"]["flatten"] == 0 and "flatten_surface" not in off["seconds"]


def test_a_cloud_without_a_surface_is_not_flattened_and_the_run_says_why(setup, tmp_path, monkeypatch):
    """Random points have no surface whose normals agree (normal_coherence < FLAT_MIN_COHERENCE): the trainer does
    not flatten them and metrics.json's skipped names the reason; with flatten_every = 0 it names that."""
    from panorecon.geometry import PointCloud

    scene, pc, depth_fn = setup
    g = np.random.default_rng(0)
    xyz = g.normal(size=(4000, 3)) * 2.0
    scattered = PointCloud(xyz.astype(np.float32), np.full((4000, 3), 128, np.uint8), None, None)
    calls = []
    monkeypatch.setattr(trainer_mod, "flatten_onto_surface", lambda model, normals: calls.append(1))
    c = cfg(iters=20, res=16, labels=12, heldout=0, checkpoint_every=0, history_every=0, flatten_every=10)
    metrics = train(scene, scattered, c, tmp_path / "r", depth_fn, progress=False)
    assert calls == [] and "no surface to flatten onto" in metrics["skipped"]["flatten"]
    metrics = train(scene, pc, c, tmp_path / "s", depth_fn, progress=False)
    assert calls == [1, 1] and "flatten" not in metrics["skipped"]
    off = train(scene, pc, dataclasses.replace(c, flatten_every=0), tmp_path / "t", depth_fn, progress=False)
    assert off["skipped"]["flatten"] == "flatten_every = 0"


def test_a_surface_starts_at_its_own_opacity_random_points_at_init_opacity(setup, tmp_path, monkeypatch):
    """init_opacity_surface applies where the given cloud's normals agree (a fused cloud), init_opacity where they
    do not (random points lie behind one another from the centre); 0 turns the rule off; metrics.json says which."""
    from panorecon.geometry import PointCloud

    scene, pc, depth_fn = setup
    xyz = np.random.default_rng(0).normal(size=(4000, 3)) * 2.0
    scattered = PointCloud(xyz.astype(np.float32), np.full((4000, 3), 128, np.uint8), None, None)
    started = []
    build = trainer_mod.GaussianModel.from_point_cloud

    def spy(cloud, sh_degree, init_opacity):
        started.append(init_opacity)
        return build(cloud, sh_degree, init_opacity)

    monkeypatch.setattr(trainer_mod.GaussianModel, "from_point_cloud", spy)
    c = cfg(iters=2, res=16, labels=4, heldout=0, checkpoint_every=0, history_every=0, disocclusion_fill_deg=0.0)
    assert (c.init_opacity, c.init_opacity_surface) == (0.1, 0.3)
    for cloud, surface_rule, want in ((pc, 0.3, 0.3), (scattered, 0.3, 0.1), (pc, 0.0, 0.1), (pc, 0.5, 0.5)):
        started.clear()
        run = dataclasses.replace(c, init_opacity_surface=surface_rule, flatten_every=0)
        m = train(scene, cloud, run, tmp_path / f"{len(cloud)}_{surface_rule}", depth_fn, progress=False)
        assert started == [want] and m["initial_opacity"] == want
    with pytest.raises(ValueError, match="init_opacity_surface = 1.0"):
        TrainConfig(init_opacity_surface=1.0)
