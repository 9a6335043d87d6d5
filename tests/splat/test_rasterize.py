"""The pure-PyTorch reference rasterizer: analytic cases, the alpha cap, culling, gradcheck, SH."""

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
from panorecon.splat.rasterize import cpu_backend, project_gaussians, quat_to_rotmat, rasterize
from panorecon.splat.rasterize.sh import C0, sh_basis
from panorecon.splat.rasterize.torch_backend import ALPHA_MAX


def camera(width=32, height=24, dtype=torch.float64):
    K = torch.tensor(intrinsics_from_fov(width, height, 60.0), dtype=dtype)[None]
    V = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=dtype)[None]
    return V, K


def scene(n, seed=0, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    means = torch.stack(
        [
            torch.rand(n, generator=g) * 3 + 2,
            torch.rand(n, generator=g) * 2 - 1,
            torch.rand(n, generator=g) * 1.4 - 0.7,
        ],
        -1,
    ).to(dtype)
    quats = torch.randn(n, 4, generator=g).to(dtype)
    scales = (torch.rand(n, 3, generator=g) * 0.15 + 0.03).to(dtype)
    opac = (torch.rand(n, generator=g) * 0.8 + 0.1).to(dtype)
    colors = torch.rand(n, 3, generator=g).to(dtype)
    return means, quats, scales, opac, colors


def test_rotation_matrices_are_proper_and_zero_quaternion_is_identity():
    q = torch.tensor([[0.0, 0, 0, 0], [2.0, 0, 0, 0], [1.0, 2.0, -0.5, 0.3]], dtype=torch.float64)
    R = quat_to_rotmat(q)
    torch.testing.assert_close(R[0], torch.eye(3, dtype=torch.float64))
    torch.testing.assert_close(R[1], torch.eye(3, dtype=torch.float64))
    torch.testing.assert_close(R[2] @ R[2].T, torch.eye(3, dtype=torch.float64))
    assert torch.linalg.det(R[2]) == pytest.approx(1.0)


def test_single_isotropic_gaussian_matches_the_analytic_2d_gaussian():
    V, K = camera(64, 64)
    s, z, o = 0.05, 4.0, 0.5
    means = torch.tensor([[z, 0.0, 0.0]], dtype=torch.float64)
    img, alpha, depth, meta = rasterize(
        means,
        torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64),
        torch.full((1, 3), s, dtype=torch.float64),
        torch.tensor([o], dtype=torch.float64),
        torch.ones(1, 3, dtype=torch.float64),
        V,
        K,
        64,
        64,
        backend="torch",
    )
    f = K[0, 0, 0].item()
    var = (f * s / z) ** 2 + 0.3  # EWA variance in pixels^2 plus the 0.3 low-pass
    jj, ii = np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5)
    expect = o * np.exp(-0.5 * ((jj - 32) ** 2 + (ii - 32) ** 2) / var)
    expect[expect < 1 / 255] = 0
    np.testing.assert_allclose(alpha[0, ..., 0].numpy(), expect, atol=1e-9)
    np.testing.assert_allclose(depth[0, ..., 0].numpy(), expect * z, atol=1e-9)
    assert meta["radii"][0, 0] == math.ceil(3 * math.sqrt(var))


def opaque_pair(dtype):
    """Two opaque (o = 1) Gaussians on the optical axis, red at z = 4 and green at z = 6, wide enough (2 m,
    ~28 px) that o exp(-sigma) > 0.9996 at the four centre pixels: alpha is the cap there."""
    means = torch.tensor([[4.0, 0.0, 0.0], [6.0, 0.0, 0.0]], dtype=dtype)
    quats = torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=dtype)
    scales = torch.full((2, 3), 2.0, dtype=dtype)
    return means, quats, scales, torch.ones(2, dtype=dtype), torch.eye(3, dtype=dtype)[:2]


@pytest.mark.parametrize("backend", ["torch", "cpu"])
def test_an_opaque_gaussian_is_capped_at_gsplats_alpha_and_hides_what_is_behind(backend):
    """alpha = min(0.999, o exp(-sigma)), gsplat's cap (the original 3DGS kernels cap at 0.99); the Gaussian
    behind would take T from 0.001 to <= 1e-4, so blending stops before it: no green at all."""
    if backend == "cpu" and not cpu_backend.available():
        pytest.skip("the C++ rasterizer could not be built here")
    dtype = torch.float64 if backend == "torch" else torch.float32
    V, K = camera(64, 64, dtype)
    img, alpha, _, _ = rasterize(*opaque_pair(dtype), V, K, 64, 64, backend=backend)
    centre = (0, slice(31, 33), slice(31, 33))
    expect = torch.full((2, 2), ALPHA_MAX, dtype=dtype)
    assert ALPHA_MAX == 0.999
    torch.testing.assert_close(alpha[centre][..., 0], expect, rtol=0, atol=0)
    torch.testing.assert_close(img[centre][..., 0], expect, rtol=0, atol=0)
    assert (img[centre][..., 1] == 0).all()


