"""Per-Gaussian blending contributions (weight_sum, weight_max, trans_max [C,N]) for backends whose kernels do
not compute them (gsplat), from the (camera, pixel, Gaussian) pairs that the compositor blended.

For one pixel the blended Gaussians, front to back, have alpha_k and transmittance in front
T_k = prod_{j<k} (1 - alpha_j); the pixel's colour is sum_k c_k alpha_k T_k. Per Gaussian:
weight_sum = sum over pixels of alpha T (pixels), weight_max = max alpha T, trans_max = max T (the
definitions of ``torch_backend``/``cpu_backend``). ``contributions_from_pairs`` evaluates them exactly from the
pairs (sorted here, so the enumerator's order does not matter); ``pairs_reference`` is the slow, dense
enumerator with the reference compositor's rules (tile test on the 3-sigma square, alpha >= 1/255, stop before
T would reach 1e-4); gsplat's own enumerator is ``gsplat_backend.blended_pairs``.
``weight_sum_by_gradient`` is an independent, backend-agnostic check of weight_sum: render one extra channel
whose per-Gaussian colour is a leaf of ones; the rendered channel is sum_k 1 alpha_k T_k, so the gradient of its
pixel sum w.r.t. Gaussian i's colour is sum over pixels of alpha_i T_i = weight_sum_i.
"""

from __future__ import annotations

from collections.abc import Callable

import torch

from .torch_backend import ALPHA_MAX, ALPHA_MIN, T_MIN


def pair_alphas(means2d, conics, opacities, image_ids, pixel_ids, gaussian_ids, width: int) -> torch.Tensor:
    """alpha [M] of each (camera, pixel, Gaussian) pair at the pixel centre (0 where sigma < 0 or alpha < 1/255);
    opacities [N] or per camera [C,N]. Float64 arithmetic: T is a product of up to thousands of factors."""
    px = (pixel_ids % width).double() + 0.5
    py = torch.div(pixel_ids, width, rounding_mode="floor").double() + 0.5
    m = means2d.detach()[image_ids, gaussian_ids].double()
    a, b, c = conics.detach()[image_ids, gaussian_ids].double().unbind(-1)
    dx, dy = px - m[:, 0], py - m[:, 1]
    sigma = 0.5 * (a * dx * dx + c * dy * dy) + b * dx * dy
    op = opacities.detach().double()
    o = op[image_ids, gaussian_ids] if op.dim() == 2 else op[gaussian_ids]
    al = torch.clamp(o * torch.exp(-sigma), max=ALPHA_MAX)
    return torch.where((sigma >= 0) & (al >= ALPHA_MIN), al, torch.zeros_like(al))


