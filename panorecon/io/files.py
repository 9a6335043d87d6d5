"""File I/O with one clear error per bad input and no half-written output (temp file, then rename)."""

from __future__ import annotations

import contextlib
import json
import os
import tempfile
from pathlib import Path

import cv2
import numpy as np

MAX_ERP_WIDTH = 16384


class PanoreconInputError(ValueError):
    """Bad user input: the message names the input and what was expected."""


@contextlib.contextmanager
def atomic_write(path: str | os.PathLike, suffix: str | None = None):
    """Yield a temporary path beside ``path``; on success rename it over ``path``, else delete it."""
    from .signals import held

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = None
    try:
        with held():  # a Ctrl-C between creating the temp file and noting its name would leave it behind
            fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=suffix or path.suffix, dir=path.parent)
            try:
                os.fchmod(fd, 0o666 & ~current_umask())  # mkstemp makes 0600; outputs get the user's normal mode
            finally:
                os.close(fd)
        yield Path(tmp)
        os.replace(tmp, path)
    except BaseException:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_write_all(paths: list[str | os.PathLike]):
    """Several outputs of one command, written together: yield a temp path beside each of ``paths`` (as
    ``atomic_write``, each keeping its suffix); when the block ends normally they are renamed into place with
    SIGINT/SIGTERM held until the last rename (``signals.held``), else all are deleted. So an error or an
    interrupt before the renames leaves none of the outputs and the files already at those paths untouched; a
    signal during the renames acts after them, with every output whole."""
    from .signals import held

    with contextlib.ExitStack() as temps:
        with held():  # each temp file is on the stack before a signal can stop this
            tmps = [temps.enter_context(atomic_write(p)) for p in paths]
        yield tmps
        with held():
            temps.close()


def file_sha256(path: str | os.PathLike) -> str:
    """SHA-256 (hex) of a file's bytes, read in 1 MiB blocks."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def current_umask() -> int:
    """The process's umask: from /proc (Linux, thread-safe), else by setting and restoring it."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except OSError:
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


@contextlib.contextmanager
def quiet_native_stderr():
    """Silence what native libraries (libpng, Open3D, VTK) print on file descriptor 2 inside the block, for
    calls whose failure panorecon checks and reports itself. Python's own sys.stderr is left alone."""
    import sys

    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):  # no real fd 2 (e.g. captured): nothing to silence
        yield
        return
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), 2)
        yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def read_image(path: str | os.PathLike, *, erp: bool = False, unchanged: bool = False) -> np.ndarray:
    """Read an image file -> [H, W, 3] uint8 RGB (or the stored dtype/channels when ``unchanged``).

    With ``erp=True`` the image must be an equirectangular panorama: width == 2 * height and width <= 16384.
    """
    path = Path(path)
    if not path.is_file():
        raise PanoreconInputError(f"{path}: no such file")
    flags = cv2.IMREAD_UNCHANGED if unchanged else cv2.IMREAD_COLOR
    size = image_size(path)  # from the header: an oversized image is refused before it is decoded
    if size is not None and erp:
        check_erp_shape(size[::-1], str(path))
    if size is not None and size[0] * size[1] > MAX_IMAGE_PIXELS:
        raise PanoreconInputError(
            f"{path}: {size[0]}x{size[1]} pixels is more than the {MAX_IMAGE_PIXELS} an image may have "
            "(OpenCV's CV_IO_MAX_IMAGE_PIXELS)"
        )
    data = np.fromfile(str(path), dtype=np.uint8)
    try:
        with quiet_native_stderr():  # libpng/libjpeg print their own complaint about a broken file
            img = cv2.imdecode(data, flags) if data.size else None
    except cv2.error as e:  # OpenCV's own limits (e.g. pixel count) raise with a multi-line message
        raise PanoreconInputError(f"{path}: OpenCV cannot decode it ({first_sentence(e)})") from None
    if img is None:
        raise PanoreconInputError(f"{path}: not a readable image (unknown format, truncated or empty file)")
    if not unchanged or (img.ndim == 3 and img.shape[2] == 3):
        img = np.ascontiguousarray(img[..., ::-1]) if img.ndim == 3 else img
    if erp:
        check_erp_shape(img.shape[:2], str(path))
    return img


def first_sentence(error: BaseException, limit: int = 160) -> str:
    """A third-party exception's message folded to one line: its first line, cut after the first sentence when
    longer than ``limit`` characters (torch and OpenCV append pages of advice)."""
    text = str(error).strip()
    line = text.splitlines()[0].strip() if text else type(error).__name__
    if len(line) > limit and ". " in line:
        line = line[: line.index(". ") + 1]
    return line


MAX_IMAGE_PIXELS = 1 << 30  # OpenCV's default CV_IO_MAX_IMAGE_PIXELS


def image_size(path: str | os.PathLike) -> tuple[int, int] | None:
    """(width, height) from an image file's header (Pillow reads no pixel), or None when Pillow cannot tell."""
    from PIL import Image

    limit, Image.MAX_IMAGE_PIXELS = Image.MAX_IMAGE_PIXELS, None  # only the size is read; limits are ours
    try:
        with Image.open(path) as im:
            return im.size
    except Exception:  # noqa: BLE001 -- any format Pillow does not know: OpenCV decides
        return None
    finally:
        Image.MAX_IMAGE_PIXELS = limit


def check_erp_shape(hw: tuple[int, int], what: str) -> None:
    """Raise a PanoreconInputError unless (H, W) is a 2:1 panorama no wider than 16384 pixels."""
    h, w = hw
    if w != 2 * h:
        raise PanoreconInputError(
            f"{what}: size {w}x{h} is not an equirectangular panorama (expected width = 2 x height)"
        )
    if w > MAX_ERP_WIDTH:
        raise PanoreconInputError(f"{what}: width {w} is larger than the supported {MAX_ERP_WIDTH} pixels")
    if h < 2:
        raise PanoreconInputError(f"{what}: size {w}x{h} is too small (expected height >= 2)")


def write_image(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write [H, W, 3] RGB or [H, W] gray (uint8 or uint16) atomically; format from the suffix."""
    path = Path(path)
    arr = image[..., ::-1] if image.ndim == 3 else image
    ok, buf = cv2.imencode(path.suffix or ".png", np.ascontiguousarray(arr))
    if not ok:
        raise OSError(f"could not encode image for {path}")
    with atomic_write(path) as tmp:
        buf.tofile(str(tmp))


def save_npy(path: str | os.PathLike, array: np.ndarray) -> None:
    """np.save atomically."""
    with atomic_write(path, suffix=".npy") as tmp:
        np.save(tmp, array)


def json_text(obj) -> str:
    """Pretty JSON text with a final newline; NaN/Inf are refused (they are not JSON)."""
    return json.dumps(obj, indent=2, allow_nan=False, default=_json_default) + "\n"


def write_json(path: str | os.PathLike, obj) -> None:
    """``json_text(obj)``, atomically."""
    with atomic_write(path) as tmp:
        tmp.write_text(json_text(obj))


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