def test_behind_near_and_off_image_gaussians_are_culled():
    V, K = camera()
    means = torch.tensor([[-3.0, 0, 0], [0.005, 0, 0], [3.0, 50.0, 0], [3.0, 0, 0]], dtype=torch.float64)
    _, _, _, radii = project_gaussians(
        means,
        torch.tensor([[1.0, 0, 0, 0]] * 4, dtype=torch.float64),
        torch.full((4, 3), 0.1, dtype=torch.float64),
        V,
        K,
        32,
        24,
    )
    assert radii[0].tolist()[:3] == [0, 0, 0] and radii[0, 3] > 0


def test_extreme_scales_and_zero_quaternions_stay_finite():
    V, K = camera()
    means, quats, scales, opac, colors = scene(6)
    quats[0] = 0
    scales[1] = 1e-6
    scales[2] = 1e3
    scales[3] = torch.tensor([1e-6, 1.0, 1e-6], dtype=torch.float64)
    img, alpha, depth, _ = rasterize(means, quats, scales, opac, colors, V, K, 32, 24, backend="torch")
    assert torch.isfinite(img).all() and torch.isfinite(depth).all()
    assert (alpha >= 0).all() and (alpha <= 1).all()


def test_gradcheck_float64():
    V, K = camera(16, 12)
    means, quats, scales, opac, colors = scene(4, seed=1)
    inputs = [t.clone().requires_grad_(True) for t in (means, quats, scales, opac, colors)]

    def f(m, q, s, o, c):
        img, alpha, depth, _ = rasterize(m, q, s, o, c, V, K, 16, 12, backend="torch")
        return img.sum() + 0.3 * alpha.square().sum() + 0.1 * depth.sum()

    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_background_and_contributions():
    V, K = camera()
    means, quats, scales, opac, colors = scene(20, seed=2)
    bg = torch.tensor([[0.2, 0.4, 0.6]], dtype=torch.float64)
    img, alpha, _, meta = rasterize(
        means, quats, scales, opac, colors, V, K, 32, 24, backgrounds=bg, return_contrib=True, backend="torch"
    )
    img0, _, _, _ = rasterize(means, quats, scales, opac, colors, V, K, 32, 24, backend="torch")
    torch.testing.assert_close(img, img0 + (1 - alpha) * bg[0])
    # blending weights of all Gaussians sum to the rendered alpha over the image
    torch.testing.assert_close(meta["weight_sum"].sum(), alpha.sum())
    assert (meta["weight_max"] <= meta["trans_max"] + 1e-12).all() and (meta["trans_max"] <= 1).all()


def test_spherical_harmonics_degree_zero_is_the_colour():
    V, K = camera()
    means, quats, scales, opac, colors = scene(8, seed=3)
    sh = torch.zeros(8, 16, 3, dtype=torch.float64)
    sh[:, 0] = (colors - 0.5) / C0
    a = rasterize(means, quats, scales, opac, colors, V, K, 32, 24, backend="torch")[0]
    b = rasterize(means, quats, scales, opac, sh, V, K, 32, 24, sh_degree=3, backend="torch")[0]
    torch.testing.assert_close(a, b)
    d = torch.nn.functional.normalize(torch.randn(50, 3, dtype=torch.float64), dim=-1)
    assert sh_basis(3, d).shape == (50, 16)


@settings(max_examples=10, deadline=None)
@given(st.integers(1, 30), st.integers(0, 10_000))
def test_random_scenes_are_finite_and_bounded(n, seed):
    V, K = camera(24, 16, torch.float32)
    means, quats, scales, opac, colors = scene(n, seed=seed, dtype=torch.float32)
    img, alpha, depth, _ = rasterize(means, quats, scales, opac, colors, V, K, 24, 16, backend="torch")
    assert torch.isfinite(img).all() and (alpha >= 0).all() and (alpha <= 1 + 1e-6).all()
    assert (img <= 1 + 1e-5).all()  # colours in [0, 1] composite to at most 1
