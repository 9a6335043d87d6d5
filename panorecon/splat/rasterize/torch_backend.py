"""Pure-PyTorch tiled rasterizer: the obviously-correct reference, differentiable by autograd.

Per camera and per 16x16 tile, the Gaussians whose 3-sigma square touches the tile are sorted front to back
by depth and composited: alpha_i = min(0.999, o_i exp(-sigma_i)), sigma_i = 0.5 d^T conic d at pixel centres;
alpha < 1/255 or sigma < 0 contributes nothing; blending stops before the Gaussian that would bring the
transmittance to 1e-4 or below (gsplat's rules). Works in the dtype of its inputs (float64 for gradcheck).
"""

from __future__ import annotations

import torch

ALPHA_MIN = 1.0 / 255.0
ALPHA_MAX = 0.999  # gsplat's cap (RasterizeToPixels3DGSFwd.cu); the original 3DGS kernels use 0.99
T_MIN = 1e-4


def rasterize_tiles(
    means2d,
    conics,
    colors,
    opacities,
    depths,
    radii,
    width: int,
    height: int,
    tile_size: int = 16,
    backgrounds=None,
    return_contrib: bool = False,
):
    """means2d [C,N,2], conics [C,N,3], colors [C,N,D], opacities [N] or [C,N], depths [C,N], radii [C,N] ->
    (image [C,H,W,D], alpha [C,H,W,1], depth [C,H,W,1] accumulated z, contrib dict or None)."""
    C, N, D = colors.shape
    dev, dt = colors.device, colors.dtype
    rows_img, rows_alpha, rows_depth = [], [], []
    contrib = None
    if return_contrib:
        contrib = {k: torch.zeros(C, N, dtype=dt, device=dev) for k in ("weight_sum", "weight_max", "trans_max")}
    for c in range(C):
        idx_all = torch.nonzero(radii[c] > 0).flatten()
        m2 = means2d[c, idx_all].detach()
        r = radii[c, idx_all].to(dt)
        order = torch.argsort(depths[c, idx_all].detach(), stable=True)
        tile_rows_img, tile_rows_alpha, tile_rows_depth = [], [], []
        for ty in range(0, height, tile_size):
            th = min(tile_size, height - ty)
            cols_img, cols_alpha, cols_depth = [], [], []
            for tx in range(0, width, tile_size):
                tw = min(tile_size, width - tx)
                touch = (
                    (m2[:, 0] + r >= tx) & (m2[:, 0] - r <= tx + tw) & (m2[:, 1] + r >= ty) & (m2[:, 1] - r <= ty + th)
                )
                hit = idx_all[order[touch[order]]]
                img, a, z = _tile(
                    c,
                    hit,
                    means2d,
                    conics,
                    colors,
                    opacities,
                    depths,
                    tx,
                    ty,
                    tw,
                    th,
                    contrib,
                    None if backgrounds is None else backgrounds[c],
                )
                cols_img.append(img)
                cols_alpha.append(a)
                cols_depth.append(z)
            tile_rows_img.append(torch.cat(cols_img, 1))
            tile_rows_alpha.append(torch.cat(cols_alpha, 1))
            tile_rows_depth.append(torch.cat(cols_depth, 1))
        rows_img.append(torch.cat(tile_rows_img, 0))
        rows_alpha.append(torch.cat(tile_rows_alpha, 0))
        rows_depth.append(torch.cat(tile_rows_depth, 0))
    return torch.stack(rows_img), torch.stack(rows_alpha), torch.stack(rows_depth), contrib


def _tile(c, hit, means2d, conics, colors, opacities, depths, tx, ty, tw, th, contrib, background):
    """One tile -> (rgb [th, tw, D], alpha [th, tw, 1], accumulated z [th, tw, 1])."""
    dev, dt = colors.device, colors.dtype
    D = colors.shape[-1]
    if len(hit) == 0:
        img = colors.new_zeros(th, tw, D) if background is None else background.expand(th, tw, D).clone()
        return img, colors.new_zeros(th, tw, 1), colors.new_zeros(th, tw, 1)
    ii, jj = torch.meshgrid(
        torch.arange(th, device=dev, dtype=dt) + ty + 0.5,
        torch.arange(tw, device=dev, dtype=dt) + tx + 0.5,
        indexing="ij",
    )
    px = torch.stack([jj.reshape(-1), ii.reshape(-1)], -1)  # [P, 2] (x, y)
    d = px[:, None, :] - means2d[c, hit][None]  # [P, G, 2]
    a, b, cc = conics[c, hit].unbind(-1)
    sigma = 0.5 * (a * d[..., 0] ** 2 + cc * d[..., 1] ** 2) + b * d[..., 0] * d[..., 1]
    o = opacities[c, hit] if opacities.dim() == 2 else opacities[hit]
    al = torch.clamp(o * torch.exp(-sigma), max=ALPHA_MAX)
    al = torch.where((sigma >= 0) & (al >= ALPHA_MIN), al, torch.zeros_like(al))
    keep = torch.cumprod(1 - al.detach(), dim=1) > T_MIN  # monotone: once it fails every later one fails
    al = torch.where(keep, al, torch.zeros_like(al))
    T_after = torch.cumprod(1 - al, dim=1)
    T_before = torch.cat([torch.ones_like(T_after[:, :1]), T_after[:, :-1]], 1)
    w = al * T_before  # [P, G]
    rgb = w @ colors[c, hit]
    if background is not None:
        rgb = rgb + T_after[:, -1:] * background
    if contrib is not None:
        wd = w.detach()
        contrib["weight_sum"][c].index_add_(0, hit, wd.sum(0))
        contrib["weight_max"][c, hit] = torch.maximum(contrib["weight_max"][c, hit], wd.max(0).values)
        tb = torch.where(al.detach() >= ALPHA_MIN, T_before.detach(), torch.zeros_like(wd))
        contrib["trans_max"][c, hit] = torch.maximum(contrib["trans_max"][c, hit], tb.max(0).values)
    return (rgb.reshape(th, tw, D), (1 - T_after[:, -1]).reshape(th, tw, 1), (w @ depths[c, hit]).reshape(th, tw, 1))
