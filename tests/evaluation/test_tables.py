"""The tables' harness: several suites as one grid, a shared reference run computed once, resumption from a
results.csv alone, budgets read from one run, and pairs across code versions left out."""

import pandas as pd
import pytest

from panorecon.evaluation import ablate
from panorecon.evaluation.ablate import run_suites
from panorecon.evaluation.report import at_budget, budget_steps
from panorecon.evaluation.stats import compare
from panorecon.evaluation.suite import load_suite

COMMON = """
[defaults]
width = 64
teacher = "sim:clean"
source = "fibonacci"
iters = 8
res = 16
labels = 6
heldout = 1
sh_degree = 0
history_every = 4
checkpoint_every = 0
eval_at = [4]
strategy = "adaptive"
"""
# two tables that share their reference cell (fibonacci, 6 labels, adaptive) on bedroom, seed 0
TABLE_A = (
    'title = "A"\nrows = ["labels"]\nreference = { labels = 6 }\n'
    + COMMON
    + "[grid]\nscene = ['bedroom']\nlabels = [6, 4]\n"
)
TABLE_B = (
    'title = "B"\nrows = ["strategy"]\nreference = { strategy = "adaptive" }\n'
    + COMMON
    + "[grid]\nscene = ['bedroom']\nstrategy = ['adaptive', 'default']\n"
)


@pytest.fixture()
def two_tables(tmp_path, monkeypatch):
    """Two suite files, and the list of tasks every run_suites call handed to the workers."""
    (tmp_path / "table_a.toml").write_text(TABLE_A)
    (tmp_path / "table_b.toml").write_text(TABLE_B)
    suites = [load_suite(tmp_path / "table_a.toml"), load_suite(tmp_path / "table_b.toml")]
    ran: list = []
    real = ablate._run_tasks

    def counting(fn, tasks, *a, **k):
        ran.append([t[0].run_id() for t in tasks])
        return real(fn, tasks, *a, **k)

    monkeypatch.setattr(ablate, "_run_tasks", counting)
    return tmp_path, suites, ran


def test_the_shared_reference_cell_runs_once_and_appears_in_both_tables(two_tables):
    d, suites, ran = two_tables
    a, b = run_suites(suites, d / "out", jobs=1, progress=False)
    assert len(ran) == 1 and len(ran[0]) == 3 == len(set(ran[0]))  # 4 rows, 3 distinct runs
    shared_a = a[a["reference"]].iloc[0]
    shared_b = b[b["reference"]].iloc[0]
    assert shared_a["run_id"] == shared_b["run_id"] and shared_a["psnr_ho"] == shared_b["psnr_ho"]
    assert (shared_a["label"], shared_b["label"]) == ("6", "adaptive")  # each under its own table's label
    for stem in ("table_a", "table_b"):
        csv = pd.read_csv(d / "out" / stem / "results.csv")
        assert len(csv) == 2 and (d / "out" / stem / "results.md").is_file()


def test_a_deleted_cache_reruns_nothing_that_results_csv_has(two_tables):
    import shutil

    d, suites, ran = two_tables
    first = run_suites(suites, d / "out", jobs=1, progress=False)
    shutil.rmtree(d / "out" / "cache")
    again = run_suites(suites, d / "out", jobs=1, progress=False)
    assert ran[1] == []  # nothing handed to a worker
    for f, g in zip(first, again):
        pd.testing.assert_series_equal(f["cached"], g["cached"])  # as recorded when computed
        pd.testing.assert_series_equal(f["psnr_ho"], g["psnr_ho"])
        pd.testing.assert_series_equal(f["label"], g["label"])
    # a results.csv that lost a row: that row alone is run again
    csv = d / "out" / "table_a" / "results.csv"
    kept = pd.read_csv(csv)
    kept[kept["label"] != 4].to_csv(csv, index=False)
    run_suites(suites, d / "out", jobs=1, progress=False)
    assert len(ran[2]) == 1 and ran[2][0] == first[0].loc[first[0]["label"] == "4", "run_id"].iloc[0]


def test_every_run_is_read_at_each_budget(two_tables):
    d, suites, _ = two_tables
    a, _ = run_suites(suites, d / "out", jobs=1, progress=False)
    assert budget_steps(a) == [4, 8]
    last = at_budget(a, 8)
    pd.testing.assert_series_equal(last["psnr_ho"], a["psnr_ho"], check_names=False)
    early = at_budget(a, 4)
    assert (early["sec_train"] < a["sec_train"] + 1e-9).all() and early["psnr_ho"].notna().all()
    assert (early["psnr_ho"] != a["psnr_ho"]).any()
    md = (d / "out" / "table_a" / "results.md").read_text()
    assert "## At each training budget" in md and "### Step 4" in md and "### Step 8" in md


