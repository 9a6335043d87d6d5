"""Per-Gaussian contributions for backends without them (``rasterize/contrib.py``), on the CPU: from the blended
pairs and by the ones-channel gradient, against the ``cpu`` backend's and the reference's own contributions."""

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
from panorecon.splat.rasterize import cpu_backend, project_gaussians, rasterize
from panorecon.splat.rasterize.contrib import contributions_from_pairs, pairs_reference, weight_sum_by_gradient
from panorecon.splat.rasterize.torch_backend import rasterize_tiles

needs_cpu = pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
W, H = 40, 28


def scene(n, seed, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    means = torch.stack(
        [
            torch.rand(n, generator=g) * 4 + 0.5,
            torch.rand(n, generator=g) * 3 - 1.5,
            torch.rand(n, generator=g) * 2 - 1,
        ],
        -1,
    )
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.2 + 0.02
    opac = torch.rand(n, generator=g) * 0.98 + 0.01
    opac[:3] = 1.0  # alpha clamped at 0.999: deep occlusion, the T stop is reached
    rgb = torch.rand(n, 3, generator=g)
    Ks = torch.tensor(intrinsics_from_fov(W, H, 70.0))[None].repeat(2, 1, 1)
    Vs = torch.stack(
        [
            torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0])),
            torch.tensor(look_at_viewmat([0.2, -0.3, 0.1], [1, 0.4, -0.2])),
        ]
    )
    return [t.to(dtype) for t in (means, quats, scales, opac, rgb, Vs, Ks)]


def reference_contrib(m, q, s, o, rgb, Vs, Ks):
    means2d, conics, depths, radii = project_gaussians(m, q, s, Vs, Ks, W, H)
    *_, contrib = rasterize_tiles(
        means2d, conics, rgb[None].expand(2, -1, -1), o, depths, radii, W, H, return_contrib=True
    )
    return (means2d, conics, depths, radii), contrib


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_contributions_from_reference_pairs_equal_the_reference_compositor(seed):
    m, q, s, o, rgb, Vs, Ks = scene(150, seed, torch.float64)
    (means2d, conics, depths, radii), ref = reference_contrib(m, q, s, o, rgb, Vs, Ks)
    pairs = pairs_reference(means2d, conics, o, radii, W, H)
    got = contributions_from_pairs(means2d, conics, o, depths, *pairs, W, H)
    assert ref["trans_max"].max() == 1 and (ref["weight_sum"] > 0).sum() > 50
    for k in ("weight_sum", "weight_max", "trans_max"):
        torch.testing.assert_close(got[k], ref[k], atol=1e-10, rtol=1e-9)


def test_pair_order_does_not_matter_and_per_camera_opacities_are_read():
    m, q, s, o, rgb, Vs, Ks = scene(80, 3, torch.float64)
    (means2d, conics, depths, radii), ref = reference_contrib(m, q, s, o, rgb, Vs, Ks)
    pairs = pairs_reference(means2d, conics, o, radii, W, H)
    perm = torch.randperm(len(pairs[0]), generator=torch.Generator().manual_seed(0))
    got = contributions_from_pairs(means2d, conics, o[None].expand(2, -1), depths, *(p[perm] for p in pairs), W, H)
    for k in ref:
        torch.testing.assert_close(got[k], ref[k], atol=1e-10, rtol=1e-9)
    empty = contributions_from_pairs(means2d, conics, o, depths, *(p[:0] for p in pairs), W, H)
    assert all(float(v.abs().sum()) == 0 for v in empty.values())


@needs_cpu
@pytest.mark.parametrize("seed", [0, 1])
def test_pairs_and_gradient_equal_the_cpu_backends_contributions(seed):
    m, q, s, o, rgb, Vs, Ks = scene(150, seed)
    _, _, _, meta = rasterize(m, q, s, o, rgb, Vs, Ks, W, H, backend="cpu", return_contrib=True)
    pairs = pairs_reference(meta["means2d"], meta["conics"], o, meta["radii"], W, H)
    got = contributions_from_pairs(meta["means2d"], meta["conics"], o, meta["depths"], *pairs, W, H)
    for k in ("weight_sum", "weight_max", "trans_max"):
        torch.testing.assert_close(got[k], meta[k], atol=2e-5, rtol=1e-4)
    # the ones channel: the gradient of its pixel sum w.r.t. a per-Gaussian colour of ones is sum alpha T,
    # here through the torch reference's autograd (any differentiable backend would do)
    by_grad = weight_sum_by_gradient(
        lambda ones: rasterize(m, q, s, o, ones, Vs, Ks, W, H, backend="torch")[0], 2, len(m)
    )
    torch.testing.assert_close(by_grad, meta["weight_sum"], atol=2e-5, rtol=1e-4)


@needs_cpu
@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 60), opacity=st.floats(0.004, 1.0))
def test_gradient_weight_sum_matches_cpu_for_any_scene(seed, n, opacity):
    m, q, s, o, rgb, Vs, Ks = scene(n, seed)
    o = torch.full_like(o, opacity)
    _, _, _, meta = rasterize(m, q, s, o, rgb, Vs, Ks, W, H, backend="cpu", return_contrib=True)
    by_grad = weight_sum_by_gradient(lambda ones: rasterize(m, q, s, o, ones, Vs, Ks, W, H, backend="torch")[0], 2, n)
    torch.testing.assert_close(by_grad, meta["weight_sum"], atol=2e-5, rtol=1e-4)
