"""How often each interval method declares a difference that is not there: null tables of paired differences
shaped like the suites (scenes × seeds), per-run noise of unequal size between scenes, no effect.

    python eval/interval_null_rates.py [--tables 400] [--shape 2x3 --shape 8x3] [--margin 0.1]

Prints JSON: per shape, the rate at which the 95 % interval excludes 0 for the methods of
``panorecon/evaluation/stats.py`` (stratified t over seeds, t over scene means) and for bootstraps over the
same differences (``scipy.stats.bootstrap`` BCa and percentile over the runs; a stratified percentile bootstrap
that resamples seeds within each scene, rliable's scheme). The nominal rate is 0.05. And the equivalence
verdict's error rate: on tables whose true difference is exactly the margin (+margin and -margin, half each),
how often each t interval lies inside ±margin (``stats.equivalent``); at most 0.05 is asked, TOST at 2.5 % a
side gives about 0.025.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
from scipy import stats

from panorecon.evaluation.environment import git_commit
from panorecon.evaluation.stats import equivalent, new_scenes, these_scenes


def differences(rng, scenes: int, seeds: int, sd: float = 0.07, effect: float = 0.0) -> list[np.ndarray]:
    """Paired differences ``effect`` + noise: scene s has noise sd × (1 + s % 3) (0: the null)."""
    return [effect + (1 + s % 3) * sd * rng.standard_normal(seeds) for s in range(scenes)]


def excludes_zero(low: float, high: float) -> bool:
    return not (low <= 0 <= high)


def rates(scenes: int, seeds: int, tables: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    hits = dict.fromkeys(["t_these_scenes", "t_new_scenes", "bootstrap_bca", "bootstrap_percentile"], 0)
    hits["bootstrap_stratified"] = 0
    for _ in range(tables):
        g = differences(rng, scenes, seeds)
        x = np.concatenate(g)
        for name, iv in (("t_these_scenes", these_scenes(g)), ("t_new_scenes", new_scenes(g))):
            hits[name] += bool(np.isfinite(iv.low)) and excludes_zero(iv.low, iv.high)
        for method in ("BCa", "percentile"):
            ci = stats.bootstrap((x,), np.mean, method=method, n_resamples=999, random_state=rng).confidence_interval
            hits[f"bootstrap_{method.lower()}"] += excludes_zero(ci.low, ci.high)
        boot = np.mean([rng.choice(gi, (999, len(gi))).mean(1) for gi in g], axis=0)
        hits["bootstrap_stratified"] += excludes_zero(*np.percentile(boot, [2.5, 97.5]))
    return {k: round(v / tables, 4) for k, v in hits.items()}


def equivalence_rates(scenes: int, seeds: int, tables: int, margin: float, seed: int = 0) -> dict:
    """How often each t interval declares equivalence within ±``margin`` when the true difference is ±margin."""
    rng = np.random.default_rng(seed)
    hits = {"t_these_scenes": 0, "t_new_scenes": 0}
    for i in range(tables):
        g = differences(rng, scenes, seeds, effect=margin if i % 2 else -margin)
        hits["t_these_scenes"] += equivalent(these_scenes(g), margin)
        hits["t_new_scenes"] += equivalent(new_scenes(g), margin)
    return {k: round(v / tables, 4) for k, v in hits.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tables", type=int, default=400)
    ap.add_argument("--shape", action="append", default=None, help="SCENESxSEEDS (default 2x3 and 8x3)")
    ap.add_argument("--margin", type=float, default=0.1, help="equivalence margin (the PSNR default, dB)")
    args = ap.parse_args()
    shapes = [tuple(map(int, s.split("x"))) for s in (args.shape or ["2x3", "8x3"])]
    out = {"commit": git_commit(), "tables": args.tables, "nominal": 0.05, "margin": args.margin}
    out["rates"] = {f"{s}x{k}": rates(s, k, args.tables) for s, k in shapes}
    out["equivalence_at_margin"] = {f"{s}x{k}": equivalence_rates(s, k, args.tables, args.margin) for s, k in shapes}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
