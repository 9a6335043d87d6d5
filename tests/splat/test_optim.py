"""VisibleAdam.step_visible against torch.optim.Adam: the rows it steps follow Adam exactly, the others stay."""

import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from panorecon.splat.optim import VisibleAdam


def _groups(params, lrs=(1e-2, 3e-3)):
    return [{"params": [p], "lr": lr, "name": n} for (n, p), lr in zip(params.items(), lrs)]


def _params(n, seed):
    g = torch.Generator().manual_seed(seed)
    return {"means": torch.randn(n, 3, generator=g), "shN": torch.randn(n, 15, 3, generator=g)}


@settings(max_examples=25, deadline=None)
@given(st.integers(2, 40), st.integers(0, 10_000), st.integers(1, 6))
def test_the_stepped_rows_follow_adam_on_those_rows_alone_and_the_others_stay(n, seed, steps):
    """Each step a random subset of rows is visible: those rows move exactly as Adam would move a parameter made of
    them alone, given the same moments and step count; every other row and its moments are bit-unchanged."""
    g = torch.Generator().manual_seed(seed + 1)
    full = {k: torch.nn.Parameter(v.clone()) for k, v in _params(n, seed).items()}
    opt = VisibleAdam(_groups(full), eps=1e-15)
    for step in range(steps):
        index = torch.nonzero(torch.rand(n, generator=g) < 0.4).flatten()
        grads = {k: torch.randn(len(index), *p.shape[1:], generator=g) for k, p in full.items()}
        before = {k: (p.detach().clone(), {s: v.clone() for s, v in opt.state[p].items()}) for k, p in full.items()}
        opt.step_visible(index, grads)
        outside = torch.ones(n, dtype=torch.bool)
        outside[index] = False
        for k, p in full.items():
            rows = torch.nn.Parameter(before[k][0][index])
            ref = torch.optim.Adam([rows], lr=opt.param_groups[list(full).index(k)]["lr"], eps=1e-15)
            if before[k][1]:  # the rows' own moments and the shared step count
                ref.state[rows] = {
                    "step": before[k][1]["step"].clone(),
                    "exp_avg": before[k][1]["exp_avg"][index].clone(),
                    "exp_avg_sq": before[k][1]["exp_avg_sq"][index].clone(),
                }
            rows.grad = grads[k]
            ref.step()
            torch.testing.assert_close(p.detach()[index], rows.detach(), rtol=1e-6, atol=1e-7)
            for s in ("exp_avg", "exp_avg_sq"):
                torch.testing.assert_close(opt.state[p][s][index], ref.state[rows][s], rtol=1e-6, atol=1e-12)
                if before[k][1]:
                    assert torch.equal(opt.state[p][s][outside], before[k][1][s][outside])
            assert torch.equal(p.detach()[outside], before[k][0][outside])
            assert float(opt.state[p]["step"]) == step + 1


def test_every_row_visible_is_the_dense_fused_step():
    dense_p = {k: torch.nn.Parameter(v) for k, v in _params(50, 3).items()}
    vis_p = {k: torch.nn.Parameter(v.clone()) for k, v in _params(50, 3).items()}
    dense = VisibleAdam(_groups(dense_p), eps=1e-15, fused=True)
    vis = VisibleAdam(_groups(vis_p), eps=1e-15, fused=True)
    g = torch.Generator().manual_seed(7)
    for _ in range(5):
        grads = {k: torch.randn(p.shape, generator=g) for k, p in dense_p.items()}
        for k, p in dense_p.items():
            p.grad = grads[k].clone()
        dense.step()
        vis.step_visible(torch.arange(50), grads)
    for k in dense_p:
        torch.testing.assert_close(vis_p[k].detach(), dense_p[k].detach(), rtol=1e-5, atol=1e-6)
    # the state is torch's layout: a checkpoint of one loads into the other
    dense.load_state_dict(vis.state_dict())


def test_a_missing_gradient_skips_its_group_and_bad_input_is_one_clear_error():
    p = {k: torch.nn.Parameter(v) for k, v in _params(6, 0).items()}
    opt = VisibleAdam(_groups(p))
    idx = torch.tensor([1, 4])
    opt.step_visible(idx, {"means": torch.ones(2, 3), "shN": None})
    assert p["shN"] not in opt.state or not opt.state[p["shN"]]
    with pytest.raises(ValueError, match=r"'means'.*\(2, 3\)"):
        opt.step_visible(idx, {"means": torch.ones(3, 3)})
    decayed = VisibleAdam([{"params": [p["means"]], "lr": 1e-3, "name": "means", "weight_decay": 0.1}])
    with pytest.raises(ValueError, match="weight_decay"):
        decayed.step_visible(idx, {"means": torch.ones(2, 3)})
