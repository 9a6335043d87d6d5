"""Argparse ``type=`` validators for the CLI's numeric options, defined once and shared by every subcommand.

A validator turns the option's text into a value or raises ``argparse.ArgumentTypeError`` with what was
expected; argparse then prints one ``usage`` line and ``error: argument --x: ...`` and exits 2 before any
work starts. Use e.g. ``p.add_argument("--views", type=VIEWS)`` or ``type=int_in(1, 100, "views")``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
from pathlib import Path

from . import checks as C


class _Cli:
    """A ``checks`` check whose CheckError becomes argparse's ArgumentTypeError (argparse then shows its text)."""

    def __call__(self, text: str):
        try:
            return super().__call__(text)
        except C.CheckError as e:
            raise argparse.ArgumentTypeError(str(e)) from None


class _IntIn(_Cli, C.IntIn):
    """An integer in [lo, hi] (hi None: unbounded); see ``checks.IntIn``."""


class _FloatIn(_Cli, C.FloatIn):
    """A finite float in [lo, hi]; see ``checks.FloatIn``."""


class _FiniteVector(_Cli, C.FiniteVector):
    """``n`` comma-separated finite numbers; see ``checks.FiniteVector``."""


def cli_check(check):
    """The command-line form of a ``checks`` check (the same bounds, argparse's error); others as they are."""
    if isinstance(check, C.IntIn):
        return _IntIn(check.lo, check.hi, check.what, check.even)
    if isinstance(check, C.FloatIn):
        return _FloatIn(check.lo, check.hi, check.what, check.expect)
    if isinstance(check, C.FiniteVector):
        return _FiniteVector(check.n, check.what)
    return _CheckedText(check)


class _CheckedText:
    """Any other check (text -> value, CheckError when refused) with its CheckError as argparse's one line."""

    def __init__(self, check):
        self.check = check
        self.__name__ = getattr(check, "__name__", "value")

    def __call__(self, text: str):
        try:
            return self.check(text)
        except C.CheckError as e:
            raise argparse.ArgumentTypeError(str(e)) from None


def finite_vector(n: int, what: str = "vector") -> _FiniteVector:
    """Validator for ``n`` comma-separated finite numbers (e.g. a centre ``x,y,z`` in metres)."""
    return _FiniteVector(n, what)


def int_in(lo: int, hi: int | None = None, what: str = "integer", even: bool = False) -> _IntIn:
    """Validator for an integer in [lo, hi] (and even, if asked)."""
    return _IntIn(lo, hi, what, even)


def float_in(lo: float | None = None, hi: float | None = None, what: str = "number") -> _FloatIn:
    """Validator for a finite float in [lo, hi]."""
    return _FloatIn(lo, hi, what)


# the project's numeric options (their bounds: ``checks``)
ERP_WIDTH = cli_check(C.ERP_WIDTH)
VIEWS = cli_check(C.VIEWS)
VIEW_SIZE = cli_check(C.VIEW_SIZE)
ITERS = cli_check(C.ITERS)
LABEL_RES = cli_check(C.LABEL_RES)
LABELS = cli_check(C.LABELS)
SEED = cli_check(C.SEED)
JOBS = cli_check(C.JOBS)
STEPS = cli_check(C.STEPS)
STEP = cli_check(C.STEP)
POSITIVE_FLOAT = cli_check(C.POSITIVE_FLOAT)
FINITE_FLOAT = cli_check(C.FINITE_FLOAT)
FRACTION = cli_check(C.FRACTION)
LOSS_WEIGHT = cli_check(C.LOSS_WEIGHT)


def _read_only(path: Path) -> bool:
    """Not writable by this process, or without any write permission bit (chmod a-w: refused even for root)."""
    return not os.access(path, os.W_OK | (os.X_OK if path.is_dir() else 0)) or not (path.stat().st_mode & 0o222)


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


# ---------------------------------------------------------------- path roles (the collision check)
# Every path argument is declared with its role: an input (``in_path``, ``scene``, ``SpecArg``) or an output
# (``out_file``, ``out_dir``, ``out_dir_writing(...)``). Their values are ``PathArg``s (plain ``str`` subclasses,
# so commands use them as before) and ``path_collisions`` (run by cli.main on the parsed arguments, before
# any command starts) refuses an output that is an input or another output, after real paths (symlinks
# followed, hard links by inode). A new argument gets the check by declaring its type; nothing else to do.


