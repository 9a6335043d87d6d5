"""eval/pareto_gaussians.py: held-out PSNR against Gaussians and seconds from a results.csv, the means it plots
being the report's averages."""

import importlib.util
from pathlib import Path

import pandas as pd
import pytest

spec = importlib.util.spec_from_file_location(
    "pareto_gaussians", Path(__file__).parents[2] / "eval" / "pareto_gaussians.py"
)
script = importlib.util.module_from_spec(spec)
spec.loader.exec_module(script)


def test_both_plots_and_their_means(tmp_path):
    rows = []
    for label, g, ho in (("old", 80_000, 30.0), ("new", 50_000, 29.0)):
        for scene, shift in (("bedroom", 2.0), ("beach", -2.0)):
            for seed in (0, 1):
                rows.append(
                    dict(
                        label=label,
                        scene=scene,
                        seed=seed,
                        psnr_ho=ho + shift + 0.1 * seed,
                        gaussians=g,
                        sec_total=60.0,
                    )
                )
    pd.DataFrame(rows).to_csv(tmp_path / "results.csv", index=False)
    out = script.main([str(tmp_path / "results.csv"), str(tmp_path / "p")])
    assert (tmp_path / "p_gaussians.png").stat().st_size > 10_000 and (tmp_path / "p_seconds.png").is_file()
    assert out["gaussians"]["new"]["gaussians"] == 50_000
    assert out["gaussians"]["old"]["psnr_ho"] == pytest.approx(30.05)
