"""The standard 3DGS PLY layout, as the original code and common viewers read it:
x, y, z, nx, ny, nz, f_dc_0..2, f_rest_0..(3*(K-1)-1) (channel-major), opacity (logit), scale_0..2 (log),
rot_0..3 (wxyz); binary little-endian float32, through ``io.ply`` (plyfile), checked against the original 3DGS
code's ``save_ply``/``load_ply`` in ``tests/splat/test_ply_3dgs.py``."""

from __future__ import annotations

import os

import numpy as np
import torch

from ..io import PanoreconInputError
from ..io.ply import read_ply, write_ply
from .model import GaussianModel


def ply_properties(n_rest: int) -> list[str]:
    """Property names in file order for ``n_rest`` = 3 * ((d+1)^2 - 1) f_rest values."""
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(n_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def save_ply(model: GaussianModel, path: str | os.PathLike) -> None:
    """Write ``model`` in the 3DGS layout (float32; normals 0, as the original writes them), atomically; a model
    with a footprint filter is written as rendered (the filter baked into its scales and opacities, as
    Mip-Splatting exports), so that any 3DGS viewer shows what was trained."""
    with torch.no_grad():
        n = len(model)
        logit_opacities, log_scales = model.logit_opacities, model.log_scales
        if model.footprint is not None:
            scales, opacities = model.rendered()
            logit_opacities, log_scales = torch.logit(opacities, eps=1e-7), torch.log(scales)  # eps: renders nothing
        # f_rest is channel-major: all bands of red, then green, then blue
        rest = model.shN.detach().transpose(1, 2).reshape(n, -1)
        cols = [
            model.means,
            torch.zeros(n, 3),
            model.sh0.detach()[:, 0],
            rest,
            logit_opacities[:, None],
            log_scales,
            model.quats,
        ]
        data = torch.cat([c.detach().float().cpu() for c in cols], 1).numpy()
    write_ply(path, [(name, data[:, i]) for i, name in enumerate(ply_properties(rest.shape[1]))])


def load_ply(path: str | os.PathLike) -> GaussianModel:
    """A 3DGS PLY -> ``GaussianModel`` (float32). Properties are found by name, as the original ``load_ply`` finds
    them (f_rest_i in numeric order; nx, ny, nz and any others ignored), so a file from another 3DGS writer
    reads whatever its property order. A file without the layout raises ``PanoreconInputError`` naming it."""
    fields = read_ply(path, "3DGS PLY")
    n_rest = sum(name.startswith("f_rest_") for name in fields)
    k = n_rest // 3
    need = [p for p in ply_properties(n_rest) if p not in ("nx", "ny", "nz")]
    missing = [p for p in need if p not in fields]
    if missing or n_rest % 3 or round((k + 1) ** 0.5) ** 2 != k + 1:
        raise PanoreconInputError(
            f"3DGS PLY {path}: properties {list(fields)[:6]}... are not the 3DGS layout "
            f"(missing {missing[:4]}, {n_rest} f_rest values; expected {need[:3]}..., f_rest_0..3*((d+1)^2-1)-1)"
        )

    n = len(fields["x"])

    def cols(names: list[str]) -> torch.Tensor:  # [N, len(names)] float32
        return torch.from_numpy(
            np.stack([fields[p].astype(np.float32) for p in names], 1) if names else np.zeros((n, 0), np.float32)
        )

    return GaussianModel(
        cols(["x", "y", "z"]),
        cols([f"rot_{i}" for i in range(4)]),
        cols([f"scale_{i}" for i in range(3)]),
        cols(["opacity"])[:, 0],
        cols([f"f_dc_{i}" for i in range(3)])[:, None, :],
        cols([f"f_rest_{i}" for i in range(n_rest)]).reshape(n, 3, k).transpose(1, 2).contiguous(),
    )
