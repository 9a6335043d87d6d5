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


SEEDED = "seeds = [0, 1, 2]\nreference = { source = 'fibonacci' }\n[defaults]\nteacher = 'sim:clean'\niters = 5\n"
SEEDED += "[grid]\nscene = ['bedroom', 'beach']\nsource = ['fibonacci', 'random']\n"


def test_seeds_run_every_row_per_seed_and_the_reference_names_one_row(tmp_path):
    s = load_suite(write(tmp_path, SEEDED))
    assert len(s.rows) == 2 * 2 * 3 and s.seeds == [0, 1, 2] and s.reference == "fibonacci"
    for r in s.rows:
        assert r.train == {"iters": 5, "seed": r.seed}  # the training seed is the row's seed
    fib = {r.seed: r for r in s.rows if r.source == "fibonacci" and r.scene == "bedroom"}
    assert len({fib[k].points_key() for k in fib}) == 3  # the simulated teacher's noise is seeded
    assert len({fib[k].train_key() for k in fib}) == 3
    unseeded = load_suite(write(tmp_path, SEEDED.replace("seeds = [0, 1, 2]\n", "")))
    assert unseeded.seeds == [0] and len(unseeded.rows) == 4 and unseeded.rows[0].train == {"iters": 5}


def test_a_stage_the_seed_does_not_change_is_shared_between_seeds():
    from panorecon.pipeline import Row
    from panorecon.sources import uses_seed

    model = "onnx:/nonexistent/model.onnx"  # a network: its depth does not depend on the seed
    rows = [Row("bedroom", 64, "fibonacci", model, train={"seed": k}, seed=k) for k in (0, 1)]
    assert rows[0].points_key() == rows[1].points_key() and rows[0].train_key() != rows[1].train_key()
    assert not uses_seed("fibonacci", model) and uses_seed("fibonacci", "sim:relative") and uses_seed("random", None)


def test_the_seed_changes_the_teacher_noise_and_random_points():
    import numpy as np

    from panorecon.scenes import load_scene
    from panorecon.sources import run_source

    scene = load_scene("bedroom", 64)
    c0, c0_again, c1 = (run_source(scene, "fibonacci", "sim:relative", views=6, seed=k)[0].xyz for k in (0, 0, 1))
    assert np.array_equal(c0, c0_again)
    assert not np.array_equal(c0, c1)
    r0, r1 = (run_source(scene, "random", None, seed=k)[0].xyz for k in (0, 1))
    assert not (r0 == r1).all()


@pytest.mark.parametrize(
    "text, match",
    [
        ("seeds = []\n" + BASE, "seeds = \\[\\]: expected a non-empty list of integers"),
        ("seeds = [0, 'a']\n" + BASE, "expected a non-empty list of integers"),
        ("seeds = [0, -1]\n" + BASE, "seeds: -1 is out of range"),
        ("seeds = [1, 1]\n" + BASE, "repeats a seed"),
        ("seeds = 3\n" + BASE, "seeds must be a list"),
        ("seeds = [0, 1]\n" + BASE + "seed = 4", "seeds = \\[...\\] or a seed setting, not both"),
        ("reference = { sorce = 'fibonacci' }\n" + BASE, "unknown key 'sorce' in reference; did you mean 'source'"),
        ("reference = { scene = 'bedroom' }\n" + BASE, "compared on every scene and seed"),
        ("reference = { source = 'cube' }\n" + BASE, "matches no row; the rows are fibonacci"),
        ("reference = { views = 0 }\n" + BASE, "reference views = 0: 0 is out of range"),
        ("reference = 'fibonacci'\n" + BASE, "reference must be a table"),
        ("reference = {}\n" + BASE, "reference is empty"),
    ],
)
def test_bad_seeds_and_references_are_one_clear_error(tmp_path, text, match):
    with pytest.raises(PanoreconInputError, match=match) as e:
        load_suite(write(tmp_path, text))
    assert "s.toml" in str(e.value)


def test_a_reference_that_matches_several_rows_says_which(tmp_path):
    text = "rows = ['source', 'views']\nreference = { source = 'fibonacci' }\n" + BASE + "[grid]\nviews = [8, 12]"
    with pytest.raises(PanoreconInputError, match="matches 2 rows \\(fibonacci / 8, fibonacci / 12\\); add keys"):
        load_suite(write(tmp_path, text))
    ok = load_suite(write(tmp_path, text.replace("source = 'fibonacci' }", "source = 'fibonacci', views = 12 }")))
    assert ok.reference == "fibonacci / 12"


