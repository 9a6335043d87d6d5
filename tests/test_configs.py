"""One declaration per setting: every config field is a CLI option of its command, and every scene, source and
trainer field is also a suite key, with the same name, default and check (``panorecon.configs``, ``checks``)."""

from __future__ import annotations

import argparse
import dataclasses

import pytest

from panorecon import checks as C
from panorecon import cli_types as T
from panorecon.cli import COMMANDS, build_config, build_parser, main
from panorecon.configs import SceneArgs, SourceArgs, TrainCommandConfig
from panorecon.evaluation.suite import load_suite, row_settings
from panorecon.io import PanoreconInputError
from panorecon.splat.trainer import TrainConfig


def _parser_of(words):
    p = build_parser()
    for w in words:
        p = next(a for a in p._actions if isinstance(a, argparse._SubParsersAction)).choices[w]
    return p


LEAVES = [(words, config) for words, (_, config, _) in COMMANDS.items() if config is not None]


@pytest.mark.parametrize("words, config", LEAVES, ids=[" ".join(w) for w, _ in LEAVES])
def test_every_config_field_is_an_option_with_its_default_choices_and_check(words, config):
    actions = {a.dest: a for a in _parser_of(words)._actions if not isinstance(a, argparse._HelpAction)}
    settings = list(C.settings(config))
    assert {s.name for s in settings} == set(actions), "an option without a field, or a field without an option"
    for s in settings:
        a = actions[s.name]
        if s.meta.get("positional"):
            assert a.option_strings == []
        else:
            assert a.option_strings == [f"--{s.name.replace('_', '-')}"], s.name
        assert (tuple(a.default) if isinstance(a.default, list) else a.default) == s.default, s.name
        assert (tuple(a.choices) if a.choices is not None else None) == s.choices, s.name
        check = s.meta.get("check")
        if isinstance(check, (C.IntIn, C.FloatIn)):
            assert isinstance(a.type, type(check)) and (a.type.lo, a.type.hi) == (check.lo, check.hi), s.name
        role = s.meta.get("role")
        if role == "out-dir":
            assert isinstance(a.type, T._OutDirWriting) and a.type.writes == s.meta["writes"], s.name
        elif role == "teacher":
            assert isinstance(a.type, T.SpecArg) and a.type.check is check, s.name
        elif role is not None:
            assert a.type is {"in": T.in_path, "scene": T.scene, "out-file": T.out_file}[role], s.name


def test_a_train_command_with_no_options_trains_with_the_trainers_defaults(tmp_path):
    args = build_parser().parse_args(["train", "bedroom", "--source", "random", "--out", str(tmp_path / "o")])
    cfg = build_config(args.config, vars(args))
    assert isinstance(cfg, TrainCommandConfig) and cfg.train == TrainConfig()
    assert cfg.train.digest() == TrainConfig().digest()


SUITE_CONFIGS = (SceneArgs, SourceArgs, TrainConfig)
TRAIN_OPTIONS = {s.name: s for s in C.settings(TrainCommandConfig)}


@pytest.mark.parametrize("s", [s for c in SUITE_CONFIGS for s in C.settings(c)], ids=lambda s: s.name)
def test_every_scene_source_and_trainer_field_is_a_suite_key_and_a_train_option(s):
    key = row_settings()[s.name]
    option = TRAIN_OPTIONS[s.name]
    assert key.default == option.default == s.default
    assert key.meta.get("check") is option.meta.get("check") is s.meta.get("check")
    assert key.choices == option.choices == s.choices


def _bad_values(s):
    """Values the setting's check or choices refuse: just outside its bounds, NaN for a float, a non-choice."""
    check = s.meta.get("check") or C.default_check(s.type.replace("| None", "").strip())
    out = []
    if s.choices is not None:
        out.append("no-such-choice")
    if isinstance(check, C.IntIn):
        out += [check.lo - 1] + ([check.hi + 1] if check.hi is not None else [])
    if isinstance(check, C.FloatIn):
        out += [check.lo - 1.0] if check.lo is not None else []
        out += [check.hi + 1.0] if check.hi is not None else []
    return out


