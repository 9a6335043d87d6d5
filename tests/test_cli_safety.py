"""Nothing a user gives panorecon may destroy their files or leave a half-made result (issue 28).

Table-driven over every subcommand the parser has (a new subcommand fails ``test_every_subcommand_has_a_row``
until it gets a row in BASE): from each row's valid arguments, the classes of mistakes are generated from the
argument declarations themselves (cli_types roles and validators): an output that is an input or another output
(also through a symlink, and an input inside an output folder where the command writes), an output under a
file or in a read-only folder, NaN/Inf and off-by-one numbers, unknown/repeated spec keys, and depth files of
the wrong size or type. Each must exit 2 with at most two lines, no traceback, and the watched folder
byte-identical. All in-process (main() refuses before any work), so the whole table runs in seconds.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import stat
from pathlib import Path

import numpy as np
import pytest

from panorecon import cli_types as T
from panorecon.cli import build_parser, main

W = "{W}"
CLASH = "an output may not overwrite"
# one valid argument set per subcommand: positional values, then options (all paths inside the workspace)
BASE: dict[tuple[str, ...], tuple[list[str], dict[str, str | None]]] = {
    ("scenes", "list"): ([], {"--root": W}),
    ("scenes", "check"): ([W], {"--json": f"{W}/check.json"}),
    ("render",): ([f"{W}/pano.png"], {"--depth": f"{W}/d.npy", "--out": f"{W}/r"}),
    ("gt-cloud",): ([f"{W}/pano.png"], {"--depth": f"{W}/d.npy", "--out": f"{W}/g.ply"}),
    ("inspect",): ([f"{W}/cloud.ply"], {"--screenshot": f"{W}/s.png", "--clip-z": "1"}),
    ("teachers", "list"): ([], {}),
    ("teachers", "train"): ([], {"--steps": "2", "--width": "4", "--out": f"{W}/tt"}),
    ("sources", "list"): ([], {}),
    ("points",): (
        [f"{W}/pano.png"],
        {
            "--depth": f"{W}/d.npy",
            "--source": "fibonacci",
            "--teacher": f"file:{W}/t.npy",
            "--views": "6",
            "--width": "64",
            "--out": f"{W}/p.ply",
            "--report": f"{W}/p.json",
            "--distance-out": f"{W}/p.npy",
        },
    ),
    ("train",): (
        [f"{W}/pano.png"],
        {
            "--depth": f"{W}/d.npy",
            "--source": "fibonacci",
            "--teacher": f"file:{W}/t.npy",
            "--width": "64",
            "--iters": "4",
            "--out": f"{W}/t",
        },
    ),
    ("ablate",): ([f"{W}/suite.toml"], {"--out": f"{W}/a", "--cache": f"{W}/cache", "--from-csv": f"{W}/r.csv"}),
    ("bench",): ([], {"--suite": f"{W}/suite.toml", "--baseline": f"{W}/baseline.json", "--out": f"{W}/b.json"}),
    ("generate",): ([], {"--prompt": "a room", "--model": f"{W}/model", "--out": f"{W}/gen.png"}),
    ("export",): (
        [f"{W}/pano.png"],
        {"--depth": f"{W}/d.npy", "--source": "fibonacci", "--format": "colmap", "--out": f"{W}/e"},
    ),
    ("view",): ([f"{W}/cloud.ply"], {}),
    ("mesh",): ([f"{W}/cloud.ply"], {"--out": f"{W}/m.ply", "--centre": "0,0,0"}),
    ("demo",): ([], {"--scene": f"{W}/pano.png", "--depth": f"{W}/d.npy", "--width": "64", "--out": f"{W}/dm"}),
}


def subcommands(parser: argparse.ArgumentParser, prefix=()) -> dict[tuple[str, ...], argparse.ArgumentParser]:
    """Every leaf subcommand of the parser -> its parser."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return {prefix: parser}
    found = {}
    for name, sub in subs[0].choices.items():
        found.update(subcommands(sub, (*prefix, name)))
    return found


PARSERS = subcommands(build_parser())


def test_every_subcommand_has_a_row():
    assert set(PARSERS) == set(BASE), "add a row to BASE for each new subcommand (its valid arguments)"


def _actions(cmd):
    return [a for a in PARSERS[cmd]._actions if not isinstance(a, argparse._HelpAction)]


def _key(action) -> str:
    return action.option_strings[0] if action.option_strings else action.dest


