"""The Gaussian model: parameters in their optimisation spaces, initialised from any ``PointCloud``, and its
near plane (``near_plane_for``: relative to the scene's own scale).

means [N,3] metres; quats [N,4] wxyz (unnormalised); log_scales [N,3] (log metres); logit_opacities [N];
sh0 [N,1,3] (degree-0 SH of the colour) and shN [N,(d+1)^2-1,3]. float32.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from ..geometry import PointCloud
from .footprint import filtered
from .rasterize.sh import C0

# the rasterizer's near plane, a fraction of the distance from the origin within which the nearest 1 % of the
# Gaussians lie: 1 cm for a room whose nearest surfaces are ~1 m from the panorama centre (gsplat's fixed 0.01 m),
# and the same fraction of the same room given in millimetres or kilometres (a fixed plane culls a 5 mm room)
NEAR_FRACTION = 0.01
NEAR_QUANTILE = 0.01
# the smallest initial scale, a fraction of the median nearest-neighbour distance: duplicate points (distance 0)
# stay finite at any scene scale
MIN_SCALE_FRACTION = 1e-3

PARAM_NAMES = ("means", "quats", "log_scales", "logit_opacities", "sh0", "shN")  # in the constructor's order


def nearest_neighbour_scale(xyz: np.ndarray, k: int = 3) -> np.ndarray:
    """Mean distance (metres) from each point to its k nearest other points, [N] float64 (SciPy KD-tree,
    exact). A single point has no neighbour: 1."""
    from scipy.spatial import cKDTree

    pts = np.asarray(xyz, np.float64)
    kk = min(k + 1, len(pts))
    if kk < 2:
        return np.ones(len(pts))
    d, _ = cKDTree(pts).query(pts, k=kk, workers=-1)
    return d[:, 1:].mean(1)  # drop the point itself (distance 0, or a duplicate's 0: the same value)


def near_plane_for(means: torch.Tensor) -> float:
    """The rasterizer's near plane (metres) for Gaussians at ``means`` [N, 3]: ``NEAR_FRACTION`` x the
    ``NEAR_QUANTILE`` quantile of their distances from the origin (the panorama centre, where the label cameras
    are); scales with the scene, so a scene rendered at any scale is the same picture. Computed once, when a
    model is built (one read back to the host); 0.01 for a model without a Gaussian at a positive distance."""
    with torch.no_grad():
        r = torch.linalg.vector_norm(means.detach().float(), dim=1)
        r = r[torch.isfinite(r) & (r > 0)]
        if not len(r):
            return 0.01
        k = max(1, int(NEAR_QUANTILE * len(r)))
        return NEAR_FRACTION * float(r.kthvalue(k).values)


class GaussianModel(nn.Module):
    def __init__(self, means, quats, log_scales, logit_opacities, sh0, shN):
        super().__init__()
        self.near_plane = near_plane_for(means)
        # (variance [N], strength) of the footprint filter (splat/footprint.py) while a trainer keeps one; None: none
        self.footprint: tuple[torch.Tensor, float] | None = None
        self.means = nn.Parameter(means)
        self.quats = nn.Parameter(quats)
        self.log_scales = nn.Parameter(log_scales)
        self.logit_opacities = nn.Parameter(logit_opacities)
        self.sh0 = nn.Parameter(sh0)
        self.shN = nn.Parameter(shN)

    @classmethod
    def from_point_cloud(cls, pc: PointCloud, sh_degree: int = 3, init_opacity: float = 0.1):
        """Isotropic Gaussians at the points: scale = mean distance to the 3 nearest neighbours (at least
        ``MIN_SCALE_FRACTION`` of their median, so duplicate points stay finite), colour in the DC band, opacity
        ``init_opacity``."""
        if len(pc) == 0:
            raise ValueError("GaussianModel.from_point_cloud: the point cloud is empty")
        if not 0 <= sh_degree <= 3:
            raise ValueError(f"sh_degree={sh_degree}: expected 0..3")
        if not 0 < init_opacity < 1:
            raise ValueError(f"init_opacity={init_opacity}: expected a value in (0, 1)")
        n = len(pc)
        nn_scale = nearest_neighbour_scale(pc.xyz)
        positive = nn_scale[nn_scale > 0]
        scale = np.maximum(nn_scale, MIN_SCALE_FRACTION * (float(np.median(positive)) if len(positive) else 1.0))
        log_s = torch.from_numpy(np.log(scale)).float()[:, None].repeat(1, 3)
        quats = torch.zeros(n, 4)
        quats[:, 0] = 1
        logit = torch.full((n,), float(np.log(init_opacity / (1 - init_opacity))))
        sh0 = ((torch.from_numpy(pc.rgb).float() - 0.5) / C0)[:, None, :]
        shN = torch.zeros(n, (sh_degree + 1) ** 2 - 1, 3)
        # copy: the parameters must never share memory with the caller's point cloud
        return cls(torch.tensor(pc.xyz, dtype=torch.float32), quats, log_s, logit, sh0, shN)

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def sh_degree(self) -> int:
        return int(round((self.shN.shape[1] + 1) ** 0.5)) - 1

    def scales(self) -> torch.Tensor:
        return torch.exp(self.log_scales)

    def opacities(self) -> torch.Tensor:
        return torch.sigmoid(self.logit_opacities)

    def rendered(self) -> tuple[torch.Tensor, torch.Tensor]:
        """Scales [N, 3] and opacities [N] as rendered: through the footprint filter while one is set
        (``footprint``), else ``scales()`` and ``opacities()``."""
        if self.footprint is None:
            return self.scales(), self.opacities()
        return filtered(self.log_scales, self.logit_opacities, *self.footprint)

    def sh(self) -> torch.Tensor:
        """All SH coefficients [N, (d+1)^2, 3]."""
        return torch.cat([self.sh0, self.shN], 1)


def flatten_to_discs(model: GaussianModel, normals: np.ndarray, thickness: float) -> None:
    """Make each Gaussian whose row of ``normals`` [N, 3] is a finite non-zero vector a disc on that normal's
    plane, in place: its local z rotated onto the normal (quaternion from the identity) and its z scale
    ``thickness`` times its x scale; the other Gaussians are left as they are. For a freshly built isotropic
    model (``from_point_cloud``), before any optimizer holds its parameters."""
    nrm = np.asarray(normals, np.float64)
    if nrm.shape != (len(model), 3):
        raise ValueError(f"flatten_to_discs: normals {nrm.shape} for {len(model)} Gaussians; expected [N, 3]")
    disc = np.isfinite(nrm).all(1) & (np.linalg.norm(np.nan_to_num(nrm), axis=1) > 0.5)
    nz = nrm[disc] * np.where(nrm[disc, 2:3] < 0, -1.0, 1.0)  # a disc has no side: n_z >= 0
    q = np.stack([1 + nz[:, 2], -nz[:, 1], nz[:, 0], np.zeros(len(nz))], 1)  # z onto n (w x y z)
    mask = torch.from_numpy(disc).to(model.quats.device)
    with torch.no_grad():
        model.quats[mask] = torch.from_numpy(q / np.linalg.norm(q, axis=1, keepdims=True)).to(model.quats)
        model.log_scales[mask, 2] = model.log_scales[mask, 0] + float(np.log(thickness))


def covariances(model: GaussianModel) -> np.ndarray:
    """Σ = R diag(s²) Rᵀ [N, 3, 3] float64 of every Gaussian (R from its wxyz quaternion, s its scales)."""
    from .rasterize.projection import quat_to_rotmat

    R = quat_to_rotmat(model.quats.detach().cpu().double()).numpy()
    s = np.exp(model.log_scales.detach().cpu().double().numpy())
    return np.einsum("nij,nj,nkj->nik", R, s**2, R)


def rotmat_to_wxyz(R: np.ndarray) -> np.ndarray:
    """Unit wxyz quaternions [N, 4] float64 of rotation matrices [N, 3, 3] (Shepperd's method: each from the
    largest of its four squared components, so none divides by a small one; w >= 0 where w is that one)."""
    R = np.asarray(R, np.float64)
    d0, d1, d2 = R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]
    big = np.stack([1 + d0 + d1 + d2, 1 + d0 - d1 - d2, 1 - d0 + d1 - d2, 1 - d0 - d1 + d2], 1)
    k = big.argmax(1)
    s = 2 * np.sqrt(np.maximum(big[np.arange(len(R)), k], 1e-300))  # 4 x the largest component
    zy, yz, xz, zx, yx, xy = R[:, 2, 1], R[:, 1, 2], R[:, 0, 2], R[:, 2, 0], R[:, 1, 0], R[:, 0, 1]
    cands = np.stack(
        [
            np.stack([s / 4, (zy - yz) / s, (xz - zx) / s, (yx - xy) / s], 1),
            np.stack([(zy - yz) / s, s / 4, (xy + yx) / s, (xz + zx) / s], 1),
            np.stack([(xz - zx) / s, (xy + yx) / s, s / 4, (yz + zy) / s], 1),
            np.stack([(yx - xy) / s, (xz + zx) / s, (yz + zy) / s, s / 4], 1),
        ],
        1,
    )
    q = cands[np.arange(len(R)), k]
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def from_covariances(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(wxyz quaternions [N, 4], log scales [N, 3]) float64 of covariances [N, 3, 3] (eigen-decomposed; a
    reflection turned into a rotation by flipping one axis; eigenvalues floored at 1e-30)."""
    lam, V = np.linalg.eigh(cov)
    V[np.linalg.det(V) < 0, :, 0] *= -1
    return rotmat_to_wxyz(V), 0.5 * np.log(np.maximum(lam, 1e-30))
