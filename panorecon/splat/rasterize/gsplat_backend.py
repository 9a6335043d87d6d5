"""The ``gsplat`` backend: gsplat's CUDA rasterizer behind panorecon's ``rasterize`` contract.

Installed with ``pip install 'panorecon[cuda]'``; its CUDA kernels are compiled ahead of time by
``python -m panorecon.splat.rasterize.build --cuda`` (or on first use). ``available()`` means built and
runnable: CUDA is present, gsplat imports and a one-Gaussian render ran. Conventions shared with the
reference (``projection.py``, ``torch_backend.py``): OpenCV world-to-camera viewmats, pixel centres at +0.5, the
EWA low-pass eps2d, alpha = min(0.999, o exp(-sigma)) skipped below 1/255, blending stopped before T reaches
1e-4; ``render_mode="RGB+D"`` gives the accumulated z that our ``depth`` is.

Where the two differ (gsplat 1.5, ``ProjectionEWA3DGSFused.cu``): the reference's radius is
ceil(3 sqrt(largest eigenvalue of the 2D covariance)) and its tile test uses that square; gsplat keeps a radius
per image axis, ceil(e sqrt(cov_xx)) and ceil(e sqrt(cov_yy)) with e = min(3.33, sqrt(2 ln(255 o))) (an
opacity-aware box), culls Gaussians whose opacity is below 1/255, and culls against the image with the per-axis
box. ``radii`` here is the larger of the two axes. Densification reads radii only as visibility (radius > 0);
the sets differ only for Gaussians that blend nothing (opacity < 1/255) or whose reference square reaches the
image but whose gsplat box does not, and ``means2d`` (and its gradient) agree where both see a Gaussian
(``tests/splat/test_rasterize_gsplat.py``, marked ``cuda``). Per-Gaussian contributions, which gsplat's kernels
do not return, come from the pairs gsplat blended (``blended_pairs``) through ``contrib.contributions_from_pairs``.
"""

from __future__ import annotations

import logging
import time

import torch

log = logging.getLogger("panorecon.splat")
_state: dict = {}  # "ok": bool, "error": str, "seconds": build/first-run time


def _try_run() -> None:
    if not torch.cuda.is_available():
        _state.update(ok=False, error="no CUDA device")
        return
    try:
        from gsplat import rasterization
    except ImportError as e:
        _state.update(ok=False, error=f"gsplat is not installed ({e}); pip install 'panorecon[cuda]'")
        return
    t = time.perf_counter()
    try:  # the first call compiles gsplat's kernels unless a prebuilt wheel carries them
        dev = torch.device("cuda")
        eye = torch.eye(4, device=dev)[None]
        K = torch.tensor([[[8.0, 0, 8], [0, 8.0, 8], [0, 0, 1]]], device=dev)
        rasterization(
            torch.tensor([[0.0, 0, 2]], device=dev),
            torch.tensor([[1.0, 0, 0, 0]], device=dev),
            torch.full((1, 3), 0.3, device=dev),
            torch.ones(1, device=dev),
            torch.ones(1, 3, device=dev),
            eye,
            K,
            16,
            16,
        )
        torch.cuda.synchronize()
    except Exception as e:  # a failed kernel build: report it, fall back to the other backends
        first_line = str(e).splitlines()[0] if str(e) else ""
        _state.update(ok=False, error=f"gsplat did not run: {type(e).__name__}: {first_line}")
        log.warning("gsplat backend unavailable (%s)", _state["error"])
        return
    _state.update(ok=True, error=None, seconds=time.perf_counter() - t)


def available() -> bool:
    """CUDA present, gsplat importable and its kernels built and run once (cached for the process)."""
    if "ok" not in _state:
        _try_run()
    return _state["ok"]


def unavailable_reason() -> str | None:
    return None if available() else _state["error"]


def build_seconds() -> float | None:
    """Seconds the first gsplat render took in this process (the kernel build when they were not built yet)."""
    return _state.get("seconds") if available() else None


def rasterize_gsplat(
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
    return_contrib: bool = False,
):
    """-> (image [C,H,W,D], alpha [C,H,W,1], accumulated z [C,H,W,1], meta with means2d, conics, depths,
    radii [C,N] (the larger per-axis radius) and, with ``return_contrib``, weight_sum / weight_max / trans_max
    [C,N] (detached))."""
    from gsplat import rasterization

    from .contrib import contributions_from_pairs

    # our convention: a zero-norm quaternion is the identity rotation (gsplat would normalise it to NaN)
    zero = quats.norm(dim=-1, keepdim=True) < 1e-12
    quats = torch.where(zero, torch.tensor([1.0, 0.0, 0.0, 0.0], device=quats.device, dtype=quats.dtype), quats)
    out, alpha, meta = rasterization(
        means,
        quats,
        scales,
        opacities,
        colors,
        viewmats,
        Ks,
        width,
        height,
        near_plane=near_plane,
        far_plane=far_plane,
        eps2d=eps2d,
        rasterize_mode="antialiased" if antialiased else "classic",
        sh_degree=sh_degree,
        packed=False,
        tile_size=tile_size,
        backgrounds=backgrounds,
        render_mode="RGB+D",
    )
    radii = meta["radii"]
    if radii.dim() == 3:  # gsplat >= 1.5 gives per-axis radii
        radii = radii.max(dim=-1).values
    result = {"means2d": meta["means2d"], "conics": meta["conics"], "depths": meta["depths"], "radii": radii}
    if return_contrib:
        with torch.no_grad():
            image_ids, pixel_ids, gaussian_ids = blended_pairs(meta, width, height, tile_size)
            result.update(
                contributions_from_pairs(
                    meta["means2d"],
                    meta["conics"],
                    meta["opacities"],
                    meta["depths"],
                    image_ids,
                    pixel_ids,
                    gaussian_ids,
                    width,
                    height,
                )
            )
    return out[..., :-1], alpha, out[..., -1:], result  # RGB+D: the colour channels, then z


def blended_pairs(meta: dict, width: int, height: int, tile_size: int):
    """(image_ids, pixel_ids, gaussian_ids) [M] int64 of every pair gsplat blended in the render that produced
    ``meta`` (``gsplat.rasterize_to_indices_in_range`` over all batches, starting from T = 1)."""
    from gsplat import rasterize_to_indices_in_range

    means2d = meta["means2d"]
    C, N = means2d.shape[:2]
    T = torch.ones(C, height, width, device=means2d.device, dtype=means2d.dtype)
    flatten_ids = meta["flatten_ids"]
    gids, pids, iids = rasterize_to_indices_in_range(
        0,
        len(flatten_ids) + 1,
        T,
        means2d,
        meta["conics"],
        meta["opacities"],
        width,
        height,
        tile_size,
        meta["isect_offsets"],
        flatten_ids,
    )
    return iids.long(), pids.long(), gids.long() % N  # flatten_ids index the [C * N] flattened Gaussians
