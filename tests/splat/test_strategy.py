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


def test_the_gradient_statistics_of_the_seen_rows_equal_the_dense_sums():
    """DefaultStrategy.observe sums over the rows some camera sees (CPU): bit for bit the dense formula (every row,
    the unseen ones + 0), the one GPU tensors take, over several observations of two cameras."""
    from panorecon.splat.strategy import DefaultStrategy

    g = torch.Generator().manual_seed(4)
    n, width, height = 500, 64, 48
    strategy, grad_sum, count = DefaultStrategy(), torch.zeros(n), torch.zeros(n)
    ndc = torch.tensor([width / 2, height / 2])
    for _ in range(4):
        means2d = torch.zeros(2, n, 2, requires_grad=True)
        means2d.grad = torch.randn(2, n, 2, generator=g)
        radii = ((torch.rand(2, n, generator=g) < 0.1) * 3).to(torch.int32)
        model = torch.zeros(n)  # observe reads only len(model)
        strategy.observe(model, {"means2d": means2d, "radii": radii}, width, height)
        vis = radii > 0
        grad_sum += ((means2d.grad * ndc).norm(dim=-1) * vis).sum(0)
        count += vis.sum(0)
    assert count.sum() > 50
    assert torch.equal(strategy.grad_sum, grad_sum) and torch.equal(strategy.count, count)
