"""The cube-face panorama render against one exact-ray camera per ERP pixel."""

import numpy as np
import pytest
import torch

from panorecon.geometry import fibonacci_directions
from panorecon.splat.model import GaussianModel
from panorecon.splat.panorama import render_panorama, render_panorama_reference
from panorecon.splat.rasterize.sh import C0


def shell_model(n=1500, radius=2.0, scale=0.12) -> GaussianModel:
    """Opaque, smoothly coloured Gaussians on a sphere around the origin (colour = direction, so any face
    mix-up or flipped axis shows)."""
    d = fibonacci_directions(n)
    rgb = torch.tensor(0.5 + 0.45 * d, dtype=torch.float32)
    return GaussianModel(
        torch.tensor(d * radius, dtype=torch.float32),
        torch.tensor([[1.0, 0, 0, 0]]).repeat(n, 1),
        torch.full((n, 3), float(np.log(scale))),
        torch.full((n,), 4.0),
        ((rgb - 0.5) / C0)[:, None, :],
        torch.zeros(n, 0, 3),
    )


def test_panorama_matches_per_pixel_rays():
    model = shell_model()
    fast = render_panorama(model, 32, backend="cpu", view_size=48)
    ref = render_panorama_reference(model, 32, backend="cpu")
    assert fast.shape == ref.shape == (32, 64, 3) and fast.dtype == np.float32
    err = np.abs(fast - ref)
    assert err.mean() < 0.02 and np.percentile(err, 99) < 0.1, (err.mean(), np.percentile(err, 99))
    # colour = direction: the panorama's left-right and up-down follow the ERP convention
    assert ref[0, :, 2].mean() > 0.8 and ref[-1, :, 2].mean() < 0.2


def test_panorama_sees_from_its_position():
    """Moved 1 m towards +x, the panorama changes, and still matches the exact rays from there."""
    model = shell_model()
    centre = render_panorama(model, 16, backend="cpu", view_size=24)
    moved = render_panorama(model, 16, position=(1.0, 0.0, 0.0), backend="cpu", view_size=24)
    ref = render_panorama_reference(model, 16, (1.0, 0.0, 0.0), backend="cpu")
    assert np.abs(moved - centre).mean() > 0.05
    assert np.abs(moved - ref).mean() < 0.025


def test_panorama_rejects_tiny_height():
    with pytest.raises(ValueError, match="height"):
        render_panorama(shell_model(10), 1)
