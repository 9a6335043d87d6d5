"""Regularisers of the Gaussians' geometry, beside the photometric and depth terms of ``losses.py``.

Depth spread (TrainConfig.w_spread): every pseudo-label camera sits at the panorama centre, so a stack of
semi-transparent Gaussians spread along a pixel's ray blends to the right colour there and to a smeared one from
anywhere else. The term is the blending weights' depth variance along each ray, relative to its squared mean
depth (scale-free: a cloud in arbitrary units, a room or a valley weigh alike), as Mip-NeRF 360's and 2DGS's
distortion losses concentrate the weights. With the weights w_i and view depths z_i of one pixel's Gaussians,
A = sum w_i (its alpha), S1 = sum w_i z_i (the accumulated depth every render has) and S2 = sum w_i z_i^2 (one more
render, of z^2 as colour):

    sum_i sum_j w_i w_j (z_i - z_j)^2 / 2 = A S2 - S1^2,

so the relative variance of the normalised weights is A S2 / S1^2 - 1, and the term is its mean over pixels,
weighted by A (an empty pixel has no spread to penalise). ``depth_spread_reference`` is the double sum itself.
float32: A S2 / S1^2 - 1 keeps ~1e-7 of relative variance (a spread of 0.03 % of the depth); rounding below 0
is clamped.

Surface anchor (TrainConfig.w_anchor): training moves the Gaussians along the centre's rays, where no label sees
the difference (on bedroom with a near-true teacher the fused cloud lies 0.12 % from the true surface, median, and
the Gaussians after 1,500 steps 1.7 %: docs/benchmarks.md). The term holds each Gaussian near the fused surface
along its own ray: with D(u) the distance of the nearest point of the given cloud in the ERP bin of direction u
(``surface_distances``, bins of the label pixel's size) and d = ln(r / D(u)) for a Gaussian at distance r, it is
the mean over Gaussians of min(d^2, ANCHOR_BAND^2). A Gaussian more than ANCHOR_BAND (in ln distance) from the
surface, the disocclusion fill behind a depth edge or a point of another layer, is left where it is.

Flattening (TrainConfig.flatten_every): from the centre a Gaussian's shape along its own ray is invisible, so a
blob and a disc on the surface render alike there and differently from anywhere else. ``flatten_onto_surface``
shears each Gaussian along its ray onto the plane of the fused surface's normal at its bin (``surface_normals``:
the given cloud's nearest points per ERP bin, their normals from central differences), which leaves what the
centre sees (to first order) and lays the Gaussian on the surface for every other view. It is a projection, not a
loss term: the trainer applies it every ``flatten_every`` steps and after the last, unless the cloud has no surface
to flatten onto (``normal_coherence`` below FLAT_MIN_COHERENCE: random points). What the given cloud contributes
(normals, coherence, each bin's plane basis: ``flatten_frames``) is computed once per run; each
flattening is one pass over the Gaussians (a C++ kernel on the CPU, torch elsewhere).
"""

from __future__ import annotations

import numpy as np
import torch

from ..geometry.sphere import direction_to_erp_pixel, erp_grid_normals
from .rasterize import rasterize

SPREAD_EPS = 1e-12  # S1^2 below this (a pixel nothing covers): no spread
ANCHOR_BAND = 0.1  # ln distance: within about 10 % of the fused surface a Gaussian is pulled onto it
FLAT_THICKNESS = 0.05  # a flattened Gaussian's extent along the surface normal, over the RMS of its two axes
FLAT_MIN_COS = 0.2  # |n·u| below this (the centre sees the surface within ~12 degrees of grazing): not flattened
# a cloud whose neighbouring bins' normals agree (within ~25 degrees) less often than this has no surface to flatten
# onto (random points agree about a quarter of the time: tests/splat/test_regularisers.py)
FLAT_MIN_COHERENCE = 0.4


