"""A teacher spec, ``kind:arg?key=value&...``, parsed once where it is read (the command line, a suite file).

Each teacher kind's module declares its own grammar: ``ARG`` (what the argument is) and ``OPTIONS`` (option key
-> parser, see ``io.specs``). ``TeacherSpec`` is the parsed spec; it is also the spec's text (a ``str``), so a
cache key, a results row or a report that records the spec records the same text as before.
"""

from __future__ import annotations

import importlib
import os
from types import MappingProxyType

from .. import checks as C
from ..io.specs import SpecError, parse_options

# each kind -> the module (under panorecon.teachers) that declares its ARG and OPTIONS
KIND_MODULES = {
    "sim": "sim",
    "onnx": "onnx_teacher",
    "file": "file_teacher",
    "hf": "hf_teacher",
    "moge": "moge_teacher",
}
PATH_KINDS = ("file", "onnx")  # kinds whose argument must be an existing file (hf/moge: a folder or a model id)


def _grammar(kind: str):
    module = importlib.import_module(f".{KIND_MODULES[kind]}", __package__)
    return module.ARG, module.OPTIONS


def expected_kinds() -> str:
    return ", ".join(f"{k}:{_grammar(k)[0]}" for k in KIND_MODULES)


class TeacherSpec(str):
    """A parsed teacher spec: ``kind`` (``sim``, ``onnx``, ``file``, ``hf``, ``moge``), ``arg`` (the profile,
    file, folder or model id) and ``options`` (key -> parsed value, read-only). Built from its text, which it
    equals; a malformed spec raises SpecError (a PanoreconInputError) naming it and what was expected."""

    kind: str
    arg: str
    options: MappingProxyType

    def __new__(cls, text: str):
        if isinstance(text, TeacherSpec):
            return text
        kind, colon, rest = str(text).partition(":")
        if not colon or kind not in KIND_MODULES:
            raise SpecError(f"teacher {text!r}: expected {expected_kinds()}")
        arg, _, query = rest.partition("?")
        arg_help, options = _grammar(kind)
        if not arg:
            raise SpecError(f"teacher {text!r}: {kind}: needs an argument ({kind}:{arg_help})")
        self = super().__new__(cls, text)
        self.kind, self.arg = kind, arg
        self.options = MappingProxyType(parse_options(f"teacher {text}", query, options))
        return self

    @property
    def path(self) -> str | None:
        """The file or folder the spec names (None for ``sim:`` and for a model id that is not a path)."""
        if self.kind == "sim":
            return None
        return self.arg if self.kind in PATH_KINDS or os.path.exists(self.arg) else None


class TeacherSpecCheck:
    """The check of a teacher-spec setting (``checks.opt(check=...)``): text -> TeacherSpec, CheckError with
    the reason for a malformed spec or a ``file:``/``onnx:`` file that does not exist (nothing is read)."""

    __name__ = "teacher spec"

    def __call__(self, text: str) -> TeacherSpec:
        try:
            spec = TeacherSpec(text)
        except SpecError as e:
            raise C.CheckError(str(e)) from None
        if spec.kind in PATH_KINDS and not os.path.isfile(spec.arg):
            raise C.CheckError(f"teacher {str(spec)!r}: {spec.arg}: no such file")
        return spec

    def check(self, value) -> None:
        self(value)


TEACHER_SPEC = TeacherSpecCheck()
