"""How sure a table is: 95 % intervals of row means, paired differences to a reference row, verdicts, and the
number of scenes × seeds a difference would need (``docs/guide.md``, "Intervals and verdicts", says why these).

A suite's runs form a table ``y[row, scene, seed]``. A row's difference to the reference is taken run by run,
``d[scene, seed] = y[row, scene, seed] - y[reference, scene, seed]`` (same scene, same seed: the same teacher
noise and the same held-out views), and summarised as the mean over scenes of each scene's mean over seeds.
Two questions, two intervals (both Student t, float64):

- **these scenes** (scenes fixed, seeds random): could other seeds move the number? The stratified mean's
  standard error ``sqrt(sum_s v_s / n_s) / S`` (``v_s`` the sample variance over scene ``s``'s ``n_s`` seeds)
  with Welch-Satterthwaite degrees of freedom. Needs >= 2 seeds in some scene; a scene left with one (its other
  runs failed) takes the pooled within-scene variance. Also the interval of a row's own mean.
- **new scenes** (scenes random, seeds nested): would it hold on other scenes like these? A one-sample t
  interval over the per-scene means (``scipy.stats.ttest_1samp``), ``S - 1`` degrees of freedom: exact for
  normal scene effects at any number of seeds. Needs >= 2 scenes (2 scenes give 1 degree of freedom,
  t = 12.7: only a large, consistent difference is resolved).

A verdict is ``better`` / ``worse`` when the 95 % interval excludes 0 (by the metric's direction), else
``not resolved``; ``n/a: <reason>`` below a method's minimum. Two more statements say what an interval rules
out, whether or not it excludes 0:

- **equivalent** (within ``±margin``): the 95 % interval lies strictly inside ``(-margin, +margin)``, i.e. both
  one-sided tests ``H0: d <= -margin`` and ``H0: d >= +margin`` reject at 2.5 % each (TOST; its size is at most
  2.5 %, within the 5 % asked; ``eval/interval_null_rates.py`` checks it by simulation). The margin is per
  metric: a suite's ``margins`` table, else ``DEFAULT_MARGINS`` (0.1 dB for a PSNR).
- **the paper's size ruled out**: the 95 % interval excludes the paper's own difference for the same two rows.

``needed_*`` turn the observed spread into the smallest design that would resolve the observed difference with
80 % power at the 5 % level (``|d| >= (t_.975 + t_.80) * SE``, the usual t-based sample-size rule).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from scipy import stats

LEVEL = 0.95
POWER = 0.80
MAX_N = 1000  # designs searched up to this many seeds per scene / scenes

# metric column -> +1 higher is better, -1 lower is better, 0 no better direction (counts)
DIRECTION = {
    "psnr_pl": 1,
    "ssim_pl": 1,
    "lpips_pl": -1,
    "psnr_ho": 1,
    "ssim_ho": 1,
    "lpips_ho": -1,
    # held-out scores on the co-visible pixels (splat/evaluate.py); the oracle itself depends only on the scene and
    # the held-out views, never on the row, so it has no direction (its paired difference is 0)
    "heldout_covisible_psnr": 1,
    "heldout_oracle_gap": -1,
    "heldout_aligned_psnr": 1,
    "heldout_aligned_ssim": 1,
    "heldout_oracle_aligned_gap": -1,
    "abs_rel": -1,
    "rmse": -1,
    "delta1": 1,
    "chamfer": -1,
    "accuracy": -1,
    "completeness": -1,
    "fscore": 1,
    "sec_points": -1,
    "sec_train": -1,
    "sec_total": -1,
    "peak_mb": -1,
    "panoramas": 0,
    "points": 0,
    "gaussians": 0,
}


# metric -> equivalence margin in the metric's unit, when a suite states none. 0.1 dB of PSNR (2.3 % of the
# mean squared error) is below every difference the paper's claims rest on (0.17-0.93 dB) and about one seed's
# spread of one run on one scene (guide, "Intervals and verdicts"). Other metrics: only where a suite states one.
DEFAULT_MARGINS = {
    c: 0.1
    for c in (
        "psnr_pl",
        "psnr_ho",
        "heldout_covisible_psnr",
        "heldout_oracle_gap",
        "heldout_aligned_psnr",
        "heldout_oracle_aligned_gap",
    )
}  # every PSNR and every gap between two PSNRs, in dB


def margin_for(column: str, margins: dict | None = None) -> float | None:
    """The equivalence margin of ``column`` (a budget column ``psnr_ho@300`` as ``psnr_ho``): the suite's
    ``margins`` entry, else ``DEFAULT_MARGINS``'s; None when neither names it (no equivalence verdict)."""
    key = column.split("@")[0]
    return {**DEFAULT_MARGINS, **(margins or {})}.get(key)


