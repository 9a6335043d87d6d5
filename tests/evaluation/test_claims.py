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
    assert "default +0.13 [" in line and "(needs 1 × " in line
