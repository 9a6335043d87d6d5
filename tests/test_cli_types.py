"""Numeric and path options are validated at the parser: one line, exit 2, before any work."""

import argparse

import pytest
from hypothesis import given
from hypothesis import strategies as st

from panorecon import cli_types as T
from panorecon.cli import build_parser, main

BOUNDS = {
    "--views": (1, 1000),
    "--view-size": (16, 4096),
    "--width": (16, 16384),
    "--iters": (1, 10_000_000),
    "--res": (8, 4096),
    "--labels": (1, 100_000),
    "--seed": (0, 2**32 - 1),
    "--jobs": (1, 1024),
}
COMMAND = {
    "--views": ["points", "bedroom", "--source", "fibonacci", "--out", "c.ply"],
    "--view-size": ["points", "bedroom", "--source", "fibonacci", "--out", "c.ply"],
    "--width": ["render", "bedroom", "--out", "o"],
    "--iters": ["train", "bedroom", "--source", "random", "--out", "o"],
    "--res": ["train", "bedroom", "--source", "random", "--out", "o"],
    "--labels": ["train", "bedroom", "--source", "random", "--out", "o"],
    "--seed": ["train", "bedroom", "--source", "random", "--out", "o"],
    "--jobs": ["ablate", "s.toml", "--out", "o"],
}


@pytest.mark.parametrize("option", sorted(BOUNDS))
@given(value=st.integers(min_value=-(2**40), max_value=2**40))
def test_integer_options_are_accepted_exactly_in_their_range(option, value):
    lo, hi = BOUNDS[option]
    ok = lo <= value <= hi and not (option == "--width" and value % 2)
    parser = build_parser()
    try:
        args = parser.parse_args(COMMAND[option] + [option, str(value)])
    except SystemExit as e:
        assert not ok and e.code == 2
    else:
        assert ok and getattr(args, option[2:].replace("-", "_")) == value


@given(text=st.text(max_size=12))
def test_any_text_is_an_integer_in_range_or_a_clear_error(text):
    try:
        v = T.VIEWS(text)
    except argparse.ArgumentTypeError as e:
        assert "expected an integer from 1 to 1000" in str(e)
    else:
        assert isinstance(v, int) and 1 <= v <= 1000


@given(value=st.floats(allow_nan=True, allow_infinity=True))
def test_float_options_refuse_nan_inf_and_out_of_range(value):
    f = T.float_in(1.0, 170.0)
    try:
        out = f(repr(value))
    except argparse.ArgumentTypeError:
        assert not (1.0 <= value <= 170.0)
    else:
        assert out == value


@pytest.mark.parametrize(
    "argv, needle",
    [
        (
            ["points", "bedroom", "--source", "fibonacci", "--views", "0", "--out", "X/c.ply"],
            "--views: 0 is out of range",
        ),
        (
            ["points", "bedroom", "--source", "fibonacci", "--view-size", "1", "--out", "X/c.ply"],
            "--view-size: 1 is out",
        ),
        (["points", "bedroom", "--source", "fibonacci", "--view-size", "100000", "--out", "X/c.ply"], "--view-size"),
        (
            ["train", "bedroom", "--source", "fibonacci", "--teacher", "sim:clean", "--iters", "-3", "--out", "X"],
            "--iters",
        ),
        (
            ["train", "bedroom", "--source", "fibonacci", "--teacher", "sim:clean", "--res", "abc", "--out", "X"],
            "'abc' is not an integer",
        ),
        (["train", "bedroom", "--source", "fibonacci", "--labels", "0", "--out", "X"], "--labels"),
        (["train", "bedroom", "--source", "fibonacci", "--seed", "-1", "--out", "X"], "--seed"),
        (["ablate", "s.toml", "--out", "X", "--jobs", "0"], "--jobs: 0"),
        (["train", "bedroom", "--source", "fibonacci", "--out", "afile"], "afile: exists and is not a folder"),
        (["points", "bedroom", "--source", "fibonacci", "--out", "afile/c.ply"], "is not a folder"),
        (["ablate", "s.toml", "--out", "afile"], "afile: exists and is not a folder"),
    ],
)
def test_bad_options_are_one_line_exit_2_and_write_nothing(tmp_path, monkeypatch, capsys, argv, needle):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "afile").write_text("x")
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert needle in err and err.count("\n") == 1 and err.startswith("panorecon ")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["afile"]


def test_os_errors_of_the_users_paths_are_one_line(tmp_path, capsys, monkeypatch):
    import panorecon.commands as commands

    def denied(config):
        raise PermissionError(13, "Permission denied", str(tmp_path / "x.ply"))

    monkeypatch.setattr(commands, "sources_list", denied)
    assert main(["sources", "list"]) == 2
    err = capsys.readouterr().err
    assert err == f"panorecon: error: {tmp_path / 'x.ply'}: Permission denied\n"

    def bug(config):
        raise OSError(5, "Input/output error")  # not a user mistake: left as a traceback

    monkeypatch.setattr(commands, "sources_list", bug)
    with pytest.raises(OSError):
        main(["sources", "list"])


def test_an_out_folder_that_cannot_be_written_is_refused_at_the_parser(tmp_path, monkeypatch, capsys):
    import os

    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if str(p) == str(tmp_path) else real(p, mode))
    assert main(["train", "bedroom", "--source", "random", "--out", str(tmp_path / "new")]) == 2
    assert "is not writable" in capsys.readouterr().err and not (tmp_path / "new").exists()


def test_inspect_of_a_cut_off_ply_is_one_line(tmp_path, capfd):
    import numpy as np

    from panorecon.geometry import PointCloud

    PointCloud(np.random.default_rng(0).normal(size=(300, 3)), np.zeros((300, 3))).save_ply(tmp_path / "c.ply")
    data = (tmp_path / "c.ply").read_bytes()
    (tmp_path / "c.ply").write_bytes(data[: len(data) // 2])
    capfd.readouterr()
    assert main(["inspect", str(tmp_path / "c.ply"), "--screenshot", str(tmp_path / "s.png")]) == 2
    err = capfd.readouterr().err
    assert "c.ply" in err and "cut-off" in err and err.count("\n") == 1
    assert not (tmp_path / "s.png").exists()
