"""The standard 3DGS PLY layout, as the original code and common viewers read it:
x, y, z, nx, ny, nz, f_dc_0..2, f_rest_0..(3*(K-1)-1) (channel-major), opacity (logit), scale_0..2 (log),
rot_0..3 (wxyz); binary little-endian float32."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from ..io import PanoreconInputError, atomic_write
from .model import GaussianModel


def ply_properties(n_rest: int) -> list[str]:
    """Property names in file order for ``n_rest`` = 3 * ((d+1)^2 - 1) f_rest values."""
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(n_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def save_ply(model: GaussianModel, path: str | os.PathLike) -> None:
    with torch.no_grad():
        n = len(model)
        # f_rest is channel-major: all bands of red, then green, then blue
        rest = model.shN.detach().transpose(1, 2).reshape(n, -1)
        cols = [
            model.means,
            torch.zeros(n, 3),
            model.sh0.detach()[:, 0],
            rest,
            model.logit_opacities[:, None],
            model.log_scales,
            model.quats,
        ]
        data = torch.cat([c.detach().float().cpu() for c in cols], 1).numpy()
    names = ply_properties(rest.shape[1])
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {n}\n" + "".join(f"property float {p}\n" for p in names) + "end_header\n"
    )
    with atomic_write(path) as tmp, open(tmp, "wb") as f:
        f.write(header.encode("ascii"))
        f.write(np.ascontiguousarray(data, dtype="<f4").tobytes())


def load_ply(path: str | os.PathLike) -> GaussianModel:
    path = Path(path)
    if not path.is_file():
        raise PanoreconInputError(f"{path}: no such file")
    raw = path.read_bytes()
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply\n") or end < 0:
        raise PanoreconInputError(f"{path}: not a PLY file")
    lines = raw[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise PanoreconInputError(f"{path}: expected a binary little-endian 3DGS PLY")
    n = int(next(ln.split()[2] for ln in lines if ln.startswith("element vertex")))
    names = [ln.split()[2] for ln in lines if ln.startswith("property float")]
    n_rest = sum(p.startswith("f_rest_") for p in names)
    if names != ply_properties(n_rest) or n_rest % 3:
        raise PanoreconInputError(f"{path}: properties {names[:6]}... are not the 3DGS layout")
    body = raw[end + len(b"end_header\n") :]
    if len(body) < n * len(names) * 4:
        raise PanoreconInputError(f"{path}: truncated ({len(body)} bytes for {n} Gaussians)")
    a = torch.from_numpy(np.frombuffer(body, dtype="<f4", count=n * len(names)).reshape(n, len(names)).copy())
    k = n_rest // 3
    return GaussianModel(
        a[:, 0:3],
        a[:, -4:],
        a[:, -7:-4],
        a[:, -8],
        a[:, 6:9][:, None, :],
        a[:, 9 : 9 + n_rest].reshape(n, 3, k).transpose(1, 2).contiguous(),
    )
