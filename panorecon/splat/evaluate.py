"""The trainer's scores: its views rendered (over the sky environment), PSNR / SSIM / LPIPS of the pseudo-label
and held-out views, the held-out views' co-visible pixels against the reprojection oracle (the ceiling the
training panorama allows there), the colour-aligned scores of real held-out panoramas, and the summaries of a
run's held-out history."""

from __future__ import annotations

import math
import statistics

import numpy as np
import torch

from ..metrics.lpips import lpips_distance, lpips_or_reason
from .labels import COVISIBLE_REL_TOL, MIN_COVISIBLE_PIXELS, LabelView, covisible_shortfall
from .losses import ssim
from .model import GaussianModel
from .rasterize import rasterize

COVISIBLE_PERCENT = f"{COVISIBLE_REL_TOL:.0%}"
_COVISIBLE = (
    "co-visible pixels: those whose true 3D point X the training panorama sees (|X| from the panorama centre "
    f"within {COVISIBLE_PERCENT} of the panorama's true distance along X / |X|; sky where the panorama sees sky "
    "along the same ray), on views with at least "
    f"{MIN_COVISIBLE_PIXELS} of them"
)
ORACLE_MEANING = {
    "covisible_psnr": f"the Gaussians' render against the true view on the {_COVISIBLE}",
    "oracle_psnr": "reprojection oracle on the same pixels: the training panorama's colour at each co-visible "
    "pixel's true 3D point (perfect geometry, the training capture's exposure), raw: the ceiling a "
    "reconstruction from that one panorama can reach there",
    "oracle_gap": "oracle_psnr - covisible_psnr (dB, per view, averaged over the same views): the part of the "
    "co-visible error that is the method's to win (0: at the ceiling)",
    "covisible_fraction": "share of all held-out pixels that are co-visible",
}
# metrics.json 'meaning' of a synthetic scene's held-out scores (true renders)
RENDER_SCORE_MEANING = {
    "psnr": "the Gaussians' render against the true render, every pixel (the headline; disocclusion included)",
    "ssim": "SSIM of the same, every pixel",
    "lpips": "LPIPS of the same, every pixel",
    **ORACLE_MEANING,
}
# ... and of a real scene's (other panoramas: every score on the co-visible pixels)
HELDOUT_SCORE_MEANING = {
    "psnr": "raw: the Gaussians' render against the held-out panorama's view, co-visible pixels",
    "aligned_psnr": "the render after an affine 3x4 colour transform (RGB -> RGB + offset) fitted per view by "
    "least squares (float64) on the co-visible pixels, render mapped onto the held-out image (Mip-NeRF 360 "
    "color_correct, affine)",
    "aligned_ssim": "SSIM of the aligned render over the 11x11 windows wholly inside the co-visible pixels",
    "aligned_lpips": "LPIPS of the aligned render, only on views whose every pixel is co-visible",
    **ORACLE_MEANING,
    "oracle_aligned_psnr": "the reprojection oracle after the same per-view colour alignment",
    "oracle_aligned_gap": "oracle_aligned_psnr - aligned_psnr (dB, averaged over the views with both)",
}


def psnr(a: torch.Tensor, b: torch.Tensor) -> float:
    mse = float(torch.mean((a - b) ** 2))
    return float("inf") if mse == 0 else 10 * math.log10(1.0 / mse)


def _cameras(views: list[LabelView], device) -> tuple[torch.Tensor, torch.Tensor]:
    """-> viewmats [V,4,4], Ks [V,3,3] float32 on ``device``."""
    V = torch.tensor(np.stack([v.camera.viewmat for v in views]), dtype=torch.float32, device=device)
    K = torch.tensor(np.stack([v.camera.K for v in views]), dtype=torch.float32, device=device)
    return V, K


