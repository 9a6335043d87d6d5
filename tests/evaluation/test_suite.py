import pytest
from hypothesis import given
from hypothesis import strategies as st

from panorecon.evaluation.suite import load_suite
from panorecon.io import PanoreconInputError


def write(tmp_path, text):
    p = tmp_path / "s.toml"
    p.write_text(text)
    return p


def test_grid_times_variants(tmp_path):
    s = load_suite(
        write(
            tmp_path,
            """
title = "t"
rows = ["label"]
[defaults]
width = 64
teacher = "sim:clean"
iters = 5
[grid]
scene = ["bedroom", "beach"]
[[variants]]
label = "F15"
source = "fibonacci"
views = 15
[[variants]]
label = "rand"
source = "random"
train = false
""",
        )
    )
    assert len(s.rows) == 4
    f15 = [r for r in s.rows if r.label == "F15"]
    assert {r.scene for r in f15} == {"bedroom", "beach"} and all(
        r.views == 15 and r.train == {"iters": 5} for r in f15
    )
    assert all(r.train is None for r in s.rows if r.label == "rand")


@pytest.mark.parametrize(
    "text, match",
    [
        ("[grid]\nscene = ['bedroom']\nsource = ['fibonacci']\ncolour = 3", "unknown key"),
        ("[grid]\nscene = 'bedroom'\nsource = ['fibonacci']", "non-empty list"),
        ("[grid]\nscene = ['bedroom']", "no 'source'"),
        ("[grid\nscene = 1", "not valid TOML"),
    ],
)
def test_bad_suites_name_the_file_and_the_problem(tmp_path, text, match):
    with pytest.raises(PanoreconInputError, match=match) as e:
        load_suite(write(tmp_path, text))
    assert "s.toml" in str(e.value)


def test_shipped_suites_load():
    from pathlib import Path

    suites = sorted((Path(__file__).parents[2] / "eval" / "suites").glob("*.toml"))
    assert {p.stem for p in suites} >= {"quick", "bench", "table2", "table4", "table5", "table6", "table7", "real"}
    for p in suites:
        if "{root}" in p.read_text():  # dataset suites: tests/evaluation/test_suite_datasets.py
            continue
        assert load_suite(p).rows


BASE = "[defaults]\nscene = 'bedroom'\nsource = 'fibonacci'\nteacher = 'sim:clean'\n"


@pytest.mark.parametrize(
    "text, match",
    [
        ("[defualts]\nscene = 'bedroom'", "unknown key 'defualts' in the top level; did you mean 'defaults'"),
        (BASE + "iter = 3", "unknown key 'iter' in \\[defaults\\]; did you mean 'iters'"),
        (BASE + "[grid]\nstrategie = ['adaptive']", "did you mean 'strategy'"),
        (BASE + "[[variants]]\nveiws = 3", "\\[\\[variants\\]\\] 1; did you mean 'views'"),
        (BASE + "iters = '300'", "iters = '300' is str; expected an integer"),
        (BASE + "iters = 3.5", "expected an integer"),
        (BASE + "train = 1", "expected true or false"),
        (BASE + "w_l1 = 'x'", "expected a number"),
        (BASE + "views = 0", "views = 0: 0 is out of range"),
        (BASE + "width = 63", "width = 63: 63 is out of range"),
        (BASE + "iters = -5", "iters = -5"),
        (BASE + "lr_means = -1.0", "expected a finite value >= 0"),
        (BASE + "lr_means = nan", "expected a finite value >= 0"),
        (BASE + "strategy = 'fancy'", "expected one of default, adaptive"),
        (BASE + "[grid]\nviews = [8, 'x']", "views = 'x' is str"),
        ("rows = 'source'\n" + BASE, "rows must be a list"),
        ("rows = ['sorce']\n" + BASE, "unknown key 'sorce' in rows; did you mean 'source'"),
        ("title = 3\n" + BASE, "title must be a string"),
        (BASE + "[paper]\ncaptoin = 'x'", "did you mean 'caption'"),
        (BASE + "[paper]\nrows = [{label = 'a', vals = [1]}]", "did you mean 'values'"),
    ],
)
def test_the_typed_schema_names_the_key_and_the_closest_valid_name(tmp_path, text, match):
    with pytest.raises(PanoreconInputError, match=match) as e:
        load_suite(write(tmp_path, text))
    assert "s.toml" in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize(
    "text, match",
    [
        (BASE.replace("'bedroom'", "'bedrom'"), "unknown scene 'bedrom'; did you mean 'bedroom'"),
        (BASE.replace("'fibonacci'", "'fibonaci'"), "unknown point source 'fibonaci'"),
        (BASE.replace("sim:clean", "sim:cleen"), "unknown simulated profile"),
        (BASE.replace("sim:clean", "file:nowhere.npy"), "nowhere.npy: no such file"),
        (BASE.replace("teacher = 'sim:clean'\n", ""), "needs a teacher"),
        (BASE.replace("'bedroom'", "'prompt:a castle'"), "PANORECON_TEXT2PANO_MODEL"),
    ],
)
def test_every_name_is_resolved_before_any_stage_and_before_out_is_made(tmp_path, monkeypatch, text, match):
    from panorecon.evaluation import ablate

    monkeypatch.delenv("PANORECON_TEXT2PANO_MODEL", raising=False)
    monkeypatch.setattr(ablate, "_run_tasks", lambda *a, **k: pytest.fail("a stage ran"))
    with pytest.raises(PanoreconInputError, match=match) as e:
        ablate.run_suite(load_suite(write(tmp_path, text)), tmp_path / "out", progress=False)
    assert "s.toml" in str(e.value) and not (tmp_path / "out").exists()


KEYS = [
    "scene",
    "width",
    "source",
    "teacher",
    "views",
    "train",
    "label",
    "iters",
    "res",
    "labels",
    "strategy",
    "seed",
    "w_l1",
    "fov_deg",
    "colour",
    "iter",
    "scenes",
]
VALUES = st.one_of(
    st.integers(-10, 5000),
    st.floats(allow_nan=False, width=32),
    st.booleans(),
    st.sampled_from(["bedroom", "fibonacci", "sim:clean", "adaptive", "x"]),
)


def _toml(v) -> str:
    """A TOML scalar (JSON strings are valid TOML basic strings)."""
    import json

    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return ("inf" if v > 0 else "-inf") if v in (float("inf"), float("-inf")) else repr(v)
    return json.dumps(v)


@given(table=st.dictionaries(st.sampled_from(KEYS), VALUES, max_size=6))
def test_any_defaults_table_loads_or_is_one_clear_input_error(tmp_path_factory, table):
    """Property: a suite never crashes with anything but PanoreconInputError, and what loads is well typed."""
    d = tmp_path_factory.mktemp("prop")
    path = d / "s.toml"
    path.write_text(
        "[defaults]\n"
        + "".join(f"{k} = {_toml(v)}\n" for k, v in {"scene": "bedroom", "source": "random", **table}.items())
    )
    try:
        suite = load_suite(path)
    except PanoreconInputError as e:
        assert str(e).startswith(f"suite {path}") and "\n" not in str(e)
        return
    row = suite.rows[0]
    assert isinstance(row.scene, str) and isinstance(row.width, int) and 16 <= row.width <= 16384
    assert row.views is None or (isinstance(row.views, int) and row.views >= 1)
    if row.train is not None:
        from panorecon.splat.trainer import TrainConfig

        cfg = TrainConfig(**row.train)
        assert cfg.iters >= 1 and cfg.res >= 8 and cfg.labels >= 1
