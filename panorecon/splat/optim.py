"""Adam for Gaussians, with a step over the rows a view sees (gsplat's ``visible_adam``, Taming 3DGS's
"selective Adam").

One label view per step sees a small share of the model (a 60 deg view: ~8 % of the sphere), and a Gaussian it
does not see has a zero gradient. Dense Adam still reads and writes every row of every parameter and both
moments for those Gaussians, and their momentum keeps moving them for some tens of steps after they leave the view.
``VisibleAdam.step_visible`` updates only the given rows: their parameters and moments follow Adam exactly, the
other rows, and their moments, stay as they are. The step count (and so the bias correction) is per parameter
tensor, as in ``torch.optim.Adam``, whose state layout (``step``, ``exp_avg``, ``exp_avg_sq``) and ``state_dict``
it keeps, so a checkpoint of either loads into the other and ``strategy.edit_parameters`` edits both alike.
float32 state, as the parameters.
"""

from __future__ import annotations

import math

import torch


class VisibleAdam(torch.optim.Adam):
    """``torch.optim.Adam`` (its ``step`` is the dense reference) plus ``step_visible``; no weight decay, AMSGrad or
    maximisation (``step_visible`` refuses them)."""

    @torch.no_grad()
    def step_visible(self, index: torch.Tensor, grads: dict[str, torch.Tensor | None]) -> None:
        """One Adam step on rows ``index`` [M] (int64, unique) of each group's parameter, with ``grads[name]``
        [M, ...] the gradient of those rows (groups are named by ``"name"``; a missing or None gradient skips the
        group, as a None ``.grad`` does in ``step``). Rows outside ``index`` and their moments are left as they are."""
        for group in self.param_groups:
            grad = grads.get(group["name"])
            if grad is None:
                continue
            if group["weight_decay"] or group["amsgrad"] or group["maximize"]:
                raise ValueError(
                    f"VisibleAdam.step_visible: group {group['name']!r} asks for weight_decay, amsgrad or maximize; "
                    "only plain Adam steps a subset of rows"
                )
            (param,) = group["params"]
            if grad.shape != (len(index), *param.shape[1:]):
                raise ValueError(
                    f"VisibleAdam.step_visible: gradient of {group['name']!r} has shape {tuple(grad.shape)}, "
                    f"expected {(len(index), *param.shape[1:])} (one row per index)"
                )
            state = self.state[param]
            if not state:  # as torch.optim.Adam initialises it (a float32 step tensor when fused)
                state["step"] = torch.zeros((), dtype=torch.float32, device=param.device)
                state["exp_avg"] = torch.zeros_like(param, memory_format=torch.preserve_format)
                state["exp_avg_sq"] = torch.zeros_like(param, memory_format=torch.preserve_format)
            state["step"] += 1
            step = float(state["step"])
            beta1, beta2 = group["betas"]
            exp_avg = state["exp_avg"].index_select(0, index).lerp_(grad, 1 - beta1)
            exp_avg_sq = state["exp_avg_sq"].index_select(0, index).mul_(beta2).addcmul_(grad, grad, value=1 - beta2)
            denom = (exp_avg_sq.sqrt() / math.sqrt(1 - beta2**step)).add_(group["eps"])
            rows = param.index_select(0, index).addcdiv_(exp_avg, denom, value=-group["lr"] / (1 - beta1**step))
            param.index_copy_(0, index, rows)
            state["exp_avg"].index_copy_(0, index, exp_avg)
            state["exp_avg_sq"].index_copy_(0, index, exp_avg_sq)