def depth_spread(alpha: torch.Tensor, depth_sum: torch.Tensor, depth_sq_sum: torch.Tensor) -> torch.Tensor:
    """Mean over pixels of A (A S2 / S1^2 - 1): alpha A, accumulated depth S1 and accumulated squared depth S2,
    each [..., H, W] (any units; the result is scale-free)."""
    s1_sq = depth_sum.square()
    covered = s1_sq > SPREAD_EPS
    rel = torch.where(covered, alpha * depth_sq_sum / torch.where(covered, s1_sq, 1.0) - 1, 0.0)
    return (alpha * rel.clamp(min=0)).mean()


def depth_spread_reference(weights: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """The same from each pixel's blending weights ``weights`` [P, G] and its Gaussians' view depths ``z`` [G],
    by the double sum: mean over pixels of A sum_ij w_i w_j (z_i - z_j)^2 / 2 / S1^2."""
    pair = (weights[:, :, None] * weights[:, None, :] * (z[:, None] - z[None, :]).square()).sum((1, 2)) / 2
    A, S1 = weights.sum(1), weights @ z
    covered = S1.square() > SPREAD_EPS
    return torch.where(covered, A * pair / torch.where(covered, S1.square(), 1.0), 0.0).mean()


def render_depth_sq(model, viewmats, Ks, width: int, height: int, backend: str, antialiased: bool) -> torch.Tensor:
    """S2 [C, height, width]: each pixel's blending-weighted sum of its Gaussians' squared view depths (metres^2 or
    the cloud's units), rendered as the colour (z^2, 0, 0) with the model's rendered scales and opacities."""
    scales, opacities = model.rendered()
    z = torch.einsum("cj,nj->cn", viewmats[:, 2, :3], model.means) + viewmats[:, 2, 3:]  # [C, N] view depth
    colours = torch.stack([z.square(), torch.zeros_like(z), torch.zeros_like(z)], -1)
    img = rasterize(
        model.means,
        model.quats,
        scales,
        opacities,
        colours,
        viewmats,
        Ks,
        width,
        height,
        near_plane=model.near_plane,
        backend=backend,
        antialiased=antialiased,
    )[0]
    return img[..., 0]


def _erp_bins(directions, height: int):
    """Nearest ERP bin (row, col) of directions [..., 3] on a height x 2 height grid (columns wrap)."""
    rows, cols = direction_to_erp_pixel(directions, height, 2 * height)
    if isinstance(rows, torch.Tensor):
        return rows.round().long().clamp(0, height - 1), cols.round().long() % (2 * height)
    return np.clip(np.rint(rows).astype(np.int64), 0, height - 1), np.rint(cols).astype(np.int64) % (2 * height)


def _nearest_in_bins(xyz: np.ndarray, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The surface the centre sees in the points ``xyz`` [N, 3] on a height x 2 height ERP grid: (flat indices of
    the bins that hold a point, [B] int64; the nearest such point to the centre in each, [B, 3] float64)."""
    xyz = np.asarray(xyz, np.float64)
    r = np.linalg.norm(xyz, axis=1)
    keep = np.flatnonzero(np.isfinite(r) & (r > 0))
    rows, cols = _erp_bins(xyz[keep], height)
    bins = rows * 2 * height + cols
    order = np.lexsort((r[keep], bins))  # by bin, nearest first
    first = order[np.r_[True, bins[order][1:] != bins[order][:-1]]] if len(order) else order
    return bins[first], xyz[keep][first]


def surface_distances(xyz: np.ndarray, height: int) -> np.ndarray:
    """[height, 2 height] float32: in each ERP bin the distance (the cloud's units) of the nearest of the points
    ``xyz`` [N, 3] from the centre, the surface the centre sees; NaN where no point falls. ``height``: 180 / the
    label pixel's size in degrees (``anchor_height``)."""
    bins, nearest = _nearest_in_bins(xyz, height)
    grid = np.full(height * 2 * height, np.nan)
    grid[bins] = np.linalg.norm(nearest, axis=1)
    return grid.reshape(height, 2 * height).astype(np.float32)


def anchor_height(res: int, fov_deg: float) -> int:
    """ERP height whose bins are the label pixel's size: 180 deg / (fov_deg / res)."""
    return max(2, round(180.0 * res / fov_deg))


def surface_anchor(means: torch.Tensor, surface: torch.Tensor) -> torch.Tensor:
    """Mean over the Gaussians with a surface bin of min(ln(r / D)^2, ANCHOR_BAND^2): means [N, 3] (the centre at
    0), surface [H, 2H] from ``surface_distances`` on the means' device. Scale-free; 0 when no Gaussian has one."""
    rows, cols = _erp_bins(means.detach(), surface.shape[0])
    D = surface[rows, cols]
    ok = torch.isfinite(D)
    d = torch.log(means.norm(dim=-1).clamp_min(1e-12)) - torch.log(torch.where(ok, D, 1.0))
    return torch.where(ok, d.square().clamp(max=ANCHOR_BAND**2), 0.0).sum() / ok.sum().clamp_min(1)


def surface_anchor_reference(means: torch.Tensor, xyz: np.ndarray, height: int) -> torch.Tensor:
    """``surface_anchor`` one Gaussian at a time against the points themselves: for each Gaussian the nearest
    point among those whose direction falls in its own bin, by a loop (slow; the tests' yardstick)."""
    pts = np.asarray(xyz, np.float64)
    prow, pcol = _erp_bins(pts, height)
    pr = np.linalg.norm(pts, axis=1)
    terms = []
    for m in means:
        row, col = _erp_bins(m.detach().double().numpy(), height)
        same = (prow == row) & (pcol == col)
        if not same.any():
            continue
        d = torch.log(m.double().norm()) - float(np.log(pr[same].min()))
        terms.append(torch.clamp(d * d, max=ANCHOR_BAND**2))
    return torch.stack(terms).mean() if terms else means.new_zeros((), dtype=torch.float64)


def surface_normals(xyz: np.ndarray, height: int) -> np.ndarray:
    """[height, 2 height, 3] float32 normals of the surface the centre sees in the points ``xyz`` [N, 3]: in each
    ERP bin the nearest point to the centre (as ``surface_distances``), at its own position, and the normals of
    that grid (``geometry.erp_grid_normals``; exact on a plane); NaN where a bin or a neighbour has no point."""
    bins, nearest = _nearest_in_bins(xyz, height)
    grid = np.full((height * 2 * height, 3), np.nan)
    grid[bins] = nearest
    return erp_grid_normals(grid.reshape(height, 2 * height, 3))


def normal_coherence(normals: np.ndarray) -> float:
    """Share of the pairs of neighbouring ERP bins (along longitude, wrapping, and latitude) with finite normals in
    ``normals`` [H, W, 3] whose normals agree within ~25 degrees (|n·m| >= 0.9): near 1 on a surface of planes and
    smooth patches, about 0.25 on points with no surface (random points); 0 without such a pair."""
    n = np.asarray(normals, np.float64)
    pairs = [(n, np.roll(n, -1, 1)), (n[:-1], n[1:])]
    agree = []
    for a, b in pairs:
        ok = np.isfinite(a).all(-1) & np.isfinite(b).all(-1)
        agree.append(np.abs(np.einsum("...i,...i->...", a[ok], b[ok])) >= 0.9)
    agree = np.concatenate(agree)
    return float(agree.mean()) if agree.size else 0.0


def flatten_height(points: int, res: int, fov_deg: float) -> int:
    """ERP height of the normals that flattening reads from a cloud of ``points`` points for labels of ``res``
    pixels over ``fov_deg``: bins of two label pixels (``anchor_height`` / 2), coarser where the cloud has fewer
    than 8 points per bin (an empty bin leaves its neighbours without a normal)."""
    return max(2, min(anchor_height(res, fov_deg) // 2, int(np.sqrt(points / 16))))


def flatten_frames(normals: np.ndarray, device=None) -> torch.Tensor:
    """What flattening reads from the given cloud, once per run: [H * 2H, 9] float64 on ``device``, per ERP bin
    of ``normals`` [H, 2H, 3] (row-major) a basis (t1, t2) of the surface's plane (t1 = n x the axis least along
    n, normalised; t2 = n x t1) and its normal n as given; NaN where the normal is not finite."""
    n = np.asarray(normals, np.float64).reshape(-1, 3)
    helper = np.eye(3)[np.abs(np.nan_to_num(n)).argmin(1)]  # the axis least along n
    with np.errstate(invalid="ignore", divide="ignore"):
        t1 = np.cross(n, helper)
        t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return torch.from_numpy(np.concatenate([t1, np.cross(n, t1), n], 1)).to(device)


def flatten_onto_surface(model, frames: torch.Tensor, thickness: float = FLAT_THICKNESS) -> torch.Tensor:
    """Shear every Gaussian of ``model`` along its ray u from the centre onto the plane of the surface normal n
    at its ERP bin (``frames`` from ``flatten_frames`` of ``surface_normals``, or of a true surface's
    ``erp_normals``), in place: Σ' = A Σ Aᵀ + thickness² (tr(A Σ Aᵀ) / 2) n nᵀ with A = I - u nᵀ / (n·u). A moves
    points along u only, so the centre's view of the Gaussian is unchanged to first order (the projection's
    Jacobian J has J u = 0, so J A = J), while any other position sees a disc on the surface (2DGS's and PGSR's
    flat Gaussians) whose thickness is ``thickness`` times the RMS of its two axes. Gaussians without a finite
    normal or covariance, or whose surface the centre sees at a grazing angle (|n·u| < FLAT_MIN_COS), are left as
    they are, as are those whose sheared variances pass float64's range; means, opacities and colours never change.
    On the CPU the C++ kernel (csrc/flatten_cpu.cpp), else
    ``flatten_onto_surface_torch``; both float64 inside, on the model's device. -> [N] bool: the Gaussians
    flattened."""
    from .rasterize import cpu_backend

    if model.means.device.type == "cpu" and cpu_backend.available():
        return cpu_backend.flatten_surface(
            model.means, model.quats.data, model.log_scales.data, frames, thickness, FLAT_MIN_COS
        )
    return flatten_onto_surface_torch(model, frames, thickness)


def flatten_onto_surface_torch(model, frames: torch.Tensor, thickness: float = FLAT_THICKNESS) -> torch.Tensor:
    """``flatten_onto_surface`` in torch float64 on the model's device (a GPU, or a CPU without the C++ kernel). A
    Σ Aᵀ lies in the plane (nᵀ A = 0): its 2 x 2 matrix on the bin's basis (t1, t2) is that of the axes a_k = R_k
    s_k seen through p_i = Aᵀ t_i = t_i - n (t_i·u) / (n·u); the disc's axes are its eigenvectors in closed form
    (no 3 x 3 eigensolver), with n, and their quaternion Shepperd's (``rotmat_to_wxyz``).
    ``flatten_onto_surface_reference`` is the per-axis loop. -> [N] bool."""
    from .rasterize.projection import quat_to_rotmat

    with torch.no_grad():
        means = model.means.detach().double()
        r = torch.linalg.vector_norm(means, dim=1)
        u = means / r.clamp_min(1e-300)[:, None]
        height = round((frames.shape[0] / 2) ** 0.5)
        rows, cols = _erp_bins(u, height)
        f = frames[rows * 2 * height + cols]  # [N, 9]
        t, n = f[:, :6].view(-1, 2, 3), f[:, 6:]
        cos = (n * u).sum(1)
        R = quat_to_rotmat(model.quats.detach().double())  # [N, 3, 3], columns the axes' directions
        s2 = torch.exp(2 * model.log_scales.detach().double())  # [N, 3] the axes' variances
        flat = (cos.abs() >= FLAT_MIN_COS) & (r > 0) & torch.isfinite(R).all(2).all(1) & torch.isfinite(s2).all(1)
        p = t - ((t * u[:, None]).sum(2) / cos[:, None])[..., None] * n[:, None]  # [N, 2, 3]
        c = torch.bmm(p, R)  # [N, 2, 3]: p_i · R_k
        cs = c * s2[:, None]
        m11, m22, m12 = (cs[:, 0] * c[:, 0]).sum(1), (cs[:, 1] * c[:, 1]).sum(1), (cs[:, 0] * c[:, 1]).sum(1)
        theta = 0.5 * torch.atan2(2 * m12, m11 - m22)
        mid, half = (m11 + m22) / 2, torch.hypot((m11 - m22) / 2, m12)
        e1 = torch.cos(theta)[:, None] * t[:, 0] + torch.sin(theta)[:, None] * t[:, 1]
        q = _rotmat_to_wxyz(torch.stack([e1, torch.linalg.cross(n, e1), n], -1))
        var = torch.stack([mid + half, mid - half, thickness**2 * mid], 1)
        flat &= torch.isfinite(theta) & torch.isfinite(var).all(1)  # variances past float64's range: left as they are
        model.quats.copy_(torch.where(flat[:, None], q.to(model.quats), model.quats))
        ls = (0.5 * torch.log(var.clamp_min(1e-30))).to(model.log_scales)
        model.log_scales.copy_(torch.where(flat[:, None], ls, model.log_scales))
    return flat


def _rotmat_to_wxyz(R: torch.Tensor) -> torch.Tensor:
    """``model.rotmat_to_wxyz`` in torch: [N, 3, 3] -> unit wxyz quaternions [N, 4] (Shepperd's method)."""
    d0, d1, d2 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    big = torch.stack([1 + d0 + d1 + d2, 1 + d0 - d1 - d2, 1 - d0 + d1 - d2, 1 - d0 - d1 + d2], 1)
    k = big.argmax(1, keepdim=True)
    s = 2 * torch.sqrt(big.gather(1, k)[:, 0].clamp_min(1e-300))  # 4 x the largest component
    zy, yz, xz, zx, yx, xy = R[:, 2, 1], R[:, 1, 2], R[:, 0, 2], R[:, 2, 0], R[:, 1, 0], R[:, 0, 1]
    cands = torch.stack(
        [
            torch.stack([s / 4, (zy - yz) / s, (xz - zx) / s, (yx - xy) / s], 1),
            torch.stack([(zy - yz) / s, s / 4, (xy + yx) / s, (xz + zx) / s], 1),
            torch.stack([(xz - zx) / s, (xy + yx) / s, s / 4, (yz + zy) / s], 1),
            torch.stack([(yx - xy) / s, (xz + zx) / s, (yz + zy) / s, s / 4], 1),
        ],
        1,
    )
    q = cands.gather(1, k[:, :, None].expand(-1, 1, 4))[:, 0]
    return q / torch.linalg.vector_norm(q, dim=1, keepdim=True)


def flatten_onto_surface_reference(means, quats, log_scales, normals, thickness: float = FLAT_THICKNESS):
    """``flatten_onto_surface``'s covariances, one Gaussian at a time (slow; the tests' yardstick): each of its
    axes a_k s_k mapped point by point along the ray onto the plane (x -> x - u (n·x) / (n·u)), Σ' the sum of the
    mapped axes' outer products plus the thickness term (thickness² x half their trace, along n). means [N, 3],
    quats [N, 4] wxyz, log_scales [N, 3] and normals [H, 2H, 3] numpy -> ([N, 3, 3] float64 covariances, [N] bool
    flattened)."""
    from scipy.spatial.transform import Rotation

    out, flat = [], []
    for m, q, ls in zip(np.asarray(means, np.float64), np.asarray(quats, np.float64), np.asarray(log_scales)):
        R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
        axes = [R[:, k] * np.exp(float(ls[k])) for k in range(3)]
        u = m / np.linalg.norm(m)
        row, col = direction_to_erp_pixel(u[None], normals.shape[0], normals.shape[1])
        n = normals[int(np.clip(np.rint(row[0]), 0, normals.shape[0] - 1)), int(np.rint(col[0])) % normals.shape[1]]
        if not np.isfinite(n).all() or abs(n @ u) < FLAT_MIN_COS:
            out.append(sum(np.outer(a, a) for a in axes))
            flat.append(False)
            continue
        n = n.astype(np.float64)
        mapped = [a - u * (n @ a) / (n @ u) for a in axes]
        cov = sum(np.outer(a, a) for a in mapped)
        out.append(cov + thickness**2 * np.trace(cov) / 2 * np.outer(n, n))
        flat.append(True)
    return np.array(out), np.array(flat)