def test_every_shipped_table_suite_names_seeds_and_a_reference_row(tmp_path):
    """The paper's five tables (eval/suites/table{2,4,5,6,7}.toml) name a reference that is one of their rows,
    Tables 2 and 7 (the headline claims) at least two seeds; a reference given by a row's label works too."""
    import re
    from pathlib import Path

    for p in sorted((Path(__file__).parents[2] / "eval" / "suites").glob("table[24567].toml")):
        s = load_suite(p)
        assert s.reference in {r.label for r in s.rows}, p.name
        assert len(s.seeds) >= (2 if p.stem in ("table2", "table7") else 1), p.name
        assert len(s.rows) == len(s.seeds) * len({r.label for r in s.rows}) * len({r.scene for r in s.rows}), p.name
        last = s.rows[-1].label
        q = tmp_path / p.name
        q.write_text(re.sub(r"(?m)^reference = .*$", f"reference = {{ label = {last!r} }}", p.read_text()))
        assert load_suite(q).reference == last, p.name


POPULATION = "[defaults]\nteacher = 'sim:clean'\niters = 5\nsource = 'fibonacci'\n[grid]\nscene = ['{}', 'beach']\n"


def test_a_population_of_variants_expands_to_one_row_per_variant_each_its_own_run(tmp_path):
    from panorecon.evaluation.suite import resolve_names

    s = load_suite(write(tmp_path, POPULATION.format("bedroom@1..3")))
    assert [r.scene for r in s.rows] == ["bedroom@1", "bedroom@2", "bedroom@3", "beach"]
    resolve_names(s)  # every variant name is a scene
    for key in ("points_key", "train_key", "run_id"):
        assert len({getattr(r, key)() for r in s.rows}) == 4, key  # bedroom@1 and bedroom@2 are different runs
    one = load_suite(write(tmp_path, POPULATION.format("bedroom@2..2")))
    assert [r.scene for r in one.rows] == ["bedroom@2", "beach"]
    assert one.rows[0].run_id() == s.rows[1].run_id()  # the same variant is the same run


@pytest.mark.parametrize(
    "scene, match",
    [
        ("bedroom@3..1", "1 <= A <= B"),
        ("bedroom@0..2", "1 <= A <= B"),
        ("bedroom@1..", "NAME@A..B"),
        ("bedroom@a..b", "NAME@A..B"),
        ("bedroom@1..2..3", "NAME@A..B"),
        ("nosuch@1..2", "synthetic scenes"),
    ],
)
def test_a_malformed_population_is_one_error_naming_the_file(tmp_path, scene, match):
    with pytest.raises(PanoreconInputError, match=match) as e:
        load_suite(write(tmp_path, POPULATION.format(scene)))
    msg = str(e.value)
    assert "s.toml" in msg and (repr(scene) in msg or scene.startswith("nosuch")) and "\n" not in msg


@pytest.mark.parametrize("scene", ["bedroom@0", "nosuch@2", "NAME@K"])
def test_resolve_names_refuses_a_bad_variant_before_anything_runs(tmp_path, scene):
    from panorecon.evaluation.suite import resolve_names

    s = load_suite(write(tmp_path, POPULATION.format(scene)))
    with pytest.raises(PanoreconInputError, match=f"{scene!r}") as e:
        resolve_names(s)
    assert "s.toml" in str(e.value) and "\n" not in str(e.value)


def test_scene_dir_reads_each_scene_from_its_render_folder_checked_before_anything_runs(tmp_path):
    from panorecon.cli import main

    folder = tmp_path / "scenes" / "bedroom"
    args = ["render", "bedroom", "--width", "64", "--heldout", "2", "--heldout-res", "16", "--heldout-seeds", "0", "1"]
    assert main([*args, "--out", str(folder)]) == 0
    text = '[defaults]\nwidth = {w}\nres = {r}\nheldout = 2\nsource = "fibonacci"\n[grid]\nscene = ["{s}"]\n'
    path = write(tmp_path, "seeds = [0, 1]\n" + text.format(w=64, r=16, s="bedroom"))
    s = load_suite(path, scene_dir=str(tmp_path / "scenes"))
    assert {r.scene for r in s.rows} == {str(folder)} and [r.seed for r in s.rows] == [0, 1]
    assert {r.run_id() for r in s.rows}.isdisjoint(r.run_id() for r in load_suite(path).rows)
    for seeds, w, r, scene, match in [
        ("[0, 1]", 64, 16, "beach", "beach is not a `panorecon render` folder"),
        ("[0, 1]", 128, 16, "bedroom", "64 px wide, the rows 128"),
        ("[0, 1]", 64, 32, "bedroom", "no held-out views at 32 px"),
        ("[2]", 64, 16, "bedroom", r"for seed\(s\) 2; write it with `panorecon render bedroom .*--heldout-seeds 2"),
    ]:
        bad = write(tmp_path, f"seeds = {seeds}\n" + text.format(w=w, r=r, s=scene))
        with pytest.raises(PanoreconInputError, match=match):
            load_suite(bad, scene_dir=str(tmp_path / "scenes"))


