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
POSITIVE_FLOAT = float_in(1e-12, None, "positive number")
FINITE_FLOAT = float_in(None, None, "number")


def _nearest_existing(path: Path) -> Path:
    p = path.absolute()
    while not p.exists() and p != p.parent:
        p = p.parent
    return p


def out_dir(text: str) -> str:
    """An output folder: an existing folder, or a new one whose nearest existing parent is a writable folder."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: exists and is not a folder; expected an output folder")
    base = _nearest_existing(path)
    if not base.is_dir():
        raise argparse.ArgumentTypeError(f"{text}: {base} is not a folder; expected an output folder")
    if not os.access(base, os.W_OK | os.X_OK):
        raise argparse.ArgumentTypeError(f"{text}: {base} is not writable (read-only or no permission)")
    return text


def out_file(text: str) -> str:
    """An output file: not an existing folder, and its folder exists or can be created (writable parent)."""
    path = Path(text)
    if path.is_dir() or text.endswith(os.sep):
        raise argparse.ArgumentTypeError(f"{text}: is a folder; expected an output file path")
    out_dir(str(path.parent) if str(path.parent) else ".")
    if path.exists() and not os.access(path.parent, os.W_OK):
        raise argparse.ArgumentTypeError(f"{text}: its folder is not writable")
    return text