def _role(action) -> str | None:
    t = action.type
    if t in (T.out_file,):
        return "out-file"
    if t is T.out_dir or isinstance(t, T._OutDirWriting):
        return "out-dir"
    if t in (T.in_path, T.scene):
        return "in"
    if isinstance(t, T.SpecArg):
        return "spec"
    return None


def argv_of(cmd, positional, options) -> list[str]:
    argv = [*cmd, *positional]
    for k, v in options.items():
        argv += [k] if v is None else [k, v]
    return argv


def cases():
    """(id, cmd, positional, options, setup, regex the error line must match) for every generated mistake."""
    out = []
    for cmd, (pos, opts) in BASE.items():
        acts = _actions(cmd)
        positional = [a for a in acts if not a.option_strings and a.dest not in ("command", "what")]

        def value(a, pos=pos, opts=opts, positional=positional):
            if a.option_strings:
                return opts.get(a.option_strings[0])
            i = positional.index(a)
            return pos[i] if i < len(pos) else None

        def with_value(a, v, pos=pos, opts=opts, positional=positional):
            p, o = list(pos), dict(opts)
            if a.option_strings:
                o[a.option_strings[0]] = v
            else:
                p[positional.index(a)] = v
            return p, o

        name = " ".join(cmd)
        ins = [a for a in acts if _role(a) == "in" and value(a) and not value(a).endswith("}")]
        files_in = [a for a in ins if Path(value(a)).suffix]
        outs = [a for a in acts if _role(a) in ("out-file", "out-dir") and value(a)]
        for o in outs:
            kind = _role(o)
            for i in files_in:
                if kind == "out-file":
                    out.append((f"{name}: collide {_key(o)} = {_key(i)}", cmd, *with_value(o, value(i)), None, CLASH))
                    link = f"{W}/link{Path(value(i)).suffix}"
                    out.append(
                        (
                            f"{name}: collide {_key(o)} = symlink to {_key(i)}",
                            cmd,
                            *with_value(o, link),
                            ("link", value(i)),
                            CLASH,
                        )
                    )
                else:  # the input inside the output folder, at a name the command writes there
                    pattern = next(iter(o.type.writes or ("x",)))
                    inside = f"{value(o)}/{pattern.replace('**', 'x').replace('*', 'x')}"
                    p, q = with_value(i, inside)
                    out.append(
                        (f"{name}: collide {_key(i)} inside {_key(o)}", cmd, p, q, ("copy", value(i), inside), CLASH)
                    )
            for o2 in outs:
                if o2 is not o and kind == _role(o2) == "out-file":
                    out.append((f"{name}: collide {_key(o)} = {_key(o2)}", cmd, *with_value(o, value(o2)), None, CLASH))
            out.append((f"{name}: {_key(o)} under a file", cmd, *with_value(o, f"{W}/pano.png/x.out"), None, "folder"))
            out.append(
                (f"{name}: {_key(o)} in a read-only folder", cmd, *with_value(o, f"{W}/ro/new"), None, "writable")
            )
            if kind == "out-file":
                ro_file = (f"{name}: {_key(o)} a read-only file", cmd, *with_value(o, f"{W}/ro.out"), None, "read-only")
                out.append(ro_file)
        for a in acts:
            t = a.type
            if isinstance(t, (T._IntIn, T._FloatIn)):
                bad = ["nan", "inf", "-inf", "x"]
                bad += [str(t.lo - 1)] if t.lo is not None else []
                bad += [str(t.hi + 1)] if t.hi is not None else []
                bad += ["1.5"] if isinstance(t, T._IntIn) else []
                out += [(f"{name}: {_key(a)} {b}", cmd, *with_value(a, b), None, f"argument {_key(a)}") for b in bad]
            if isinstance(t, T._FiniteVector):
                bad = ["nan,0,0", "0,inf,0", "a,b,c", "0,0", "0,0,0,0"]
                out += [(f"{name}: {_key(a)} {b}", cmd, *with_value(a, b), None, "finite numbers") for b in bad]
            if _role(a) == "spec":
                bad = [f"file:{W}/t.npy?bogus=1", f"file:{W}/t.npy?scale=1&scale=2", "sim:relative?x=1", "nope:x"]
                bad += [f"file:{W}/t.npy?metric=2", f"file:{W}/missing.npy", "hf:x?batch=0"]
                out += [(f"{name}: {_key(a)} {b}", cmd, *with_value(a, b), None, "argument --teacher") for b in bad]
            if a.option_strings and a.option_strings[0] == "--depth" and _role(a) == "in":
                for f in ("d_off.npy", "d_complex.npy", "d_bool.npy", "d_nan.npy", "d_3d.npy"):
                    out.append((f"{name}: --depth {f}", cmd, *with_value(a, f"{W}/{f}"), None, f))
    return out


