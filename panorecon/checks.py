"""Typed settings, declared once: a config field's default, help, check, choices and command-line role.

A config is a frozen dataclass whose fields are declared with ``opt``; its ``__post_init__`` calls ``validate``.
The same declaration makes the command-line option (``panorecon.cli`` builds its parser from it: the check parses
the option's text, the role says whether a path is an input or an output) and checks a suite file's key
(``evaluation/suite.py``). Nothing here imports argparse or the rest of panorecon.

A check is a callable text -> value raising ``CheckError`` with what was expected (the CLI shows it as
``argument --x: ...``) and has ``check(value)`` for a value that is already typed (a config built in code, a
TOML value).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Iterator


class CheckError(ValueError):
    """A value outside its setting's type or range: the message says what was expected."""


class IntIn:
    """An integer in [lo, hi] (hi None: unbounded), even if asked."""

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
            raise CheckError(f"{text!r} is not an integer; expected {self.expected()}") from None
        self.check(value)
        return value

    def check(self, value: int) -> None:
        if value < self.lo or (self.hi is not None and value > self.hi) or (self.even and value % 2):
            raise CheckError(f"{value} is out of range; expected {self.expected()}")

    def __repr__(self) -> str:
        return f"int_in({self.lo}, {self.hi})"


class FloatIn:
    """A finite float in [lo, hi] (either bound None: unbounded on that side)."""

    def __init__(self, lo: float | None, hi: float | None, what: str = "number", expect: str | None = None):
        self.lo, self.hi, self.what, self.expect = lo, hi, what, expect
        self.__name__ = what

    def expected(self) -> str:
        if self.expect:
            return self.expect
        if self.lo is not None and self.hi is not None:
            return f"a number from {self.lo:g} to {self.hi:g}"
        if self.lo is not None:
            return f"a number >= {self.lo:g}"
        return "a finite number" if self.hi is None else f"a number <= {self.hi:g}"

    def __call__(self, text: str) -> float:
        try:
            value = float(str(text).strip())
        except ValueError:
            raise CheckError(f"{text!r} is not a number; expected {self.expected()}") from None
        self.check(value, str(text))
        return value

    def check(self, value: float, text: str | None = None) -> None:
        if (
            not math.isfinite(value)
            or (self.lo is not None and value < self.lo)
            or (self.hi is not None and value > self.hi)
        ):
            raise CheckError(f"{value if text is None else text} is out of range; expected {self.expected()}")


class FiniteVector:
    """``n`` comma-separated finite numbers, e.g. ``x,y,z`` -> a tuple of floats."""

    def __init__(self, n: int, what: str):
        self.n, self.what = n, what
        self.__name__ = what

    def __call__(self, text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(p) for p in str(text).split(","))
        except ValueError:
            values = ()
        if len(values) != self.n or not all(math.isfinite(v) for v in values):
            raise CheckError(f"{text!r}: expected {self.n} finite numbers separated by commas")
        return values

    def check(self, value) -> None:
        if len(value) != self.n or not all(math.isfinite(float(v)) for v in value):
            raise CheckError(f"{value!r}: expected {self.n} finite numbers")


def int_in(lo: int, hi: int | None = None, what: str = "integer", even: bool = False) -> IntIn:
    """Check for an integer in [lo, hi] (and even, if asked)."""
    return IntIn(lo, hi, what, even)


def float_in(lo: float | None = None, hi: float | None = None, what: str = "number") -> FloatIn:
    """Check for a finite float in [lo, hi]."""
    return FloatIn(lo, hi, what)


# the project's numeric settings; bounds are what the code can do meaningfully, not what fits in memory today
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
COUNT = int_in(0, None, "count")
POSITIVE_FLOAT = float_in(1e-12, None, "positive number")
FINITE_FLOAT = float_in(None, None, "number")
FRACTION = float_in(0.0, 1.0, "fraction")
LOSS_WEIGHT = float_in(0.0, None, "loss weight")
NON_NEGATIVE = FloatIn(0.0, None, "number >= 0", expect="a finite value >= 0")
FOV_DEG = float_in(1.0, 170.0, "field of view")
DEPTH_SCALE = float_in(1e-9, 1e9, "depth scale")

# path roles of a str field (the CLI's collision check: an output may not overwrite an input or another output)
ROLES = ("in", "scene", "teacher", "out-file", "out-dir")


NO_NEUTRAL = object()  # ``opt(neutral=...)`` not given: the field is part of every run's identity


