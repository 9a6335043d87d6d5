"""Rasterizer benchmark: forward + backward time of the ``torch`` reference and the ``cpu`` kernel, measured in
the same run, at 128², 256², 512² with 10k and 100k Gaussians.

    python -m panorecon.bench.rasterizer [--quick] [--repeats N] [--stages] [--out result.json]

Scene: Gaussians uniformly in a box 2-8 m in front of one 60° camera, isotropic-ish scales 1-4 cm (a few
pixels each at 256²), opacities 0.1-0.9, RGB colours. Median seconds over repeats (the torch reference is
run once where one run exceeds 60 s, and says so), peak RSS of this process, ratio torch / cpu. With
``--stages``, also the cpu backend's time split at 256²/100k: projection forward, compositing forward,
compositing backward, projection backward (each stage's backward run alone with ``torch.autograd.grad``), and
the PyTorch reference projection's forward and backward in the same run; and the degree-3 SH colours of the
same Gaussians (forward + backward): the C++ kernel, which evaluates only the pairs with radius > 0, against
``sh_colors_reference`` on every Gaussian (the torch backend's path), with their ratio.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from dataclasses import dataclass

import torch

from .. import checks as C
from ..checks import opt
from ..evaluation.environment import emit, environment
from ..io import peak_rss_mb


def scene(n: int, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    means = torch.stack(
        [
            torch.rand(n, generator=g) * 6 + 2,
            (torch.rand(n, generator=g) - 0.5) * 6,
            (torch.rand(n, generator=g) - 0.5) * 6,
        ],
        -1,
    )
    quats = torch.randn(n, 4, generator=g)
    scales = torch.rand(n, 3, generator=g) * 0.03 + 0.01
    opac = torch.rand(n, generator=g) * 0.8 + 0.1
    colors = torch.rand(n, 3, generator=g)
    return means, quats, scales, opac, colors


def trained_views(run, views: int):
    """A ``panorecon train`` output's model (its point_cloud.ply) and ``views`` of its pseudo-label cameras spread
    over them (cameras.json): means, unit quats, linear scales, opacities [N], sh0 [N,1,3], [(viewmat [1,4,4],
    K [1,3,3])] and the views' size in pixels (eval/compositor_builds.py's and eval/kernel_ab.py's ``--run``)."""
    import json
    from pathlib import Path

    from panorecon.splat.ply import load_ply

    model = load_ply(Path(run) / "point_cloud.ply")
    cameras = json.loads((Path(run) / "cameras.json").read_text())["pseudo-label"]
    cameras = [cameras[round(i * len(cameras) / views)] for i in range(views)]
    with torch.no_grad():
        quats = model.quats / model.quats.norm(dim=-1, keepdim=True)
        means, quats, scales = (t.contiguous() for t in (model.means, quats, model.scales()))
        opacities, sh0 = model.opacities().contiguous(), model.sh0.detach().contiguous()
    cams = [
        (torch.tensor(c["viewmat"], dtype=torch.float32)[None], torch.tensor(c["K"], dtype=torch.float32)[None])
        for c in cameras
    ]
    return means, quats, scales, opacities, sh0, cams, cameras[0]["width"]


def fwd_bwd(backend: str, size: int, n: int) -> float:
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
    from panorecon.splat.rasterize import rasterize

    K = torch.tensor(intrinsics_from_fov(size, size, 60.0), dtype=torch.float32)[None]
    V = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None]
    leaves = [t.clone().requires_grad_(True) for t in scene(n)]
    t = time.perf_counter()
    img, alpha, depth, _ = rasterize(*leaves, V, K, size, size, backend=backend)
    (img.sum() + alpha.sum() + depth.sum()).backward()
    return time.perf_counter() - t


def cpu_stages(size: int = 256, n: int = 100_000, repeats: int = 5) -> dict:
    """Median milliseconds of the cpu backend's four stages and of the reference projection (module docstring)."""
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
    from panorecon.splat.rasterize import cpu_backend, project_gaussians

    K = torch.tensor(intrinsics_from_fov(size, size, 60.0), dtype=torch.float32)[None]
    V = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None]
    times = {
        k: []
        for k in (
            "projection_forward",
            "composite_forward",
            "composite_backward",
            "projection_backward",
            "reference_projection_forward",
            "reference_projection_backward",
        )
    }
    for _ in range(repeats):
        for project, prefix in ((cpu_backend.project, ""), (project_gaussians, "reference_")):
            means, quats, scales, opac, colors = [t.clone().requires_grad_(True) for t in scene(n)]
            t0 = time.perf_counter()
            m2d, con, dep, radii = project(means, quats, scales, V, K, size, size)
            t1 = time.perf_counter()
            cols = colors[None]
            img, alpha, depth, _ = cpu_backend.composite(m2d, con, cols, opac, dep, radii, size, size)
            t2 = time.perf_counter()
            g = torch.autograd.grad(img.sum() + alpha.sum() + depth.sum(), [m2d, con, cols, dep])
            t3 = time.perf_counter()
            torch.autograd.grad([m2d, con, cols, dep], [means, quats, scales, colors], list(g))
            t4 = time.perf_counter()
            times[prefix + "projection_forward"].append(t1 - t0)
            times[prefix + "projection_backward"].append(t4 - t3)
            if not prefix:
                times["composite_forward"].append(t2 - t1)
                times["composite_backward"].append(t3 - t2)
    sh = sh_stage(size, n, repeats)
    return {
        "size": size,
        "gaussians": n,
        **{k + "_ms": 1000 * statistics.median(v) for k, v in times.items()},
        **sh,
    }


