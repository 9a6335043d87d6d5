"""Gaussian rasterization behind one gsplat-like function. Backends: ``torch`` (the pure-PyTorch reference),
``cpu`` (C++ with a hand-written backward) and ``gsplat`` (CUDA); ``auto`` picks ``gsplat`` for CUDA tensors
when gsplat is built and runs, ``cpu`` for CPU tensors when it builds, else ``torch``. Per-Gaussian contributions
for gsplat come from ``contrib.py``."""

from __future__ import annotations

import logging

import torch

from . import cpu_backend, gsplat_backend
from .projection import project_gaussians, quat_to_rotmat
from .sh import sh_colors_reference, sh_to_rgb, split_sh
from .torch_backend import rasterize_tiles

BACKENDS = ("auto", "torch", "cpu", "gsplat")
log = logging.getLogger("panorecon.splat")
_announced: set[str] = set()


def resolve_backend(backend: str, cuda_tensors: bool = False) -> str:
    """'auto' -> for CUDA tensors 'gsplat' when it is built and runs, else 'torch'; for CPU tensors 'cpu' when
    the C++ kernel is available, else 'torch'. A named backend that cannot serve the tensors is refused."""
    if backend not in BACKENDS:
        raise ValueError(f"backend={backend!r}: expected one of {BACKENDS}")
    if backend == "cpu" and cuda_tensors:
        raise RuntimeError("backend='cpu' renders CPU tensors; for CUDA tensors use backend 'gsplat' or 'torch'")
    if backend == "cpu" and not cpu_backend.available():
        raise RuntimeError(
            f"backend='cpu' asked for, but the C++ rasterizer could not be built ({cpu_backend.unavailable_reason()})"
        )
    if backend == "gsplat" and not gsplat_backend.available():
        raise RuntimeError(
            f"backend='gsplat' asked for, but it cannot run here: {gsplat_backend.unavailable_reason()} "
            "(pip install 'panorecon[cuda]' on a CUDA machine)"
        )
    if backend == "gsplat" and not cuda_tensors:
        raise RuntimeError("backend='gsplat' renders CUDA tensors; for CPU tensors use backend 'cpu' or 'torch'")
    if backend == "auto":
        chosen = (
            ("gsplat" if gsplat_backend.available() else "torch")
            if cuda_tensors
            else "cpu"
            if cpu_backend.available()
            else "torch"
        )
    else:
        chosen = backend
    if chosen not in _announced:
        _announced.add(chosen)
        log.info("rasterizer backend: %s%s", chosen, " (auto)" if backend == "auto" else "")
    return chosen


def antialias_compensation(conics: torch.Tensor, eps2d: float) -> torch.Tensor:
    """sqrt(det S / det(S + eps2d I)) [...] of each 2D covariance S, from the conics [..., 3] = (a, b, c) of
    (S + eps2d I)^-1: det S / det(S + eps2d I) = det((I - eps2d Q)) = 1 - eps2d (a + c) + eps2d^2 (a c - b^2)
    with Q the conic. In float32 the sum cancels to ~1e-7 absolute for sub-pixel Gaussians (S -> 0, Q -> I /
    eps2d), an error of at most ~3e-4 in a compensation that small; clamped at 0 (a degenerate S), and at
    1e-12 under the root so its gradient stays finite."""
    a, b, c = conics.unbind(-1)
    ratio = 1 - eps2d * (a + c) + eps2d * eps2d * (a * c - b * b)
    return torch.sqrt(ratio.clamp(min=1e-12)) * (ratio > 0)


