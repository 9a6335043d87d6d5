"""The statistics layer on synthetic tables whose truth is known: a real effect is resolved with its sign, a null
effect is declared at about the nominal 5 % rate, pairing removes the scene effect, and the scenes × seeds
estimate gives about the power it promises."""

import math

import numpy as np
import pandas as pd
import pytest

from panorecon.evaluation import stats as S


def table(rng, scenes: int, seeds: int, effect: float, scene_sd=3.0, seed_sd=0.05, run_sd=0.05, other="row"):
    """A results frame of a reference row and ``other`` on ``scenes`` × ``seeds`` runs: scene difficulty
    (``scene_sd``), noise shared by both rows on one (scene, seed) (``seed_sd``: the teacher's noise, the held-out
    views) and each run's own noise (``run_sd``, unequal between scenes: scene s has (1 + s % 3) × run_sd), plus
    ``effect`` on ``other``."""
    recs = []
    for s in range(scenes):
        level = 28 + scene_sd * rng.standard_normal()
        for k in range(seeds):
            shared = seed_sd * rng.standard_normal()
            for label, d in (("ref", 0.0), (other, effect)):
                y = level + shared + d + (1 + s % 3) * run_sd * rng.standard_normal()
                recs.append({"label": label, "scene": f"s{s}", "seed": k, "psnr_ho": y, "lpips_ho": -y / 100})
    return pd.DataFrame(recs)


def declared(frame, column="psnr_ho"):
    c = S.compare(frame, column, "row", "ref")
    return c.verdict_these, c.verdict_new


def test_a_known_effect_is_resolved_with_its_sign_and_direction():
    rng = np.random.default_rng(1)
    up = table(rng, 2, 3, +0.5)
    assert declared(up)[0] == "better"
    assert declared(up, "lpips_ho")[0] == "better"  # lower LPIPS is better
    down = table(rng, 8, 3, -0.5)
    assert declared(down) == ("worse", "worse")
    assert declared(down, "lpips_ho") == ("worse", "worse")
    c = S.compare(down, "psnr_ho", "row", "ref")
    assert c.these.low < -0.5 < c.these.high and c.new.low < -0.5 < c.new.high and c.pairs == 24


def differences(rng, scenes: int, seeds: int, effect, run_sd=0.05) -> list[np.ndarray]:
    """Paired differences per scene as the model of ``table`` makes them (scene level and shared noise cancel):
    ``effect`` (a number, or one per scene) + the two runs' own noise, unequal between scenes."""
    effect = np.broadcast_to(effect, (scenes,))
    return [effect[s] + (1 + s % 3) * run_sd * np.sqrt(2) * rng.standard_normal(seeds) for s in range(scenes)]


def resolved(groups) -> tuple[bool, bool]:
    return tuple(S.verdict(iv, 1) in ("better", "worse") for iv in (S.these_scenes(groups), S.new_scenes(groups)))


@pytest.mark.parametrize("scenes, seeds", [(2, 3), (5, 2), (8, 1)])
def test_null_tables_declare_a_difference_at_about_the_nominal_rate(scenes, seeds):
    """400 tables with no effect (per-run noise of unequal size per scene)."""
    rng = np.random.default_rng(scenes)
    hits = np.mean([resolved(differences(rng, scenes, seeds, 0.0)) for _ in range(400)], axis=0)
    print(f"null rate {scenes} scenes x {seeds} seeds: these scenes {hits[0]:.3f}, new scenes {hits[1]:.3f}")
    assert seeds == 1 or 0.01 <= hits[0] <= 0.07  # one seed: no interval over seeds, so never declared
    assert 0.01 <= hits[1] <= 0.07


def test_the_full_table_path_pairs_runs_by_scene_and_seed():
    """compare() on whole results frames (scene difficulty and shared noise included): the same null rate."""
    rng = np.random.default_rng(2)
    hits = np.mean([[v != "not resolved" for v in declared(table(rng, 2, 3, 0.0))] for _ in range(100)], axis=0)
    print(f"null rate through compare(), 100 tables of 2 scenes x 3 seeds: {hits[0]:.2f}, {hits[1]:.2f}")
    assert hits[0] <= 0.1 and hits[1] <= 0.1
    frame = table(rng, 2, 3, 0.3).sample(frac=1, random_state=0)  # rows in any order
    d = S.paired_differences(frame, "psnr_ho", "row", "ref")
    assert len(d) == 6 and d["value"].mean() == pytest.approx(
        frame[frame.label == "row"].psnr_ho.mean() - frame[frame.label == "ref"].psnr_ho.mean()
    )
    assert d["value"].std() < 0.3  # pairs on (scene, seed): no scene difficulty left in them