def _render(
    model: GaussianModel,
    views: list[LabelView],
    cfg,
    sh_degree: int,
    backend: str,
    return_contrib: bool = False,
    cameras=None,
    background=None,
    res: int | None = None,
):
    """Render ``views`` (their cameras given as ``cameras`` = (viewmats, Ks) when already on the device) over
    their sky background (``background`` [V, h, w, 3] when already on the device), ``res`` pixels square
    (default: the views' own size; another size needs ``cameras`` and ``background`` of that size)."""
    dev = model.means.device
    V, K = cameras if cameras is not None else _cameras(views, dev)
    size = res or views[0].camera.width
    scales, opacities = model.rendered()
    img, alpha, depth, meta = rasterize(
        model.means,
        model.quats,
        scales,
        opacities,
        (model.sh0, model.shN),  # the cpu backend reads both in place: no [N, 16, 3] concatenation per step
        V,
        K,
        size,
        size,
        sh_degree=sh_degree,
        near_plane=model.near_plane,
        backend=backend,
        antialiased=cfg.antialiased,
        return_contrib=return_contrib,
    )
    if background is None and views[0].background is not None:  # the sky environment (splat/initial.py)
        background = torch.from_numpy(np.stack([v.background for v in views])).to(dev)
    if background is not None:
        img = img + (1 - alpha) * background
    return img, alpha, depth, meta


def _heldout_psnr(model, views, cfg, backend) -> float:
    """Mean PSNR (dB) of the held-out views, the cheap history sample (no SSIM, no LPIPS); masked views (other
    panoramas) over their co-visible pixels, those with fewer than MIN_COVISIBLE_PIXELS left out, as in
    ``_evaluate_masked``. Call it only when ``covisible_shortfall(views)`` is None."""
    with torch.no_grad():
        return float(np.mean([p for p in (_view_psnr(model, v, cfg, backend) for v in views) if p is not None]))


def _view_psnr(model, v, cfg, backend) -> float | None:
    """PSNR (dB) of one view over its mask (all pixels without one); None below MIN_COVISIBLE_PIXELS."""
    if v.mask is not None and int(v.mask.sum()) < MIN_COVISIBLE_PIXELS:
        return None
    return _render_psnr(_render(model, [v], cfg, model.sh_degree, backend)[0][0].clamp(0, 1), v)


def _render_psnr(img: torch.Tensor, v: LabelView) -> float:
    """PSNR (dB) of a render [h, w, 3] (clamped to [0, 1]) against view ``v`` over its mask (all pixels without)."""
    t = torch.from_numpy(v.rgb).to(img.device)
    if v.mask is None:
        return psnr(img, t)
    m = torch.from_numpy(v.mask).to(img.device)
    return psnr(img[m], t[m])


def _evaluate(model, views, cfg, backend) -> dict:
    if not views:
        return {}
    if any(v.mask is not None for v in views):
        return _evaluate_masked(model, views, cfg, backend)
    net = lpips_or_reason(views[0].camera.width)
    ps, ss, lp, kept = [], [], [], []
    with torch.no_grad():
        for v in views:
            img = _render(model, [v], cfg, model.sh_degree, backend)[0][0].clamp(0, 1).cpu()
            t = torch.from_numpy(v.rgb)
            ps.append(psnr(img, t))
            ss.append(float(ssim(img, t)))
            if not isinstance(net, str):
                lp.append(lpips_distance(net, img, t))
            kept.append((v, img.numpy()))
    scores = {
        "psnr": float(np.mean(ps)),
        "ssim": float(np.mean(ss)),
        "lpips": float(np.mean(lp)) if lp else net,
        "views": len(views),
    }
    if all(v.covisible is None for v in views):  # pseudo-labels; held-out renders of a scene without true distance
        return scores
    fraction = covisible_fraction(views)
    return {**scores, **oracle_scores(kept), "covisible_fraction": fraction, "meaning": RENDER_SCORE_MEANING}