def _with(cmd, drop=(), **opts):
    """BASE's row for cmd with options replaced (``--a_b`` written ``a_b``) and ``drop`` removed."""
    pos, base = BASE[cmd]
    o = {k: v for k, v in base.items() if k not in drop}
    o.update({f"--{k.replace('_', '-')}": v for k, v in opts.items()})
    return cmd, list(pos), o


# mistakes only the command body can see (what a source needs of the scene, a file's content): hand-written rows
BODY_CASES = [
    ("train: --source colmap-sfm on a real panorama", *_with(("train",), source="colmap-sfm"), None, "no world"),
    (
        "train: --teacher sim: on an image without --depth",
        *_with(("train",), drop=("--depth",), teacher="sim:relative"),
        None,
        "no true depth",
    ),
    ("train: --source fibonacci without --teacher", *_with(("train",), drop=("--teacher",)), None, "needs --teacher"),
    ("generate: --lora missing", *_with(("generate",), lora=f"{W}/no-lora.safetensors"), None, "no-lora"),
    (
        "generate: --model a hub id that is not in the local cache",
        *_with(("generate",), model="nobody/none"),
        None,
        "nobody/none.*not in the local Hugging Face cache",
    ),
    ("mesh: a one-point cloud", ("mesh",), [f"{W}/one.ply"], BASE[("mesh",)][1], None, r"one\.ply: 1 points"),
]
CASES = cases() + BODY_CASES


@pytest.fixture(scope="module")
def workspace(tmp_path_factory):
    from panorecon.geometry import PointCloud
    from panorecon.io import write_image

    w = tmp_path_factory.mktemp("safety")
    rng = np.random.default_rng(0)
    write_image(w / "pano.png", rng.integers(0, 255, (64, 128, 3), dtype=np.uint8))
    d = (2.0 + rng.random((64, 128))).astype(np.float32)
    np.save(w / "d.npy", d)
    np.save(w / "t.npy", d)
    np.save(w / "d_off.npy", d[:63])  # one row short
    np.save(w / "d_complex.npy", d.astype(np.complex64))
    np.save(w / "d_bool.npy", d > 2.5)
    np.save(w / "d_nan.npy", np.full_like(d, np.nan))
    np.save(w / "d_3d.npy", d[..., None])
    PointCloud(rng.normal(size=(200, 3)).astype(np.float32), rng.random((200, 3)).astype(np.float32)).save_ply(
        w / "cloud.ply"
    )
    PointCloud(np.zeros((1, 3), np.float32), np.zeros((1, 3), np.float32)).save_ply(w / "one.ply")
    (w / "suite.toml").write_text('title = "t"\nrows = ["source"]\n[grid]\nscene = ["bedroom"]\nsource = ["random"]\n')
    (w / "baseline.json").write_text("{}")
    (w / "r.csv").write_text("scene,seed,label\nbedroom,0,random\n")
    (w / "model").mkdir()
    (w / "ro").mkdir(mode=0o555)
    (w / "ro.out").write_text("keep")
    os.chmod(w / "ro.out", 0o444)
    yield w
    os.chmod(w / "ro", 0o755)


def snapshot(folder: Path) -> dict:
    return {
        str(p.relative_to(folder)): (
            stat.S_IMODE(p.lstat().st_mode),
            hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() and not p.is_symlink() else None,
        )
        for p in sorted(folder.rglob("*"))
    }


def _fill(items, w: Path):
    return [str(x).replace(W, str(w)) if isinstance(x, str) else x for x in items]


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_mistake_exits_2_with_one_line_and_changes_nothing(workspace, case, capsys):
    _, cmd, pos, opts, setup, needle = case
    made = []
    if setup and setup[0] == "link":
        made.append(workspace / f"link{Path(setup[1]).suffix}")
        made[-1].symlink_to(setup[1].replace(W, str(workspace)))
    if setup and setup[0] == "copy":
        dst = Path(setup[2].replace(W, str(workspace)))
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(setup[1].replace(W, str(workspace)), dst)
        made.append(dst.parent)
    try:
        before = snapshot(workspace)
        argv = _fill(argv_of(cmd, pos, {k: v for k, v in opts.items()}), workspace)
        capsys.readouterr()
        rc = main(argv)
        err = capsys.readouterr().err
        after = snapshot(workspace)
    finally:
        for m in made:
            shutil.rmtree(m) if m.is_dir() and not m.is_symlink() else m.unlink()
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, (argv, err)
    assert 1 <= len(lines) <= 2 and "Traceback" not in err, err
    assert re.search(needle, lines[-1]), (needle, lines[-1])
    assert after == before, sorted(set(after.items()) ^ set(before.items()))


