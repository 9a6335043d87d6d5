"""The ablation harness end to end on a tiny suite: outputs, caching across runs, the Dask engine."""

import pandas as pd
import pytest

from panorecon.bench.command import compare
from panorecon.evaluation.ablate import run_suite
from panorecon.evaluation.suite import load_suite
from panorecon.metrics.lpips import lpips_or_reason

TINY = """
title = "tiny"
rows = ["source"]
[defaults]
width = 64
teacher = "sim:clean"
iters = 8
res = 16
labels = 6
heldout = 1
sh_degree = 0
history_every = 4
[grid]
scene = ["bedroom"]
source = ["fibonacci", "random"]
"""


def _run_tiny(tmp_path_factory, name: str, text: str):
    """(folder, suite, results frame) of the suite ``text`` run into folder/out."""
    d = tmp_path_factory.mktemp(name)
    (d / "tiny.toml").write_text(text)
    suite = load_suite(d / "tiny.toml")
    return d, suite, run_suite(suite, d / "out", jobs=2, progress=False)


@pytest.fixture(scope="module")
def first_run(tmp_path_factory):
    return _run_tiny(tmp_path_factory, "ablate", TINY)


def test_outputs_have_every_metric_with_time_and_memory(first_run):
    d, suite, frame = first_run
    csv = pd.read_csv(d / "out" / "results.csv")
    assert list(csv["source"]) == ["fibonacci", "random"]
    for col in (
        "psnr_pl",
        "ssim_pl",
        "psnr_ho",
        "abs_rel",
        "chamfer",
        "sec_points",
        "sec_train",
        "sec_total",
        "peak_mb",
        "commit",
        "version_torch",
    ):
        assert col in csv, col
    assert csv["psnr_pl"].notna().all() and (csv["peak_mb"] > 100).all() and (csv["sec_total"] > 0).all()
    assert csv.loc[0, "abs_rel"] < 0.2 and pd.isna(csv.loc[1, "abs_rel"])  # random points have no depth map
    assert set(csv["cached"]) == {"none"}
    md = (d / "out" / "results.md").read_text()
    assert "| fibonacci | 1 |" in md
    reason = lpips_or_reason(16)  # 16 px labels: below AlexNet's minimum, so a reason, never a number
    assert (csv["lpips_pl_note"] == reason).all() and csv["lpips_pl"].isna().all()
    assert "| n/a |" in md and reason in md.split("n/a cells: ")[1]
    assert (d / "out" / "pareto.png").stat().st_size > 10_000
    assert (d / "out" / "psnr_vs_iterations.png").is_file()
    # held-out PSNR against training seconds, per run, and its plot
    curve = [tuple(map(float, kv.split(":"))) for kv in csv.loc[0, "history_heldout"].split(";")]
    assert len(curve) == 2 and 0 < curve[0][0] < curve[1][0]
    assert curve[1][1] == pytest.approx(csv.loc[0, "psnr_ho"], abs=1e-3)
    assert (d / "out" / "heldout_psnr_vs_seconds.png").stat().st_size > 10_000
    page = (d / "out" / "report.html").read_text()
    # both plots, and per row render | label, render | held-out and a cloud screenshot
    assert page.count("data:image/png;base64,") == 2 + 2 * 3 and page.count("<div class=strip>") == 2


def test_second_run_reads_everything_from_results_csv_then_from_the_cache(first_run, tmp_path, capsys):
    d, suite, frame = first_run
    before = (d / "out" / "results.csv").read_bytes()
    capsys.readouterr()
    again = run_suite(suite, d / "out", jobs=1, progress=False)
    assert "0 in the stage cache, 2 in results.csv, 0 to run" in capsys.readouterr().out
    assert (d / "out" / "results.csv").read_bytes() == before  # rows read back are rewritten as they were
    assert list(again["cached"]) == list(frame["cached"])  # where the stages came from when they were computed
    pd.testing.assert_series_equal(again["psnr_pl"], frame["psnr_pl"])
    import shutil

    shutil.copytree(d / "out" / "cache", tmp_path / "cache")  # the same cache, no results.csv
    from_cache = run_suite(suite, tmp_path / "out", jobs=1, progress=False, cache_dir=tmp_path / "cache")
    assert set(from_cache["cached"]) == {"points,train"}
    pd.testing.assert_series_equal(from_cache["psnr_pl"], frame["psnr_pl"])


