"""Trained Gaussians rendered back to a full equirectangular panorama (to set beside the input).

48 Fibonacci views of 60 degrees (the label views' FOV) are rasterised from ``position``, and every ERP pixel
takes the bilinear sample of the view whose axis is nearest its ray (at most 22.4 degrees away, inside that
view's inscribed 30-degree cone). Not a cube: EWA splatting's affine approximation lets Gaussians far off the
axis of a 90-degree face smear over its centre. ``render_panorama_reference`` renders one 1x1 camera per ERP
pixel, looking exactly along its ray: slow, obviously right, and the test's yardstick.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from ..geometry import (
    centred_camera,
    erp_directions,
    fibonacci_directions,
    look_at_rotation,
    perspective_to_erp,
    viewmat_from_pose,
)
from .model import GaussianModel
from .rasterize import rasterize

VIEWS, VIEW_FOV_DEG = 48, 60.0


def _render(
    model: GaussianModel, viewmats: np.ndarray, Ks: np.ndarray, width: int, height: int, backend: str
) -> np.ndarray:
    with torch.no_grad():
        scales, opacities = model.rendered()
        img = rasterize(
            model.means,
            model.quats,
            scales,
            opacities,
            model.sh(),
            torch.tensor(viewmats, dtype=torch.float32),
            torch.tensor(Ks, dtype=torch.float32),
            width,
            height,
            sh_degree=model.sh_degree,
            near_plane=model.near_plane,
            backend=backend,
        )[0]
    return img.clamp(0, 1).numpy()


def render_panorama(
    model: GaussianModel, height: int, position=(0.0, 0.0, 0.0), backend: str = "auto", view_size: int | None = None
) -> np.ndarray:
    """ERP render [height, 2*height, 3] float32 in [0, 1] of ``model`` seen from ``position`` (metres);
    ``view_size``: pixels per view (default: the ERP's resolution, height / 3 for 60 degrees)."""
    if height < 2:
        raise ValueError(f"render_panorama: height={height}, expected at least 2")
    width = 2 * height
    size = view_size or max(8, math.ceil(height * VIEW_FOV_DEG / 180))
    axes = fibonacci_directions(VIEWS)
    cams = [centred_camera(a, size, VIEW_FOV_DEG, position) for a in axes]
    imgs = _render(model, np.stack([c.viewmat for c in cams]), np.stack([c.K for c in cams]), size, size, backend)
    which = np.argmax(erp_directions(height, width) @ axes.T, axis=-1)  # the view nearest every ERP ray
    out = np.zeros((height, width, 3), np.float32)
    for k, (cam, img) in enumerate(zip(cams, imgs)):
        erp, _ = perspective_to_erp(img, cam, height, width)
        out[which == k] = erp[which == k]
    return out


def render_panorama_reference(
    model: GaussianModel, height: int, position=(0.0, 0.0, 0.0), backend: str = "torch"
) -> np.ndarray:
    """The same panorama by one 1x1-pixel camera (1 degree FOV) per ERP pixel along its exact ray; slow."""
    width = 2 * height
    dirs = erp_directions(height, width).reshape(-1, 3)
    f = 0.5 / math.tan(math.radians(0.5))
    K = np.array([[f, 0, 0.5], [0, f, 0.5], [0, 0, 1]])
    pos = np.asarray(position, float)
    out = []
    for chunk in np.array_split(np.arange(len(dirs)), max(1, len(dirs) // 256)):
        vms = np.stack([viewmat_from_pose(look_at_rotation(dirs[i]), pos) for i in chunk])
        out.append(_render(model, vms, np.repeat(K[None], len(chunk), 0), 1, 1, backend)[:, 0, 0])
    return np.concatenate(out).reshape(height, width, 3).astype(np.float32)
