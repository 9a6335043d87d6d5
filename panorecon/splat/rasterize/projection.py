"""EWA projection of 3D Gaussians into pinhole cameras (gsplat's conventions), differentiable PyTorch.

Cameras: world-to-camera ``viewmats`` [C, 4, 4] in OpenCV axes and ``Ks`` [C, 3, 3] with pixel (i, j) centred
at (j + 0.5, i + 0.5). A Gaussian is kept in a camera when near < z < far; its 2D covariance is
J W Sigma W^T J^T + eps2d * I (eps2d = 0.3 px^2 low-pass, as in 3DGS and gsplat), with the Jacobian taken at
the mean's view direction clamped to the image's extent plus 30 % of the half field of view (gsplat's rule,
which keeps Gaussians far outside the image from exploding). radius = ceil(3 sqrt(largest eigenvalue)), at
most 2^30 px; radius 0 marks a culled one, whose means2d, conics and depth are 0 (gsplat's convention).
"""

from __future__ import annotations

import torch


def quat_to_rotmat(quats: torch.Tensor) -> torch.Tensor:
    """wxyz quaternions [N, 4] (any norm) -> rotation matrices [N, 3, 3]. A zero-norm quaternion is read as
    the identity rotation."""
    norm = quats.norm(dim=-1, keepdim=True)
    identity = torch.tensor([1.0, 0.0, 0.0, 0.0], dtype=quats.dtype, device=quats.device)
    q = torch.where(norm > 1e-12, quats / norm.clamp_min(1e-12), identity)
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        [
            1 - 2 * (y * y + z * z),
            2 * (x * y - w * z),
            2 * (x * z + w * y),
            2 * (x * y + w * z),
            1 - 2 * (x * x + z * z),
            2 * (y * z - w * x),
            2 * (x * z - w * y),
            2 * (y * z + w * x),
            1 - 2 * (x * x + y * y),
        ],
        -1,
    ).reshape(-1, 3, 3)


def project_gaussians(
    means,
    quats,
    scales,
    viewmats,
    Ks,
    width: int,
    height: int,
    near_plane: float = 0.01,
    far_plane: float = 1e10,
    eps2d: float = 0.3,
):
    """-> means2d [C, N, 2] (pixels), conics [C, N, 3] (a, b, c of the inverse 2D covariance), depths [C, N]
    (camera z, metres), radii [C, N] int (0 = culled)."""
    R = viewmats[:, :3, :3]
    t = viewmats[:, :3, 3]
    p = torch.einsum("cij,nj->cni", R, means) + t[:, None, :]
    x, y, z = p.unbind(-1)
    valid = (z > near_plane) & (z < far_plane)
    zs = torch.where(valid, z, torch.ones_like(z))
    fx, fy = Ks[:, 0, 0, None], Ks[:, 1, 1, None]
    cx, cy = Ks[:, 0, 2, None], Ks[:, 1, 2, None]
    # the Jacobian is evaluated at the view direction clamped to the image's extent plus 30 % of the half FOV
    tan_x, tan_y = 0.5 * width / fx, 0.5 * height / fy
    tx = zs * torch.minimum(torch.maximum(x / zs, -(cx / fx + 0.3 * tan_x)), (width - cx) / fx + 0.3 * tan_x)
    ty = zs * torch.minimum(torch.maximum(y / zs, -(cy / fy + 0.3 * tan_y)), (height - cy) / fy + 0.3 * tan_y)
    # cov2d = J R Sigma R^T J^T = A A^T with A = J R M, M = rot(q) diag(s): J has two non-zeros per row, so
    # the rows of J R are combinations of R's rows, and A is built with broadcast products (no [C,N,3,3]
    # batched matmuls, which dominate the time at 100k Gaussians); tests compare it with the matrix form
    j00, j02 = (fx / zs)[..., None], (-fx * tx / zs**2)[..., None]
    j11, j12 = (fy / zs)[..., None], (-fy * ty / zs**2)[..., None]
    T0 = j00 * R[:, None, 0, :] + j02 * R[:, None, 2, :]  # [C, N, 3]: first row of J R
    T1 = j11 * R[:, None, 1, :] + j12 * R[:, None, 2, :]
    M = quat_to_rotmat(quats) * scales[:, None, :]  # [N, 3, 3]
    A0 = (T0[..., :, None] * M[None]).sum(-2)  # [C, N, 3]: first row of J R M
    A1 = (T1[..., :, None] * M[None]).sum(-2)
    a = (A0 * A0).sum(-1) + eps2d
    b = (A0 * A1).sum(-1)
    c = (A1 * A1).sum(-1) + eps2d
    det = a * c - b * b
    valid = valid & (det > 0)
    det_s = torch.where(valid, det, torch.ones_like(det))
    conics = torch.stack([c / det_s, -b / det_s, a / det_s], -1)
    mid = 0.5 * (a + c)
    lam = mid + torch.sqrt((mid * mid - det_s).clamp_min(0.01))
    radii = torch.ceil(3 * torch.sqrt(lam)).detach()
    means2d = torch.stack([fx * x / zs + cx, fy * y / zs + cy], -1)
    # culled: behind/near/far, degenerate, or entirely off the image
    on_image = (
        (means2d[..., 0] + radii > 0)
        & (means2d[..., 0] - radii < width)
        & (means2d[..., 1] + radii > 0)
        & (means2d[..., 1] - radii < height)
    )
    valid = valid & on_image.detach() & torch.isfinite(radii)
    # capped at 2^30 px so that the int32 conversion is defined for any finite radius
    radii = torch.where(valid, radii.clamp_max(2.0**30), torch.zeros_like(radii)).to(torch.int32)
    zero = torch.zeros((), dtype=z.dtype, device=z.device)
    means2d, conics = torch.where(valid[..., None], means2d, zero), torch.where(valid[..., None], conics, zero)
    return means2d, conics, torch.where(valid, z, zero), radii
