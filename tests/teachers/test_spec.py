"""Teacher specs (teachers/spec.py): parsed once into a TeacherSpec that is also the spec's text; each teacher
module declares its own argument and options."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

from panorecon import checks as C
from panorecon.io.specs import SpecError
from panorecon.teachers import TEACHER_SPEC, TeacherSpec, get_teacher
from panorecon.teachers.spec import KIND_MODULES


@pytest.mark.parametrize(
    "spec,needle",
    [
        ("file:d.npy?metric=2", "not a yes/no"),
        ("file:d.npy?scale=nan", "not a positive number"),
        ("file:d.npy?scale=", "not a number"),
        ("file:d.npy?scale", "no value"),
        ("hf:x?batch=0", "not a positive integer"),
        ("moge:x?device=tpu", "not a device"),
        ("sim:relative?noise=1", "known options: none"),
        ("onnx:m.onnx?batch=2", "known options: none"),
        ("bogus:x", "expected sim:<profile>, onnx:<model.onnx>, file:<depth.png|.npy>"),
        ("nocolon", "expected sim:<profile>"),
        ("file:", "file: needs an argument"),
    ],
)
def test_bad_specs_name_the_problem(spec, needle):
    with pytest.raises(SpecError, match=needle):
        TeacherSpec(spec)


def test_a_spec_is_its_text_with_its_parts_parsed():
    s = TeacherSpec("file:d.npy?scale=0.5&metric=yes")
    assert s == "file:d.npy?scale=0.5&metric=yes" and isinstance(s, str) and hash(s) == hash(str(s))
    assert (s.kind, s.arg, dict(s.options)) == ("file", "d.npy", {"scale": 0.5, "metric": True})
    assert TeacherSpec(s) is s  # parsing a parsed spec is a no-op
    with pytest.raises(TypeError):
        s.options["scale"] = 2.0  # read-only


@pytest.mark.parametrize("kind", sorted(KIND_MODULES))
def test_each_teacher_module_declares_its_argument_and_options(kind):
    module = importlib.import_module(f"panorecon.teachers.{KIND_MODULES[kind]}")
    assert module.ARG.startswith("<") and isinstance(module.OPTIONS, dict)
    assert all(callable(p) for p in module.OPTIONS.values())


def test_the_check_refuses_a_missing_file_and_names_the_path_of_an_existing_one(tmp_path):
    with pytest.raises(C.CheckError, match="nowhere.npy: no such file"):
        TEACHER_SPEC.check("file:nowhere.npy")
    d = tmp_path / "d.npy"
    np.save(d, np.ones((4, 8), np.float32))
    assert TEACHER_SPEC(f"file:{d}?scale=2").path == str(d)
    assert TEACHER_SPEC("sim:relative").path is None
    assert TEACHER_SPEC("hf:some/model-id").path is None  # a model id, not a path


def test_get_teacher_takes_the_parsed_spec_or_its_text(tmp_path):
    d = tmp_path / "d.npy"
    np.save(d, np.full((4, 8), 2.0, np.float32))
    for spec in (f"file:{d}?scale=2", TeacherSpec(f"file:{d}?scale=2")):
        t = get_teacher(spec)
        assert t.name == f"file:{d}?scale=2" and t.scale == 2.0
    assert get_teacher(TeacherSpec("sim:relative"), 3).profile.name == "relative"
