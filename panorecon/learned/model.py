"""The learned teacher's network: a small U-Net, RGB [N, 3, H, W] -> affine-invariant disparity [N, 1, H, W].

Float32 throughout. H and W must be multiples of 16 (four 2x poolings). The output has no activation: it is
known up to scale and shift (MiDaS's convention), so the exported model is read as ``output: disparity,
mode: affine`` by the ``onnx:`` teacher. Only 3x3 convolutions, batch norm, ReLU, max pooling, bilinear
upsampling and concatenation: operators every ONNX runtime has.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

LEVELS = 4  # poolings: the input size must be a multiple of 2**LEVELS


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
        nn.Conv2d(cout, cout, 3, padding=1, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class DepthNet(nn.Module):
    """U-Net with ``width`` channels at full resolution, doubling per level up to 8 x width; the decoder
    upsamples bilinearly and concatenates the encoder's features of the same level."""

    def __init__(self, width: int = 16):
        super().__init__()
        self.width = width
        chans = [min(width * 2**i, width * 8) for i in range(LEVELS + 1)]  # e.g. 16, 32, 64, 128, 128
        self.down = nn.ModuleList(
            [_block(3, chans[0])] + [_block(chans[i - 1], chans[i]) for i in range(1, LEVELS + 1)]
        )
        self.up = nn.ModuleList([_block(chans[i + 1] + chans[i], chans[i]) for i in reversed(range(LEVELS))])
        self.head = nn.Conv2d(chans[0], 1, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for i, block in enumerate(self.down):
            x = block(x if i == 0 else F.max_pool2d(x, 2))
            skips.append(x)
        x = skips.pop()
        for block in self.up:
            skip = skips.pop()
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], 1))
        return self.head(x)


def parameter_count(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
