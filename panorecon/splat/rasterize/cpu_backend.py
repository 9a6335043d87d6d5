"""The ``cpu`` backend: EWA projection (csrc/project_cpu.cpp, parallel over Gaussians), SH colours of the visible
Gaussians (csrc/sh_cpu.cpp, parallel over Gaussians) and tiled compositing (csrc/rasterize_cpu.cpp, parallel over
tiles) in C++ with hand-written backwards, through ATen's thread pool (OpenMP); the training loss's SSIM
(csrc/ssim_cpu.cpp), L1 and depth term (csrc/loss_cpu.cpp), the densification statistic (csrc/densify_cpu.cpp) and
the flattening onto the given cloud's surface (csrc/flatten_cpu.cpp) beside them. Built with
torch.utils.cpp_extension on first use (or ahead of time by ``python -m panorecon.splat.rasterize.build``) into
``$PANORECON_CACHE/torch_extensions/<checkout>`` (default ~/.cache/panorecon). Compiled with -O3 and no
-march=native, so the build is portable: the hot compositing functions are built three times (x86-64-v4 with AVX-512,
x86-64-v3 with AVX2 and FMA, and baseline x86-64) and the loader picks by CPU. csrc/peak_cpu.cpp holds the FMA loop
and copy that measure the machine's limits for the roofline benchmark. Compositing is float32; the projection runs in
the inputs' dtype (float32 in training, float64 in tests).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import logging
import os
from pathlib import Path

import torch

from .sh import check_sh, split_sh

log = logging.getLogger("panorecon.splat")
# the extension's C++ files in csrc/ and its compiler and linker flags (also eval/kernel_ab.py's, for another checkout)
SOURCE_FILES = (
    "module.cpp",
    "project_cpu.cpp",
    "sh_cpu.cpp",
    "rasterize_cpu.cpp",
    "ssim_cpu.cpp",
    "loss_cpu.cpp",
    "densify_cpu.cpp",
    "flatten_cpu.cpp",
    "peak_cpu.cpp",
)
CFLAGS, LDFLAGS = ["-O3", "-fopenmp", "-Wno-psabi"], ["-fopenmp"]
_SOURCES = [Path(__file__).parent / "csrc" / f for f in SOURCE_FILES]
_module = None
_error: str | None = None


def build_dir() -> Path:
    """``$PANORECON_CACHE/torch_extensions/<hash of this checkout's csrc path>``: one build per checkout, so two
    checkouts (a clone for CI beside a working tree) do not rebuild over each other's sources on every load."""
    root = Path(os.environ.get("PANORECON_CACHE", Path.home() / ".cache" / "panorecon"))
    checkout = hashlib.sha1(str(_SOURCES[0].parent.resolve()).encode()).hexdigest()[:12]
    d = root / "torch_extensions" / checkout
    d.mkdir(parents=True, exist_ok=True)
    return d


@contextlib.contextmanager
def _exclusive_build(directory: Path):
    """Hold an ``flock`` on ``directory/build.flock`` while torch builds there, and remove torch's own ``lock``
    file first if one is present. torch's lock (a FileBaton) is a plain file that a killed build leaves behind,
    after which every later load waits on it forever; the flock is released by the kernel when its holder dies,
    so a ``lock`` file found while holding it was left by a dead process."""
    with open(directory / "build.flock", "w") as handle:  # closing the file releases the flock
        fcntl.flock(handle, fcntl.LOCK_EX)
        stale = directory / "lock"
        if stale.exists():
            log.warning("removing %s, left by an interrupted build", stale)
            stale.unlink(missing_ok=True)
        yield


@contextlib.contextmanager
def _one_ninja():
    """The ``ninja`` package's binary first on PATH while torch builds, when that package is installed. Ninja
    versions keep incompatible build logs (1.11's and 1.13's each discard the other's), and a build directory
    whose log is discarded is rebuilt from scratch, minutes on 2 cores: without this, a load from an activated
    environment and one from outside it (/usr/bin/ninja) would rebuild at every switch."""
    try:
        import ninja
    except ImportError:
        yield
        return
    path = os.environ.get("PATH", "")
    os.environ["PATH"] = os.pathsep.join([ninja.BIN_DIR, path])
    try:
        yield
    finally:
        os.environ["PATH"] = path


def load(verbose: bool = False):
    """The compiled module, or None (with the reason logged once) when it cannot be built here."""
    global _module, _error
    if _module is not None or _error is not None:
        return _module
    try:
        from torch.utils.cpp_extension import load as load_ext

        directory = build_dir()
        with _exclusive_build(directory), _one_ninja():
            _module = load_ext(
                name="panorecon_rasterize_cpu",
                sources=[str(p) for p in _SOURCES],
                build_directory=str(directory),
                extra_cflags=CFLAGS,
                extra_ldflags=LDFLAGS,
                verbose=verbose,
            )
    except Exception as e:  # a missing compiler or headers: fall back to the reference
        _error = build_failure(e)
        log.warning("cpu rasterizer unavailable (%s); the torch reference backend runs instead", _error)
    return _module


