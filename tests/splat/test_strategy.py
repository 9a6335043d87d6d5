import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.splat.strategy import insert_descending


def topk_reference(top: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    return torch.cat([top, x[:, None]], 1).topk(top.shape[1], dim=1).values


@settings(max_examples=60, deadline=None)
@given(
    n=st.integers(1, 40),
    k=st.integers(1, 6),
    observations=st.integers(1, 12),
    ties=st.booleans(),
    seed=st.integers(0, 2**31 - 1),
)
def test_insert_descending_keeps_the_same_k_largest_as_top_k(n, k, observations, ties, seed):
    """Stream per-view contributions into the rows as AdaptiveStrategy.observe does (zeros for the unseen, many
    ties when ``ties``): the elementwise insert equals torch's top-k of the concatenation, bit for bit."""
    g = torch.Generator().manual_seed(seed)
    fast = reference = torch.zeros(n, k)
    for _ in range(observations):
        x = torch.rand(n, generator=g) * (torch.rand(n, generator=g) < 0.6)
        if ties:
            x = (x * 4).round() / 4
        fast, reference = insert_descending(fast, x), topk_reference(reference, x)
        assert torch.equal(fast, reference)
    assert torch.all(fast[:, :-1] >= fast[:, 1:])


def test_insert_descending_at_the_extremes():
    top = torch.tensor([[3.0, 2.0, 2.0], [0.0, 0.0, 0.0], [1e30, 1e-30, 0.0]])
    for x in (torch.tensor([2.0, 0.0, 1e-29]), torch.tensor([5.0, 1e-45, 1e31]), torch.zeros(3)):
        assert torch.equal(insert_descending(top, x), topk_reference(top, x))


def test_the_gradient_statistics_equal_the_dense_sums():
    """DefaultStrategy.observe (one C++ pass on the CPU) gives the dense formula's sums, the one GPU tensors take,
    over several observations of two cameras, to the last bit where torch rounds the norm as fma(y, y, x x); the
    gradients of culled pairs (radius 0) are not read, NaN or not."""
    from panorecon.splat.rasterize import cpu_backend
    from panorecon.splat.strategy import DefaultStrategy

    if not cpu_backend.available():
        pytest.skip("the cpu backend does not build here")
    g = torch.Generator().manual_seed(4)
    n, width, height = 500, 64, 48
    strategy, grad_sum, count = DefaultStrategy(), torch.zeros(n), torch.zeros(n)
    ndc = torch.tensor([width / 2, height / 2])
    for _ in range(4):
        means2d = torch.zeros(2, n, 2, requires_grad=True)
        grad = torch.randn(2, n, 2, generator=g) * torch.exp(4 * torch.randn(2, n, 1, generator=g))
        radii = ((torch.rand(2, n, generator=g) < 0.3) * 3).to(torch.int32)
        vis = radii > 0
        grad_sum += ((grad * ndc).norm(dim=-1) * vis).sum(0)
        count += vis.sum(0)
        means2d.grad = torch.where(vis[..., None], grad, torch.nan)  # what culled pairs hold must not matter
        model = torch.zeros(n)  # observe reads only len(model)
        strategy.observe(model, {"means2d": means2d, "radii": radii}, width, height)
    assert count.sum() > 500 and (count == 0).any()
    assert torch.equal(strategy.count, count)
    torch.testing.assert_close(strategy.grad_sum, grad_sum, rtol=2.5e-7, atol=0)
