"""True-depth files for ERP panoramas: 16-bit PNG, OpenEXR and NPY -> the stored values, checked.

A depth file stores ``value * scale`` metres (``scale``: metres per stored unit; default 1 for .npy/.exr,
0.001 for 16-bit PNG). Integer depth is a scaled unit: panorecon assumes millimetres for a 16-bit PNG (the
convention of Structured3D); Stanford2D3D stores 1/512 m (``--depth-scale 0.001953125``), Matterport3D 1/4000 m
(``--depth-scale 0.00025``). A map whose median distance is outside ``PLAUSIBLE_MEDIAN_M`` for a metric scene
(for a closed scene, a room, above ``CLOSED_MAX_MEDIAN_M``) gets a warning naming the likely unit and the
``--depth-scale`` that fixes it (``unit_warning``). Complex,
boolean and object arrays are refused. Invalid values become NaN: 0, 65535 in a 16-bit PNG (the usual "missing" code),
anything >= 1e9, NaN, +-inf and negative values. ``kind`` says what the value is (the conversion to ray distance,
which needs the ERP geometry, is ``panorecon.scenes.real.read_erp_depth``):

- ``distance``: metres along the ray from the panorama centre (panorecon's ERP depth);
- ``z``: metres along the axis of the cube face the ray passes through, as in a panorama stitched from six
  z-depth cube faces; distance = z / max(|dx|, |dy|, |dz|) for the unit ray d.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .files import PanoreconInputError, first_sentence, quiet_native_stderr, read_image

DEPTH_KINDS = ("distance", "z")
DEPTH_SUFFIXES = (".png", ".exr", ".npy")
PNG_DEFAULT_SCALE = 1e-3
INVALID_AT_OR_ABOVE = 1e9
PNG_MISSING = 65535
_EXR_CHANNELS = ("Z", "Y", "R", "depth", "distance")
# a metric scene's median ray distance (metres): rooms are ~1-10 m, landscapes up to a few hundred
PLAUSIBLE_MEDIAN_M = (0.2, 1000.0)
# a closed scene (valid depth over CLOSED_MIN_FRACTION of the pixels above CLOSED_LATITUDE_DEG: a ceiling, no sky)
# is a room or a hall, whose median ray distance stays below CLOSED_MAX_MEDIAN_M; a room stored in centimetres
# and read as metres has a median of 100-1000 "m", which the open-scene window above would let pass
CLOSED_LATITUDE_DEG = 60.0
CLOSED_MIN_FRACTION = 0.9
CLOSED_MAX_MEDIAN_M = 50.0
# the median ray distance (metres) the pipeline computes in: the trainer's float32 holds squared lengths (3D and
# projected covariances, the Pearson term's sums of squared depths over a label view: ~1e4 pixels) and Adam's
# eps 1e-15 sits below gradients that scale as 1 / length; within this window both stay at least 1e6 away from
# float32's limits (1.2e-38, 3.4e38) and every length constant is relative to the scene (splat/model.py), so a
# scene is the same problem at any scale in it. Outside it: PanoreconInputError, not a quietly bad model
SCENE_MEDIAN_RANGE_M = (1e-4, 1e7)
# the field's stored units (metres per unit), tried in this order when a median is implausible
UNIT_CONVENTIONS = (
    ("millimetres (Structured3D)", 1e-3),
    ("1/512 m (Stanford2D3D)", 1 / 512),
    ("1/4000 m (Matterport3D)", 1 / 4000),
    ("centimetres", 1e-2),
    ("kilometres", 1e3),
)


def check_depth_dtype(array: np.ndarray, what: str) -> None:
    """Refuse what cannot be a depth: complex, boolean, object, string or structured arrays."""
    if array.dtype.kind not in "iuf":
        raise PanoreconInputError(
            f"{what}: a {array.dtype} array is not a depth map (expected real numbers: float metres, or integers "
            "in a stored unit with --depth-scale)"
        )


def is_closed(distance_m: np.ndarray) -> bool:
    """Whether an ERP depth [H, W] sees a ceiling: finite positive depth over ``CLOSED_MIN_FRACTION`` of the
    pixels above ``CLOSED_LATITUDE_DEG`` (sky, and a pole left without data, are not finite). False for
    anything that is not a 2-D map."""
    d = np.asarray(distance_m)
    if d.ndim != 2 or d.shape[0] < 2:
        return False
    lat = 90.0 - (np.arange(d.shape[0]) + 0.5) * 180.0 / d.shape[0]  # row centres, degrees
    top = d[lat > CLOSED_LATITUDE_DEG]
    return top.size > 0 and float(np.mean(np.isfinite(top) & (top > 0))) >= CLOSED_MIN_FRACTION


def unit_warning(distance_m: np.ndarray, scale: float, what: str) -> str | None:
    """A warning when the median finite positive distance (metres, after ``scale`` metres per stored unit) is
    implausible, naming the stored unit it looks like and the --depth-scale that fixes it; None when plausible
    or empty. The window is ``PLAUSIBLE_MEDIAN_M``, with its top lowered to ``CLOSED_MAX_MEDIAN_M`` for a closed
    scene (``is_closed``: a room, where centimetres read as metres give a 100-1000 m median). Of the
    ``UNIT_CONVENTIONS`` that make the median plausible, the one nearest (in log) to the window's geometric
    centre is named first."""
    d = np.asarray(distance_m, np.float64)
    closed = is_closed(d)
    d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0:
        return None
    median = float(np.median(d))
    lo, hi = PLAUSIBLE_MEDIAN_M
    scene = "a metric scene"
    if closed:
        hi, scene = CLOSED_MAX_MEDIAN_M, "a closed scene (depth all round overhead: a ceiling, so a room or hall)"
    if lo <= median <= hi:
        return None
    stored = median / scale
    fits = [(name, s) for name, s in UNIT_CONVENTIONS if lo <= stored * s <= hi and not np.isclose(s, scale)]
    fits.sort(key=lambda u: abs(np.log(stored * u[1] / np.sqrt(lo * hi))))
    if fits:
        (name, s), others = fits[0], fits[1:]
        hint = f"it looks like {name}: pass --depth-scale {s:g} (median {stored * s:.3g} m)"
        hint += "".join(f"; or {n}: --depth-scale {u:g} (median {stored * u:.3g} m)" for n, u in others)
    else:
        hint = "no usual unit makes it plausible (a relative, unitless depth is not a true depth)"
    return (
        f"{what}: median ray distance {median:.4g} m (stored values x {scale:g} m) is implausible for {scene} "
        f"(expected {lo:g} to {hi:g} m); {hint}"
    )


def check_scene_scale(distance_m: np.ndarray, what: str) -> None:
    """PanoreconInputError naming ``what`` and the value when the median finite positive distance of
    ``distance_m`` (any shape, metres) lies outside ``SCENE_MEDIAN_RANGE_M``; nothing for an empty map."""
    d = np.asarray(distance_m, np.float64)
    with np.errstate(invalid="ignore"):
        d = d[np.isfinite(d) & (d > 0)]
    if d.size == 0:
        return
    median, (lo, hi) = float(np.median(d)), SCENE_MEDIAN_RANGE_M
    if not lo <= median <= hi:
        raise PanoreconInputError(
            f"{what}: median distance {median:.3g} m is outside the {lo:g} to {hi:g} m that panorecon computes in "
            "(float32 training); give the depth in another unit (--depth-scale) so that it falls inside"
        )


def default_depth_scale(path: str | os.PathLike) -> float:
    """Metres per stored unit when none is given: 0.001 for a 16-bit PNG (millimetres), else 1."""
    return PNG_DEFAULT_SCALE if Path(path).suffix.lower() == ".png" else 1.0


def read_depth_raw(path: str | os.PathLike) -> np.ndarray:
    """The stored values [H, W] float64 of a depth file, invalid codes already NaN (see the module doc)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in DEPTH_SUFFIXES:
        raise PanoreconInputError(f"{path}: not a depth file (expected {', '.join(DEPTH_SUFFIXES)})")
    if not path.is_file():
        raise PanoreconInputError(f"{path}: no such file")
    if suffix == ".png":
        raw = read_image(path, unchanged=True)
        if raw.ndim != 2:
            raise PanoreconInputError(f"{path}: expected a single-channel depth image, got {raw.shape[2]} channels")
        if raw.dtype != np.uint16:
            raise PanoreconInputError(
                f"{path}: depth PNG is {raw.dtype.itemsize * 8}-bit; expected 16-bit "
                "(an 8-bit PNG cannot hold metric depth)"
            )
        out = raw.astype(np.float64)
        out[raw == PNG_MISSING] = np.nan
    elif suffix == ".exr":
        out = _read_exr(path)
    else:
        try:
            out = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as e:
            raise PanoreconInputError(f"{path}: not a readable .npy depth map ({first_sentence(e)})") from None
        check_depth_dtype(out, str(path))
        if out.ndim != 2:
            raise PanoreconInputError(f"{path}: expected a 2-D numeric depth map, got {out.dtype} {out.shape}")
        out = out.astype(np.float64)
    out[~np.isfinite(out) | (out <= 0) | (out >= INVALID_AT_OR_ABOVE)] = np.nan
    return out


def _read_exr(path: Path) -> np.ndarray:
    try:
        import OpenEXR
    except ImportError:
        raise PanoreconInputError(
            f"{path}: reading EXR depth needs the OpenEXR package: "
            "pip install 'panorecon[exr]' (or pip install openexr)"
        ) from None
    try:
        with quiet_native_stderr(), OpenEXR.File(str(path)) as f:  # the library prints its own complaint
            channels = {name: np.asarray(c.pixels) for name, c in f.channels().items()}
    except Exception as e:  # OpenEXR raises bare exceptions for truncated or foreign files
        raise PanoreconInputError(f"{path}: not a readable EXR file ({first_sentence(e)})") from None
    name = next((n for n in _EXR_CHANNELS if n in channels), None)
    if name is None and len(channels) == 1:
        name = next(iter(channels))
    if name is None:
        raise PanoreconInputError(
            f"{path}: no depth channel among {sorted(channels)} "
            f"(expected one of {', '.join(_EXR_CHANNELS)} or a single channel)"
        )
    data = channels[name]
    check_depth_dtype(data, f"{path} channel {name}")
    if data.ndim == 3:  # an RGB(A) layer stored as one channel of pixel tuples: its first component
        data = data[..., 0]
    return data.astype(np.float64)
