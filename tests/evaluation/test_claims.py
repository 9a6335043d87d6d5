"""eval/claims.py: each paper claim judged from a table's results.csv (paired differences to the paper's choice)."""

import importlib.util
from pathlib import Path

import numpy as np
import pandas as pd

ROOT = Path(__file__).resolve().parents[2]
spec = importlib.util.spec_from_file_location("claims", ROOT / "eval" / "claims.py")
claims = importlib.util.module_from_spec(spec)
spec.loader.exec_module(claims)


def _table7(tmp_path: Path, default_minus_adaptive: list[float], scenes=("a",)) -> Path:
    rows = []
    rng = np.random.default_rng(0)
    for scene in scenes:
        for seed, d in enumerate(default_minus_adaptive):
            base = 40 + rng.normal()
            for label, v in (("adaptive", base), ("default", base + d)):
                rows.append(
                    {
                        "label": label,
                        "scene": scene,
                        "seed": seed,
                        "psnr_pl": v,
                        "psnr_ho": v - 10,
                        "reference": "adaptive",
                    }
                )
    (tmp_path / "table7").mkdir()
    pd.DataFrame(rows).to_csv(tmp_path / "table7" / "results.csv", index=False)
    return tmp_path


def test_a_consistent_difference_against_the_claim_contradicts_it(tmp_path):
    (c,) = [c for c in claims.judge(_table7(tmp_path, [0.30, 0.31, 0.29])) if c["table"] == "table7"]
    assert c["verdict"] == "contradicted"  # the paper: adaptive is better; here default is, on every seed


def test_a_claim_in_the_direction_claimed_is_confirmed(tmp_path):
    (c,) = [c for c in claims.judge(_table7(tmp_path, [-0.30, -0.31, -0.29])) if c["table"] == "table7"]
    assert c["verdict"] == "confirmed"


def test_an_unresolved_difference_says_what_would_resolve_it(tmp_path):
    (c,) = [c for c in claims.judge(_table7(tmp_path, [0.5, -0.3, 0.2])) if c["table"] == "table7"]
    assert c["verdict"] == "not resolved"
    line = [x for x in claims.markdown([c]).splitlines() if "Adaptive pruning" in x][0]
    assert "default +0.13 [" in line and "; needs 1 × " in line


def test_a_difference_inside_the_margin_makes_the_claim_equivalent_and_rules_out_the_papers_size(tmp_path):
    """Default − adaptive ≈ 0 on every seed: no effect either way, and the paper's −0.32 dB (its Table 7, read
    from eval/suites/table7.toml) lies outside the interval."""
    (c,) = [c for c in claims.judge(_table7(tmp_path, [0.01, -0.01, 0.0], scenes="abcd")) if c["table"] == "table7"]
    assert c["verdict"] == "equivalent"
    cell = c["pseudo_label"]["default"]
    assert cell["equivalent_these"] and cell["margin"] == 0.1
    assert abs(cell["paper"] - (41.75 - 42.07)) < 1e-9 and cell["paper_ruled_out_these"]
    assert c["paper_size_pseudo_label_these"] == "ruled out"
    line = [x for x in claims.markdown([c]).splitlines() if "Adaptive pruning" in x][0]
    assert "(paper -0.32; ≡ ±0.1)" in line and "| **equivalent** /" in line and "| ruled out / " in line
    assert "needs" not in line  # an equivalent difference needs no more runs


def test_the_papers_size_inside_the_interval_is_consistent_not_ruled_out(tmp_path):
    (c,) = [c for c in claims.judge(_table7(tmp_path, [-0.30, -0.35, -0.31], scenes="abcd")) if c["table"] == "table7"]
    assert c["verdict"] == "confirmed" and c["paper_size_pseudo_label_these"] == "consistent"
    assert not c["pseudo_label"]["default"]["equivalent_these"]


def test_a_one_seed_population_is_judged_across_new_scenes(tmp_path):
    """Table 5's population (eval/suites/table5_population.toml): one seed, many scenes. No interval exists on
    these scenes, so the claim is judged, and its difference shown, across new scenes."""
    rows = []
    rng = np.random.default_rng(1)
    for k in range(12):
        base = 41 + rng.normal()
        for label, v in (("180", base), ("120", base + 0.25 + 0.05 * rng.normal())):
            rows.append({"label": label, "scene": f"s{k}", "seed": 0, "psnr_pl": v, "psnr_ho": v - 14})
    (tmp_path / "table5_population").mkdir()
    pd.DataFrame(rows).to_csv(tmp_path / "table5_population" / "results.csv", index=False)
    (c,) = [c for c in claims.judge(tmp_path) if c["table"] == "table5_population"]
    assert c["judged_on"] == "new" and c["verdict"] == c["verdict_pseudo_label_new"] == "contradicted"
    assert c["pseudo_label"]["120"]["these"] is None or np.isnan(c["pseudo_label"]["120"]["these"]["low"])
    line = [x for x in claims.markdown([c]).splitlines() if "population" in x][0]
    assert "across new scenes" in line and "/ **contradicted** |" in line
    assert c["paper_size_pseudo_label_new"] == "ruled out"  # the paper's 120 − 180 = −0.25 dB