@dataclass(frozen=True)
class Interval:
    """An estimate with its 95 % interval [low, high] (NaN with ``reason`` when the method cannot give one)."""

    estimate: float
    low: float = math.nan
    high: float = math.nan
    df: float = math.nan
    reason: str = ""

    @property
    def half_width(self) -> float:
        return (self.high - self.low) / 2


def _by_scene(values) -> list[np.ndarray]:
    """[scene, value] rows, or a list of per-scene value arrays -> one float64 array of finite values per scene
    (scenes in order of appearance; a scene without one is left out)."""
    if isinstance(values, pd.DataFrame):
        values = [g["value"] for _, g in values.groupby("scene", sort=False)]
    groups = [np.asarray(g, np.float64) for g in values]
    return [g[np.isfinite(g)] for g in groups if np.isfinite(g).any()]


def _seed_variances(groups: list[np.ndarray]) -> np.ndarray | None:
    """Each scene's sample variance over its seeds; a scene with one value (its other runs failed) takes the
    pooled within-scene variance of the others. None when no scene has two values."""
    multi = [g for g in groups if len(g) >= 2]
    if not multi:
        return None
    pooled = sum((len(g) - 1) * g.var(ddof=1) for g in multi) / sum(len(g) - 1 for g in multi)
    return np.array([g.var(ddof=1) if len(g) >= 2 else pooled for g in groups])


def these_scenes(values, level: float = LEVEL) -> Interval:
    """Mean over scenes of each scene's mean over seeds, with the stratified t interval (scenes fixed, seeds
    random). ``values``: columns scene, value (one row per run), or one array of values per scene. A scene with
    one value borrows the pooled variance of the scenes with two or more (``_seed_variances``); the degrees of
    freedom are Welch-Satterthwaite's over the independent per-scene variances that enter."""
    groups = _by_scene(values)
    if not groups:
        return Interval(math.nan, reason="no value")
    est = float(np.mean([g.mean() for g in groups]))
    v = _seed_variances(groups)
    if v is None:
        return Interval(est, reason="one seed: an interval over seeds needs seeds = [...] with >= 2")
    s, n = len(groups), np.array([len(g) for g in groups])
    se = math.sqrt(float(np.sum(v / n)) / s**2)
    if se == 0:  # the seeds do not change it: exact on these scenes
        return Interval(est, est, est, math.inf)
    # se^2 = sum over scenes with >= 2 values of c_s v_s: their own 1 / n_s, plus their share of the pooled
    # variance that the k one-value scenes use (weight (n_s - 1) / sum(n - 1) each)
    multi = n >= 2
    k, pooled_df = int((~multi).sum()), float(np.sum(n[multi] - 1))
    c = (1 / n[multi] + k * (n[multi] - 1) / pooled_df) / s**2
    terms = c * v[multi]
    df = terms.sum() ** 2 / np.sum(terms**2 / (n[multi] - 1))
    h = stats.t.ppf(0.5 + level / 2, df) * se
    return Interval(est, est - h, est + h, float(df))


def new_scenes(values, level: float = LEVEL) -> Interval:
    """Mean of the per-scene means with a one-sample t interval over scenes (scenes random, seeds nested)."""
    groups = _by_scene(values)
    if not groups:
        return Interval(math.nan, reason="no value")
    means = np.array([g.mean() for g in groups])
    est = float(means.mean())
    if len(means) < 2:
        return Interval(est, reason="one scene: an interval over scenes needs >= 2")
    if np.ptp(means) == 0:
        return Interval(est, est, est, len(means) - 1.0)
    ci = stats.ttest_1samp(means, 0.0).confidence_interval(level)
    return Interval(est, float(ci.low), float(ci.high), len(means) - 1.0)


