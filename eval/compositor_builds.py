"""Time the cpu compositor of the checkout on PYTHONPATH (forward + backward; one thread and CPU seconds unless
``--threads``) and compare its outputs with another checkout's, so that two builds (e.g. an old commit extracted with
``git archive``) are timed one after the other on a shared machine, where wall seconds mean little.

    git archive OLD | tar -x -C /tmp/old
    PYTHONPATH=/tmp/old python eval/compositor_builds.py --save /tmp/old.pt
    PYTHONPATH=. python eval/compositor_builds.py --against /tmp/old.pt      # alternate a few times
    python eval/compositor_builds.py --run OUT --views 8 --no-contrib     # a trained model's own label views
    python eval/compositor_builds.py --run OUT --views 8 --threads 2         # as training runs it, wall ms

Scene: ``bench.rasterizer.scene`` (one 60° camera), ``--size`` and ``--gaussians`` (default 256², 100k); or with
``--run`` a ``panorecon train`` output (its point_cloud.ply and cameras.json): ``--views`` of its pseudo-label
cameras, spread over them, colours from the DC band (the trained degree), the trained opacities and shapes, which
blend far more Gaussians per pixel than the random scene. Gradients of a fixed random weighting of image, alpha
and depth. Prints one JSON line: median milliseconds (CPU with one thread, wall with ``--threads`` above 1) of the
forward (with contributions unless ``--no-contrib``) and backward over views and repeats, and with ``--against`` the
largest |difference| of every output and gradient (relative to the largest magnitude for gradients).
``mean_list_end``: the entries of its 4x4 block's list a pixel went through, on average (the kernel's ``last``): the
list entries visited per pixel; ``visible_pairs_per_view``: the Gaussians with radius > 0 in a view, on average.
With ``--lane-use`` (slow: a loop over every block), from the first repeat of each view: ``composited_per_pixel``,
the (pixel, entry) pairs that blend (alpha >= 1/255 before the pixel's end) per pixel, and ``backward_lane_use``,
those pairs over the lanes the backward evaluates (16 per entry up to its block's largest end); the forward walks
a block's list at least that far.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time


def main(argv=None) -> dict:
    import torch

    from panorecon.bench.rasterizer import scene, trained_views
    from panorecon.geometry import intrinsics_from_fov, look_at_viewmat
    from panorecon.splat.rasterize import cpu_backend
    from panorecon.splat.rasterize.sh import C0

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--gaussians", type=int, default=100_000)
    ap.add_argument("--run", default=None, help="a panorecon train output folder: its model and label views")
    ap.add_argument("--views", type=int, default=8, help="label views of --run, spread over its cameras")
    ap.add_argument("--no-contrib", action="store_true", help="forward without per-Gaussian contributions")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument(
        "--threads", type=int, default=1, help="intra-op threads; above 1, wall ms (CPU seconds add up the threads)"
    )
    ap.add_argument("--lane-use", action="store_true", help="count the lanes that blend (module docstring)")
    ap.add_argument("--save", default=None, help="write the outputs here (torch.save)")
    ap.add_argument("--against", default=None, help="compare with outputs saved by another checkout")
    args = ap.parse_args(argv)
    torch.set_num_threads(args.threads)
    clock = time.process_time if args.threads == 1 else time.perf_counter
    ext = cpu_backend.load()
    if args.run:
        means, quats, scales, opac, sh0, views, size = trained_views(args.run, args.views)
        colors = (sh0[:, 0] * C0 + 0.5).clamp_min(0).contiguous()
    else:
        size = args.size
        K = torch.tensor(intrinsics_from_fov(size, size, 60.0), dtype=torch.float32)[None]
        views = [(torch.tensor(look_at_viewmat([0, 0, 0], [1, 0, 0]), dtype=torch.float32)[None], K)]
        means, quats, scales, opac, colors = scene(args.gaussians)
    cols = colors[None].contiguous()
    g = torch.Generator().manual_seed(3)
    weights = [torch.rand(1, size, size, c, generator=g) for c in (3, 1, 1)]
    # the backward's arguments by checkout: 15 before 6652cbc; 16 with the radii (gradient buffers of the visible
    # pairs only); 18 with the forward's block lists (block_start, block_pos: forward outputs 7 and 8)
    n_args = ext.backward.__doc__.splitlines()[0].count("arg")
    n_lists = 4 if n_args == 18 else 2
    fwd, bwd, list_ends, visible, outputs = [], [], [], [], {"forward": [], "backward": []}
    composited = lanes = pixels = 0
    for V, K in views:
        m2d, con, dep, radii = ext.project_forward(means, quats, scales, V, K, size, size, 0.01, 1e10, 0.3)
        for _ in range(args.repeats):
            t0 = clock()
            f = ext.forward(m2d, con, cols, opac, dep, radii, size, size, 16, not args.no_contrib)
            t1 = clock()
            inputs = (m2d, con, cols, opac, dep, radii) if n_args >= 16 else (m2d, con, cols, opac, dep)
            b = ext.backward(*inputs, f[3], f[4], *f[5 : 5 + n_lists], *weights, size, size, 16)
            t2 = clock()
            fwd.append(t1 - t0)
            bwd.append(t2 - t1)
        outputs["forward"] += [f[k] for k in (0, 1, 2)] + ([] if args.no_contrib else f[-3:])
        list_ends.append(float(f[4].double().mean()))
        if args.lane_use:
            c, n = lane_use(m2d[0], con[0], opac, f, size)
            composited, lanes, pixels = composited + c, lanes + n, pixels + size * size
        visible.append(int((radii > 0).sum()))
        outputs["backward"] += list(b)
    out = {
        "size": size,
        "gaussians": len(means),
        "views": len(views),
        "contributions": not args.no_contrib,
        "threads": args.threads,
        "clock": "cpu" if args.threads == 1 else "wall",
        "forward_ms": 1000 * statistics.median(fwd),
        "backward_ms": 1000 * statistics.median(bwd),
        "mean_list_end": statistics.mean(list_ends),
        "visible_pairs_per_view": statistics.mean(visible),
    }
    if args.lane_use:
        out["composited_per_pixel"] = composited / pixels
        out["backward_lane_use"] = composited / lanes
    if args.against:
        other = torch.load(args.against)
        out["max_abs_difference_forward"] = [
            float((x - y).abs().max()) for x, y in zip(outputs["forward"], other["forward"])
        ]
        out["max_rel_difference_backward"] = [
            float((x - y).abs().max() / x.abs().max().clamp_min(1e-12))
            for x, y in zip(outputs["backward"], other["backward"])
        ]
    if args.save:
        torch.save(outputs, args.save)
    print(json.dumps(out))
    return out


def lane_use(m2d, con, opac, f, size: int, tile: int = 16, block: int = 4) -> tuple[int, int]:
    """-> (pairs composited, lanes the backward evaluates) of one camera's forward outputs ``f`` (image, alpha, depth,
    T, last, offsets, ids, block_start, block_pos, ...): each block's list entries before a pixel's end whose alpha
    at that pixel centre is nonzero by ``contrib.pair_alphas`` (the compositors' rules, in float64)."""
    import torch

    from panorecon.splat.rasterize.contrib import pair_alphas

    if size % tile:
        raise ValueError(f"--lane-use: the view size {size} is not a multiple of the {tile}-pixel tile")
    last, offsets, ids, starts, pos = f[4:9]
    per_side, bpt = tile // block, (tile // block) ** 2
    lane = torch.arange(block * block)
    composited = lanes = 0
    for t in range(len(offsets) - 1):
        ty, tx = divmod(t, size // tile)
        for b in range(bpt):
            entries = ids[offsets[t] + pos[starts[t * bpt + b] : starts[t * bpt + b + 1]]].long()
            i0, j0 = ty * tile + b // per_side * block, tx * tile + b % per_side * block
            pixels = (i0 + lane // block) * size + j0 + lane % block  # [16], row-major
            ends = last[0].flatten()[pixels][:, None]
            pix, gid = (x.flatten() for x in torch.broadcast_tensors(pixels[:, None], entries[None]))
            alpha = pair_alphas(m2d[None], con[None], opac, torch.zeros_like(pix), pix, gid, size).view(len(lane), -1)
            composited += int(((torch.arange(len(entries)) < ends) & (alpha > 0)).sum())
            lanes += int(ends.max()) * block * block
    return composited, lanes


if __name__ == "__main__":
    main()
