"""The option grammar of spec strings (``file:<path>?scale=S&metric=1``, ``hf:<id>?batch=N``): ``key=value`` pairs
parsed strictly. An unknown key, a key given twice, an empty key or a missing ``=`` is refused with the known keys
listed; values are checked by each option's parser (``yes_no``, ``positive_float``, ...). Which keys a spec
knows is declared by its owner (each teacher module's ``OPTIONS``, ``teachers/spec.py``)."""

from __future__ import annotations

from collections.abc import Callable

from .files import PanoreconInputError


class SpecError(PanoreconInputError):
    """A malformed spec string: the message names the spec and lists what is known."""


def yes_no(text: str) -> bool:
    low = text.lower()
    if low in ("1", "true", "yes"):
        return True
    if low in ("0", "false", "no"):
        return False
    raise ValueError("not a yes/no value (expected 1/true/yes or 0/false/no)")


def positive_float(text: str) -> float:
    import math

    try:
        value = float(text)
    except ValueError:
        raise ValueError("not a number (expected a finite number > 0)") from None
    if not (math.isfinite(value) and value > 0):
        raise ValueError("not a positive number (expected a finite number > 0)")
    return value


def positive_int(text: str) -> int:
    try:
        value = int(text, 10)
    except ValueError:
        value = 0
    if value < 1:
        raise ValueError("not a positive integer (expected an integer >= 1)")
    return value


def device(text: str) -> str:
    if text not in ("cpu", "cuda"):
        raise ValueError("not a device (expected cpu or cuda)")
    return text


def parse_options(spec: str, query: str, known: dict[str, Callable[[str], object]]) -> dict[str, object]:
    """``k=v&k2=v2`` of ``spec`` -> {key: parsed value}; SpecError for an unknown, repeated, empty or value-less
    key or a value its parser refuses. An empty ``query`` gives {}."""
    from urllib.parse import unquote

    listed = ", ".join(f"{k}=" for k in known) or "none"
    out: dict[str, object] = {}
    if not query:
        return out
    for part in query.split("&"):
        key, eq, text = part.partition("=")
        key, text = unquote(key), unquote(text)
        if key not in known:
            raise SpecError(f"{spec!r}: unknown option {key or part!r}; known options: {listed}")
        if not eq:
            raise SpecError(f"{spec!r}: option {key!r} has no value (expected {key}=VALUE)")
        if key in out:
            raise SpecError(f"{spec!r}: option {key!r} is given twice")
        try:
            out[key] = known[key](text)
        except ValueError as e:
            raise SpecError(f"{spec!r}: {key}={text!r} is {e}") from None
    return out