def test_the_table_covers_every_class():
    ids = " | ".join(c[0] for c in CASES)
    for needle in ("= --depth", "symlink", "inside --out", "= --report", "under a file", "read-only", "nan", "inf"):
        assert needle in ids, needle
    for needle in ("bogus=1", "scale=1&scale=2", "d_off.npy", "d_complex.npy", "--centre nan,0,0"):
        assert needle in ids, needle
    assert len(CASES) > 200


# ---------------------------------------------------------------- run folders


def _train_argv(w: Path, out: Path, seed: str, *extra) -> list[str]:
    return [
        "train",
        str(w / "pano.png"),
        "--depth",
        str(w / "d.npy"),
        "--source",
        "random",
        "--width",
        "32",
        "--iters",
        "2",
        "--res",
        "16",
        "--labels",
        "2",
        "--seed",
        seed,
        "--no-progress",
        "--out",
        str(out),
        *extra,
    ]


def test_a_used_folder_is_refused_or_overwritten_and_stale_temps_go(workspace, tmp_path, capsys):
    run = tmp_path / "run"
    assert main(_train_argv(workspace, run, "1")) == 0
    (run / ".ckpt.pt.abc123xy.pt").write_bytes(b"left by a killed run")
    (run / "notes.txt").write_text("the user's own file")
    before = snapshot(run)
    capsys.readouterr()
    assert main(_train_argv(workspace, run, "2")) == 2  # other inputs: refused, naming what is there
    err = capsys.readouterr().err
    assert "holds the train outputs of another run" in err and "metrics.json" in err and "--overwrite" in err
    assert snapshot(run) == before
    assert main(_train_argv(workspace, run, "2", "--overwrite")) == 0
    assert not (run / ".ckpt.pt.abc123xy.pt").exists()  # the killed run's temp file is gone
    assert (run / "notes.txt").read_text() == "the user's own file"  # not one of train's outputs: kept
    record = json.loads((run / ".panorecon-train.json").read_text())
    assert record["command"] == "train"
    assert main(_train_argv(workspace, run, "2")) == 0  # the same inputs again: its own folder


def test_unit_warning_names_the_unit_and_the_scale(workspace, tmp_path, capsys, caplog):
    np.save(tmp_path / "mm.npy", np.load(workspace / "d.npy") * 1000)
    with caplog.at_level("WARNING"):
        assert (
            main(
                [
                    "render",
                    str(workspace / "pano.png"),
                    "--depth",
                    str(tmp_path / "mm.npy"),
                    "--out",
                    str(tmp_path / "r"),
                ]
            )
            == 0
        )
    text = caplog.text
    assert "millimetres" in text and "--depth-scale 0.001" in text


def test_a_room_in_centimetres_read_as_metres_names_the_unit(workspace, tmp_path, caplog):
    np.save(tmp_path / "cm.npy", np.load(workspace / "d.npy") * 100)  # a 2-3 m room, median 250 "m"
    with caplog.at_level("WARNING"):
        out = str(tmp_path / "r")
        assert main(["render", str(workspace / "pano.png"), "--depth", str(tmp_path / "cm.npy"), "--out", out]) == 0
    assert "cm.npy" in caplog.text and "looks like centimetres: pass --depth-scale 0.01" in caplog.text


def test_a_file_teacher_of_another_size_is_resampled_with_one_line(workspace, tmp_path, caplog):
    np.save(tmp_path / "half.npy", np.load(workspace / "t.npy")[::2, ::2])  # 64x32 for a 128x64 scene
    argv = ["points", str(workspace / "pano.png"), "--depth", str(workspace / "d.npy"), "--source", "fibonacci"]
    argv += ["--teacher", f"file:{tmp_path / 'half.npy'}", "--views", "6", "--out", str(tmp_path / "p.ply")]
    with caplog.at_level("WARNING"):
        assert main(argv) == 0
    said = [r.getMessage() for r in caplog.records if "half.npy" in r.getMessage()]
    assert len(said) == 1 and "64x32 and the scene 128x64" in said[0] and "nearest neighbour" in said[0], said
