"""Densify-and-prune strategies that change the set of Gaussians during training.

``DefaultStrategy`` is the standard 3DGS schedule: accumulate the screen-space gradient of each visible
Gaussian's 2D mean (in NDC units, gradient x (W/2, H/2), as gsplat normalises it); every ``refine_every``
iterations between ``refine_start`` and ``refine_stop``, Gaussians whose mean gradient exceeds
``grad_threshold`` are cloned (largest scale <= ``dense_fraction`` x scene extent) or split into two
samples with scales / 1.6 (larger ones); Gaussians with opacity < ``prune_opacity`` are removed; opacities are
reset to at most 0.01 every ``reset_every`` iterations. The Adam moments follow every change (new Gaussians
start with zero moments).

``AdaptiveStrategy`` is the method's adaptive optimisation (§2.5): the same densification, but pruning by
contribution rather than by opacity alone (see its docstring).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from .model import PARAM_NAMES, GaussianModel
from .rasterize import cpu_backend, quat_to_rotmat


def edit_parameters(
    model: GaussianModel, optimizer: torch.optim.Optimizer, keep: torch.Tensor, new: dict | None = None
) -> None:
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

    needs_contrib = False  # whether observe() reads weight_sum / weight_max / trans_max from the render's meta

    def __post_init__(self):
        self.grad_sum = None
        self.count = None

    def state_dict(self) -> dict:
        return {"grad_sum": self.grad_sum, "count": self.count}

    def load_state_dict(self, state: dict) -> None:
        for k, v in state.items():
            setattr(self, k, v)

    def observe(self, model: GaussianModel, meta: dict, width: int, height: int) -> None:
        """After backward: accumulate the NDC-scaled 2D mean gradient of visible Gaussians."""
        g = meta["means2d"].grad
        if g is None:
            return
        n = len(model)
        if self.grad_sum is None or len(self.grad_sum) != n:
            self.grad_sum, self.count = torch.zeros(n, device=g.device), torch.zeros(n, device=g.device)
        if g.device.type == "cpu" and cpu_backend.available():  # one pass in C++, the same sums
            cpu_backend.accumulate_screen_grads(self.grad_sum, self.count, g, meta["radii"], width, height)
            return
        ndc = torch.tensor([width / 2, height / 2], device=g.device)
        vis = meta["radii"] > 0  # [C, N]
        self.grad_sum += ((g.detach() * ndc).norm(dim=-1) * vis).sum(0)
        self.count += vis.sum(0)

    def prune_mask(self, model: GaussianModel, it: int) -> torch.Tensor:
        """[N] bool: Gaussians to remove at this refinement (3DGS: opacity below ``prune_opacity``)."""
        return model.opacities().detach() < self.prune_opacity

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
                    noise = torch.randn(len(idx), 3, device=idx.device) * model.scales().detach()[idx]
                    new["means"][-2 * ns :] += (R @ noise[..., None])[..., 0]
                    new["log_scales"][-2 * ns :] -= math.log(1.6)
            low = self.prune_mask(model, it)
            keep = ~(split | low)
            edit_parameters(model, optimizer, keep, new or None)
            out.update(cloned=int(clone.sum()), split=int(split.sum()), pruned=int((low & ~split).sum()))
            self.reset_statistics()
        elif self.refine_stop <= it < self.prune_stop() and it % self.refine_every == 0 and self.grad_sum is not None:
            low = self.prune_mask(model, it)
            edit_parameters(model, optimizer, ~low)
            out.update(pruned=int(low.sum()))
            self.reset_statistics()
        if self.reset_every and it > 0 and it % self.reset_every == 0 and it < self.refine_stop:
            with torch.no_grad():
                model.logit_opacities.clamp_(max=math.log(0.01 / 0.99))
            out["reset"] = True
        return out

    def prune_stop(self) -> int:
        """Iteration after which nothing is pruned (3DGS prunes only while it densifies)."""
        return self.refine_stop

    def reset_statistics(self) -> None:
        self.grad_sum = None


def insert_descending(top: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
    """The ``k`` largest of each row of ``top`` [N, k] (sorted descending) and ``x`` [N], sorted descending: the
    values of ``torch.cat([top, x[:, None]], 1).topk(k, 1)``, exactly, by new[j] = max(top[j], min(x, top[j - 1]))
    (top[-1] = +inf), elementwise. At 330k rows and k = 5 (two threads) it takes 2.0-2.4 ms where that top-k took
    6.3-9.4 ms, in every step of the adaptive strategy."""
    above = torch.minimum(x[:, None], top[:, :-1])
    return torch.cat([torch.maximum(top[:, :1], x[:, None]), torch.maximum(top[:, 1:], above)], 1)


@dataclass
class AdaptiveStrategy(DefaultStrategy):
    """Contribution-based pruning (paper §2.5), on top of the 3DGS densification.

    Per training view a Gaussian's blending contribution is weight_sum = sum over pixels of alpha x T, counted in
    pixels of a ``reference_size``² view of the same field of view (weight_sum x reference_size² / (W H)), so a
    threshold prunes Gaussians of the same angular footprint at any training resolution; its surface evidence
    trans_max = the largest transmittance in front of it where it was composited. Between refinements each Gaussian
    keeps its ``top_k`` largest per-view contributions; its score is their mean (views it was not seen from count as
    0). At a refinement a Gaussian that some view had in its frustum is pruned when score < threshold(it), unless it
    is a surface Gaussian: trans_max >= ``surface_transmittance`` in some view, i.e. it lies at or before the depth
    where its ray's transmittance halves (the first surface, as the median depth defines it), so thin surface detail
    survives even with a small footprint, while internal Gaussians hidden behind the surface are removed.
    Relaxation: no contribution pruning for the first ``relax_fraction`` of the refinement window, then the
    threshold rises linearly from ``threshold_start`` to ``threshold_end`` at ``prune_until`` x iterations.
    Opacity pruning (< ``prune_opacity``) stays on throughout.
    """

    top_k: int = 5
    reference_size: int = 256  # contributions and thresholds in pixels of a 256² view
    threshold_start: float = 0.05
    threshold_end: float = 0.5
    surface_transmittance: float = 0.5
    relax_fraction: float = 0.3
    prune_until: int = 0  # 0: twice refine_stop, i.e. keep pruning (only) after densification ends

    needs_contrib = True

    def __post_init__(self):
        super().__post_init__()
        self.top_contrib = None  # [N, top_k] float32
        self.trans_max = None  # [N]
        self.seen = None  # [N] bool: in some view's frustum since the last refinement

    def state_dict(self) -> dict:
        return {**super().state_dict(), "top_contrib": self.top_contrib, "trans_max": self.trans_max, "seen": self.seen}

    def prune_stop(self) -> int:
        return self.prune_until or 2 * self.refine_stop

    def observe(self, model: GaussianModel, meta: dict, width: int, height: int) -> None:
        super().observe(model, meta, width, height)
        n = len(model)
        if self.top_contrib is None or len(self.top_contrib) != n:
            dev = model.means.device
            self.top_contrib = torch.zeros(n, self.top_k, device=dev)
            self.trans_max, self.seen = torch.zeros(n, device=dev), torch.zeros(n, dtype=torch.bool, device=dev)
        to_reference = self.reference_size**2 / (width * height)
        for c in range(meta["weight_sum"].shape[0]):
            self.top_contrib = insert_descending(self.top_contrib, meta["weight_sum"][c].float() * to_reference)
            self.trans_max = torch.maximum(self.trans_max, meta["trans_max"][c].float())
            self.seen |= meta["radii"][c] > 0

    def threshold(self, it: int) -> float:
        """The contribution threshold at iteration ``it`` (pixels of a ``reference_size``² view); 0 during the
        relaxation stage."""
        relax_end = self.refine_start + self.relax_fraction * (self.refine_stop - self.refine_start)
        if it < relax_end:
            return 0.0
        f = min(1.0, (it - relax_end) / max(self.prune_stop() - relax_end, 1))
        return self.threshold_start + f * (self.threshold_end - self.threshold_start)

    def prune_mask(self, model: GaussianModel, it: int) -> torch.Tensor:
        low_opacity = super().prune_mask(model, it)
        if self.top_contrib is None or len(self.top_contrib) != len(model):
            return low_opacity
        score = self.top_contrib.mean(1)
        surface = self.trans_max >= self.surface_transmittance
        return low_opacity | (self.seen & ~surface & (score < self.threshold(it)))

    def reset_statistics(self) -> None:
        super().reset_statistics()
        self.top_contrib = self.trans_max = self.seen = None


STRATEGIES = {"default": DefaultStrategy, "adaptive": AdaptiveStrategy}
