"""The projection's 2D covariance against the textbook matrix form J W Sigma W^T J^T (values and gradients)."""

import torch

from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
from panorecon.splat.rasterize import project_gaussians, quat_to_rotmat


def reference_cov2d(means, quats, scales, viewmat, K, width, height):
    """[N, 2, 2] by explicit matrices, float64, with the same clamped-direction Jacobian."""
    R, t = viewmat[:3, :3], viewmat[:3, 3]
    p = means @ R.T + t
    x, y, z = p.unbind(-1)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    lim_x, lim_y = 0.3 * 0.5 * width / fx, 0.3 * 0.5 * height / fy
    tx = z * torch.clamp(x / z, -(cx / fx + lim_x), (width - cx) / fx + lim_x)
    ty = z * torch.clamp(y / z, -(cy / fy + lim_y), (height - cy) / fy + lim_y)
    J = torch.zeros(len(means), 2, 3, dtype=means.dtype)
    J[:, 0, 0], J[:, 0, 2] = fx / z, -fx * tx / z**2
    J[:, 1, 1], J[:, 1, 2] = fy / z, -fy * ty / z**2
    Rq = quat_to_rotmat(quats)
    Sigma = Rq @ torch.diag_embed(scales**2) @ Rq.transpose(-1, -2)
    return J @ R @ Sigma @ R.T @ J.transpose(-1, -2)


def test_conics_match_the_matrix_form_with_gradients():
    g = torch.Generator().manual_seed(0)
    n = 64
    means = torch.stack(
        [
            torch.rand(n, generator=g, dtype=torch.float64) * 4 + 1,
            torch.randn(n, generator=g, dtype=torch.float64),
            torch.randn(n, generator=g, dtype=torch.float64),
        ],
        -1,
    )
    means[0] = torch.tensor([2.0, 9.0, 0.0], dtype=torch.float64)  # far outside the image: clamped Jacobian
    quats = torch.randn(n, 4, generator=g, dtype=torch.float64)
    scales = torch.rand(n, 3, generator=g, dtype=torch.float64) * 0.3 + 0.01
    scales[0] = 20.0  # large enough to reach the image (a culled pair's conic is 0)
    V = torch.tensor(look_at_viewmat([0.1, 0, 0.2], [1, 0.2, 0]), dtype=torch.float64)
    K = torch.tensor(intrinsics_from_fov(48, 32, 70.0), dtype=torch.float64)
    leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales)]
    _, conics, _, radii = project_gaussians(*leaves, V[None], K[None], 48, 32, eps2d=0.3)
    kept = radii[0] > 0
    assert kept[0] and kept.sum() > 40, "the clamped one and most others reach the image"
    ref_leaves = [t.clone().requires_grad_(True) for t in (means, quats, scales)]
    cov = reference_cov2d(*ref_leaves, V, K, 48, 32) + 0.3 * torch.eye(2, dtype=torch.float64)
    inv = torch.linalg.inv(cov)
    ref_conics = torch.stack([inv[:, 0, 0], inv[:, 0, 1], inv[:, 1, 1]], -1)
    assert (conics[0][~kept] == 0).all(), "a culled pair's conic is 0"
    torch.testing.assert_close(conics[0][kept], ref_conics[kept], rtol=1e-10, atol=1e-12)
    w = torch.randn(n, 3, generator=g, dtype=torch.float64) * kept[:, None]
    (conics[0] * w).sum().backward()
    (ref_conics * w).sum().backward()
    for a, b in zip(leaves, ref_leaves):
        torch.testing.assert_close(a.grad, b.grad, rtol=1e-8, atol=1e-10)
