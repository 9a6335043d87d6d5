"""Time the cpu backend's kernels of this checkout against another checkout's, both built and loaded in one process
and called alternately (new, old, old, new, ...), so that the drift of a shared machine falls on both alike; and check
that both give the same outputs (``torch.equal``). Sequential runs of two builds (``compositor_builds.py``) do not
resolve a 10 % change on a machine whose speed moves by 18 % in 20 minutes; interleaved calls do.

    git archive OLD | tar -x -C /tmp/old
    python eval/kernel_ab.py /tmp/old                       # the bench scene (200k Gaussians, 256^2)
    python eval/kernel_ab.py /tmp/old --run OUT --views 8   # a panorecon train output's model and label views
    python eval/kernel_ab.py /tmp/old --run OUT --size 128  # ... at the coarse steps' size (K scaled)

This checkout's build is the package's own (``cpu_backend.load()``); the other one is built once into
``$PANORECON_CACHE/torch_extensions/kernel_ab/``. Given this checkout itself, both sides are the same build.

Stages (SH at degree 0, the trainer's; SSIM of a 256^2 x 3 render against a target): projection, SH colours,
compositing and SSIM, forward and backward; and the densification statistic: the C++ pass of ``csrc/densify_cpu.cpp``
where a build has it, else the PyTorch formula ``DefaultStrategy.observe`` used before (a nonzero, gathers, a norm
and two ``index_add_``). Prints one JSON line: per stage the median ms of each build, old / new, and whether the
outputs are equal. Two threads unless ``--threads``; wall clock.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path


def build(csrc: Path, name: str):
    """The extension of the C++ sources in ``csrc`` (those of ``cpu_backend.SOURCE_FILES`` it has) under the module
    name ``name``, with the backend's flags, in the panorecon cache."""
    from torch.utils.cpp_extension import load

    from panorecon.splat.rasterize import cpu_backend

    directory = cpu_backend.build_dir().parent / "kernel_ab" / name
    directory.mkdir(parents=True, exist_ok=True)
    files = [str(csrc / f) for f in cpu_backend.SOURCE_FILES if (csrc / f).exists()]
    return load(
        name=name,
        sources=files,
        build_directory=str(directory),
        extra_cflags=cpu_backend.CFLAGS,
        extra_ldflags=cpu_backend.LDFLAGS,
    )


def inputs(run: str | None, views: int, gaussians: int, size: int | None = None):
    """(means, quats, scales, opacities, sh0, [(viewmat [1,4,4], K [1,3,3])], size); ``size``: the views rendered at
    this size instead of their own (K scaled, as the trainer's coarse steps do)."""
    import torch

    from panorecon.bench.rasterizer import scene, trained_views
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
    from panorecon.splat.rasterize.sh import C0

    if run is not None:
        means, quats, scales, opac, sh0, cams, own = trained_views(run, views)
        if size is None or size == own:
            return means, quats, scales, opac, sh0, cams, own
        scale = torch.tensor([[size / own], [size / own], [1.0]])
        return means, quats, scales, opac, sh0, [(V, K * scale) for V, K in cams], size
    size = size or 256
    K = torch.tensor(intrinsics_from_fov(size, size, 60.0), dtype=torch.float32)[None]
    cams = [(torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None], K)]
    means, quats, scales, opac, colors = scene(gaussians)
    sh0 = ((colors - 0.5) / C0)[:, None].contiguous()
    return means, quats, scales, opac, sh0, cams, size


def observe_torch(grad_sum, count, g, radii, width, height):
    """``DefaultStrategy.observe``'s CPU formula before the C++ pass (b7864dc), in place."""
    import torch

    ndc = torch.tensor([width / 2, height / 2])
    vis = radii > 0
    rows = torch.nonzero(vis.any(0)).flatten()
    seen = vis[:, rows]
    grad_sum.index_add_(0, rows, ((g[:, rows] * ndc).norm(dim=-1) * seen).sum(0))
    count.index_add_(0, rows, seen.sum(0).to(count.dtype))


