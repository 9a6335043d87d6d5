"""Real spherical harmonics up to degree 3 with the 3DGS / gsplat constants and sign conventions."""

from __future__ import annotations

import torch

C0 = 0.28209479177387814
C1 = 0.4886025119029199
C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
C3 = (
    -0.5900435899266435,
    2.890611442640554,
    -0.4570457994644658,
    0.3731763325901154,
    -0.4570457994644658,
    1.445305721320277,
    -0.5900435899266435,
)


def sh_basis(degree: int, dirs: torch.Tensor) -> torch.Tensor:
    """Basis values [..., (degree + 1)^2] at unit directions [..., 3]."""
    if not 0 <= degree <= 3:
        raise ValueError(f"sh_degree={degree}: expected 0..3")
    x, y, z = dirs.unbind(-1)
    out = [torch.full_like(x, C0)]
    if degree >= 1:
        out += [-C1 * y, C1 * z, -C1 * x]
    if degree >= 2:
        xx, yy, zz, xy, yz, xz = x * x, y * y, z * z, x * y, y * z, x * z
        out += [C2[0] * xy, C2[1] * yz, C2[2] * (2 * zz - xx - yy), C2[3] * xz, C2[4] * (xx - yy)]
    if degree >= 3:
        out += [
            C3[0] * y * (3 * xx - yy),
            C3[1] * xy * z,
            C3[2] * y * (4 * zz - xx - yy),
            C3[3] * z * (2 * zz - 3 * xx - 3 * yy),
            C3[4] * x * (4 * zz - xx - yy),
            C3[5] * z * (xx - yy),
            C3[6] * x * (xx - 3 * yy),
        ]
    return torch.stack(out, -1)


def check_sh(degree: int, coeffs: torch.Tensor | int) -> None:
    """One clear error unless 0 <= ``degree`` <= 3 and coeffs [N, K, 3] (or K given as an int) has
    K >= (degree + 1)^2."""
    k = coeffs if isinstance(coeffs, int) else coeffs.shape[-2]
    if not 0 <= degree <= 3 or k < (degree + 1) ** 2:
        raise ValueError(
            f"sh_degree={degree} with {k} coefficients per channel: expected 0..3, "
            "and (degree + 1)^2 coefficients or more"
        )


def split_sh(coeffs) -> tuple[torch.Tensor, torch.Tensor]:
    """SH coefficients as (DC band [N,1,3], higher bands [N,K-1,3]): a pair as given (the model's sh0 and shN), or
    views of one [N,K,3] tensor."""
    if isinstance(coeffs, (tuple, list)):
        dc, rest = coeffs
        if dc.dim() != 3 or dc.shape[1:] != (1, 3) or rest.dim() != 3 or rest.shape[0] != dc.shape[0]:
            raise ValueError(
                f"SH coefficients as a pair of shapes {tuple(dc.shape)} and {tuple(rest.shape)}: expected "
                "[N, 1, 3] and [N, K - 1, 3]"
            )
        return dc, rest
    return coeffs[:, :1], coeffs[:, 1:]


def sh_to_rgb(degree: int, coeffs: torch.Tensor, dirs: torch.Tensor) -> torch.Tensor:
    """coeffs [N, K, 3] (K >= (degree + 1)^2), dirs [C, N, 3] unit -> colours [C, N, 3] = SH + 0.5, >= 0."""
    check_sh(degree, coeffs)
    k = (degree + 1) ** 2
    basis = sh_basis(degree, dirs)  # [C, N, k]
    return (torch.einsum("cnk,nkd->cnd", basis, coeffs[:, :k]) + 0.5).clamp_min(0.0)


def sh_colors_reference(degree: int, coeffs: torch.Tensor, means: torch.Tensor, campos: torch.Tensor) -> torch.Tensor:
    """Colours [C, N, 3] of every Gaussian seen from camera centres campos [C, 3]: ``sh_to_rgb`` along
    (mean - centre) / max(|mean - centre|, 1e-12). The torch backends' path, and the reference of the cpu
    backend's ``sh_colors``."""
    dirs = means[None] - campos[:, None]
    return sh_to_rgb(degree, coeffs, dirs / dirs.norm(dim=-1, keepdim=True).clamp_min(1e-12))