def test_a_pair_computed_by_two_versions_of_the_code_is_not_paired():
    frame = pd.DataFrame(
        {
            "label": ["ref", "row"] * 3,
            "scene": ["s1", "s1", "s2", "s2", "s3", "s3"],
            "seed": [0] * 6,
            "psnr_ho": [20.0, 21.0, 20.0, 21.5, 20.0, 30.0],
            "code": ["a", "a", "a", "a", "a", "b"],
        }
    )
    c = compare(frame, "psnr_ho", "row", "ref")
    assert c.pairs == 2 and c.new.estimate == pytest.approx(1.25)
    assert compare(frame.drop(columns="code"), "psnr_ho", "row", "ref").pairs == 3


def test_set_overrides_the_defaults_of_every_suite_and_refuses_a_row_variable(tmp_path):
    from panorecon.evaluation.suite import parse_override
    from panorecon.io import PanoreconInputError

    (tmp_path / "table_a.toml").write_text(TABLE_A)
    over = dict(parse_override(t) for t in ("iters=10000", "teacher=sim:relative", 'backend="torch"'))
    assert over == {"iters": 10000, "teacher": "sim:relative", "backend": "torch"}
    suite = load_suite(tmp_path / "table_a.toml", overrides=over)
    assert {r.train["iters"] for r in suite.rows} == {10000} and {r.teacher for r in suite.rows} == {"sim:relative"}
    base = load_suite(tmp_path / "table_a.toml")
    assert not {r.run_id() for r in suite.rows} & {r.run_id() for r in base.rows}  # other runs, other results
    with pytest.raises(PanoreconInputError, match="labels is a row variable"):
        load_suite(tmp_path / "table_a.toml", overrides={"labels": 8})
    with pytest.raises(PanoreconInputError, match="--set iters = -1"):
        load_suite(tmp_path / "table_a.toml", overrides={"iters": -1})
    with pytest.raises(PanoreconInputError, match="expected KEY=VALUE"):
        parse_override("iters")


def test_runs_go_in_scene_seed_blocks_whatever_is_already_done():
    from panorecon.pipeline import Row

    every = [Row(scene, 64, "fibonacci", None, seed=seed) for scene in ("b", "a") for seed in (2, 0, 1)]
    todo = [r for r in every if (r.scene, r.seed) != ("b", 0)]  # one block already done
    order = [(r.scene, r.seed) for r in ablate._block_order(todo, every)]
    assert order == [("b", 1), ("b", 2), ("a", 0), ("a", 1), ("a", 2)]


def _sleep_then_report_pid(cache_root: str, seconds: float) -> int:
    """A worker task: sleep, then return this worker's process id."""
    import os
    import time

    time.sleep(seconds)
    return os.getpid()


def test_an_interrupt_ends_the_runs_in_flight_too(tmp_path):
    """Ctrl-C or SIGTERM reaches the parent only (SIGTERM from a scheduler, or a Ctrl-C outside the terminal's
    process group): the worker still running a 60 s task is ended with it, not waited for."""
    import time

    from panorecon.interrupts import Interrupted

    pids = []

    def interrupt_on_the_first(task, pid):
        pids.append(pid)
        raise Interrupted()

    t0 = time.perf_counter()
    with pytest.raises(Interrupted):
        ablate._run_tasks(
            _sleep_then_report_pid, [0.2, 60.0], str(tmp_path), 2, "local", None, False, interrupt_on_the_first
        )
    assert len(pids) == 1
    assert time.perf_counter() - t0 < 30  # the 60 s worker was ended (the pool waits for it to exit), not awaited


def test_a_source_that_gives_no_point_is_a_failed_row_kept_in_results_csv(tmp_path, monkeypatch):
    """COLMAP SfM on 64-px panoramas triangulates nothing: that run's outcome is a row saying so ("failed: ..."),
    the other rows still run, results.md lists it under the failed runs, and a rerun without the cache does not
    try it again (an "n/a: ..." row, which cannot run here, would be)."""
    import shutil

    suite_file = tmp_path / "sources.toml"
    suite_file.write_text(
        'title = "S"\nrows = ["source"]\nreference = { source = "fibonacci" }\n'
        + COMMON
        + "[grid]\nscene = ['bedroom']\nsource = ['fibonacci', 'colmap-sfm']\n"
    )
    ran: list = []
    real = ablate._run_tasks

    def counting(fn, tasks, *a, **k):
        ran.append([t[0].source for t in tasks])
        return real(fn, tasks, *a, **k)

    monkeypatch.setattr(ablate, "_run_tasks", counting)
    out = tmp_path / "out"
    frame = run_suites([load_suite(suite_file)], out, jobs=1, progress=False)[0]
    sfm = frame.set_index("label").loc["colmap-sfm"]
    assert (
        sfm["unavailable_note"].startswith("failed: source 'colmap-sfm'") and "gave no point" in sfm["unavailable_note"]
    )
    assert frame.set_index("label").loc["fibonacci", "psnr_ho"] > 0
    md = (out / "results.md").read_text()
    assert "Failed runs" in md and "- colmap-sfm, bedroom, seed 0: source 'colmap-sfm'" in md
    assert "n/a cells: failed" not in md
    shutil.rmtree(out / "cache")
    run_suites([load_suite(suite_file)], out, jobs=1, progress=False)
    assert ran == [["fibonacci", "colmap-sfm"], []]
