"""The 2D mip filter (``rasterize(..., antialiased=True)``, gsplat's antialiased mode): the compensation from the
conics against the determinants of the covariances themselves, the analytic single Gaussian, the cpu backend
against the torch reference (values and gradients), and what it is for: a sub-pixel Gaussian fades with its
size instead of covering the low-pass's 0.3 px^2."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.splat.rasterize import antialias_compensation, cpu_backend, rasterize

from .test_rasterize import camera, scene

EPS2D = 0.3


def compensation_reference(cov: torch.Tensor, eps2d: float) -> torch.Tensor:
    """sqrt(det S / det(S + eps2d I)) of covariances [..., 2, 2], 0 where det S <= 0: the definition."""
    eye = torch.eye(2, dtype=cov.dtype)
    ratio = torch.linalg.det(cov) / torch.linalg.det(cov + eps2d * eye)
    return torch.sqrt(ratio.clamp(min=0))


def conics_of(cov: torch.Tensor, eps2d: float) -> torch.Tensor:
    """(a, b, c) of (S + eps2d I)^-1, as the projection returns them."""
    inv = torch.linalg.inv(cov + eps2d * torch.eye(2, dtype=cov.dtype))
    return torch.stack([inv[..., 0, 0], inv[..., 0, 1], inv[..., 1, 1]], -1)


def covariances(log_sx, log_sy, theta):
    sx, sy = torch.exp(log_sx), torch.exp(log_sy)
    c, s = torch.cos(theta), torch.sin(theta)
    R = torch.stack([torch.stack([c, -s], -1), torch.stack([s, c], -1)], -2)
    D = torch.diag_embed(torch.stack([sx * sx, sy * sy], -1))
    return R @ D @ R.transpose(-1, -2)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-6.0, 5.0),  # log standard deviations in pixels: 0.0025 px to 150 px
    st.floats(-6.0, 5.0),
    st.floats(0.0, math.pi),
)
def test_compensation_from_the_conic_is_the_ratio_of_determinants(log_sx, log_sy, theta):
    cov = covariances(*(torch.tensor(v, dtype=torch.float64) for v in (log_sx, log_sy, theta)))
    got = antialias_compensation(conics_of(cov, EPS2D), EPS2D)
    torch.testing.assert_close(got, compensation_reference(cov, EPS2D), atol=1e-9, rtol=1e-7)
    assert 0 <= float(got) <= 1


def test_compensation_gradients_match_the_determinants():
    g = torch.Generator().manual_seed(0)
    params = [torch.randn(32, generator=g, dtype=torch.float64) for _ in range(3)]
    params[0] = params[0] * 2  # sizes from ~0.02 px to ~50 px
    outs = []
    for fn in (
        lambda cov: antialias_compensation(conics_of(cov, EPS2D), EPS2D),
        lambda cov: compensation_reference(cov, EPS2D),
    ):
        leaves = [p.clone().requires_grad_(True) for p in params]
        (fn(covariances(*leaves)) * torch.linspace(0.5, 2, 32, dtype=torch.float64)).sum().backward()
        outs.append([p.grad for p in leaves])
    for a, b in zip(*outs):
        torch.testing.assert_close(a, b, atol=1e-9, rtol=1e-6)
    conics = conics_of(covariances(*params), EPS2D).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda q: antialias_compensation(q, EPS2D), (conics,), eps=1e-7, atol=1e-6)


def test_a_degenerate_covariance_is_invisible_and_its_gradient_finite():
    """A 2D covariance flat along one axis (det S = 0, a Gaussian seen edge-on) fades to nothing: in float32 the
    ratio cancels to ~1e-7, a compensation of ~3e-4 at most."""
    conics = torch.tensor([[1 / EPS2D, 0.0, 1 / (EPS2D + 1.0)], [1 / EPS2D, 0.0, 1 / EPS2D]], requires_grad=True)
    rho = antialias_compensation(conics, EPS2D)
    assert (rho < 1e-3).all()
    rho.sum().backward()
    assert torch.isfinite(conics.grad).all()


@pytest.mark.parametrize("backend", ["torch", "cpu"])
def test_a_single_gaussian_is_the_analytic_compensated_gaussian(backend):
    if backend == "cpu" and not cpu_backend.available():
        pytest.skip("the C++ rasterizer could not be built here")
    dtype = torch.float64 if backend == "torch" else torch.float32
    V, K = camera(64, 64, dtype)
    s, z, o = 0.016, 4.0, 0.8  # 0.22 px: smaller than the low-pass
    _, alpha, _, _ = rasterize(
        torch.tensor([[z, 0.0, 0.0]], dtype=dtype),
        torch.tensor([[1.0, 0, 0, 0]], dtype=dtype),
        torch.full((1, 3), s, dtype=dtype),
        torch.tensor([o], dtype=dtype),
        torch.ones(1, 3, dtype=dtype),
        V,
        K,
        64,
        64,
        backend=backend,
        antialiased=True,
    )
    var = (K[0, 0, 0].item() * s / z) ** 2
    jj, ii = np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5)
    expect = o * var / (var + EPS2D) * np.exp(-0.5 * ((jj - 32) ** 2 + (ii - 32) ** 2) / (var + EPS2D))
    expect[expect < 1 / 255] = 0
    np.testing.assert_allclose(alpha[0, ..., 0].numpy(), expect, atol=1e-6 if backend == "cpu" else 1e-12)


def _coverage(size_px: float, antialiased: bool) -> float:
    """Summed alpha (px^2) of one Gaussian of opacity 0.9 and standard deviation ``size_px`` at the centre."""
    V, K = camera(64, 64)
    z = 4.0
    s = size_px * z / K[0, 0, 0].item()
    _, alpha, _, _ = rasterize(
        torch.tensor([[z, 0.0, 0.0]], dtype=torch.float64),
        torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64),
        torch.full((1, 3), s, dtype=torch.float64),
        torch.tensor([0.9], dtype=torch.float64),
        torch.ones(1, 3, dtype=torch.float64),
        V,
        K,
        64,
        64,
        backend="torch",
        antialiased=antialiased,
    )
    return float(alpha.sum())


def test_a_sub_pixel_gaussian_fades_with_its_size_instead_of_covering_the_low_pass():
    """Classic dilation: a Gaussian of any size covers at least o 2 pi 0.3 px^2 (the low-pass); with the mip
    filter an isotropic one's peak is p = o v / (v + 0.3) and its coverage 2 pi (v + 0.3) (p - 1/255), its own
    o 2 pi v less the tail under 1/255: it falls with its variance v; both agree for large ones."""
    sizes = (0.15, 0.25, 0.4)
    classic = [_coverage(s, False) for s in sizes]
    floor = 0.9 * 2 * math.pi * EPS2D
    assert all(c > 0.9 * floor for c in classic)
    for s in sizes:
        v = s * s
        peak = 0.9 * v / (v + EPS2D)
        assert _coverage(s, True) == pytest.approx(2 * math.pi * (v + EPS2D) * (peak - 1 / 255), rel=0.05)
    assert _coverage(0.15, True) < 0.1 * classic[0]
    assert _coverage(6.0, True) == pytest.approx(_coverage(6.0, False), rel=0.01)


@pytest.mark.skipif(not cpu_backend.available(), reason="needs the cpu backend")
def test_cpu_matches_the_torch_reference_values_and_gradients_antialiased():
    V, K = camera(48, 40, torch.float32)
    V = torch.cat([V, V.flip(1)])  # two cameras: per-camera opacities
    K = torch.cat([K, K])
    base = [t.float() for t in scene(40, seed=3)]
    base[2] = base[2] * 0.1  # many sub-pixel Gaussians, where the filter acts
    out = {}
    for backend in ("torch", "cpu"):
        leaves = [t.clone().requires_grad_(True) for t in base]
        img, alpha, depth, _ = rasterize(*leaves, V, K, 48, 40, backend=backend, antialiased=True)
        (img.square().sum() + alpha.sum() + 0.1 * depth.sum()).backward()
        out[backend] = [img.detach(), alpha.detach(), depth.detach()] + [t.grad for t in leaves]
    for a, b in zip(out["cpu"], out["torch"]):
        scale = b.abs().max().clamp_min(1.0)
        torch.testing.assert_close(a / scale, b / scale, atol=2e-4, rtol=1e-3)


def test_gradcheck_float64_antialiased():
    V, K = camera(16, 12)
    means, quats, scales, opac, colors = scene(4, seed=1)
    scales = scales * 0.2
    inputs = [t.clone().requires_grad_(True) for t in (means, quats, scales, opac, colors)]

    def f(m, q, s, o, c):
        img, alpha, depth, _ = rasterize(m, q, s, o, c, V, K, 16, 12, backend="torch", antialiased=True)
        return img.sum() + 0.3 * alpha.square().sum() + 0.1 * depth.sum()

    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)