CASES = [
    (s.name, v)
    for s in C.settings(TrainCommandConfig)
    if s.name in row_settings() and s.meta.get("role") is None
    for v in _bad_values(s)
]


def test_the_table_of_bad_values_covers_the_train_fields():
    names = {n for n, _ in CASES}
    assert {"iters", "res", "width", "views", "seed", "strategy", "backend", "w_depth", "depth_scale"} <= names


@pytest.mark.parametrize("name, value", CASES, ids=[f"{n}={v}" for n, v in CASES])
def test_a_value_out_of_range_is_refused_by_the_option_and_the_suite_with_the_same_words(tmp_path, capsys, name, value):
    argv = ["train", "bedroom", "--source", "random", "--out", str(tmp_path / "o")]
    if name.startswith("depth_"):
        argv += ["--depth", str(tmp_path / "d.npy")]
    assert main([*argv, f"--{name.replace('_', '-')}", str(value)]) == 2
    cli_err = capsys.readouterr().err.strip()
    suite = tmp_path / "s.toml"
    toml_value = f'"{value}"' if isinstance(value, str) else repr(value)
    if TRAIN_OPTIONS[name].meta.get("many"):  # a list in the suite, one or more values after the option
        toml_value = f"[{toml_value}]"
    depth = f'depth = "{tmp_path / "d.npy"}"\n' if name.startswith("depth_") else ""
    suite.write_text(f'[defaults]\n{depth}{name} = {toml_value}\n[grid]\nscene = ["bedroom"]\nsource = ["random"]\n')
    with pytest.raises(PanoreconInputError) as e:
        load_suite(suite)
    said = str(e.value)
    assert f"s.toml: [defaults] {name} = " in said and cli_err.count("\n") == 0
    if value == "no-such-choice":  # argparse's own words for a choice: both name every allowed value
        assert all(c in said and c in cli_err for c in row_settings()[name].choices), (said, cli_err)
    else:
        assert f"argument --{name.replace('_', '-')}: " in cli_err
        assert said.split("expected", 1)[1] == cli_err.split("expected", 1)[1].removesuffix(" (see --help)")


def test_a_suite_key_of_the_wrong_type_names_key_file_and_type(tmp_path):
    suite = tmp_path / "s.toml"
    suite.write_text('[defaults]\niters = "many"\n[grid]\nscene = ["bedroom"]\nsource = ["random"]\n')
    with pytest.raises(PanoreconInputError, match=r"s\.toml: \[defaults\] iters = 'many' is str; expected an integer"):
        load_suite(suite)


def test_a_config_built_in_code_is_checked_as_the_option_is():
    with pytest.raises(ValueError, match="iters = 0: 0 is out of range; expected an integer from 1"):
        TrainConfig(iters=0)
    with pytest.raises(ValueError, match="strategy = .fast.: expected one of default, adaptive"):
        TrainConfig(strategy="fast")
    with pytest.raises(ValueError, match="without --depth"):
        SceneArgs(scene="bedroom", depth_scale=0.001)
    with pytest.raises(dataclasses.FrozenInstanceError):
        TrainConfig().iters = 5


def test_a_teacher_spec_is_parsed_once_where_the_command_line_is_read(tmp_path):
    from panorecon.teachers import TeacherSpec

    argv = ["train", "bedroom", "--source", "fibonacci", "--teacher", "sim:relative", "--out", str(tmp_path / "o")]
    args = build_parser().parse_args(argv)
    cfg = build_config(args.config, vars(args))
    assert isinstance(cfg.source.teacher, TeacherSpec) and cfg.source.teacher.kind == "sim"
    assert cfg.source.teacher == "sim:relative"