def rasterize(
    means,
    quats,
    scales,
    opacities,
    colors,
    viewmats,
    Ks,
    width: int,
    height: int,
    *,
    sh_degree=None,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    backgrounds=None,
    backend: str = "auto",
    eps2d: float = 0.3,
    antialiased: bool = False,
    tile_size: int = 16,
    return_contrib: bool = False,
):
    """Render Gaussians into C cameras.

    means [N,3] metres; quats [N,4] wxyz (any norm, zero = identity); scales [N,3] metres (linear);
    opacities [N] in [0,1]; colors [N,3] RGB, [C,N,D] per camera, or SH coefficients with ``sh_degree``: [N,K,3],
    or the pair (DC band [N,1,3], higher bands [N,K-1,3]) as the model keeps them (the cpu backend reads the pair
    in place; the others concatenate it);
    viewmats [C,4,4]
    world-to-camera (OpenCV); Ks [C,3,3]. Returns image [C,H,W,3], alpha [C,H,W,1], depth [C,H,W,1]
    (accumulated z; expected depth = depth / alpha) and meta: means2d [C,N,2], conics, depths [C,N],
    radii [C,N], backend, and with ``return_contrib`` weight_sum / weight_max / trans_max [C,N] (detached).
    ``antialiased``: each Gaussian's opacity in each camera times ``antialias_compensation`` (Mip-Splatting's 2D
    mip filter, gsplat's ``rasterize_mode='antialiased'``): the ``eps2d`` low-pass then keeps a Gaussian's
    integrated alpha instead of widening it, so one smaller than a pixel fades rather than grows.
    """
    backend = resolve_backend(backend, means.is_cuda)
    if isinstance(colors, (tuple, list)):
        if sh_degree is None:
            raise ValueError("colors as a pair (DC band, higher bands) are SH coefficients: give sh_degree")
        if backend != "cpu":
            colors = torch.cat(split_sh(colors), 1)
    if backend == "gsplat":
        image, alpha, depth, meta = gsplat_backend.rasterize_gsplat(
            means,
            quats,
            scales,
            opacities,
            colors,
            viewmats,
            Ks,
            width,
            height,
            sh_degree,
            near_plane,
            far_plane,
            backgrounds,
            eps2d,
            antialiased,
            tile_size,
            return_contrib,
        )
        return image, alpha, depth, {**meta, "backend": backend}
    # the C++ projection does not differentiate w.r.t. the cameras: the reference runs when they need gradients
    project = (
        cpu_backend.project
        if backend == "cpu" and not (viewmats.requires_grad or Ks.requires_grad)
        else project_gaussians
    )
    means2d, conics, depths, radii = project(
        means, quats, scales, viewmats, Ks, width, height, near_plane, far_plane, eps2d
    )
    if sh_degree is None:
        per_camera = (
            colors.dim() == 3 and colors.shape[0] == len(viewmats) and (backend == "torch" or colors.shape[-1] == 3)
        )
        if not per_camera and (colors.dim() != 2 or colors.shape[-1] != 3):
            raise ValueError(
                f"colors of shape {tuple(colors.shape)}: expected [N, 3] RGB, [C, N, D] per camera (D = 3 "
                "on the cpu backend), or SH coefficients [N, K, 3] with sh_degree"
            )
        cols = colors if per_camera else colors[None].expand(len(viewmats), -1, -1)
    else:
        campos = -torch.einsum("cji,cj->ci", viewmats[:, :3, :3], viewmats[:, :3, 3])
        if backend == "cpu":  # only the pairs the compositor reads (radius > 0)
            cols = cpu_backend.sh_colors(sh_degree, colors, means, campos, radii)
        else:
            cols = sh_colors_reference(sh_degree, colors, means, campos)
    if antialiased:  # [C, N]: the compensation differs per camera
        opacities = opacities[None] * antialias_compensation(conics, eps2d)
    if backend == "cpu":
        image, alpha, depth, contrib = cpu_backend.composite(
            means2d, conics, cols, opacities, depths, radii, width, height, tile_size, return_contrib
        )
        if backgrounds is not None:
            image = image + (1 - alpha) * backgrounds[:, None, None, :].to(image.dtype)
    else:
        image, alpha, depth, contrib = rasterize_tiles(
            means2d, conics, cols, opacities, depths, radii, width, height, tile_size, backgrounds, return_contrib
        )
    meta = {"means2d": means2d, "conics": conics, "depths": depths, "radii": radii, "backend": backend}
    if contrib:
        meta.update(contrib)
    return image, alpha, depth, meta


__all__ = ["rasterize", "antialias_compensation", "project_gaussians", "quat_to_rotmat", "sh_to_rgb", "BACKENDS"]
