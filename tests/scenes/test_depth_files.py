"""Depth files of real panoramas (``scenes.real.read_erp_depth`` on ``io.depth``): 16-bit PNG, EXR and NPY readers,
invalid codes, z -> distance."""

import sys

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from panorecon.geometry import erp_z_to_distance_factor
from panorecon.io import PanoreconInputError
from panorecon.io.depth import read_depth_raw
from panorecon.scenes.real import read_erp_depth


def _write_exr(path, a, channel="Z"):
    import OpenEXR

    with OpenEXR.File({"type": OpenEXR.scanlineimage}, {channel: np.ascontiguousarray(a, np.float32)}) as f:
        f.write(str(path))


def _distance(h=16, w=32, seed=0):
    return np.random.default_rng(seed).uniform(0.5, 9.0, (h, w)).astype(np.float32)


@pytest.mark.parametrize("fmt", ["png", "exr", "npy"])
def test_each_format_reads_back_metres(tmp_path, fmt):
    d = _distance()
    path = tmp_path / f"d.{fmt}"
    if fmt == "png":
        cv2.imwrite(str(path), np.round(d * 1000).astype(np.uint16))  # default scale 0.001
        tol = 0.5e-3
    elif fmt == "exr":
        _write_exr(path, d)
        tol = 1e-6
    else:
        np.save(path, d.astype(np.float64))
        tol = 1e-6
    out = read_erp_depth(path)
    assert out.dtype == np.float32 and out.shape == d.shape
    np.testing.assert_allclose(out, d, atol=tol)


def test_scale_multiplies(tmp_path):
    d = _distance()
    cv2.imwrite(str(tmp_path / "d.png"), np.round(d * 512).astype(np.uint16))
    np.testing.assert_allclose(read_erp_depth(tmp_path / "d.png", 1 / 512), d, atol=1 / 1024)
    np.save(tmp_path / "d.npy", d / 2)
    np.testing.assert_allclose(read_erp_depth(tmp_path / "d.npy", 2.0), d, rtol=1e-6)


def test_invalid_values_are_masked(tmp_path):
    raw = np.full((4, 8), 1000, np.uint16)
    raw[0, 0], raw[0, 1] = 0, 65535
    cv2.imwrite(str(tmp_path / "d.png"), raw)
    out = read_erp_depth(tmp_path / "d.png")
    assert np.isnan(out[0, :2]).all() and np.isfinite(out[0, 2:]).all() and np.isfinite(out[1:]).all()
    f = np.full((4, 8), 2.0)
    f[0, :6] = [0.0, -1.0, np.nan, np.inf, 1e9, 5e12]
    np.save(tmp_path / "f.npy", f)
    out = read_erp_depth(tmp_path / "f.npy")
    assert np.isnan(out[0, :6]).all() and (out[0, 6:] == 2).all() and (out[1:] == 2).all()
    _write_exr(tmp_path / "f.exr", f)
    assert np.isnan(read_erp_depth(tmp_path / "f.exr")[0, :6]).all()


@given(st.floats(0.1, 50.0), st.integers(0, 2**16))
def test_z_kind_gives_back_the_ray_distance(dist, seed):
    d = _distance(8, 16, seed) * np.float32(dist / 5)
    z = d / erp_z_to_distance_factor(8, 16)
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        np.save(Path(tmp) / "z.npy", z)
        np.testing.assert_allclose(read_erp_depth(Path(tmp) / "z.npy", kind="z"), d, rtol=1e-6)


@pytest.mark.parametrize(
    "make,needle",
    [
        (lambda p: cv2.imwrite(str(p / "d.png"), np.full((4, 8), 200, np.uint8)), "8-bit; expected 16-bit"),
        (lambda p: cv2.imwrite(str(p / "d.png"), np.zeros((4, 8), np.uint16)), "no valid pixel"),
        (lambda p: cv2.imwrite(str(p / "d.png"), np.full((4, 8, 3), 9, np.uint16)), "single-channel"),
        (lambda p: cv2.imwrite(str(p / "d.png"), np.full((4, 4), 9, np.uint16)), "not an equirectangular"),
        (lambda p: np.save(p / "d.npy", np.full((4, 8), np.nan)), "no valid pixel"),
        (lambda p: np.save(p / "d.npy", np.ones((2, 4, 8))), "2-D numeric"),
        (lambda p: (p / "d.exr").write_bytes(b"not an exr"), "not a readable EXR"),
        (lambda p: (p / "d.tif").write_bytes(b""), "not a depth file"),
    ],
)
def test_broken_depth_files_are_one_clear_error(tmp_path, make, needle):
    make(tmp_path)
    path = next(tmp_path.iterdir())
    with pytest.raises(PanoreconInputError, match=needle) as e:
        read_erp_depth(path)
    assert path.name in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    "kind,scale,needle",
    [("planar", None, "--depth-kind"), ("z", 0.0, "--depth-scale"), ("z", float("nan"), "--depth-scale")],
)
def test_bad_kind_or_scale(tmp_path, kind, scale, needle):
    np.save(tmp_path / "d.npy", np.ones((4, 8)))
    with pytest.raises(PanoreconInputError, match=needle):
        read_erp_depth(tmp_path / "d.npy", scale, kind)


def test_exr_without_openexr_says_what_to_install(tmp_path, monkeypatch):
    _write_exr(tmp_path / "d.exr", np.ones((4, 8)))
    monkeypatch.setitem(sys.modules, "OpenEXR", None)
    with pytest.raises(PanoreconInputError, match=r"needs the OpenEXR package: pip install 'panorecon\[exr\]'"):
        read_depth_raw(tmp_path / "d.exr")


def test_exr_channel_choice(tmp_path):
    _write_exr(tmp_path / "one.exr", np.full((4, 8), 3.0), channel="whatever")
    assert (read_erp_depth(tmp_path / "one.exr") == 3).all()


@pytest.mark.parametrize("s", [1e-3, 1e3], ids=["at_scale_1e-3", "at_scale_1e3"])
def test_a_depth_at_an_extreme_but_computable_scale_is_read(tmp_path, s):
    np.save(tmp_path / "d.npy", _distance() * s)
    np.testing.assert_allclose(read_erp_depth(tmp_path / "d.npy"), _distance() * s, rtol=1e-6)


@pytest.mark.parametrize("s", [1e-9, 1e8], ids=["at_scale_1e-9", "at_scale_1e8"])  # >= 1e9 is an invalid code
def test_a_depth_too_small_or_too_large_for_float32_is_one_error_naming_its_median(tmp_path, s):
    np.save(tmp_path / "d.npy", _distance() * s)
    with pytest.raises(PanoreconInputError, match=r"d\.npy: median distance [0-9.e+-]+ m is outside") as e:
        read_erp_depth(tmp_path / "d.npy")
    assert f"{float(np.median(_distance() * s)):.3g}" in str(e.value) and "--depth-scale" in str(e.value)
