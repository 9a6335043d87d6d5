"""Spec options (io/specs.py) and depth plausibility (io/depth.py): property tests (hypothesis) and named cases."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from panorecon.io import PanoreconInputError
from panorecon.io.depth import PLAUSIBLE_MEDIAN_M, UNIT_CONVENTIONS, read_depth_raw, unit_warning
from panorecon.io.specs import SpecError, parse_options, positive_float, yes_no
from panorecon.scenes.real import read_erp_depth

FILE = {"scale": positive_float, "metric": yes_no}  # the file: teacher's options
keys = st.text(st.characters(min_codepoint=97, max_codepoint=122), min_size=1, max_size=8)


@given(scale=st.floats(1e-6, 1e6), metric=st.sampled_from(["1", "0", "true", "no"]), swap=st.booleans())
def test_valid_options_parse_in_any_order(scale, metric, swap):
    parts = [f"scale={scale!r}", f"metric={metric}"]
    opts = parse_options("file:x", "&".join(parts[::-1] if swap else parts), FILE)
    assert opts == {"scale": scale, "metric": metric in ("1", "true")}


@given(key=keys.filter(lambda k: k not in FILE), value=st.text(max_size=5).filter(lambda v: "&" not in v))
def test_an_unknown_key_is_refused_listing_the_known_ones(key, value):
    with pytest.raises(SpecError, match="known options: scale=, metric="):
        parse_options("file:x", f"scale=1&{key}={value}", FILE)


@given(key=st.sampled_from(sorted(FILE)), a=st.sampled_from(["1", "0"]), b=st.sampled_from(["1", "0"]))
def test_a_repeated_key_is_refused(key, a, b):  # even with valid, equal values
    with pytest.raises(SpecError, match="given twice"):
        parse_options("file:x", f"{key}={a if key == 'metric' else a + '.5'}&{key}={b if key == 'metric' else 2}", FILE)


@given(text=st.text(max_size=30))
def test_any_query_parses_or_raises_a_spec_error(text):
    try:
        opts = parse_options("file:x", text, FILE)
    except SpecError as e:
        assert "\n" not in str(e)
    else:
        assert set(opts) <= set(FILE)


# ---------------------------------------------------------------- depth units


@given(
    median=st.floats(1.0, 50.0),
    unit=st.sampled_from([u for u in UNIT_CONVENTIONS if u[1] < 1]),
    spread=st.floats(0.01, 0.5),
)
def test_a_metric_depth_stored_in_a_small_unit_and_read_as_metres_names_the_fix(median, unit, spread):
    name, s = unit
    rng = np.random.default_rng(0)
    d = median * np.exp(rng.normal(0, spread, 500))
    stored = d / s
    assert unit_warning(d, 1.0, "d") is None  # in metres: plausible
    warning = unit_warning(stored, 1.0, "d")  # the stored values taken as metres
    if np.median(stored) > PLAUSIBLE_MEDIAN_M[1]:
        assert warning is not None and f"--depth-scale {s:g}" in warning
    assert unit_warning(stored * s, s, "d") is None  # read with the right scale: no warning


@given(median=st.sampled_from([1e-6, 1e-4, 1e6, 1e9]))
def test_absurd_medians_warn(median):
    assert "implausible" in unit_warning(np.full(10, median), 1.0, "d")


@given(dtype=st.sampled_from(["complex64", "complex128", "bool", "U3", "datetime64[s]"]))
def test_non_real_depth_arrays_are_refused(tmp_path_factory, dtype):
    path = tmp_path_factory.mktemp("d") / "d.npy"
    np.save(path, np.ones((8, 16)).astype(dtype))
    with pytest.raises(PanoreconInputError, match="not a depth map|numeric|cannot be loaded"):
        read_depth_raw(path)


@given(
    h=st.integers(2, 16),
    dh=st.integers(-1, 1),
    dw=st.integers(-1, 1),
    value=st.floats(allow_nan=True, allow_infinity=True, width=32),
)
def test_erp_depth_reads_or_refuses_with_one_line(tmp_path_factory, h, dh, dw, value):
    path = tmp_path_factory.mktemp("d") / "d.npy"
    arr = np.full((h + dh, 2 * h + dw), value, np.float32)
    np.save(path, arr)
    try:
        d = read_erp_depth(path)
    except PanoreconInputError as e:
        assert "\n" not in str(e)
        assert (dh, dw) != (0, 0) or not (np.isfinite(value) and 0 < value < 1e9)
    else:
        assert (dh, dw) == (0, 0) and d.shape == (h, 2 * h) and np.isfinite(d).all()


def test_integer_npy_in_millimetres_warns(tmp_path, caplog):
    np.save(tmp_path / "d.npy", np.full((8, 16), 2500, np.int64))
    with caplog.at_level("WARNING"):
        d = read_erp_depth(tmp_path / "d.npy")
    assert float(d[0, 0]) == 2500.0
    assert "millimetres" in caplog.text and "--depth-scale 0.001" in caplog.text