def test_verify_recomputes_committed_rows_and_finds_them_reproduced(first_run, tmp_path):
    from panorecon.evaluation.verify import pick_rows, seed_sd, verdict, verify_suites

    d, suite, frame = first_run
    before = (d / "out" / "results.csv").read_bytes()
    (text,) = verify_suites([suite], d / "out", k=1, jobs=1, threads=1)
    assert text == (d / "out" / "verify.md").read_text()
    lines = [line for line in text.splitlines() if line.startswith("| fibonacci | bedroom | 0 |")]
    assert {line.split(" | ")[4] for line in lines} >= {"psnr_pl", "psnr_ho", "abs_rel", "gaussians"}
    assert all(line.rstrip(" |").endswith("reproduced") for line in lines), text
    assert (d / "out" / "results.csv").read_bytes() == before  # nothing committed is touched
    # a difference is weighed by the seed spread: within 2.77 SDs drifted, beyond it changed
    assert verdict(30.0, 30.0, 0.1) == "reproduced" and verdict(30.0, 30.2, 0.1) == "drifted"
    assert verdict(0.02, 0.02 + 1e-9, 0.1) == "reproduced"  # float32 rounding
    records = {
        str(i): {"label": 120, "scene": s, "m": v}
        for i, (s, v) in enumerate([("a", 1), ("a", 3), ("b", 5), ("b", 5), ("c", 9)])
    }
    assert seed_sd(records, "120", "m") == pytest.approx(1.0)  # (2 * 1 + 0 * 1) / 2 df, one-seed scene left out
    assert verdict(30.0, 30.3, 0.1) == "changed beyond noise" and verdict(30.0, 30.1, float("nan")).startswith(
        "differs"
    )
    # the chosen rows cover the table rows first
    records = {r.run_id(): {"unavailable_note": float("nan")} for r in suite.rows}
    assert {r.label for r in pick_rows(suite.rows, records, 2)} == {"fibonacci", "random"}


def test_a_cached_row_keeps_the_commit_of_the_run_that_computed_it(first_run):
    d, suite, frame = first_run
    from panorecon.evaluation.ablate import result_row
    from panorecon.pipeline import StageCache

    cache = StageCache(d / "out" / "cache")
    row = suite.rows[0]
    pts, tr = cache.done("points", row.points_key()), cache.done("train", row.train_key())
    assert pts["commit"] == tr["commit"] == frame.loc[0, "commit"]
    later = result_row(row, pts, tr, {"commit": "a later commit", "versions": {}}, True, True)
    assert later["commit"] == tr["commit"]


def test_dask_engine_gives_the_same_points(first_run, tmp_path):
    d, _, frame = first_run
    (tmp_path / "pts.toml").write_text(TINY.replace("iters = 8", "train = false"))
    out = run_suite(load_suite(tmp_path / "pts.toml"), tmp_path / "out", jobs=1, engine="dask", progress=False)
    assert out.loc[0, "abs_rel"] == pytest.approx(frame.loc[0, "abs_rel"], rel=1e-9)
    assert "psnr_pl" not in out


