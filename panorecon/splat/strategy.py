"""Densify-and-prune strategies that change the set of Gaussians during training.

``DefaultStrategy`` is the standard 3DGS schedule: accumulate the screen-space gradient of each visible
Gaussian's 2D mean (in NDC units, gradient x (W/2, H/2), as gsplat normalises it); every ``refine_every``
iterations between ``refine_start`` and ``refine_stop``, Gaussians whose mean gradient exceeds
``grad_threshold`` are cloned (largest scale <= ``dense_fraction`` x scene extent) or split into two
samples with scales / 1.6 (larger ones); Gaussians with opacity < ``prune_opacity`` are removed; opacities are
reset to at most 0.01 every ``reset_every`` iterations. The Adam moments follow every change (new Gaussians
start with zero moments).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .model import GaussianModel
from .rasterize import quat_to_rotmat

PARAM_NAMES = ("means", "quats", "log_scales", "logit_opacities", "sh0", "shN")


def edit_parameters(model: GaussianModel, optimizer: torch.optim.Optimizer, keep: torch.Tensor, new: dict | None = None) -> None:
    """Keep the Gaussians selected by the bool mask ``keep`` and append ``new`` (name -> tensor of new rows),
    editing every parameter and its Adam state (exp_avg, exp_avg_sq) in step."""
    for group in optimizer.param_groups:
        (old,) = group["params"]
        name = group["name"]
        extra = None if new is None else new[name].detach()
        data = old.detach()[keep] if extra is None else torch.cat([old.detach()[keep], extra])
        p = torch.nn.Parameter(data)
        state = optimizer.state.pop(old, None)
        if state is not None:
            for key in ("exp_avg", "exp_avg_sq"):
                v = state[key][keep]
                state[key] = v if extra is None else torch.cat([v, torch.zeros_like(extra)])
            optimizer.state[p] = state
        group["params"] = [p]
        setattr(model, name, p)


@dataclass
class DefaultStrategy:
    grad_threshold: float = 0.0002
    dense_fraction: float = 0.01
    prune_opacity: float = 0.005
    refine_start: int = 500
    refine_stop: int = 15_000
    refine_every: int = 100
    reset_every: int = 3000
    max_gaussians: int = 2_000_000

    def __post_init__(self):
        self.grad_sum = None
        self.count = None

    def observe(self, model: GaussianModel, meta: dict, width: int, height: int) -> None:
        """After backward: accumulate the NDC-scaled 2D mean gradient of visible Gaussians."""
        g = meta["means2d"].grad
        if g is None:
            return
        n = len(model)
        if self.grad_sum is None or len(self.grad_sum) != n:
            self.grad_sum, self.count = torch.zeros(n), torch.zeros(n)
        scaled = g.detach() * torch.tensor([width / 2, height / 2])
        vis = meta["radii"] > 0
        self.grad_sum += (scaled.norm(dim=-1) * vis).sum(0)
        self.count += vis.sum(0)

    def step(self, model: GaussianModel, optimizer, it: int, extent: float) -> dict:
        """Refine at scheduled iterations; returns counts of what changed."""
        out = {"cloned": 0, "split": 0, "pruned": 0, "reset": False}
        if self.refine_start <= it < self.refine_stop and it % self.refine_every == 0 and self.grad_sum is not None:
            avg = self.grad_sum / self.count.clamp_min(1)
            big_grad = (avg > self.grad_threshold) & (self.count > 0)
            if len(model) + int(big_grad.sum()) > self.max_gaussians:
                big_grad[:] = False
            max_scale = model.scales().detach().max(-1).values
            clone = big_grad & (max_scale <= self.dense_fraction * extent)
            split = big_grad & ~clone
            new = {}
            if clone.any() or split.any():
                # clones: same parameters; splits: two samples from the Gaussian, scales / 1.6, replacing it
                sel = torch.cat([torch.nonzero(clone).flatten(), torch.nonzero(split).flatten().repeat(2)])
                for name in PARAM_NAMES:
                    new[name] = getattr(model, name).detach()[sel].clone()
                ns = int(split.sum())
                if ns:
                    idx = torch.nonzero(split).flatten().repeat(2)
                    R = quat_to_rotmat(model.quats.detach()[idx])
                    noise = torch.randn(len(idx), 3) * model.scales().detach()[idx]
                    new["means"][-2 * ns:] += (R @ noise[..., None])[..., 0]
                    new["log_scales"][-2 * ns:] -= math.log(1.6)
            low = model.opacities().detach() < self.prune_opacity
            keep = ~(split | low)
            edit_parameters(model, optimizer, keep, new or None)
            out.update(cloned=int(clone.sum()), split=int(split.sum()), pruned=int((low & ~split).sum()))
            self.grad_sum = None
        if self.reset_every and it > 0 and it % self.reset_every == 0 and it < self.refine_stop:
            with torch.no_grad():
                model.logit_opacities.clamp_(max=math.log(0.01 / 0.99))
            out["reset"] = True
        return out