def test_pairing_removes_the_scene_effect():
    rng = np.random.default_rng(3)
    frame = table(rng, 4, 3, 0.5, scene_sd=3.0)
    paired = S.compare(frame, "psnr_ho", "row", "ref")
    runs = {k: frame[frame["label"] == k]["psnr_ho"].to_numpy() for k in ("row", "ref")}
    unpaired = S.unpaired(runs["row"], runs["ref"])
    means = {k: frame[frame["label"] == k].groupby("scene")["psnr_ho"].mean().to_numpy() for k in ("row", "ref")}
    unpaired_scenes = S.unpaired(means["row"], means["ref"])
    assert paired.these.estimate == pytest.approx(unpaired.estimate)
    assert paired.these.half_width < unpaired.half_width / 10
    assert paired.new.half_width < unpaired_scenes.half_width / 10
    assert paired.verdict_these == "better" and S.verdict(unpaired, 1) == "not resolved"


def test_the_seeds_it_asks_for_give_about_80_percent_power():
    """needed_seeds from a well-measured spread (300 seeds), then 400 tables at that many seeds."""
    rng = np.random.default_rng(4)
    effect = 0.06
    k = S.needed_seeds(differences(rng, 2, 300, effect))
    assert 3 <= k <= 50
    power = np.mean([resolved(differences(rng, 2, k, effect))[0] for _ in range(400)])
    print(f"needed_seeds = {k}: power {power:.3f} at 2 scenes x {k} seeds")
    assert 0.7 <= power <= 0.95


def test_the_scenes_it_asks_for_give_about_80_percent_power():
    """An effect that differs between scenes (sd 0.1 around 0.1): needed_scenes from 300 scenes, then tables."""
    rng = np.random.default_rng(5)
    n = S.needed_scenes(differences(rng, 300, 2, 0.1 + 0.1 * rng.standard_normal(300)), 2)
    assert 4 <= n <= 40
    power = np.mean([resolved(differences(rng, n, 2, 0.1 + 0.1 * rng.standard_normal(n)))[1] for _ in range(400)])
    print(f"needed_scenes = {n}: power {power:.3f} at {n} scenes x 2 seeds")
    assert 0.7 <= power <= 0.9


def test_small_designs_say_what_they_need():
    one_seed = pd.DataFrame({"scene": ["a", "b"], "value": [0.1, 0.2]})
    iv = S.these_scenes(one_seed)
    assert iv.estimate == pytest.approx(0.15) and "needs seeds" in iv.reason
    assert S.verdict(iv, 1).startswith("n/a: one seed")
    assert S.new_scenes(one_seed.iloc[:1]).reason.startswith("one scene")
    exact = pd.DataFrame({"scene": ["a"] * 3, "value": [0.2] * 3})  # a stage the seeds do not change
    assert S.verdict(S.these_scenes(exact), -1) == "worse"
    assert S.verdict(S.Interval(1.0, 0.5, 1.5), 0) == "higher"


def test_the_stratified_interval_matches_the_textbook_cases():
    """One scene: the one-sample t interval; equal-size scenes with equal variances: the pooled t interval."""
    from scipy import stats

    rng = np.random.default_rng(6)
    x = rng.normal(size=5)
    ci = stats.ttest_1samp(x, 0).confidence_interval()
    iv = S.these_scenes(pd.DataFrame({"scene": ["a"] * 5, "value": x}))
    assert (iv.low, iv.high) == pytest.approx((ci.low, ci.high))
    two = pd.DataFrame({"scene": ["a"] * 4 + ["b"] * 4, "value": [0, 1, 2, 3, 10, 11, 12, 13]})
    iv = S.these_scenes(two)
    se = np.sqrt((np.var([0, 1, 2, 3], ddof=1) / 4) * 2) / 2
    h = stats.t.ppf(0.975, 6) * se
    assert iv.estimate == pytest.approx(6.5) and iv.df == pytest.approx(6) and iv.half_width == pytest.approx(h)


def test_a_scene_left_with_one_value_borrows_the_pooled_seed_variance():
    """A row whose other runs on a scene failed keeps its interval: that scene's variance is the pooled variance of
    the others, and the degrees of freedom are those of the variances that entered (here scene a's 3)."""
    from scipy import stats

    a = [0.0, 1.0, 2.0, 3.0]
    frame = pd.DataFrame({"scene": ["a"] * 4 + ["b"], "value": a + [10.0]})
    iv = S.these_scenes(frame)
    v = np.var(a, ddof=1)
    h = stats.t.ppf(0.975, 3) * np.sqrt((v / 4 + v / 1) / 4)
    assert iv.estimate == pytest.approx(5.75) and iv.df == pytest.approx(3) and iv.half_width == pytest.approx(h)
    assert S.needed_seeds(frame) is not None
    # every scene with one value: still no interval over seeds
    assert S.these_scenes(frame.iloc[[0, 4]]).reason.startswith("one seed")