def contributions_from_pairs(
    means2d, conics, opacities, depths, image_ids, pixel_ids, gaussian_ids, width: int, height: int
) -> dict:
    """Exact weight_sum / weight_max / trans_max [C,N] (dtype of means2d) from the pairs a compositor blended.

    means2d [C,N,2], conics [C,N,3], opacities [N] or [C,N], depths [C,N]; image_ids, pixel_ids (row-major),
    gaussian_ids [M] int64 in any order. Pairs are ordered by (camera, pixel, depth) (stable), T is an
    exclusive product per pixel in float64 (log-sum over each pixel's run), and blending stops before T would
    fall to 1e-4, as in the compositors."""
    C, N = depths.shape
    dev, dt = means2d.device, means2d.dtype
    out = {k: torch.zeros(C * N, dtype=torch.float64, device=dev) for k in ("weight_sum", "weight_max", "trans_max")}
    if len(gaussian_ids):
        image_ids, pixel_ids, gaussian_ids = image_ids.long(), pixel_ids.long(), gaussian_ids.long()
        order = torch.argsort(depths.detach()[image_ids, gaussian_ids], stable=True)
        ray = image_ids * (width * height) + pixel_ids
        order = order[torch.argsort(ray[order], stable=True)]
        ray, img, pix, gid = ray[order], image_ids[order], pixel_ids[order], gaussian_ids[order]
        al = pair_alphas(means2d, conics, opacities, img, pix, gid, width)
        log_keep = torch.log1p(-al)  # alpha <= 0.999: finite
        incl = torch.cumsum(log_keep, 0)
        start = torch.ones_like(ray, dtype=torch.bool)
        start[1:] = ray[1:] != ray[:-1]
        first = torch.cummax(torch.where(start, torch.arange(len(ray), device=dev), 0), 0).values
        before_run = (incl - log_keep)[first]  # cumulative log up to the run's first pair, exclusive
        T_before = torch.exp(incl - log_keep - before_run)
        T_after = torch.exp(incl - before_run)
        # the stop rule is monotone along a pixel's run: once T after a Gaussian is <= 1e-4 nothing else blends
        blended = (T_after > T_MIN) & (al > 0)
        w = torch.where(blended, al * T_before, torch.zeros_like(al))
        flat = img * N + gid
        out["weight_sum"].index_add_(0, flat, w)
        out["weight_max"].scatter_reduce_(0, flat, w, "amax")
        out["trans_max"].scatter_reduce_(0, flat, torch.where(blended, T_before, torch.zeros_like(al)), "amax")
    return {k: v.reshape(C, N).to(dt) for k, v in out.items()}


def pairs_reference(means2d, conics, opacities, radii, width: int, height: int, tile_size: int = 16):
    """The (image_ids, pixel_ids, gaussian_ids) [M] that ``torch_backend`` may blend: the Gaussian is visible
    (radius > 0), its 3-sigma square touches the pixel's tile, and alpha >= 1/255 at the pixel centre (the T
    stop is applied by ``contributions_from_pairs``). Dense over pixels x Gaussians per camera: for tests."""
    C, N = radii.shape
    dev = means2d.device
    ys, xs = torch.meshgrid(torch.arange(height, device=dev), torch.arange(width, device=dev), indexing="ij")
    tx0 = (torch.div(xs, tile_size, rounding_mode="floor") * tile_size).reshape(-1, 1).double()
    ty0 = (torch.div(ys, tile_size, rounding_mode="floor") * tile_size).reshape(-1, 1).double()
    tw = torch.clamp(width - tx0, max=tile_size)
    th = torch.clamp(height - ty0, max=tile_size)
    pix = torch.arange(width * height, device=dev)
    out = []
    for c in range(C):
        m = means2d.detach()[c].double()
        r = radii[c].double()
        touch = (
            (m[:, 0] + r >= tx0)
            & (m[:, 0] - r <= tx0 + tw)
            & (m[:, 1] + r >= ty0)
            & (m[:, 1] - r <= ty0 + th)
            & (radii[c] > 0)
        )  # [P, N]
        p, g = torch.nonzero(touch, as_tuple=True)
        img = torch.full_like(p, c)
        al = pair_alphas(means2d, conics, opacities, img, pix[p], g, width)
        keep = al > 0
        out.append((img[keep], pix[p][keep], g[keep]))
    return tuple(torch.cat(parts) for parts in zip(*out))


def weight_sum_by_gradient(
    render_channel: Callable[[torch.Tensor], torch.Tensor], C: int, N: int, device=None
) -> torch.Tensor:
    """weight_sum [C,N] of any differentiable backend: ``render_channel(ones)`` renders per-Gaussian colours
    ``ones`` [C,N,1] (a leaf requiring grad) and returns the rendered channel [C,H,W,1]; the gradient of its sum
    w.r.t. ``ones`` is sum over pixels of alpha_i T_i."""
    ones = torch.ones(C, N, 1, device=device, requires_grad=True)
    with torch.enable_grad():
        channel = render_channel(ones)
        (grad,) = torch.autograd.grad(channel.sum(), ones)
    return grad[..., 0]