def opt(
    default=None,
    help: str = "",
    *,
    check: Callable | None = None,
    choices: tuple | Callable[[], tuple] | None = None,
    role: str | None = None,
    writes: tuple[str, ...] = (),
    flag: str | None = None,
    positional: bool = False,
    required: bool = False,
    many: bool = False,
    repeat: bool = False,
    metavar: str | None = None,
    group: str | None = None,
    exclusive: str | None = None,
    suite: bool = True,
    neutral=NO_NEUTRAL,
) -> dataclasses.Field:
    """A config field. ``check``: text -> value (and ``.check(value)``); ``choices``: the allowed values, or a
    function giving them (a registry, read when needed); ``role``: a path's role (ROLES); ``writes``: for an
    output folder, what the command writes in it (fnmatch patterns, ``*`` crosses folders); ``flag``: the option
    (default ``--field-name``); ``positional``: a positional argument (with a default: optional); ``required``:
    the option must be given; ``many``: one or more values (a tuple); ``repeat``: with ``many``, one value per
    occurrence of the option (``--set a=1 --set b=2``; a list after one option would swallow positionals);
    ``group``: a help section; ``exclusive``: exactly one field of that name's group is given; ``suite``: also a
    suite-file key where the config is a suite row's; ``neutral``: for an option added after run identities were
    first committed, the value at which it behaves as before it existed (``identity`` leaves it out there)."""
    if role is not None and role not in ROLES:
        raise ValueError(f"role {role!r}: expected one of {', '.join(ROLES)}")
    meta = dict(
        help=help,
        check=check,
        choices=choices,
        role=role,
        writes=tuple(writes),
        flag=flag,
        positional=positional,
        required=required,
        many=many,
        repeat=repeat,
        metavar=metavar,
        group=group,
        exclusive=exclusive,
        suite=suite,
    )
    if neutral is not NO_NEUTRAL:
        meta["neutral"] = neutral
    return dataclasses.field(default=default, metadata=meta)


def nest(cls, **overrides: dict) -> dataclasses.Field:
    """A field holding a nested config (its fields become options of the same command); ``overrides``: field
    name -> ``opt`` settings (e.g. ``default``, ``flag``) that differ for this command."""
    defaults = {k: v["default"] for k, v in overrides.items() if "default" in v}
    return dataclasses.field(default_factory=lambda: cls(**defaults), metadata={"nested": cls, "overrides": overrides})


@dataclasses.dataclass(frozen=True)
class Setting:
    """One leaf field of a config as seen from outside: its name, default, annotated type and ``opt`` settings
    (a nesting field's overrides applied)."""

    name: str
    default: object
    type: str
    meta: dict

    @property
    def choices(self) -> tuple | None:
        c = self.meta.get("choices")
        return tuple(c()) if callable(c) else c


def settings(cls, overrides: dict | None = None) -> Iterator[Setting]:
    """Every leaf setting of config class ``cls``, nested configs flattened in declaration order."""
    for f in dataclasses.fields(cls):
        if "nested" in f.metadata:
            yield from settings(f.metadata["nested"], f.metadata["overrides"])
            continue
        meta = {**f.metadata, **(overrides or {}).get(f.name, {})}
        default = meta.pop("default", f.default)
        yield Setting(f.name, default, str(f.type), meta)


def default_check(base: str):
    """The check of a number setting declared without one: a count (int) or a finite number >= 0 (float)."""
    return {"int": COUNT, "float": NON_NEGATIVE}.get(base)


TYPE_NAMES = {"str": "a string", "int": "an integer", "float": "a number", "bool": "true or false"}
PLURALS = {"str": "strings", "int": "integers", "float": "numbers", "bool": "booleans"}


def problem(s: Setting, value) -> str | None:
    """Why ``value`` does not fit setting ``s`` (None when it does): `` is str; expected an integer`` for a wrong
    type, ``: <what the check or the choices expect>`` for a value out of range."""
    if value is None and ("None" in s.type or s.default is None):
        return None
    many = bool(s.meta.get("many"))
    base = s.type.replace("| None", "").strip()
    if many:  # tuple[T, ...]: a list of T
        base = base.removeprefix("tuple[").removesuffix(", ...]")
    want = {"str": str, "int": int, "float": (int, float), "bool": bool}.get(base)
    items = value if many and isinstance(value, (list, tuple)) else [value]
    if (many and not isinstance(value, (list, tuple))) or (
        want is not None and any(not isinstance(v, want) or (base != "bool" and isinstance(v, bool)) for v in items)
    ):
        return f" is {type(value).__name__}; expected {f'a list of {PLURALS[base]}' if many else TYPE_NAMES[base]}"
    choices = s.choices
    if choices is not None and any(v not in choices for v in items):
        return f": expected one of {', '.join(map(str, choices))}"
    check = s.meta.get("check")
    try:
        check = check if check is not None else default_check(base)
        for v in items if check is not None and hasattr(check, "check") else ():
            check.check(v)
    except CheckError as e:
        return f": {e}"
    return None


def validate(config) -> None:
    """Raise ValueError ``name = value: expected ...`` for the first field of ``config`` (a dataclass instance)
    whose value does not fit its declaration (nested configs check themselves when they are built)."""
    for f in dataclasses.fields(config):
        if "nested" in f.metadata:
            continue
        why = problem(Setting(f.name, f.default, str(f.type), dict(f.metadata)), getattr(config, f.name))
        if why:
            raise ValueError(f"{f.name} = {getattr(config, f.name)!r}{why}")


def identity(config) -> dict:
    """The fields of ``config`` (a flat dataclass instance built with ``opt``) that make a run's identity, as
    ``dataclasses.asdict`` gives them, less every field at its declared ``neutral`` value: an option added later
    leaves the identity of a run that does not use it as it was before the option existed. A field without a
    neutral value is always in."""
    out = dataclasses.asdict(config)
    for f in dataclasses.fields(config):
        if "neutral" in f.metadata and _same(getattr(config, f.name), f.metadata["neutral"]):
            del out[f.name]
    return out


def _same(a, b) -> bool:
    """``a == b`` for settings, where True is not 1 and False is not 0."""
    return type(a) is type(b) and a == b if isinstance(a, bool) or isinstance(b, bool) else a == b