def build_failure(e: Exception) -> str:
    """One line for a failed build: the exception's first line without the compiler command that ninja echoes
    after it, and the first line that says what went wrong, when there is one: the compiler's ``error:`` (file,
    line, what) or the shell's ``not found`` (no compiler at ``$CXX``)."""
    lines = str(e).splitlines()
    head = f"{type(e).__name__}: {lines[0].split(': [', 1)[0] if lines else ''}"
    first_error = next((ln.strip() for ln in lines if "error:" in ln or ln.endswith("not found")), None)
    return f"{head}; {first_error}" if first_error else head


def available() -> bool:
    return load() is not None


def unavailable_reason() -> str | None:
    """Why the extension could not be built here (one line, as logged), or None when it loads."""
    load()
    return _error


class _Project(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, quats, scales, viewmats, Ks, width, height, near_plane, far_plane, eps2d):
        means2d, conics, depths, radii = load().project_forward(
            means, quats, scales, viewmats, Ks, width, height, near_plane, far_plane, eps2d
        )
        ctx.save_for_backward(means, quats, scales, viewmats, Ks, radii)
        ctx.args = (width, height, near_plane, far_plane, eps2d)
        ctx.mark_non_differentiable(radii)
        return means2d, conics, depths, radii

    @staticmethod
    def backward(ctx, g_means2d, g_conics, g_depths, _g_radii):
        means, quats, scales, viewmats, Ks, radii = ctx.saved_tensors
        g = [
            t.contiguous() if t is not None else torch.zeros(shape, dtype=means.dtype)
            for t, shape in ((g_means2d, (*radii.shape, 2)), (g_conics, (*radii.shape, 3)), (g_depths, radii.shape))
        ]
        gm, gq, gs = load().project_backward(means, quats, scales, viewmats, Ks, radii, *g, *ctx.args)
        return gm, gq, gs, None, None, None, None, None, None, None


def project(
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
    """``projection.project_gaussians`` in C++, in the dtype of ``means`` (float32 or float64): means2d
    [C,N,2], conics [C,N,3], depths [C,N], radii [C,N] int32. Differentiable w.r.t. means, quats and scales
    (not the cameras); a culled (camera, Gaussian) pair, radius 0, passes no gradient back."""
    dtype = means.dtype if means.dtype in (torch.float32, torch.float64) else torch.float32
    f = lambda t: t.to(dtype).contiguous()  # noqa: E731
    means2d, conics, depths, radii = _Project.apply(
        f(means),
        f(quats),
        f(scales),
        f(viewmats),
        f(Ks),
        width,
        height,
        float(near_plane),
        float(far_plane),
        float(eps2d),
    )
    return means2d, conics, depths, radii


class _ShColors(torch.autograd.Function):
    @staticmethod
    def forward(ctx, dc, rest, means, campos, radii, degree):
        ctx.save_for_backward(dc, rest, means, campos, radii)
        ctx.degree = degree
        return load().sh_forward(dc, rest, means, campos, radii, degree)

    @staticmethod
    def backward(ctx, g_colors):
        dc, rest, means, campos, radii = ctx.saved_tensors
        g_dc, g_rest, g_means = load().sh_backward(dc, rest, means, campos, radii, g_colors.contiguous(), ctx.degree)
        # degree 0 reads no higher band and not the view direction: None, not tensors of zeros, for shN and means
        # (the trainer's steps at 200k Gaussians would allocate, fault in and zero 36 MB a step for shN, and Adam
        # would step shN on zeros; the means' zeros would be added to the projection's gradient)
        if ctx.degree == 0:
            return g_dc, None, None, None, None, None
        return g_dc, g_rest, g_means, None, None, None


def sh_colors(degree: int, coeffs, means, campos, radii):
    """``sh.sh_colors_reference`` in C++ for the (camera, Gaussian) pairs with radius > 0, in the dtype of ``means``:
    coeffs [N,K,3] or the pair (sh0 [N,1,3], shN [N,K-1,3]) (no concatenation: the trainer's path), means [N,3],
    campos [C,3] camera centres, radii [C,N] -> colours [C,N,3], 0 (and no gradient) where culled. Differentiable
    w.r.t. the coefficients and means (through the view direction); at degree 0 the higher bands get no gradient
    (None: a pair's shN.grad stays None, and Adam leaves shN and its state alone until degree 1)."""
    dc, rest = split_sh(coeffs)
    check_sh(degree, rest.shape[1] + 1)
    dtype = means.dtype if means.dtype in (torch.float32, torch.float64) else torch.float32

    def rows(t):  # unit strides inside a row; any row stride (views of one [N,K,3] tensor are read in place)
        t = t.to(dtype)
        return t if t.stride(-1) == 1 and (t.shape[1] <= 1 or t.stride(1) == 3) else t.contiguous()

    f = lambda t: t.to(dtype).contiguous()  # noqa: E731
    return _ShColors.apply(rows(dc), rows(rest), f(means), f(campos), radii.to(torch.int32).contiguous(), int(degree))


class _Composite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, colors, opacities, depths, radii, width, height, tile, want_contrib):
        ext = load()
        image, alpha, depth, T_final, last, *lists, w_sum, w_max, t_max = ext.forward(
            means2d, conics, colors, opacities, depths, radii, width, height, tile, want_contrib
        )
        # lists: the tiles' depth-sorted ids and the 4x4 blocks' lists, which the backward walks again
        ctx.save_for_backward(means2d, conics, colors, opacities, depths, radii, T_final, last, *lists)
        ctx.size = (width, height, tile)
        ctx.mark_non_differentiable(w_sum, w_max, t_max)
        return image, alpha, depth, w_sum, w_max, t_max

    @staticmethod
    def backward(ctx, g_image, g_alpha, g_depth, *_contrib_grads):
        means2d, conics, colors, opacities, depths, radii, T_final, last, *lists = ctx.saved_tensors
        width, height, tile = ctx.size
        g = [
            t.contiguous() if t is not None else torch.zeros_like(ref)
            for t, ref in (
                (g_image, T_final[..., None].expand(-1, -1, -1, 3)),
                (g_alpha, T_final[..., None]),
                (g_depth, T_final[..., None]),
            )
        ]
        gm, gc, gcol, gop, gz = load().backward(
            means2d,
            conics,
            colors,
            opacities,
            depths,
            radii,
            T_final,
            last,
            *lists,
            g[0],
            g[1],
            g[2],
            width,
            height,
            tile,
        )
        return gm, gc, gcol, gop, gz, None, None, None, None, None