def _evaluate_masked(model, views, cfg, backend) -> dict:
    """PSNR over each view's masked pixels (the co-visible ones of a real held-out panorama), averaged over the
    views with at least MIN_COVISIBLE_PIXELS of them ('n/a: <reason>' with none); SSIM and LPIPS need whole
    windows, so they read n/a. Beside it (``_aligned_scores``): the render after a per-view affine colour
    alignment onto the held-out image, and the reprojection oracle (the training panorama's own colour at the
    true 3D points) raw and aligned, with the gaps to it: the ceiling the raw number is read against."""
    ps, pixels, kept = [], 0, []
    with torch.no_grad():
        for v in views:
            if v.mask is not None and int(v.mask.sum()) < MIN_COVISIBLE_PIXELS:
                continue
            img = _render(model, [v], cfg, model.sh_degree, backend)[0][0].clamp(0, 1)
            ps.append(_render_psnr(img, v))
            pixels += int(v.mask.sum())
            kept.append((v, img.cpu().numpy()))
    reason = "n/a: held-out real panoramas are scored on their co-visible pixels only (PSNR)"
    return {
        "psnr": float(np.mean(ps)) if ps else covisible_shortfall(views),
        "ssim": reason,
        "lpips": reason,
        "views": len(ps),
        "pixels": pixels,
        "min_pixels_per_view": MIN_COVISIBLE_PIXELS,
        "protocol": "other panoramas of the space, pixels the training "
        f"panorama also sees (true distances agree within {COVISIBLE_PERCENT})",
        "covisible_fraction": sum(int(v.mask.sum()) for v in views) / float(sum(v.mask.size for v in views)),
        **_aligned_scores(kept, lpips_or_reason(views[0].camera.width) if kept else None, covisible_shortfall(views)),
    }


def _mean_scores(vals: dict, why: dict, shortfall: str) -> dict:
    """Each key's mean over the views where it was computed (``vals`` key -> [float]) and its view count
    (``<key>_views``); where none: the first view's reason (``why``), else ``shortfall``."""
    out = {}
    for k, xs in vals.items():
        out[k] = float(np.mean(xs)) if xs else why.get(k, shortfall)
        out[f"{k}_views"] = len(xs)
    return out


def oracle_scores(kept: list, shortfall: str | None = None) -> dict:
    """The co-visible scores of held-out views ``kept`` [(view, render [h, w, 3] float32 in [0, 1])]: on each
    view with an oracle and MIN_COVISIBLE_PIXELS co-visible pixels, the render's PSNR (covisible_psnr) and the
    oracle's (oracle_psnr) on those pixels and their difference (oracle_gap), each averaged over those views,
    with ``<key>_views``; where there is none, 'n/a: <reason>' (``shortfall`` if given)."""
    from ..metrics.aligned import masked_psnr

    vals = {k: [] for k in ("covisible_psnr", "oracle_psnr", "oracle_gap")}
    reason = shortfall or "n/a: no held-out view to score"
    for v, img in kept:
        if v.oracle is None:
            reason = shortfall or "n/a: the held-out views have no reprojection oracle (no true distance)"
        elif int(v.covisible.sum()) < MIN_COVISIBLE_PIXELS:
            reason = shortfall or f"n/a: no held-out view has {MIN_COVISIBLE_PIXELS} co-visible pixels"
        else:
            model, oracle = masked_psnr(img, v.rgb, v.covisible), masked_psnr(v.oracle, v.rgb, v.covisible)
            vals["covisible_psnr"].append(model)
            vals["oracle_psnr"].append(oracle)
            vals["oracle_gap"].append(oracle - model)
    return _mean_scores(vals, {}, reason)


def covisible_fraction(views: list[LabelView]) -> float | str:
    """Share of the pixels of the held-out ``views`` with a co-visibility mask that are co-visible."""
    masks = [v.covisible for v in views if v.covisible is not None]
    if not masks:
        return "n/a: the held-out views have no co-visibility mask (no true distance)"
    return sum(int(m.sum()) for m in masks) / float(sum(m.size for m in masks))


