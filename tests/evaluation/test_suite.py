import pytest

from panorecon.evaluation.suite import load_suite
from panorecon.io import PanoreconInputError


def write(tmp_path, text):
    p = tmp_path / "s.toml"
    p.write_text(text)
    return p


def test_grid_times_variants(tmp_path):
    s = load_suite(write(tmp_path, """
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
"""))
    assert len(s.rows) == 4
    f15 = [r for r in s.rows if r.label == "F15"]
    assert {r.scene for r in f15} == {"bedroom", "beach"} and all(r.views == 15 and r.train == {"iters": 5} for r in f15)
    assert all(r.train is None for r in s.rows if r.label == "rand")


@pytest.mark.parametrize("text, match", [
    ("[grid]\nscene = ['bedroom']\nsource = ['fibonacci']\ncolour = 3", "unknown key"),
    ("[grid]\nscene = 'bedroom'\nsource = ['fibonacci']", "non-empty list"),
    ("[grid]\nscene = ['bedroom']", "no 'source'"),
    ("[grid\nscene = 1", "not valid TOML"),
])
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