def composite(
    means2d,
    conics,
    colors,
    opacities,
    depths,
    radii,
    width: int,
    height: int,
    tile: int = 16,
    return_contrib: bool = False,
):
    """Same contract as ``torch_backend.rasterize_tiles`` without backgrounds; float32. -> (image, alpha,
    depth, contrib dict of weight_sum / weight_max / trans_max [C,N] or None). Opacities per camera [C,N]
    composite one camera at a time (the kernel reads one [N] vector)."""
    if opacities.dim() == 2 and len(opacities) > 1:
        parts = [
            composite(
                means2d[i : i + 1], conics[i : i + 1], colors[i : i + 1], opacities[i], depths[i : i + 1],
                radii[i : i + 1], width, height, tile, return_contrib,
            )
            for i in range(len(opacities))
        ]  # fmt: skip
        image, alpha, depth = (torch.cat([p[k] for p in parts]) for k in range(3))
        contrib = {k: torch.cat([p[3][k] for p in parts]) for k in parts[0][3]} if return_contrib else None
        return image, alpha, depth, contrib
    if opacities.dim() == 2:
        opacities = opacities[0]
    f = lambda t: t.float().contiguous()  # noqa: E731
    image, alpha, depth, w_sum, w_max, t_max = _Composite.apply(
        f(means2d),
        f(conics),
        f(colors),
        f(opacities),
        f(depths),
        radii.to(torch.int32).contiguous(),
        width,
        height,
        tile,
        return_contrib,
    )
    contrib = {"weight_sum": w_sum, "weight_max": w_max, "trans_max": t_max} if return_contrib else None
    return image, alpha, depth, contrib


def accumulate_screen_grads(grad_sum, count, g_means2d, radii, width: int, height: int) -> None:
    """DefaultStrategy's statistic in C++, in place: ``grad_sum[n] +=`` the sum over the cameras c with
    ``radii[c, n] > 0`` of ``|g_means2d[c, n] * (width / 2, height / 2)|`` and ``count[n] +=`` their number.
    grad_sum, count [N] float32 contiguous (updated); g_means2d [C, N, 2]; radii [C, N]."""
    if not (grad_sum.dtype == count.dtype == torch.float32 and grad_sum.is_contiguous() and count.is_contiguous()):
        raise ValueError("accumulate_screen_grads: grad_sum and count must be contiguous float32 tensors")
    g = g_means2d.detach().float().contiguous()
    load().accumulate_screen_grads(grad_sum, count, g, radii.to(torch.int32).contiguous(), width / 2, height / 2)


def flatten_surface(means, quats, log_scales, frames, thickness: float, min_cos: float) -> torch.Tensor:
    """``regularisers.flatten_onto_surface_torch`` in C++, in place: quats [N, 4] and log_scales [N, 3] (float32, a
    model's parameters' data) of the Gaussians at means [N, 3] flattened onto ``frames`` [2 H^2, 9] float64
    (``regularisers.flatten_frames``) -> [N] bool, the Gaussians flattened."""
    if not quats.dtype == log_scales.dtype == torch.float32:
        raise ValueError("flatten_surface: quats and log_scales must be float32 tensors")
    height = round((frames.shape[0] / 2) ** 0.5)
    q, ls = quats.contiguous(), log_scales.contiguous()  # the kernel writes contiguous rows: copied back if not
    flat = load().flatten_surface(
        means.detach().float().contiguous(), q, ls, frames.double().contiguous(), height, thickness, min_cos
    )
    for dst, src in ((quats, q), (log_scales, ls)):
        if src.data_ptr() != dst.data_ptr():
            dst.copy_(src)
    return flat
