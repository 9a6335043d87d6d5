"""Nothing committed is dropped: a results.csv holding runs the invocation does not produce is refused before
anything runs, and rows that are the suite's own under a default that has since moved are named as such."""

import dataclasses

import pandas as pd
import pytest

from panorecon.evaluation.ablate import run_suite
from panorecon.evaluation.orphans import explain, moved_defaults
from panorecon.evaluation.suite import load_suite
from panorecon.io import PanoreconInputError

SUITE = """
title = "t"
rows = ["source"]
[defaults]
width = 64
teacher = "sim:clean"
iters = 5
[grid]
scene = ["bedroom"]
source = ["fibonacci", "icosahedral"]
"""


def test_the_moved_defaults_are_the_options_on_by_default_since():
    moved = moved_defaults()
    assert moved["flatten_every"] == ("train", 0, 100) and moved["edge_reach"] == ("fusion", 0, 3)
    assert "w_spread" not in moved  # added off: its default is its neutral value


def _committed(tmp_path, rows) -> None:
    (tmp_path / "out").mkdir()
    records = [{"run_id": r.run_id(), "label": r.label, "scene": r.scene, "sec_total": 3600.0} for r in rows]
    frame = pd.DataFrame(records)
    frame.to_csv(tmp_path / "out" / "results.csv", index=False)


def test_rows_under_older_defaults_are_named_and_nothing_runs_or_is_written(tmp_path):
    (tmp_path / "s.toml").write_text(SUITE)
    suite = load_suite(tmp_path / "s.toml")
    old = [dataclasses.replace(r, train={**r.train, "flatten_every": 0}, fusion={"edge_reach": 0}) for r in suite.rows]
    stranger = dataclasses.replace(suite.rows[0], train={"iters": 6})
    _committed(tmp_path, [*old, stranger])
    before = (tmp_path / "out" / "results.csv").read_bytes()
    with pytest.raises(PanoreconInputError) as e:
        run_suite(suite, tmp_path / "out", jobs=1, progress=False)
    msg = str(e.value)
    assert "holds 3 run(s)" in msg and "nothing was run" in msg
    assert "2 are its rows under the defaults before they moved" in msg
    assert "flatten_every = 0 (now 100)" in msg and "edge_reach = 0 (now 3)" in msg
    assert "[pinned]: flatten_every = 0; edge_reach = 0" in msg and "2.0 CPU h" in msg
    assert "1 are no row of this suite" in msg
    assert (tmp_path / "out" / "results.csv").read_bytes() == before and not (tmp_path / "out" / "cache").exists()
    groups, strangers = explain(suite.rows, {r.run_id(): {} for r in [*old, stranger]})
    assert list(groups) == [("flatten_every", "edge_reach")] and strangers == [stranger.run_id()]


def test_pinning_them_reads_the_committed_rows(tmp_path):
    (tmp_path / "s.toml").write_text(SUITE.replace("[grid]", "[pinned]\nflatten_every = 0\nedge_reach = 0\n[grid]"))
    suite = load_suite(tmp_path / "s.toml")
    (tmp_path / "today.toml").write_text(SUITE)
    assert {r.run_id() for r in suite.rows}.isdisjoint(r.run_id() for r in load_suite(tmp_path / "today.toml").rows)
    unpinned = load_suite(tmp_path / "s.toml", unpinned=True)
    _committed(tmp_path, suite.rows)
    with pytest.raises(PanoreconInputError, match=r"--unpinned leaves out the suite's \[pinned\] settings"):
        run_suite(unpinned, tmp_path / "out", jobs=1, progress=False)
