"""The footprint filter (splat/footprint.py): the log-space fast path against the float64 covariance reference,
values and gradients; near-singular and huge Gaussians; the sampling variance against a per-camera loop; the
trainer's use of it (rendered, baked into the PLY, resumed exactly)."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.splat import footprint
from panorecon.splat.model import GaussianModel
from panorecon.splat.rasterize.projection import quat_to_rotmat


def _gaussians(n=64, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    quats = torch.randn(n, 4, generator=g, dtype=dtype)
    log_scales = torch.randn(n, 3, generator=g, dtype=dtype) * 2 - 3  # 1e-4 .. 10, anisotropic
    logits = torch.randn(n, generator=g, dtype=dtype)
    var = torch.rand(n, generator=g, dtype=dtype) * 1e-3 + 1e-6
    return quats, log_scales, logits, var


def _fast_covariance(quats, log_scales, logits, var, strength):
    scales, opac = footprint.filtered(log_scales, logits, var, strength)
    R = quat_to_rotmat(quats)
    return R @ torch.diag_embed(scales**2) @ R.transpose(-1, -2), opac


@pytest.mark.parametrize("strength", [0.2, 1.0, 7.5])
def test_the_fast_filter_is_the_covariance_sum_and_keeps_the_integral(strength):
    args = _gaussians()
    cov, opac = _fast_covariance(*args, strength)
    cov_ref, opac_ref = footprint.filtered_covariance(*args, strength)
    torch.testing.assert_close(cov, cov_ref, rtol=1e-10, atol=1e-14)
    torch.testing.assert_close(opac, opac_ref, rtol=1e-10, atol=1e-14)
    # the integral of opacity x Gaussian kernel, o sqrt(det cov), is what the filter keeps
    before = torch.sigmoid(args[2]) * torch.exp(args[1].sum(-1))
    torch.testing.assert_close(opac_ref * torch.sqrt(torch.linalg.det(cov_ref)), before, rtol=1e-10, atol=0)


def test_the_fast_filters_gradients_are_the_references():
    quats, log_scales, logits, var = (t.requires_grad_() for t in _gaussians(n=16, seed=1))
    w = torch.randn(16, 3, 3, dtype=torch.float64)
    u = torch.randn(16, dtype=torch.float64)

    def grads(fn):
        cov, opac = fn(quats, log_scales, logits, var, 0.7)
        return torch.autograd.grad((cov * w).sum() + (opac * u).sum(), (quats, log_scales, logits, var))

    for g, g_ref in zip(grads(_fast_covariance), grads(footprint.filtered_covariance)):
        torch.testing.assert_close(g, g_ref, rtol=1e-8, atol=1e-10)


def test_strength_zero_is_exactly_no_filter():
    _, log_scales, logits, var = _gaussians(dtype=torch.float32)
    scales, opac = footprint.filtered(log_scales, logits, var, 0.0)
    assert torch.equal(scales, torch.exp(log_scales)) and torch.equal(opac, torch.sigmoid(logits))


def test_near_singular_and_huge_gaussians_give_finite_values_and_gradients():
    # a scale of 1e-30 (its square underflows float32), 1e-3, and 1e15: float32, as the trainer runs it
    log_scales = torch.tensor([[-69.0, -69.0, -6.9], [-6.9, -6.9, -6.9], [34.5, 34.5, 34.5]], requires_grad=True)
    logits = torch.zeros(3, requires_grad=True)
    var = torch.full((3,), 1e-4)
    scales, opac = footprint.filtered(log_scales, logits, var, 1.0)
    (scales.sum() + opac.sum()).backward()
    for t in (scales, opac, log_scales.grad, logits.grad):
        assert torch.isfinite(t).all()
    scales, opac = scales.detach(), opac.detach()
    assert scales[0, 0].item() == pytest.approx(1e-2, rel=1e-5)  # the floor sqrt(v): a needle becomes a pixel
    assert opac[0].item() < 1e-30  # ... whose colour is spread thin: the integral kept
    assert scales[2, 0].item() == pytest.approx(math.exp(34.5), rel=1e-6)
    assert opac[2].item() == pytest.approx(0.5, rel=1e-6)


@settings(max_examples=60, deadline=None)
@given(
    log_s=st.lists(st.floats(-80.0, 80.0), min_size=3, max_size=3),
    logit=st.floats(-30.0, 30.0),
    log_v=st.floats(-150.0, 60.0),
    strength=st.floats(1e-3, 100.0),
)
def test_the_filter_never_shrinks_a_gaussian_nor_raises_its_opacity(log_s, logit, log_v, strength):
    log_scales = torch.tensor([log_s], dtype=torch.float32)
    var = torch.tensor([math.exp(log_v)], dtype=torch.float32)
    scales, opac = footprint.filtered(log_scales, torch.tensor([logit]), var, strength)
    raw = torch.exp(log_scales)
    assert torch.isfinite(scales).all() and torch.isfinite(opac).all()
    assert (scales >= raw * (1 - 1e-6)).all()
    assert opac[0] <= torch.sigmoid(torch.tensor(logit)) * (1 + 1e-6)


def _cameras(n=12, f=40.0, size=32, seed=0):
    """n pinhole cameras at the origin looking in random directions, and one 2 m off it."""
    rng = np.random.default_rng(seed)
    viewmats = []
    for k in range(n):
        z = rng.normal(size=3)
        z /= np.linalg.norm(z)
        x = np.cross([0.0, 0.0, 1.0], z)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z])  # rows: camera axes in the world
        t = -R @ (np.array([2.0, 0, 0]) if k == n - 1 else np.zeros(3))
        viewmats.append(np.block([[R, t[:, None]], [np.zeros((1, 3)), np.ones((1, 1))]]))
    K = np.array([[f, 0, size / 2], [0, f * 1.25, size / 2], [0, 0, 1]])
    return torch.tensor(np.array(viewmats), dtype=torch.float32), torch.tensor(np.array([K] * n), dtype=torch.float32)


def _slow_variance(means, viewmats, Ks, size, margin):
    out = []
    for p in means.double().numpy():
        best = math.inf
        for V, K in zip(viewmats.double().numpy(), Ks.double().numpy()):
            c = V[:3, :3] @ p + V[:3, 3]
            if c[2] <= 0:
                continue
            u, v = K[0, 0] * c[0] / c[2] + K[0, 2], K[1, 1] * c[1] / c[2] + K[1, 2]
            if abs(u - size / 2) <= margin * size / 2 and abs(v - size / 2) <= margin * size / 2:
                best = min(best, c[2] / min(K[0, 0], K[1, 1]))
        out.append(best**2)
    out = np.array(out)
    out[~np.isfinite(out)] = out[np.isfinite(out)].max()
    return out


def test_the_sampling_variance_is_the_finest_camera_that_sees_each_gaussian(monkeypatch):
    monkeypatch.setattr(footprint, "CHUNK", 50)  # several blocks
    viewmats, Ks = _cameras()
    means = torch.tensor(np.random.default_rng(1).normal(size=(300, 3)) * 3, dtype=torch.float32)
    fast = footprint.sampling_variance(means, viewmats, Ks, 32, 32)
    np.testing.assert_allclose(fast.numpy(), _slow_variance(means, viewmats, Ks, 32, footprint.MARGIN), rtol=1e-5)
    # one camera straight at a point d away: (d / f)^2, and the same scene at 1000x its size gives 10^6 x
    V = torch.eye(4)[None]
    K = torch.tensor([[[50.0, 0, 16], [0, 50.0, 16], [0, 0, 1]]])
    assert footprint.sampling_variance(torch.tensor([[0.0, 0, 5]]), V, K, 32, 32).item() == pytest.approx(0.01)
    big = viewmats.clone()
    big[:, :3, 3] *= 1000
    np.testing.assert_allclose(
        footprint.sampling_variance(means * 1000, big, Ks, 32, 32).numpy(), fast.numpy() * 1e6, rtol=1e-4
    )


def test_a_gaussian_no_camera_sees_takes_the_largest_variance_seen():
    V = torch.eye(4)[None]
    K = torch.tensor([[[50.0, 0, 16], [0, 50.0, 16], [0, 0, 1]]])
    var = footprint.sampling_variance(torch.tensor([[0.0, 0, 5], [0.0, 0, 10], [0.0, 0, -3]]), V, K, 32, 32)
    assert var.tolist() == pytest.approx([0.01, 0.04, 0.04])


def test_refresh_follows_the_models_size_and_the_step():
    viewmats, Ks = _cameras()
    model = GaussianModel(
        torch.randn(10, 3),
        torch.randn(10, 4),
        torch.zeros(10, 3),
        torch.zeros(10),
        torch.zeros(10, 1, 3),
        torch.zeros(10, 0, 3),
    )
    footprint.refresh(model, 0.2, viewmats, Ks, 32)
    first = model.footprint[0]
    assert model.footprint[1] == 0.2 and len(first) == 10
    with torch.no_grad():
        model.means.mul_(2)
    footprint.refresh(model, 0.2, viewmats, Ks, 32, step=150)
    assert model.footprint[0] is first  # between refreshes the variances stay
    footprint.refresh(model, 0.2, viewmats, Ks, 32, step=200)
    torch.testing.assert_close(model.footprint[0], first * 4)
    footprint.refresh(model, 0.0, viewmats, Ks, 32)
    assert model.footprint is None and torch.equal(model.rendered()[0], model.scales())
