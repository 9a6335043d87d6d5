"""The C++ SH colours (``cpu_backend.sh_colors``) against the PyTorch reference ``sh_colors_reference``: colours of the
pairs with radius > 0 and the gradients of coefficients and means (through the view direction), in float64 (to
rounding) and float32 (to a stated tolerance), for every degree; culled pairs read 0 and pass no gradient."""

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.splat.rasterize import cpu_backend
from panorecon.splat.rasterize.sh import sh_colors_reference

pytestmark = pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")


def case(n, seed, dtype, cameras=3):
    """coeffs [n,16,3], means [n,3], camera centres [cameras,3], radii [cameras,n] (about a third culled),
    upstream gradients [cameras,n,3]. Gaussian 0 sits on camera 0's centre (the clamped direction norm);
    Gaussian 1 has a DC term that drives its colour below 0 (the clamp)."""
    g = torch.Generator().manual_seed(seed)
    coeffs = torch.randn(n, 16, 3, generator=g, dtype=dtype)
    means = torch.randn(n, 3, generator=g, dtype=dtype)
    campos = torch.randn(cameras, 3, generator=g, dtype=dtype)
    radii = (torch.rand(cameras, n, generator=g) > 0.33).to(torch.int32) * 3
    means[0] = campos[0]
    coeffs[1, 0] = -10.0
    radii[:, :2] = 3
    ups = torch.randn(cameras, n, 3, generator=g, dtype=dtype)
    return coeffs, means, campos, radii, ups


def both(degree, n=300, seed=0, dtype=torch.float64):
    """(colours, d coeffs, d means) of the C++ kernel and of the reference, the reference masked to kept pairs."""
    coeffs, means, campos, radii, ups = case(n, seed, dtype)
    out = []
    for fn in ("cpu", "reference"):
        c = coeffs.clone().requires_grad_(True)
        m = means.clone().requires_grad_(True)
        if fn == "cpu":
            colors = cpu_backend.sh_colors(degree, c, m, campos, radii)
        else:
            colors = sh_colors_reference(degree, c, m, campos) * (radii[..., None] > 0)
        (colors * ups).sum().backward()
        grad_m = m.grad if m.grad is not None else torch.zeros_like(m)  # degree 0 does not read the direction
        out.append((colors.detach(), c.grad, grad_m))
    return out


@pytest.mark.parametrize("degree", [0, 1, 2, 3])
def test_float64_matches_the_reference_to_rounding(degree):
    (col, gc, gm), (col_r, gc_r, gm_r) = both(degree)
    torch.testing.assert_close(col, col_r, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(gc, gc_r, rtol=1e-12, atol=1e-12)
    # Gaussian 0 sits on a camera centre: its direction gradient is 1e12 x the upstream one in both
    torch.testing.assert_close(gm[1:], gm_r[1:], rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(gm[0], gm_r[0], rtol=1e-10, atol=0.0)


@pytest.mark.parametrize("degree", [1, 3])
def test_float32_matches_the_reference(degree):
    (col, gc, gm), (col_r, gc_r, gm_r) = both(degree, dtype=torch.float32)
    torch.testing.assert_close(col, col_r, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(gc, gc_r, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(gm[1:], gm_r[1:], rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("degree", [0, 3])
def test_culled_pairs_read_zero_and_pass_no_gradient(degree):
    """Whatever gradient arrives for a culled pair (NaN here) is not read; degree 0 has a path of its own."""
    coeffs, means, campos, radii, ups = case(50, 3, torch.float64)
    radii[:, 10:] = 0
    ups[:, 10:] = torch.nan
    c = coeffs.clone().requires_grad_(True)
    m = means.clone().requires_grad_(True)
    colors = cpu_backend.sh_colors(degree, c, m, campos, radii)
    assert bool((colors[:, 10:] == 0).all())
    colors.backward(ups)
    assert bool((c.grad[10:] == 0).all()) and (m.grad is None or bool((m.grad[10:] == 0).all()))
    assert bool((c.grad[2:10] != 0).any()) and bool(torch.isfinite(c.grad).all())


@pytest.mark.parametrize("degree", [0, 3])
def test_the_clamp_at_zero_passes_no_gradient_below_it(degree):
    (col, gc, _), _ = both(degree)
    assert bool((col[:, 1] == 0).all())  # Gaussian 1's DC term of -10 puts every channel below 0
    assert bool((gc[1] == 0).all())


def test_bad_degree_is_one_clear_error():
    coeffs, means, campos, radii, _ = case(5, 0, torch.float32)
    with pytest.raises(ValueError, match="sh_degree=4"):
        cpu_backend.sh_colors(4, coeffs, means, campos, radii)
    with pytest.raises(ValueError, match="4 coefficients"):
        cpu_backend.sh_colors(2, coeffs[:, :4], means, campos, radii)


@settings(max_examples=20, deadline=None)
@given(degree=st.integers(0, 3), n=st.integers(2, 200), seed=st.integers(0, 10_000))
def test_random_cases_agree(degree, n, seed):
    (col, gc, gm), (col_r, gc_r, gm_r) = both(degree, n, seed)
    torch.testing.assert_close(col, col_r, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(gc, gc_r, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(gm[1:], gm_r[1:], rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("degree", [0, 1, 3])
@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_the_pair_sh0_shN_is_the_same_as_one_tensor(degree, dtype):
    """The trainer's form, the model's (sh0 [N,1,3], shN [N,K-1,3]) read in place, against the reference on their
    concatenation: the same colours and gradients (each band its own gradient tensor)."""
    coeffs, means, campos, radii, ups = case(120, 5, dtype)
    k = (degree + 1) ** 2
    # degree 0 with all 15 higher bands, as in the trainer's first steps; others with exactly the bands they read
    sh0, shN = (t.clone().requires_grad_(True) for t in (coeffs[:, :1], coeffs[:, 1 : max(k, 16 * (degree == 0))]))
    m = means.clone().requires_grad_(True)
    colors = cpu_backend.sh_colors(degree, (sh0, shN), m, campos, radii)
    (colors * ups).sum().backward()
    c = coeffs[:, : 1 + shN.shape[1]].clone().requires_grad_(True)
    m_r = means.clone().requires_grad_(True)
    ref = sh_colors_reference(degree, c, m_r, campos) * (radii[..., None] > 0)
    (ref * ups).sum().backward()
    tol = dict(rtol=1e-12, atol=1e-12) if dtype == torch.float64 else dict(rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(colors, ref.detach(), **tol)
    torch.testing.assert_close(sh0.grad, c.grad[:, :1], **tol)
    if degree == 0:  # no higher band is read: no gradient tensor for them at all
        assert shN.grad is None
    else:
        assert shN.grad.shape == shN.shape and shN.grad.is_contiguous()
        torch.testing.assert_close(shN.grad, c.grad[:, 1:], **tol)
    if degree > 0:
        torch.testing.assert_close(
            m.grad[1:], m_r.grad[1:], **(tol if dtype == torch.float64 else dict(rtol=1e-4, atol=1e-4))
        )


def test_a_pair_of_wrong_shapes_is_one_clear_error():
    coeffs, means, campos, radii, _ = case(5, 0, torch.float32)
    with pytest.raises(ValueError, match=r"expected \[N, 1, 3\] and \[N, K - 1, 3\]"):
        cpu_backend.sh_colors(1, (coeffs[:, :2], coeffs[:, 2:]), means, campos, radii)
    with pytest.raises(ValueError, match="3 coefficients"):
        cpu_backend.sh_colors(1, (coeffs[:, :1], coeffs[:, 1:3]), means, campos, radii)