def test_bench_compare_fails_on_regressions_and_warns_on_slowdowns():
    base = {
        "suite": {"fibonacci": {"abs_rel": 0.03, "psnr_pl": 21.0}},
        "fusion": {"abs_rel": 0.01, "speedup_vs_reference": 3.0},
        "rasterizer": {"speedup_cpu_vs_torch": 10.0, "max_abs_difference": {"image": 0, "grad_means": 0}},
    }
    same = {**base, "rasterizer": {**base["rasterizer"], "max_abs_difference": {"image": 1e-6, "grad_means": 1e-5}}}
    assert compare(same, base) == ([], [])
    worse = {
        **same,
        "suite": {"fibonacci": {"abs_rel": 0.2, "psnr_pl": 18.0}},
        "fusion": {"abs_rel": 0.01, "speedup_vs_reference": 1.0},
    }
    fails, warns = compare(worse, base)
    assert len(fails) == 2 and any("abs_rel" in f for f in fails) and any("psnr_pl" in f for f in fails)
    assert len(warns) == 1 and "fusion speedup" in warns[0]
    lost = {**same, "suite": {"fibonacci": {"psnr_pl": 21.0}}}
    assert any("no longer measured" in f for f in compare(lost, base)[0])
    drift = {**same, "rasterizer": {**same["rasterizer"], "max_abs_difference": {"image": 0.1, "grad_means": 0}}}
    assert any("rasterizer" in f for f in compare(drift, base)[0])


def test_a_source_that_cannot_run_here_reads_na_and_the_suite_goes_on(tmp_path, capsys):
    import pycolmap

    if pycolmap.has_cuda:
        pytest.skip("colmap-mvs runs here")
    (tmp_path / "s.toml").write_text(
        TINY.replace('source = ["fibonacci", "random"]', 'source = ["colmap-mvs", "random"]').replace(
            "iters = 8", "train = false"
        )
    )
    out = run_suite(load_suite(tmp_path / "s.toml"), tmp_path / "out", jobs=1, progress=False)
    assert out.loc[0, "unavailable_note"].startswith("n/a: needs a CUDA build of pycolmap")
    assert out.loc[1, "points"] == 100_000
    assert "n/a: needs a CUDA build" in (tmp_path / "out" / "results.md").read_text()
    # read again, the n/a row is as finished as any other; --retry-unavailable takes it again from the stages
    capsys.readouterr()
    run_suite(load_suite(tmp_path / "s.toml"), tmp_path / "out", jobs=1, progress=False)
    assert "0 in the stage cache, 2 in results.csv, 0 to run" in capsys.readouterr().out
    run_suite(load_suite(tmp_path / "s.toml"), tmp_path / "out", jobs=1, progress=False, retry_unavailable=True)
    assert "1 in the stage cache, 1 in results.csv, 0 to run" in capsys.readouterr().out


SEEDED = TINY.replace(
    'rows = ["source"]',
    'rows = ["source"]\nseeds = [0, 1]\nreference = { source = "fibonacci" }\nmargins = { chamfer = 100.0 }',
) + (
    '[paper]\ncolumns = ["PSNR"]\nrows = [{ label = "theirs", values = [30.0] }, '
    '{ label = "ours", values = [40.0], match = { source = "fibonacci" } }, '
    '{ label = "random", values = [39.9], match = { source = "random" } }]\n'
)


@pytest.fixture(scope="module")
def seeded_run(tmp_path_factory):
    return _run_tiny(tmp_path_factory, "seeded", SEEDED)


def test_a_suite_with_seeds_and_a_reference_runs_end_to_end(seeded_run):
    d, suite, frame = seeded_run
    csv = pd.read_csv(d / "out" / "results.csv")
    assert sorted(zip(csv["source"], csv["seed"])) == [("fibonacci", 0), ("fibonacci", 1), ("random", 0), ("random", 1)]
    assert list(csv.groupby("source")["reference"].all()) == [True, False]
    fib = csv[csv["source"] == "fibonacci"]
    assert fib["abs_rel"].nunique() == 2  # the teacher's noise differs between the seeds
    md = (d / "out" / "results.md").read_text()
    assert "| source | scenes × seeds |" in md and "| fibonacci | 1 × 2 |" in md and " ± " in md
    assert "## Against the reference: fibonacci" in md
    section = md.split("## Against the reference")[1]
    row = next(line for line in section.splitlines() if line.startswith("| random | "))
    # one scene: no interval across scenes; Chamfer of random points is far worse on both seeds
    assert "n/a: one scene" in row
    chamfer = md.split("Every metric, these scenes")[1]
    assert "worse, within ±100" in chamfer.split("| random |")[1].split("\n")[0]  # the suite's margin
    # the paper's random − fibonacci = −0.1 dB beside ours, on its protocol (pseudo-label PSNR)
    paper = md.split("The paper's own differences")[1].split("| random |")[1].split("\n")[0]
    assert paper.startswith(" −0.10 | ") and paper.rstrip().endswith(("ruled out on these scenes |", "consistent |"))
    page = (d / "out" / "report.html").read_text()
    assert "Against the reference: fibonacci" in page and " ± " in page