def _aligned_scores(kept: list, net, shortfall: str | None) -> dict:
    """The aligned and oracle scores of masked held-out views: ``kept`` [(view, render [h, w, 3] float32 in
    [0, 1])] (the views with MIN_COVISIBLE_PIXELS co-visible pixels), ``net`` the LPIPS network or its n/a
    reason. Each is the mean over the views where it could be computed, with its view count; 'n/a: <reason>'
    (the first view's) where none could. The raw oracle and its gap: ``oracle_scores``."""
    from ..metrics.aligned import apply_color_affine, fit_color_affine, masked_psnr, masked_ssim

    vals = {k: [] for k in ("aligned_psnr", "aligned_ssim", "aligned_lpips", "oracle_aligned_psnr")}
    vals["oracle_aligned_gap"] = []
    why = {}
    for v, img in kept:
        m, truth = v.mask, v.rgb.astype(np.float64)
        results = {}
        M = fit_color_affine(img[m], truth[m])
        if isinstance(M, str):
            results.update(aligned_psnr=M, aligned_ssim=M, aligned_lpips=M)
        else:
            aligned = apply_color_affine(img, M)
            results["aligned_psnr"] = masked_psnr(aligned, truth, m)
            results["aligned_ssim"] = masked_ssim(aligned, truth, m)
            if isinstance(net, str):
                results["aligned_lpips"] = net
            elif not m.all():
                results["aligned_lpips"] = (
                    f"n/a: LPIPS needs every pixel of a view; {int(m.sum())} of {m.size} are co-visible"
                )
            else:
                t32 = lambda a: torch.from_numpy(a.astype(np.float32))  # noqa: E731
                results["aligned_lpips"] = lpips_distance(net, t32(aligned), t32(truth))
        if v.oracle is None:
            results["oracle_aligned_psnr"] = "n/a: the view has no reprojection oracle"
        else:  # NaN outside the mask: never selected
            Mo = fit_color_affine(v.oracle[m], truth[m])
            results["oracle_aligned_psnr"] = (
                Mo if isinstance(Mo, str) else masked_psnr(apply_color_affine(v.oracle, Mo), truth, m)
            )
        a, o = results["aligned_psnr"], results["oracle_aligned_psnr"]
        results["oracle_aligned_gap"] = o if isinstance(o, str) else a if isinstance(a, str) else o - a
        for k, r in results.items():
            if isinstance(r, str):
                why.setdefault(k, r)
            else:
                vals[k].append(r)
    return {
        **_mean_scores(vals, why, shortfall or "n/a: no held-out view to score"),
        **oracle_scores(kept, shortfall),
        "meaning": HELDOUT_SCORE_MEANING,
    }


def best_heldout(history: list[dict], reason: str | None = None) -> dict | str:
    """The history sample with the highest held-out PSNR: its iteration, training seconds, Gaussians and PSNR
    (what a run's quality-against-time reads as), or 'n/a: <reason>' (``reason`` if given) when none has one."""
    samples = [h for h in history if "heldout_psnr" in h]
    if not samples:
        return reason or "n/a: no held-out PSNR in the history (no held-out views, or history_every = 0)"
    b = max(samples, key=lambda h: h["heldout_psnr"])
    return {k: b[k] for k in ("iteration", "seconds", "gaussians", "heldout_psnr") if k in b}


def heldout_plateau(history: list[dict], reason: str | None = None) -> dict | str:
    """Held-out PSNR over the second half of the run's history samples (iteration > half the last one): their
    number, mean, sample SD, min and max (dB). The level a run settles at and its step-to-step wobble, which
    ``heldout_best``, a maximum over those noisy samples, reads above; 'n/a: <reason>' with fewer than 2 such
    samples."""
    samples = [h for h in history if "heldout_psnr" in h]
    late = [h for h in samples if h["iteration"] > samples[-1]["iteration"] / 2] if samples else []
    if len(late) < 2:
        return reason or "n/a: fewer than 2 held-out PSNR samples in the second half of the history"
    psnr = [h["heldout_psnr"] for h in late]
    return {
        "from_iteration": late[0]["iteration"],
        "samples": len(psnr),
        "mean": statistics.fmean(psnr),
        "sd": statistics.stdev(psnr),
        "min": min(psnr),
        "max": max(psnr),
    }


def heldout_summary(held: dict | str) -> str:
    """The held-out part of a run's one-line summary from metrics.json's 'held-out' block (or its n/a text): the
    PSNR (the headline), then the co-visible pixels' PSNR, the oracle's and the gap, where there are some."""
    if not isinstance(held, dict):
        return f"held-out PSNR {held}"
    p = held["psnr"]
    line = f"held-out PSNR {p:.2f} dB" if isinstance(p, float) else f"held-out PSNR {p}"
    if isinstance(held.get("oracle_gap"), float):
        line += (
            f" (co-visible pixels {held['covisible_fraction']:.0%}: {held['covisible_psnr']:.2f} dB against the "
            f"oracle's {held['oracle_psnr']:.2f} dB, gap {held['oracle_gap']:.2f} dB)"
        )
    return line