# equivalence within a margin and the paper's size ruled out, on hand-made intervals


@pytest.mark.parametrize(
    "low, high, margin, expected",
    [
        (-0.03, 0.02, 0.1, True),  # inside ±0.1
        (-0.05, -0.01, 0.1, True),  # resolved, and still inside
        (-0.03, 0.12, 0.1, False),  # crosses +margin
        (-0.10, 0.05, 0.1, False),  # touches -margin: not strictly inside
        (-0.03, 0.02, 0.01, False),  # a smaller margin
        (-0.03, 0.02, None, False),  # no margin: no equivalence verdict
        (math.nan, math.nan, 0.1, False),  # no interval
    ],
)
def test_equivalent_when_the_interval_lies_inside_the_margin(low, high, margin, expected):
    assert S.equivalent(S.Interval((low + high) / 2, low, high), margin) is expected


@pytest.mark.parametrize(
    "low, high, paper, expected",
    [
        (-0.03, 0.02, -0.40, True),  # the paper's Fibonacci 20 vs icosahedron: excluded
        (-0.33, -0.19, -0.30, False),  # inside: consistent with the paper
        (-0.46, -0.33, -0.93, True),  # same sign, smaller than the paper's: still ruled out
        (-0.03, 0.02, math.nan, None),  # the paper reports no difference for this pair
        (math.nan, math.nan, -0.40, None),
    ],
)
def test_the_papers_size_is_ruled_out_when_the_interval_excludes_it(low, high, paper, expected):
    assert S.rules_out(S.Interval((low + high) / 2, low, high), paper) is expected


def _constant_pairs(d: list[float], scenes=4) -> pd.DataFrame:
    """Reference 30 dB and ``row`` 30 + d[k] dB on every scene, seed k (a tight, known interval around mean(d))."""
    recs = []
    for s in range(scenes):
        for k, dk in enumerate(d):
            recs += [
                {"label": "ref", "scene": f"s{s}", "seed": k, "psnr_pl": 30.0 + 0.01 * s},
                {"label": "row", "scene": f"s{s}", "seed": k, "psnr_pl": 30.0 + 0.01 * s + dk},
            ]
    return pd.DataFrame(recs)


def test_compare_reads_the_suites_margin_and_the_papers_difference():
    frame = _constant_pairs([0.01, -0.02, 0.0])
    c = S.compare(frame, "psnr_pl", "row", "ref", paper=-0.40)
    assert c.verdict_these == "not resolved" and c.margin == 0.1 and c.equivalent_these
    assert c.paper_ruled_out_these and c.says("these") == "equivalent (±0.1); paper's −0.40 ruled out"
    narrow = S.compare(frame, "psnr_pl", "row", "ref", margins={"psnr_pl": 0.001}, paper=-0.40)
    assert not narrow.equivalent_these and narrow.says("these") == "not resolved; paper's −0.40 ruled out"
    near = S.compare(frame, "psnr_pl", "row", "ref", paper=0.0)  # the paper's figure inside the interval
    assert near.paper_ruled_out_these is False and "paper" not in near.says("these")


def test_a_resolved_difference_smaller_than_the_margin_says_both():
    c = S.compare(_constant_pairs([-0.03, -0.04, -0.035]), "psnr_pl", "row", "ref")
    assert c.verdict_these == "worse" and c.says("these") == "worse, within ±0.1"
    assert S.margin_for("psnr_ho@300") == 0.1 and S.margin_for("lpips_pl") is None
    assert S.margin_for("lpips_pl", {"lpips_pl": 0.005}) == 0.005


@pytest.mark.parametrize("scenes, seeds", [(2, 3), (8, 3)])
def test_equivalence_is_declared_at_most_5_percent_of_the_time_when_the_truth_is_at_the_margin(scenes, seeds):
    """400 tables whose true difference equals the margin (either sign): equivalence must be rare (TOST's size)."""
    rng = np.random.default_rng(10 + scenes)
    margin = 0.1
    for sign in (1, -1):
        hits = []
        for _ in range(400):
            g = differences(rng, scenes, seeds, sign * margin)
            hits.append([S.equivalent(S.these_scenes(g), margin), S.equivalent(S.new_scenes(g), margin)])
        assert (np.mean(hits, axis=0) <= 0.05).all(), np.mean(hits, axis=0)
    # and at no difference, with a spread the margin can see past, it is declared: the check above can fail
    at_zero = [
        S.equivalent(S.these_scenes(differences(rng, scenes, seeds, 0.0, run_sd=0.01)), margin) for _ in range(100)
    ]
    assert np.mean(at_zero) >= 0.9
