"""eval/compositor_builds.py on a tiny scene: it times, saves, and compares a build's outputs with saved ones."""

import importlib.util
from pathlib import Path

import pytest

from panorecon.splat.rasterize import cpu_backend

spec = importlib.util.spec_from_file_location(
    "compositor_builds", Path(__file__).parents[2] / "eval" / "compositor_builds.py"
)
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
def test_same_build_against_itself_differs_nowhere(tmp_path):
    tiny = ["--size", "32", "--gaussians", "300", "--repeats", "1"]
    first = script.main([*tiny, "--save", str(tmp_path / "a.pt")])
    assert first["forward_ms"] > 0 and first["backward_ms"] > 0
    again = script.main([*tiny, "--against", str(tmp_path / "a.pt")])
    assert len(again["max_abs_difference_forward"]) == 6 and len(again["max_rel_difference_backward"]) == 5
    assert max(again["max_abs_difference_forward"]) == 0 and max(again["max_rel_difference_backward"]) == 0


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
def test_a_trained_runs_label_views(tmp_path):
    """--run reads a train output's model and cameras.json: each view's image, alpha and depth are compared
    (no contributions with --no-contrib)."""
    import torch

    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
    from panorecon.io import write_json
    from panorecon.splat.model import GaussianModel
    from panorecon.splat.ply import save_ply

    g = torch.Generator().manual_seed(0)
    n = 400
    model = GaussianModel(
        torch.randn(n, 3, generator=g) * 0.5 + torch.tensor([3.0, 0.0, 0.0]),
        torch.randn(n, 4, generator=g),
        torch.full((n, 3), -3.0),
        torch.zeros(n),
        torch.randn(n, 1, 3, generator=g),
        torch.zeros(n, 15, 3),
    )
    save_ply(model, tmp_path / "point_cloud.ply")
    camera = {
        "viewmat": look_at_viewmat([0, 0, 0], [1, 0, 0]).tolist(),
        "K": intrinsics_from_fov(32, 32, 60.0).tolist(),
        "width": 32,
        "height": 32,
    }
    write_json(tmp_path / "cameras.json", {"pseudo-label": [camera] * 4, "held-out": []})
    run = ["--run", str(tmp_path), "--views", "2", "--repeats", "1", "--no-contrib"]
    first = script.main([*run, "--save", str(tmp_path / "a.pt")])
    assert first["gaussians"] == n and first["views"] == 2 and first["size"] == 32 and not first["contributions"]
    again = script.main([*run, "--against", str(tmp_path / "a.pt")])
    assert len(again["max_abs_difference_forward"]) == 2 * 3 and max(again["max_abs_difference_forward"]) == 0


@pytest.mark.skipif(not cpu_backend.available(), reason="the C++ rasterizer could not be built here")
def test_lane_use_counts_the_blends_a_list_free_walk_finds():
    """--lane-use's composited pairs equal, within float rounding at the 1/255 cut, a walk over every visible
    Gaussian in depth order per pixel (no tiles, no block lists), stopping where T would reach 1e-4."""
    import numpy as np
    import torch

    from panorecon.bench.rasterizer import scene
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat

    size = 32
    ext = cpu_backend.load()
    means, quats, scales, opac, colors = scene(600)
    scales = scales * 12  # a few pixels wide at 32 px: each pixel blends tens of them
    opac = torch.where(torch.arange(600) % 4 == 0, opac, torch.full_like(opac, 0.99))  # and many pixels stop early
    V = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None]
    K = torch.tensor(intrinsics_from_fov(size, size, 60.0), dtype=torch.float32)[None]
    m2d, con, dep, radii = ext.project_forward(means, quats, scales, V, K, size, size, 0.01, 1e10, 0.3)
    f = ext.forward(m2d, con, colors[None].contiguous(), opac, dep, radii, size, size, 16, False)
    composited, lanes = script.lane_use(m2d[0], con[0], opac, f, size)

    vis = np.flatnonzero(radii[0].numpy() > 0)
    vis = vis[np.argsort(dep[0].numpy()[vis], kind="stable")]
    m, q, o = m2d[0].double().numpy()[vis], con[0].double().numpy()[vis], opac.double().numpy()[vis]
    walked = stopped = 0
    for i in range(size):
        for j in range(size):
            dx, dy = j + 0.5 - m[:, 0], i + 0.5 - m[:, 1]
            sigma = 0.5 * (q[:, 0] * dx * dx + q[:, 2] * dy * dy) + q[:, 1] * dx * dy
            alpha = np.minimum(0.999, o * np.exp(-sigma))
            T = 1.0
            for a in alpha[(sigma >= 0) & (alpha >= 1 / 255)]:
                if T * (1 - a) <= 1e-4:
                    stopped += 1
                    break
                T *= 1 - a
                walked += 1
    assert walked > 10 * size * size and stopped > size * size / 4  # pixels blend many Gaussians, many stop
    assert abs(composited - walked) <= 0.001 * walked
    assert composited <= lanes <= 16 * int(f[4].max()) * (size // 4) ** 2