class PathArg(str):
    """A path argument's text with its role: ``role`` "in" | "out"; ``kind`` "file" | "dir"; ``writes``: for an
    output folder, the glob patterns (relative, fnmatch: ``*`` crosses ``/``) of what the command writes in it
    (``("**",)``: it replaces the whole folder); ``paths``: the file paths the value names (a spec names its
    file; a scene name names none)."""

    role: str = "in"
    kind: str = "file"
    writes: tuple[str, ...] = ()
    paths: tuple[str, ...] = ()

    @classmethod
    def make(cls, text: str, role: str, kind: str, writes=(), paths=None) -> PathArg:
        value = cls(text)
        value.role, value.kind, value.writes = role, kind, tuple(writes)
        value.paths = (text,) if paths is None else tuple(paths)
        return value


def in_path(text: str) -> PathArg:
    """An input file or folder (its existence is checked by the command that reads it, with its own message)."""
    return PathArg.make(text, "in", "file")


def scene(text: str) -> PathArg:
    """A SCENE argument: a built-in name, ``<dataset>:<root>/<key>`` or a path; an existing path is an input."""
    return PathArg.make(text, "in", "file", paths=(text,) if os.path.exists(text) else ())


class SpecArg(_CheckedText):
    """A spec option (a teacher spec): its setting's check parses it (a malformed one is argparse's one line,
    before any work); a spec that names an existing file or folder makes it an input (``path_collisions``)."""

    def __call__(self, text: str) -> PathArg:
        path = getattr(super().__call__(text), "path", None)
        return PathArg.make(text, "in", "file", paths=(path,) if path and os.path.exists(path) else ())


def out_dir(text: str, writes: tuple[str, ...] = ()) -> PathArg:
    """An output folder: an existing folder, or a new one whose nearest existing parent is a writable folder."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: exists and is not a folder; expected an output folder")
    base = _nearest_existing(path)
    if not base.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: {base} is not a folder; expected an output folder")
    if _read_only(base):
        raise argparse.ArgumentTypeError(f"{text}: {base} is not writable (read-only or no permission)")
    return PathArg.make(text, "out", "dir", writes)


class _OutDirWriting:
    """``out_dir`` that also declares the files the command writes inside (see ``PathArg.writes``)."""

    def __init__(self, writes: tuple[str, ...]):
        self.writes = writes
        self.__name__ = "output folder"

    def __call__(self, text: str) -> PathArg:
        return out_dir(text, self.writes)


def out_dir_writing(*patterns: str) -> _OutDirWriting:
    """Validator for an output folder the command writes ``patterns`` into (``"**"``: the whole folder)."""
    return _OutDirWriting(patterns)


def out_file(text: str) -> PathArg:
    """An output file: not an existing folder, and its folder exists or can be created (writable parent)."""
    path = Path(text)
    if path.is_dir() or text.endswith(os.sep):
        raise argparse.ArgumentTypeError(f"{text}: is a folder; expected an output file path")
    out_dir(str(path.parent) if str(path.parent) else ".")
    if path.exists() and _read_only(path):
        raise argparse.ArgumentTypeError(f"{text}: exists and is read-only")
    return PathArg.make(text, "out", "file")


def _same(a: str, b: str) -> bool:
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)  # hard links
    except OSError:
        return False


def _written_in(folder: str, patterns: tuple[str, ...], path: str) -> bool:
    """Whether ``path`` lies in ``folder`` where a pattern of what the command writes there matches it."""
    import fnmatch

    rel = os.path.relpath(os.path.realpath(path), os.path.realpath(folder))
    if rel == os.curdir or rel.startswith(os.pardir + os.sep) or rel == os.pardir:
        return False
    return any(fnmatch.fnmatchcase(rel, p) for p in patterns)


def path_collisions(values: dict[str, object], names: dict[str, str] | None = None) -> str | None:
    """The first collision among the ``PathArg`` values of parsed arguments (``vars(args)``; lists searched too)
    as one line naming both arguments, or None. An output collides with an input or another output that is the
    same file (real path or inode), with an input that is its folder, and an output folder with anything inside
    it that the command writes there (``writes``). ``names``: dest -> the option as the user typed it."""
    names = names or {}
    items = []
    for dest, value in values.items():
        for v in value if isinstance(value, (list, tuple)) else [value]:
            if isinstance(v, PathArg):
                label = f"{names.get(dest, dest)} {v}"
                items.extend((label, v, p) for p in (v.paths if v.role == "in" else (str(v),)))
    for i, (la, a, pa) in enumerate(items):
        if a.role != "out":
            continue
        for j, (lb, b, pb) in enumerate(items):
            if i == j or (b.role == "out" and j < i):
                continue
            what = "an input" if b.role == "in" else "another output"
            if _same(pa, pb):
                return f"{la} is the same path as {lb}: an output may not overwrite {what}"
            if a.kind == "dir" and _written_in(pa, a.writes, pb):
                return f"{lb} lies in {la}, where this command writes: an output may not overwrite {what}"
            if b.kind == "dir" and b.role == "out" and _written_in(pb, b.writes, pa):
                return f"{la} lies in {lb}, where this command writes: an output may not overwrite {what}"
    return None


# ---------------------------------------------------------------- a config's fields as argparse options
class Parser(argparse.ArgumentParser):
    """argparse with a one-line error (``panorecon <command>: error: ...``, exit 2) instead of usage + error;
    subcommand parsers inherit it."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