def test_from_csv_re_renders_the_same_tables_without_running(seeded_run, tmp_path):
    from panorecon.cli import main

    d, suite, frame = seeded_run
    csv = d / "out" / "results.csv"
    body = lambda p: (p / "results.md").read_text().split("## Averaged", 1)[1].split("## Per scene")[0]  # noqa: E731
    # with the suite file: its title, row header and reference; the same tables as the run wrote
    assert main(["ablate", str(d / "tiny.toml"), "--from-csv", str(csv), "--out", str(tmp_path / "s")]) == 0
    assert (tmp_path / "s" / "results.md").read_text().startswith("# tiny")
    assert body(tmp_path / "s") == body(d / "out")
    # the CSV alone: its reference column names the reference; rows are headed "row"
    assert main(["ablate", "--from-csv", str(csv), "--out", str(tmp_path / "re"), "--no-progress"]) == 0
    # (no suite: no [paper] figures and the default margins, so the tables up to the paired ones are the same)
    averaged = lambda p: body(p).split("## Against")[0]  # noqa: E731
    assert averaged(tmp_path / "re") == averaged(d / "out").replace("| source |", "| row |")
    assert "The paper's own differences" not in body(tmp_path / "re") and "within ±100" not in body(tmp_path / "re")
    assert not (tmp_path / "re" / "cache").exists()
    for name in ("pareto.png", "psnr_vs_iterations.png", "report.html", "results.csv"):
        assert (tmp_path / "re" / name).stat().st_size > 1000, name


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda f: f.drop(columns=["scene"]), "no column scene"),
        (lambda f: f[["label", "scene", "seed"]], "no metric column"),
        (lambda f: f.assign(seed="x"), "seed 'x' is not an integer"),
        (lambda f: f.assign(seed=0), "appears 2 times"),
        (lambda f: f.assign(reference=True), "reference marks 2 rows"),
    ],
)
def test_from_csv_refuses_a_bad_csv_with_one_line(seeded_run, tmp_path, capsys, edit, match):
    from panorecon.cli import main

    d, _, _ = seeded_run
    bad = tmp_path / "bad.csv"
    edit(pd.read_csv(d / "out" / "results.csv")).to_csv(bad, index=False)
    assert main(["ablate", "--from-csv", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert match in err and err.count("\n") == 1 and not (tmp_path / "o").exists()


def test_from_csv_never_overwrites_its_input(seeded_run, tmp_path, capsys):
    from panorecon.cli import main

    d, _, _ = seeded_run
    copy = tmp_path / "results.csv"
    copy.write_bytes((d / "out" / "results.csv").read_bytes())
    assert main(["ablate", "--from-csv", str(copy), "--out", str(tmp_path)]) == 2
    assert (
        "may not overwrite an input" in capsys.readouterr().err
        and copy.read_bytes() == (d / "out" / "results.csv").read_bytes()
    )
    assert not (tmp_path / "results.md").exists()
    (tmp_path / "empty.csv").write_text("")
    assert main(["ablate", "--from-csv", str(tmp_path / "empty.csv"), "--out", str(tmp_path / "o")]) == 2
    assert "not a CSV table" in capsys.readouterr().err