def unpaired(a: np.ndarray, b: np.ndarray, level: float = LEVEL) -> Interval:
    """mean(a) - mean(b) with Welch's two-sample t interval, the runs taken as independent (no pairing)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    ci = stats.ttest_ind(a, b, equal_var=False).confidence_interval(level)
    return Interval(float(a.mean() - b.mean()), float(ci.low), float(ci.high))


def verdict(iv: Interval, direction: int) -> str:
    """better / worse / not resolved for a difference (row - reference) whose metric has ``direction``
    (+1 higher is better, -1 lower, 0 neither: then higher / lower); ``n/a: ...`` without an interval."""
    if math.isnan(iv.low):
        return f"n/a: {iv.reason}" if iv.reason else "n/a"
    if iv.low <= 0 <= iv.high:
        return "not resolved"
    up = iv.low > 0
    if direction == 0:
        return "higher" if up else "lower"
    return "better" if up == (direction > 0) else "worse"


def equivalent(iv: Interval, margin: float | None) -> bool:
    """True when the 95 % interval lies strictly inside (-margin, +margin) (two one-sided tests at 2.5 % each);
    False without an interval or a margin."""
    if margin is None or not (np.isfinite(iv.low) and np.isfinite(iv.high)):
        return False
    return -margin < iv.low and iv.high < margin


def rules_out(iv: Interval, value: float) -> bool | None:
    """Whether the 95 % interval excludes ``value`` (the paper's difference); None without an interval or a
    value to test."""
    if not (math.isfinite(value) and np.isfinite(iv.low) and np.isfinite(iv.high)):
        return None
    return not (iv.low <= value <= iv.high)


def direction(column: str) -> int:
    """+1 / -1 / 0 of ``column`` (``DIRECTION``; a budget column ``psnr_ho@300`` as ``psnr_ho``)."""
    return DIRECTION.get(column.split("@")[0], 0)


def mixed_code_pairs(frame: pd.DataFrame, label: str, reference: str) -> pd.Index:
    """(scene, seed) pairs where ``label``'s run and ``reference``'s were computed by different code (their
    ``code`` columns differ); empty without a ``code`` column."""
    if "code" not in frame:
        return pd.Index([])
    runs = frame[frame["label"].isin([label, reference])]
    codes = runs.pivot_table(index=["scene", "seed"], columns="label", values="code", aggfunc="first", sort=False)
    if label not in codes or reference not in codes:
        return pd.Index([])
    both = codes[[label, reference]].dropna()
    return both.index[both[label] != both[reference]]


def paired_differences(frame: pd.DataFrame, column: str, label: str, reference: str) -> pd.DataFrame:
    """Columns scene, seed, value = ``label``'s ``column`` minus ``reference``'s, on every (scene, seed) both
    have a finite value for and (with a ``code`` column) both were computed by the same code: a difference
    across two versions of the code is not a paired difference."""
    runs = frame[["label", "scene", "seed", column]].copy()
    runs[column] = pd.to_numeric(runs[column], errors="coerce")
    wide = runs.pivot_table(index=["scene", "seed"], columns="label", values=column, aggfunc="mean", sort=False)
    if label not in wide or reference not in wide:
        return pd.DataFrame({"scene": [], "seed": [], "value": []})
    d = (wide[label] - wide[reference]).dropna()
    d = d[~d.index.isin(mixed_code_pairs(frame, label, reference))]
    return pd.DataFrame({"scene": d.index.get_level_values(0), "seed": d.index.get_level_values(1), "value": d.values})


def _quantiles(df: float) -> float:
    return stats.t.ppf(0.5 + LEVEL / 2, df) + stats.t.ppf(POWER, df)


def needed_seeds(diffs) -> int | None:
    """Seeds per scene (on these scenes) for the observed mean difference to be resolved with 80 % power, from
    each scene's spread over seeds; None when there is no spread to go by or no difference."""
    groups = _by_scene(diffs)
    v = _seed_variances(groups)
    if v is None:
        return None
    est = abs(np.mean([g.mean() for g in groups]))
    if est == 0 or v.sum() == 0:
        return None if est == 0 else 2
    s = len(groups)
    for k in range(2, MAX_N + 1):
        se = math.sqrt(v.sum() / k) / s
        df = (k - 1) * v.sum() ** 2 / np.sum(v**2)
        if est >= _quantiles(df) * se:
            return k
    return MAX_N + 1


def needed_scenes(diffs, seeds: int) -> int | None:
    """Scenes (each run with ``seeds`` seeds) for the observed mean difference to be resolved across scenes with
    80 % power: a nested model, Var(scene mean) = between-scene variance + seed variance / seeds, its two parts
    estimated from the observed scene means and seeds (one seed: their sum). None with < 2 scenes or no
    difference."""
    groups = _by_scene(diffs)
    if len(groups) < 2:
        return None
    means = np.array([g.mean() for g in groups])
    est = abs(means.mean())
    if est == 0:
        return None
    n = np.array([len(g) for g in groups])
    v = _seed_variances(groups)
    within = float(np.mean(v)) if v is not None else 0.0
    between = max(0.0, means.var(ddof=1) - within * np.mean(1 / n))
    per_scene = between + within / seeds
    if per_scene == 0:
        return 2
    for s in range(2, MAX_N + 1):
        if est >= _quantiles(s - 1) * math.sqrt(per_scene / s):
            return s
    return MAX_N + 1


def _design(n: int | None, fixed: int, scenes_first: bool) -> str:
    if n is None:
        return "n/a"
    if n > MAX_N:
        return f"> {MAX_N}" + (f" × {fixed}" if scenes_first else "")
    return f"{n} × {fixed}" if scenes_first else f"{fixed} × {n}"


RESOLVED = ("better", "worse", "higher", "lower")


@dataclass(frozen=True)
class Comparison:
    """One row's paired difference to the reference on one metric, with what each interval rules out."""

    label: str
    column: str
    these: Interval
    new: Interval
    verdict_these: str  # better / worse / higher / lower / not resolved / n/a: ...
    verdict_new: str
    to_resolve_these: str  # "scenes × seeds" on these scenes
    to_resolve_new: str  # "scenes × seeds" across new scenes
    pairs: int
    margin: float | None = None  # the equivalence margin (metric's unit); None: no equivalence verdict
    equivalent_these: bool = False  # the interval lies inside ±margin
    equivalent_new: bool = False
    paper: float = math.nan  # the paper's own difference for the same two rows (NaN: it reports none)
    paper_ruled_out_these: bool | None = None  # the interval excludes ``paper`` (None: nothing to test)
    paper_ruled_out_new: bool | None = None

    def says(self, which: str) -> str:
        """The verdict of the ``"these"`` or ``"new"`` interval in words: ``not resolved``, ``worse``,
        ``equivalent (±0.1)``, ``worse, within ±0.1`` (resolved but smaller than the margin), then ``; paper's
        −0.40 ruled out`` where the interval excludes the paper's difference."""
        v, eq = getattr(self, f"verdict_{which}"), getattr(self, f"equivalent_{which}")
        if eq:
            m = f"{self.margin:g}"
            v = f"{v}, within ±{m}" if v in RESOLVED else f"equivalent (±{m})"
        if getattr(self, f"paper_ruled_out_{which}"):
            v += f"; paper's {self.paper:+.2f} ruled out".replace("-", "−")
        return v


def compare(
    frame: pd.DataFrame,
    column: str,
    label: str,
    reference: str,
    margins: dict | None = None,
    paper: float = math.nan,
) -> Comparison:
    """``label`` against ``reference`` on ``column``: both intervals, verdicts, the designs that would resolve the
    observed difference (scenes × seeds), equivalence within the column's margin (``margin_for(column,
    margins)``) and whether the paper's own difference ``paper`` (same two rows) is ruled out."""
    d = paired_differences(frame, column, label, reference)
    sign = direction(column)
    these, new = these_scenes(d), new_scenes(d)
    scenes = d["scene"].nunique()
    seeds = int(d.groupby("scene")["seed"].nunique().max()) if len(d) else 0
    margin = margin_for(column, margins)
    return Comparison(
        label,
        column,
        these,
        new,
        verdict(these, sign),
        verdict(new, sign),
        "resolved" if verdict(these, sign) in RESOLVED else _design(needed_seeds(d), scenes, False),
        "resolved" if verdict(new, sign) in RESOLVED else _design(needed_scenes(d, max(seeds, 1)), max(seeds, 1), True),
        len(d),
        margin,
        equivalent(these, margin),
        equivalent(new, margin),
        float(paper),
        rules_out(these, paper),
        rules_out(new, paper),
    )


def run_values(frame: pd.DataFrame, column: str, label: str | None = None) -> pd.DataFrame:
    """Columns scene, value: ``column`` of every run (of ``label``), as float (NaN for n/a)."""
    runs = frame if label is None else frame[frame["label"] == label]
    return pd.DataFrame({"scene": runs["scene"].values, "value": pd.to_numeric(runs[column], errors="coerce").values})