def _cli_type(s: C.Setting):
    """The argparse ``type=`` of a setting: its path role's (the collision check reads it) or its check."""
    role = s.meta.get("role")
    if role == "out-dir":
        return out_dir_writing(*s.meta["writes"])
    if role is not None:
        if role == "teacher":
            return SpecArg(s.meta["check"])
        return {"in": in_path, "scene": scene, "out-file": out_file}[role]
    check = s.meta.get("check") or C.default_check(s.type.replace("| None", "").strip())
    return cli_check(check) if check is not None else None


def _help(s: C.Setting) -> str:
    """The option's help as argparse takes it: a literal % doubled (argparse formats help with % params)."""
    shown = ",".join(map(str, s.default)) if isinstance(s.default, tuple) else s.default
    plain = s.default in (None, ()) or isinstance(s.default, bool) or "(default" in s.meta["help"]
    text = s.meta["help"] if plain else f"{s.meta['help']} (default {shown})".lstrip()
    return text.replace("%", "%%")


def add_settings(parser: argparse.ArgumentParser, config: type) -> None:
    """One argument per leaf setting of ``config`` (``checks.settings``): positional or ``--field-name``, with
    its type (check or path role), default, choices and help; help sections and exclusive groups as declared."""
    groups: dict[str, argparse._ActionsContainer] = {}
    for s in C.settings(config):
        m, kw = s.meta, {"help": _help(s)}
        where = parser
        if m.get("group"):
            if m["group"] not in groups:
                groups[m["group"]] = parser.add_argument_group(m["group"])
            where = groups[m["group"]]
        if m.get("exclusive"):
            key = "exclusive:" + m["exclusive"]
            if key not in groups:
                groups[key] = parser.add_mutually_exclusive_group(required=True)
            where = groups[key]
        if s.type == "bool":
            where.add_argument(f"--{s.name.replace('_', '-')}", dest=s.name, action="store_true", **kw)
            continue
        kw.update(type=_cli_type(s), choices=s.choices, metavar=m.get("metavar"))
        kw["default"] = list(s.default) if m.get("many") else s.default
        if m.get("positional"):
            nargs = ("+" if m.get("required") else "*") if m.get("many") else (None if m.get("required") else "?")
            where.add_argument(s.name, nargs=nargs, **kw)
            continue
        if m.get("repeat"):  # one value per occurrence: --set a=1 --set b=2
            kw["action"] = "append"
        elif m.get("many"):  # one or more values after the option: --eval-at 300 1000
            kw["nargs"] = "+"
        flag = m.get("flag") or f"--{s.name.replace('_', '-')}"
        where.add_argument(flag, dest=s.name, required=bool(m.get("required")), **kw)


def build_config(config: type, values: dict):
    """The config (nested ones built too) from parsed values by field name; lists become tuples."""
    kwargs = {}
    for f in dataclasses.fields(config):
        if "nested" in f.metadata:
            kwargs[f.name] = build_config(f.metadata["nested"], values)
        else:
            v = values[f.name]
            kwargs[f.name] = tuple(v) if isinstance(v, list) else v
    return config(**kwargs)


def parse_config(config: type, argv: list[str] | None, description: str, prog: str | None = None):
    """``argv`` parsed into ``config`` by the same rules as the ``panorecon`` commands (a module's own ``main``,
    e.g. the micro-benchmarks'); a bad option exits 2 with one line."""
    parser = Parser(prog=prog, description=description)
    add_settings(parser, config)
    try:
        return build_config(config, vars(parser.parse_args(argv)))
    except ValueError as e:
        parser.error(str(e))
