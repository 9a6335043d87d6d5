"""The ``gsplat`` backend: gsplat's CUDA rasterizer behind panorecon's ``rasterize`` contract.

Used when CUDA and the gsplat package are present (``pip install 'panorecon[cuda]'``). Conventions are the
same as ours (OpenCV world-to-camera viewmats, pixel centres at +0.5, EWA low-pass eps2d, 3σ radii), so only
the output layout is adapted: ``render_mode="RGB+D"`` gives the accumulated z that our ``depth`` is. gsplat
does not return per-Gaussian blending contributions, so ``return_contrib`` (the adaptive strategy) needs the
``cpu`` or ``torch`` backend.
"""
from __future__ import annotations

import torch


def available() -> bool:
    if not torch.cuda.is_available():
        return False
    try:
        import gsplat  # noqa: F401  (the check is whether it imports)
    except ImportError:
        return False
    return True


def rasterize_gsplat(means, quats, scales, opacities, colors, viewmats, Ks, width, height, sh_degree, near_plane,
                     far_plane, backgrounds, eps2d, tile_size):
    """-> (image [C,H,W,3], alpha [C,H,W,1], accumulated z [C,H,W,1], meta with means2d, conics, depths, radii [C,N])."""
    from gsplat import rasterization

    # our convention: a zero-norm quaternion is the identity rotation (gsplat would normalise it to NaN)
    zero = quats.norm(dim=-1, keepdim=True) < 1e-12
    quats = torch.where(zero, torch.tensor([1.0, 0.0, 0.0, 0.0], device=quats.device, dtype=quats.dtype), quats)
    out, alpha, meta = rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height,
                                     near_plane=near_plane, far_plane=far_plane, eps2d=eps2d, sh_degree=sh_degree,
                                     packed=False, tile_size=tile_size, backgrounds=backgrounds, render_mode="RGB+D")
    radii = meta["radii"]
    if radii.dim() == 3:  # gsplat >= 1.5 gives per-axis radii
        radii = radii.max(dim=-1).values
    return out[..., :3], alpha, out[..., 3:4], {"means2d": meta["means2d"], "conics": meta["conics"],
                                                "depths": meta["depths"], "radii": radii}