def main(argv=None) -> dict:
    import torch

    from panorecon.splat.losses import gaussian_kernel_1d

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("old", help="the other checkout (its panorecon/splat/rasterize/csrc is built)")
    ap.add_argument("--run", default=None, help="a panorecon train output folder: its model and label views")
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--gaussians", type=int, default=200_000, help="bench scene size without --run")
    ap.add_argument("--size", type=int, default=None, help="view size in pixels (default: the views' own, or 256)")
    ap.add_argument("--repeats", type=int, default=10)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    from panorecon.splat.rasterize import cpu_backend

    here = Path(cpu_backend.__file__).resolve().parent / "csrc"
    theirs = (Path(args.old) / "panorecon" / "splat" / "rasterize" / "csrc").resolve()
    if not theirs.is_dir():
        raise SystemExit(f"{args.old}: no panorecon/splat/rasterize/csrc there (expected a panorecon checkout)")
    new = cpu_backend.load()  # this checkout's own build
    builds = {"new": new, "old": new if theirs == here else build(theirs, "kernel_ab_old")}
    means, quats, scales, opac, sh0, cams, S = inputs(args.run, args.views, args.gaussians, args.size)
    rest = torch.zeros(len(means), 15, 3)
    g = torch.Generator().manual_seed(3)
    upstream = [torch.rand(1, S, S, c, generator=g) for c in (3, 1, 1)]
    g_m2d, g_con, g_dep = (torch.rand(1, len(means), k, generator=g).squeeze(-1) for k in (2, 3, 1))
    image, target = torch.rand(3, S, S, generator=g), torch.rand(3, S, S, generator=g)
    taps, one = gaussian_kernel_1d(), torch.tensor(1.0)
    times = {key: {} for key in builds}
    outputs = {key: [] for key in builds}

    def timed(key, stage, fn):
        t0 = time.perf_counter()
        out = fn()
        times[key].setdefault(stage, []).append(1000 * (time.perf_counter() - t0))
        return out

    def one_build(key, V, K, record):
        ext = builds[key]
        m2d, con, dep, radii = timed(
            key, "projection_forward", lambda: ext.project_forward(means, quats, scales, V, K, S, S, 0.01, 1e10, 0.3)
        )
        gp = timed(
            key,
            "projection_backward",
            lambda: ext.project_backward(means, quats, scales, V, K, radii, g_m2d, g_con, g_dep, S, S, 0.01, 1e10, 0.3),
        )
        campos = -(V[0, :3, :3].T @ V[0, :3, 3])[None].contiguous()
        cols = timed(key, "sh_forward", lambda: ext.sh_forward(sh0, rest, means, campos, radii, 0))
        g_cols = torch.ones_like(cols)
        gs = timed(key, "sh_backward", lambda: ext.sh_backward(sh0, rest, means, campos, radii, g_cols, 0))
        f = timed(key, "composite_forward", lambda: ext.forward(m2d, con, cols, opac, dep, radii, S, S, 16, False))
        b = timed(
            key,
            "composite_backward",
            lambda: ext.backward(m2d, con, cols, opac, dep, radii, f[3], f[4], *f[5:9], *upstream, S, S, 16),
        )
        value, partials = timed(key, "ssim_forward", lambda: ext.ssim_forward(image, target, taps))
        gx = timed(key, "ssim_backward", lambda: ext.ssim_backward(image, target, taps, partials, one))
        grad_sum, count = torch.zeros(len(means)), torch.zeros(len(means))
        g2d = b[0]  # the compositor's gradient of means2d: zero for culled pairs
        if hasattr(ext, "accumulate_screen_grads"):
            statistic = lambda: ext.accumulate_screen_grads(grad_sum, count, g2d, radii, S / 2, S / 2)  # noqa: E731
        else:
            statistic = lambda: observe_torch(grad_sum, count, g2d, radii, S, S)  # noqa: E731
        timed(key, "densify_statistic", statistic)
        if record:
            outputs[key] += [m2d, con, dep, radii, *gp, cols, *gs, *f[:3], *b, value, gx, grad_sum, count]

    for r in range(args.repeats):
        for V, K in cams:
            for key in ("new", "old") if r % 2 == 0 else ("old", "new"):
                one_build(key, V, K, record=r == 0)
    stages = {}
    for stage in times["new"]:
        new, old = statistics.median(times["new"][stage]), statistics.median(times["old"][stage])
        stages[stage] = {"new_ms": round(new, 3), "old_ms": round(old, 3), "old_over_new": round(old / new, 3)}
    out = {
        "old": str(args.old),
        "scene": args.run or f"bench scene, {len(means)} Gaussians",
        "views": len(cams),
        "size": S,
        "threads": args.threads,
        "repeats": args.repeats,
        "stages": stages,
        "outputs_equal": all(torch.equal(a, b) for a, b in zip(outputs["new"], outputs["old"])),
    }
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main()