PAPER = "\n[paper]\ncolumns = ['PSNR', 'SSIM', 'Time']\nrows = [\n{rows}\n]\n"


def test_a_paper_row_matched_to_one_of_ours_gives_the_papers_figures(tmp_path):
    rows = (
        "{ label = 'ours', values = [42.07, 0.992, '8 min'], match = { source = 'fibonacci' } },\n"
        "{ label = 'theirs', values = [38.64, 0.945, '1 min'] },\n"  # no match: shown, never compared
        "{ label = 'random init', values = [30.5, 0.9, '2 min'], match = { label = 'random' } }"
    )
    s = load_suite(write(tmp_path, SEEDED + PAPER.format(rows=rows)))
    assert s.paper_labels == {"fibonacci": 0, "random": 2}
    assert s.paper_figures() == {
        "psnr_pl": {"fibonacci": 42.07, "random": 30.5},
        "ssim_pl": {"fibonacci": 0.992, "random": 0.9},
    }


@pytest.mark.parametrize(
    "match, error",
    [
        ("{ source = 'cube' }", "\\[paper\\] rows\\[1\\] match \\{ source = 'cube' \\} matches no row; the rows are"),
        ("{ teacher = 'sim:clean' }", "\\[paper\\] rows\\[1\\] match .* matches 2 rows \\(fibonacci, random\\)"),
        ("{ sorce = 'fibonacci' }", "unknown key 'sorce' in \\[paper\\] rows\\[1\\] match; did you mean 'source'"),
        ("{ scene = 'bedroom' }", "picks a table row, compared on every scene and seed"),
    ],
)
def test_a_paper_match_that_does_not_pick_one_row_is_one_clear_error(tmp_path, match, error):
    rows = f"{{ label = 'x', values = [42.0, 0.99, '1 min'], match = {match} }}"
    with pytest.raises(PanoreconInputError, match=error) as e:
        load_suite(write(tmp_path, SEEDED + PAPER.format(rows=rows)))
    assert "s.toml" in str(e.value)


@pytest.mark.parametrize(
    "margins, error",
    [
        ("{ psnr = 0.1 }", "unknown key 'psnr' in margins"),
        ("{ points = 10 }", "unknown key 'points' in margins"),  # a count has no better direction
        ("{ psnr_pl = 0 }", "margins psnr_pl = 0: expected a positive number"),
        ("{ psnr_pl = 'a' }", "margins psnr_pl = 'a': expected a positive number"),
        ("0.1", "margins must be a table"),
    ],
)
def test_margins_name_metrics_with_a_direction_and_positive_values(tmp_path, margins, error):
    with pytest.raises(PanoreconInputError, match=error):
        load_suite(write(tmp_path, f"margins = {margins}\n" + SEEDED))
    ok = load_suite(write(tmp_path, "margins = { psnr_pl = 0.05, lpips_ho = 0.002 }\n" + SEEDED))
    assert ok.margins == {"psnr_pl": 0.05, "lpips_ho": 0.002}


def test_the_shipped_tables_tie_the_papers_rows_to_ours():
    """Tables 2, 5, 6 and 7 give the paper's figure for the rows its claims are about (Table 4's are real
    networks our sim: stand-ins do not stand for)."""
    from pathlib import Path

    suites = Path(__file__).resolve().parents[2] / "eval" / "suites"
    expect = {
        "table2": {"fibonacci": 42.07, "colmap-sfm": 38.64, "colmap-mvs": 37.93},
        "table5": {"120": 42.12, "180": 42.37, "240": 42.07, "300": 42.03, "360": 41.44},
        "table6": {"Icosahedron (20)": 41.67, "Fibonacci 15": 41.58, "Fibonacci 20": 42.07, "Fibonacci 25": 42.24},
        "table7": {"default": 41.75, "adaptive": 42.07},
        "table4": {},
    }
    for name, figures in expect.items():
        assert load_suite(suites / f"{name}.toml").paper_figures()["psnr_pl"] == figures, name


MILLION = """
seeds = [{seeds}]
[defaults]
source = "fibonacci"
teacher = "sim:clean"
train = false
[grid]
scene = ["bedroom@1..1000", "beach"]
views = [{views}]
"""


def test_a_million_row_suite_is_refused_with_its_exact_count_before_any_row_is_built(tmp_path, monkeypatch):
    import panorecon.evaluation.suite as suite_mod

    built = []
    monkeypatch.setattr(suite_mod, "Row", lambda *a, **k: built.append(1))
    monkeypatch.setattr(suite_mod, "_expand_variants", lambda *a: built.append(1))
    # (1000 + 1) scenes x 100 view counts x 10 seeds = 1,001,000 rows
    text = MILLION.format(views=", ".join(map(str, range(1, 101))), seeds=", ".join(map(str, range(10))))
    with pytest.raises(PanoreconInputError) as e:
        load_suite(write(tmp_path, text), max_runs=10_000)
    assert str(e.value) == (
        f"suite {tmp_path / 's.toml'} expands to 1001000 runs, more than --max-runs 10000; "
        "pass a larger --max-runs to run it"
    )
    assert not built


