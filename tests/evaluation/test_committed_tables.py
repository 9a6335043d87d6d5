"""Every committed table stays one command away: its suite expands to exactly the runs of its results.csv, so
the README's command finds every committed run and runs nothing. Expansion only: nothing is trained."""

from pathlib import Path

import pandas as pd
import pytest

from panorecon.evaluation.orphans import explain
from panorecon.evaluation.suite import load_suite

ROOT = Path(__file__).resolve().parents[2]
# benchmarks/tables/<name>/results.csv is made by eval/suites/<name>.toml (the budget pilot, benchmarks/tables/pilot,
# holds cost measurements that eval/table_budget.py reads, not a table)
TABLES = sorted(p.parent.name for p in (ROOT / "benchmarks" / "tables").glob("*/results.csv"))


def test_the_committed_tables_are_the_papers_five_and_their_reruns():
    assert TABLES == [
        "table2",
        "table2_learned",
        "table4",
        "table4_learned",
        "table5",
        "table5_population",
        "table6",
        "table7",
        "table7_flatten",
    ]


@pytest.mark.parametrize("name", TABLES)
def test_a_committed_table_is_its_suites_expansion_nothing_to_run_none_left_over(name):
    suite = load_suite(ROOT / "eval" / "suites" / f"{name}.toml")
    want = {r.run_id() for r in suite.rows}
    committed = pd.read_csv(ROOT / "benchmarks" / "tables" / name / "results.csv")
    have = set(committed["run_id"])
    leftover = {rid: {} for rid in have - want}
    moved, strangers = explain(suite.rows, leftover) if leftover else ({}, [])
    said = "; ".join(f"{len(v)} ran with {', '.join(k)} at the neutral value" for k, v in moved.items())
    assert not want - have and not leftover, (
        f"{name}: {len(want - have)} suite runs not in results.csv, {len(leftover)} committed runs not in the suite "
        f"({said or 'no moved default explains them'}; {len(strangers)} unexplained): pin what the table ran with "
        "in the suite's [pinned]"
    )
    assert len(committed) == len(have)  # one row per run


@pytest.mark.parametrize("name", TABLES)
def test_unpinned_is_todays_defaults_and_orphans_the_table(name):
    suite = load_suite(ROOT / "eval" / "suites" / f"{name}.toml", unpinned=True)
    have = set(pd.read_csv(ROOT / "benchmarks" / "tables" / name / "results.csv")["run_id"])
    assert suite.pinned and not {r.run_id() for r in suite.rows} & have
