"""The trainer on a device: what metrics.json records, no host reads in the step loop, non-finite losses still
caught; and (marked ``cuda``) training on a GPU against the CPU, checkpoints across devices, gsplat + adaptive."""

import json

import numpy as np
import pytest
import torch

from panorecon.geometry import erp_directions
from panorecon.scenes import Scene
from panorecon.sources import run_source
from panorecon.splat import trainer as trainer_mod
from panorecon.splat.ply import load_ply
from panorecon.splat.rasterize import gsplat_backend
from panorecon.splat.trainer import TrainConfig, train
from panorecon.teachers import get_teacher

needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
needs_gsplat = pytest.mark.skipif(not gsplat_backend.available(), reason="needs CUDA and gsplat")


def box_room(width: int = 128) -> Scene:
    """A box room in closed form (ray distance to its walls, a 3D checker colour): a scene with true depth that
    needs no Open3D, so these tests run on GPU machines without it (no world: no held-out views)."""
    lo, hi = np.array([-3.0, -4.0, -1.6]), np.array([2.0, 3.5, 1.1])
    d = erp_directions(width // 2, width)
    with np.errstate(divide="ignore", invalid="ignore"):
        dist = np.where(d > 0, hi / d, np.where(d < 0, lo / d, np.inf)).min(-1)
    p = d * dist[..., None]
    checker = (np.floor(p * 2).sum(-1) % 2)[..., None]
    rgb = (255 * (0.25 + 0.5 * checker * np.array([0.9, 0.6, 0.3]) + 0.2 * (p - lo) / (hi - lo))).clip(0, 255)
    return Scene(
        "box-room",
        "synthetic",
        "analytic box room",
        rgb.astype(np.uint8),
        dist.astype(np.float32),
        np.zeros(dist.shape, bool),
        distance_kind="truth",
    )


@pytest.fixture(scope="module")
def setup():
    scene = box_room()
    pc, _ = run_source(scene, "fibonacci", "sim:clean")
    teacher = get_teacher("sim:clean")
    depth_fn = lambda cams: [v.depth for v in teacher.predict_views(scene, cams)]  # noqa: E731
    return scene, pc.subset(slice(None, None, 4)), depth_fn


def cfg(**kw):
    base = dict(
        iters=30, res=32, labels=12, heldout=2, checkpoint_every=20, history_every=10, sh_degree=1, sh_increase_every=15
    )
    base.update(kw)
    return TrainConfig(**base)


def test_metrics_record_the_device(setup, tmp_path):
    scene, pc, depth_fn = setup
    m = train(scene, pc, cfg(iters=2), tmp_path, depth_fn, progress=False, device="cpu")
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["device"] == m["device"] == "cpu" and isinstance(saved["device_name"], str)
    assert saved["peak_gpu_memory_mb"].startswith("n/a")


SYNC_METHODS = ("item", "tolist", "__bool__", "__float__", "__int__", "__index__")


@pytest.mark.parametrize("strategy", ["default", "adaptive"])
def test_the_step_loop_reads_nothing_back_between_history_steps(setup, tmp_path, monkeypatch, strategy):
    """Counts every tensor -> Python read (item, float(), int(), bool(), ...) between consecutive steps' loss
    calls: zero except after steps that record history or checkpoint (multiples of 10 and 20 here)."""
    scene, pc, depth_fn = setup
    reads, at_loss = {"n": 0}, []
    for name in SYNC_METHODS:
        real = getattr(torch.Tensor, name)

        def counted(self, *a, _real=real, **k):
            reads["n"] += 1
            return _real(self, *a, **k)

        monkeypatch.setattr(torch.Tensor, name, counted)
    real_loss = trainer_mod.total_loss

    def loss(*a, **k):
        at_loss.append(reads["n"])
        return real_loss(*a, **k)

    monkeypatch.setattr(trainer_mod, "total_loss", loss)
    train(scene, pc, cfg(strategy=strategy), tmp_path, depth_fn, progress=False, device="cpu")
    between = np.diff(at_loss)  # between[k - 1]: reads after step k's loss, up to step k + 1's
    steps = np.arange(1, len(between) + 1)
    quiet = between[(steps % 10 != 0)]
    assert len(quiet) == 27 and quiet.max() == 0, dict(zip(steps.tolist(), between.tolist()))
    assert between[steps % 10 == 0].min() > 0  # the history reads are seen: the counter works


def test_a_non_finite_loss_is_caught_with_its_iteration(setup, tmp_path, monkeypatch):
    scene, pc, depth_fn = setup
    real, calls = trainer_mod.total_loss, {"n": 0}

    def nan_from_7(*a, **k):
        calls["n"] += 1
        out = real(*a, **k)
        return out * float("nan") if calls["n"] >= 7 else out

    monkeypatch.setattr(trainer_mod, "total_loss", nan_from_7)
    with pytest.raises(FloatingPointError, match="iteration 6"):
        train(scene, pc, cfg(), tmp_path, depth_fn, progress=False, device="cpu")
    assert calls["n"] == 10  # caught at the first step that reads back (history at 10), not later
    assert not (tmp_path / "ckpt.pt").exists()  # nothing non-finite was checkpointed


@pytest.mark.cuda
@needs_cuda
@pytest.mark.parametrize("backend", ["torch", "gsplat"])
def test_cuda_training_matches_the_cpu_at_its_first_steps(setup, tmp_path, backend):
    if backend == "gsplat" and not gsplat_backend.available():
        pytest.skip("needs gsplat")
    scene, pc, depth_fn = setup
    c = cfg(iters=5, history_every=1, checkpoint_every=0, backend="auto" if backend == "gsplat" else backend)
    cpu = train(
        scene,
        pc,
        cfg(iters=5, history_every=1, checkpoint_every=0, backend="torch"),
        tmp_path / "cpu",
        depth_fn,
        progress=False,
        device="cpu",
    )
    gpu = train(scene, pc, c, tmp_path / "gpu", depth_fn, progress=False, device="cuda")
    assert gpu["backend"] == backend and gpu["device"].startswith("cuda") and gpu["peak_gpu_memory_mb"] > 0
    for a, b in zip(cpu["history"], gpu["history"]):
        assert a["psnr"] == pytest.approx(b["psnr"], abs=0.05)
    pa, pb = load_ply(tmp_path / "cpu" / "point_cloud.ply"), load_ply(tmp_path / "gpu" / "point_cloud.ply")
    # Adam moves each coordinate by about its learning rate per step whatever the gradient's size: 5 steps bound it
    torch.testing.assert_close(pa.means, pb.means, atol=1e-3, rtol=0)


@pytest.mark.cuda
@needs_cuda
def test_a_cuda_checkpoint_resumes_on_the_cpu(setup, tmp_path, monkeypatch):
    scene, pc, depth_fn = setup
    c = cfg(backend="torch")
    real, calls = trainer_mod.total_loss, {"n": 0}

    def interrupt(*a, **k):
        calls["n"] += 1
        if calls["n"] == 25:  # after the checkpoint at 20
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(trainer_mod, "total_loss", interrupt)
    with pytest.raises(KeyboardInterrupt):
        train(scene, pc, c, tmp_path, depth_fn, progress=False, device="cuda")
    monkeypatch.setattr(trainer_mod, "total_loss", real)
    assert (tmp_path / "ckpt.pt").exists()
    m = train(scene, pc, c, tmp_path, depth_fn, progress=False, device="cpu")
    assert m["device"] == "cpu" and m["iterations"] == 30 and np.isfinite(m["pseudo-label"]["psnr"])


@pytest.mark.cuda
@needs_gsplat
def test_the_adaptive_strategy_trains_on_gsplat(setup, tmp_path):
    scene, pc, depth_fn = setup
    c = cfg(iters=60, strategy="adaptive", backend="gsplat")
    m = train(scene, pc, c, tmp_path, depth_fn, progress=False, device="cuda")
    assert m["backend"] == "gsplat" and m["strategy"] == "adaptive" and np.isfinite(m["pseudo-label"]["psnr"])