@pytest.mark.parametrize(
    "text",
    [
        MILLION.format(views="3, 5", seeds="0, 1, 2"),
        MILLION.format(views="3", seeds="0").replace('scene = ["bedroom@1..1000", "beach"]', "")
        + '[[variants]]\nscene = "bedroom@2..4"\n[[variants]]\nscene = "beach"\n',
        POPULATION.format("bedroom@1..3"),
        BASE + "[grid]\nviews = [3, 4]\nw_l1 = [0.5, 0.8]\n[[variants]]\nlabel = 'a'\n[[variants]]\nlabel = 'b'\n",
        BASE + "[grid]\nscene = ['bedroom', 'beach@1..2']\n[[variants]]\nscene = 'beach'\n[[variants]]\nviews = 3\n",
    ],
)
def test_the_row_count_from_the_sizes_is_the_expanded_count(tmp_path, text):
    n = len(load_suite(write(tmp_path, text)).rows)
    assert len(load_suite(write(tmp_path, text), max_runs=n).rows) == n
    with pytest.raises(PanoreconInputError, match=f"expands to {n} runs, more than --max-runs {n - 1};"):
        load_suite(write(tmp_path, text), max_runs=n - 1)


def test_every_shipped_suite_counts_its_rows_exactly():
    from pathlib import Path

    from panorecon.evaluation.suite import _suite_data, count_rows

    for p in sorted((Path(__file__).parents[2] / "eval" / "suites").glob("*.toml")):
        if "{root}" in p.read_text():
            continue
        data = _suite_data(p)  # with the suite it extends
        seeds = data.get("seeds")
        n = count_rows(p, data.get("defaults", {}), data.get("grid", {}), data.get("variants", [{}]), seeds, None)
        assert n == len(load_suite(p).rows), p.name


PINNED = """
title = "t"
rows = ["source"]
[defaults]
width = 64
teacher = "sim:clean"
iters = 5
[pinned]
flatten_every = 0
edge_reach = 0
[grid]
scene = ["bedroom"]
source = ["fibonacci"]
"""


def test_pinned_settings_hold_unless_unpinned(tmp_path):
    (row,) = load_suite(write(tmp_path, PINNED)).rows
    assert row.train == {"iters": 5, "flatten_every": 0} and row.fusion == {"edge_reach": 0}
    (today,) = load_suite(write(tmp_path, PINNED), unpinned=True).rows
    assert today.train == {"iters": 5} and today.fusion is None and today.run_id() != row.run_id()
    # --set over a pinned setting: another run, as asked
    (other,) = load_suite(write(tmp_path, PINNED), overrides={"flatten_every": 50}).rows
    assert other.train["flatten_every"] == 50


@pytest.mark.parametrize(
    "text, match",
    [
        (PINNED.replace("edge_reach = 0", "edge_reach = -1"), "edge_reach = -1"),
        (PINNED.replace("edge_reach = 0", "flatten = 0"), "did you mean 'flatten_every'"),
        (PINNED.replace("source = [", "flatten_every = [0, 100]\nsource = ["), r"\[pinned\] flatten_every"),
    ],
)
def test_bad_pins_are_one_clear_error(tmp_path, text, match):
    with pytest.raises(PanoreconInputError, match=match):
        load_suite(write(tmp_path, text))


def test_a_suite_that_extends_another_is_it_with_its_own_tables_over(tmp_path):
    (tmp_path / "base.toml").write_text(PINNED)
    later = 'extends = "base.toml"\n[pinned]\nflatten_every = 100\n[defaults]\niters = 7\n'
    (tmp_path / "later.toml").write_text(later)
    s = load_suite(tmp_path / "later.toml")
    assert s.name == "later" and s.title == "t" and s.pinned == {"flatten_every": 100, "edge_reach": 0}
    (row,) = s.rows
    assert row.train == {"iters": 7, "flatten_every": 100} and row.fusion == {"edge_reach": 0}
    (tmp_path / "loop.toml").write_text('extends = "loop2.toml"\n')
    (tmp_path / "loop2.toml").write_text('extends = "loop.toml"\n')
    with pytest.raises(PanoreconInputError, match="extends it back"):
        load_suite(tmp_path / "loop.toml")
    (tmp_path / "lost.toml").write_text('extends = "nowhere.toml"\n')
    with pytest.raises(PanoreconInputError, match="nowhere.toml: no such file"):
        load_suite(tmp_path / "lost.toml")
