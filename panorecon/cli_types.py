"""Argparse ``type=`` validators for the CLI's numeric options, defined once and shared by every subcommand.

A validator turns the option's text into a value or raises ``argparse.ArgumentTypeError`` with what was
expected; argparse then prints one ``usage`` line and ``error: argument --x: ...`` and exits 2 before any
work starts. Use e.g. ``p.add_argument("--views", type=VIEWS)`` or ``type=int_in(1, 100, "views")``.
"""

from __future__ import annotations

import argparse
import math
import os
from pathlib import Path


class _IntIn:
    """An integer in [lo, hi] (hi None: unbounded). A class rather than a closure so argparse's messages
    and repr() name the range."""

    def __init__(self, lo: int, hi: int | None, what: str = "integer", even: bool = False):
        self.lo, self.hi, self.what, self.even = lo, hi, what, even
        self.__name__ = what  # argparse uses it in "invalid <name> value"

    def expected(self) -> str:
        kind = "an even integer" if self.even else "an integer"
        return f"{kind} from {self.lo} to {self.hi}" if self.hi is not None else f"{kind} >= {self.lo}"

    def __call__(self, text: str) -> int:
        try:
            value = int(str(text).strip(), 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer; expected {self.expected()}") from None
        if value < self.lo or (self.hi is not None and value > self.hi) or (self.even and value % 2):
            raise argparse.ArgumentTypeError(f"{value} is out of range; expected {self.expected()}")
        return value

    def __repr__(self) -> str:
        return f"int_in({self.lo}, {self.hi})"


class _FloatIn:
    """A finite float in [lo, hi] (either bound None: unbounded on that side)."""

    def __init__(self, lo: float | None, hi: float | None, what: str = "number"):
        self.lo, self.hi, self.what = lo, hi, what
        self.__name__ = what

    def expected(self) -> str:
        if self.lo is not None and self.hi is not None:
            return f"a number from {self.lo:g} to {self.hi:g}"
        if self.lo is not None:
            return f"a number >= {self.lo:g}"
        return "a finite number" if self.hi is None else f"a number <= {self.hi:g}"

    def __call__(self, text: str) -> float:
        try:
            value = float(str(text).strip())
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number; expected {self.expected()}") from None
        if (
            not math.isfinite(value)
            or (self.lo is not None and value < self.lo)
            or (self.hi is not None and value > self.hi)
        ):
            raise argparse.ArgumentTypeError(f"{text} is out of range; expected {self.expected()}")
        return value


class _FiniteVector:
    """``n`` comma-separated finite numbers, e.g. ``x,y,z`` -> a tuple of floats."""

    def __init__(self, n: int, what: str):
        self.n, self.what = n, what
        self.__name__ = what

    def __call__(self, text: str) -> tuple[float, ...]:
        parts = str(text).split(",")
        try:
            values = tuple(float(p) for p in parts)
        except ValueError:
            values = ()
        if len(values) != self.n or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"{text!r}: expected {self.n} finite numbers separated by commas")
        return values


def finite_vector(n: int, what: str = "vector") -> _FiniteVector:
    """Validator for ``n`` comma-separated finite numbers (e.g. a centre ``x,y,z`` in metres)."""
    return _FiniteVector(n, what)


def int_in(lo: int, hi: int | None = None, what: str = "integer", even: bool = False) -> _IntIn:
    """Validator for an integer in [lo, hi] (and even, if asked)."""
    return _IntIn(lo, hi, what, even)


def float_in(lo: float | None = None, hi: float | None = None, what: str = "number") -> _FloatIn:
    """Validator for a finite float in [lo, hi]."""
    return _FloatIn(lo, hi, what)


# the project's numeric options; bounds are what the code can do meaningfully, not what fits in memory today
ERP_WIDTH = int_in(16, 16384, "ERP width", even=True)  # io.files.MAX_ERP_WIDTH; 16 px is the smallest usable pyramid
VIEWS = int_in(1, 1000, "view count")
VIEW_SIZE = int_in(16, 4096, "view size")  # below 16 px a view holds no usable depth gradient
ITERS = int_in(1, 10_000_000, "step count")
LABEL_RES = int_in(8, 4096, "label view size")
LABELS = int_in(1, 100_000, "label view count")
SEED = int_in(0, 2**32 - 1, "seed")
JOBS = int_in(1, 1024, "job count")
STEPS = int_in(1, 10_000_000, "step count")
STEP = int_in(0, 10_000_000, "step")
POSITIVE_FLOAT = float_in(1e-12, None, "positive number")
FINITE_FLOAT = float_in(None, None, "number")
FRACTION = float_in(0.0, 1.0, "fraction")
LOSS_WEIGHT = float_in(0.0, None, "loss weight")


def _read_only(path: Path) -> bool:
    """Not writable by this process, or without any write permission bit (chmod a-w: refused even for root)."""
    return not os.access(path, os.W_OK | (os.X_OK if path.is_dir() else 0)) or not (path.stat().st_mode & 0o222)


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


# ---------------------------------------------------------------- path roles (the collision check)
# Every path argument is declared with its role: an input (``in_path``, ``scene``, ``teacher_spec``) or an output
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


SPEC_PATH_KINDS = ("file", "onnx", "hf", "moge")  # teacher kinds whose argument is a path (hf/moge: or a model id)


def teacher_spec(text: str) -> PathArg:
    """A teacher spec: its syntax and option keys are checked here (``panorecon.io.specs``), before any work; a
    spec that names a file (``file:``, ``onnx:``, a local ``hf:``/``moge:`` folder) makes that file an input."""
    from .io.specs import SpecError, check_teacher_spec

    try:
        path = check_teacher_spec(text)
    except SpecError as e:
        raise argparse.ArgumentTypeError(str(e)) from None
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