def sh_stage(size: int, n: int, repeats: int) -> dict:
    """Median milliseconds of degree-3 SH colours forward + backward: C++ (visible pairs) and the einsum
    reference ``sh_colors_reference`` (all pairs), the visible fraction and the ratio reference / C++."""
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
    from panorecon.splat.rasterize import cpu_backend
    from panorecon.splat.rasterize.sh import sh_colors_reference

    K = torch.tensor(intrinsics_from_fov(size, size, 60.0), dtype=torch.float32)[None]
    V = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None]
    means, quats, scales, _, _ = scene(n)
    # half the Gaussians mirrored behind the camera, as in a panorama's views where most of the sphere is unseen
    means[: n // 2, 0] *= -1
    radii = cpu_backend.project(means, quats, scales, V, K, size, size)[3]
    coeffs = torch.randn(n, 16, 3, generator=torch.Generator().manual_seed(1)) * 0.1
    campos = torch.zeros(1, 3)
    times = {"sh_forward_backward": [], "reference_sh_forward_backward": []}
    for _ in range(repeats):
        for key in times:
            c, m = coeffs.clone().requires_grad_(True), means.clone().requires_grad_(True)
            t0 = time.perf_counter()
            if key.startswith("reference"):
                cols = sh_colors_reference(3, c, m, campos)
            else:
                cols = cpu_backend.sh_colors(3, c, m, campos, radii)
            cols.sum().backward()
            times[key].append(time.perf_counter() - t0)
    ms = {k + "_ms": 1000 * statistics.median(v) for k, v in times.items()}
    return {
        **ms,
        "sh_visible_fraction": float((radii > 0).float().mean()),
        "sh_speedup_cpu_vs_reference": ms["reference_sh_forward_backward_ms"] / ms["sh_forward_backward_ms"],
    }


def max_difference(size: int, n: int) -> dict:
    """Largest |cpu - torch| on the image and on the means gradient (the correctness check of the benchmark)."""
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
    from panorecon.splat.rasterize import rasterize

    K = torch.tensor(intrinsics_from_fov(size, size, 60.0), dtype=torch.float32)[None]
    V = torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None]
    out = {}
    for backend in ("cpu", "torch"):
        leaves = [t.clone().requires_grad_(True) for t in scene(n)]
        img, *_ = rasterize(*leaves, V, K, size, size, backend=backend)
        img.sum().backward()
        out[backend] = (img.detach(), leaves[0].grad)
    return {
        "image": float((out["cpu"][0] - out["torch"][0]).abs().max()),
        "grad_means": float((out["cpu"][1] - out["torch"][1]).abs().max()),
    }


@dataclass(frozen=True)
class BenchRasterizerConfig:
    quick: bool = opt(False, "one size, 128² and 10k Gaussians (CI)")
    repeats: int = opt(3, "timed runs per size and backend", check=C.int_in(1, None, "repeat count"))
    stages: bool = opt(False, "also the cpu backend's time per stage at 256²/100k")
    out: str | None = opt(None, "also write the result JSON here", role="out-file")


def main(argv=None) -> dict:
    from ..cli_types import parse_config

    cfg = parse_config(BenchRasterizerConfig, argv, __doc__.splitlines()[0])
    grid = [(128, 10_000)] if cfg.quick else [(s, n) for s in (128, 256, 512) for n in (10_000, 100_000)]
    fwd_bwd("cpu", 32, 100)  # build / load the extension outside the timings
    rows = []
    for size, n in grid:
        row = {"size": size, "gaussians": n}
        for backend in ("cpu", "torch"):
            first = fwd_bwd(backend, size, n)
            reps = [first] + ([fwd_bwd(backend, size, n) for _ in range(cfg.repeats - 1)] if first < 60 else [])
            row[backend] = {"median_seconds": statistics.median(reps), "runs": len(reps)}
        row["speedup_cpu_vs_torch"] = row["torch"]["median_seconds"] / row["cpu"]["median_seconds"]
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    extra = {"cpu_stages": cpu_stages()} if cfg.stages else {}
    return emit(
        {
            "benchmark": "rasterizer forward+backward",
            **environment(),
            "threads": torch.get_num_threads(),
            "max_abs_difference": max_difference(*grid[0]),
            **extra,
            "peak_rss_mb": peak_rss_mb(),
            "results": rows,
        },
        cfg.out,
    )


if __name__ == "__main__":
    main()
