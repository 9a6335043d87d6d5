"""eval/strategy_levers.py on a tiny run: its overrides reach the adaptive strategy the trainer builds, the
registry is restored afterwards, and a name that is not an AdaptiveStrategy field is one argparse error."""

import importlib.util
from pathlib import Path

import pytest

from panorecon.splat import strategy

spec = importlib.util.spec_from_file_location(
    "strategy_levers", Path(__file__).parents[2] / "eval" / "strategy_levers.py"
)
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)

TINY = ["--width", "128", "--iters", "12", "--res", "16", "--labels", "8"]


def test_overrides_reach_the_strategy_and_the_registry_is_restored(tmp_path, monkeypatch):
    built = []
    real = strategy.AdaptiveStrategy.__post_init__

    def spy(self):
        built.append(self)
        real(self)

    monkeypatch.setattr(strategy.AdaptiveStrategy, "__post_init__", spy)
    row = script.main(["bedroom", str(tmp_path / "a"), "threshold_end=0.25", "top_k=2", *TINY])
    assert row["overrides"] == {"threshold_end": 0.25, "top_k": 2} and row["strategy"] == "adaptive"
    ((s,),) = [built]
    assert (s.threshold_end, s.top_k, s.refine_stop) == (0.25, 2, 6)  # refine_stop is still the trainer's
    assert strategy.STRATEGIES["adaptive"] is strategy.AdaptiveStrategy
    assert row["gaussians"] > 0 and row["psnr_pl"] > 0


def test_a_field_that_is_not_the_adaptive_strategys_is_refused(tmp_path, capsys):
    with pytest.raises(SystemExit):
        script.main(["bedroom", str(tmp_path / "b"), "refine_stop=10", *TINY])
    assert "'refine_stop' is not an AdaptiveStrategy field" in capsys.readouterr().err
