"""results.md tables shaped like the paper's, and the plots: error against run time (Pareto), PSNR against steps."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd

from ..io import atomic_write

# (column, header, format) of the averaged table; a column absent from the frame (no training) is left out
TABLE_COLUMNS = [
    ("panoramas", "panoramas", "{:.0f}"),
    ("psnr_pl", "PSNR", "{:.2f}"),
    ("ssim_pl", "SSIM", "{:.3f}"),
    ("lpips_pl", "LPIPS", "{:.3f}"),
    ("psnr_ho", "held-out PSNR", "{:.2f}"),
    ("ssim_ho", "held-out SSIM", "{:.3f}"),
    # the held-out pixels the training panorama also sees (co-visible), the reprojection oracle there (the
    # training panorama's colour at the true points: the ceiling) and the gap between them (the part of the
    # error that is the method's to win); on other panoramas (real datasets) also after a per-view colour
    # alignment, where "held-out PSNR" itself is over the co-visible pixels
    ("heldout_covisible_psnr", "held-out PSNR, co-visible", "{:.2f}"),
    ("heldout_oracle_psnr", "oracle PSNR (ceiling)", "{:.2f}"),
    ("heldout_oracle_gap", "gap to oracle (dB)", "{:.2f}"),
    ("heldout_aligned_psnr", "held-out PSNR, colour-aligned", "{:.2f}"),
    ("heldout_aligned_ssim", "held-out SSIM, colour-aligned", "{:.3f}"),
    ("heldout_oracle_aligned_psnr", "oracle PSNR, colour-aligned", "{:.2f}"),
    ("heldout_oracle_aligned_gap", "gap to oracle, colour-aligned (dB)", "{:.2f}"),
    ("abs_rel", "AbsRel", "{:.4f}"),
    ("chamfer", "Chamfer (m)", "{:.4f}"),
    ("accuracy", "Acc. (m)", "{:.4f}"),
    ("completeness", "Comp. (m)", "{:.4f}"),
    ("points", "points", "{:,.0f}"),
    ("gaussians", "Gaussians", "{:,.0f}"),
    ("sec_points", "points s", "{:.1f}"),
    ("sec_train", "train s", "{:.1f}"),
    ("sec_total", "total s", "{:.1f}"),
    ("peak_mb", "peak MB", "{:.0f}"),
]


def pareto(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points not dominated in (x, y), both lower-is-better."""
    return [
        i for i, (s, e) in enumerate(points) if not any(s2 <= s and e2 <= e and (s2, e2) != (s, e) for s2, e2 in points)
    ]


def _fmt(v, f: str) -> str:
    return "n/a" if v is None or (isinstance(v, float) and math.isnan(v)) else f.format(v)


def _text(v) -> str:
    """A text cell of a results frame: "" for a missing one (NaN in a column read back from CSV)."""
    return v if isinstance(v, str) else ""


def with_seed(frame: pd.DataFrame) -> pd.DataFrame:
    """``frame`` with a ``seed`` column (0 where results predate seeds)."""
    return frame if "seed" in frame else frame.assign(seed=0)


def without_measurement(frame: pd.DataFrame) -> pd.Series:
    """Per run: True where it has no measurement, its ``unavailable_note`` saying why ("n/a: ..." cannot run
    here, "failed: ..." ran and gave nothing)."""
    if "unavailable_note" not in frame:
        return pd.Series(False, index=frame.index)
    return frame["unavailable_note"].map(_text) != ""


def average_table(frame: pd.DataFrame) -> pd.DataFrame:
    """Mean over scenes (each scene's mean over its seeds) of every numeric table column, one row per label (in
    the suite's order), with ``scenes``, ``seeds`` (most seeds of a scene), ``runs`` (all three counting runs
    with a measurement) and ``<column>_hw``: the half-width of the mean's 95 % interval over seeds with the
    scenes fixed (NaN with one seed, and for counts; ``stats.these_scenes``)."""
    from .stats import DIRECTION, run_values, these_scenes

    frame = with_seed(frame)
    cols = [c for c, *_ in TABLE_COLUMNS if c in frame]
    order = list(dict.fromkeys(frame["label"]))
    measured = frame[~without_measurement(frame)]
    rows = []
    for label in order:
        g = frame[frame["label"] == label]
        seeds = measured[measured["label"] == label].groupby("scene")["seed"].nunique()
        rec = {"scenes": len(seeds), "seeds": int(seeds.max()) if len(seeds) else 0, "runs": int(seeds.sum())}
        for c in cols:
            iv = these_scenes(run_values(g, c))
            # counts (points, Gaussians, panoramas) are shown without one
            rec[c], rec[f"{c}_hw"] = iv.estimate, iv.half_width if DIRECTION.get(c, 0) else math.nan
        rows.append(rec)
    return pd.DataFrame(rows, index=pd.Index(order, name="label"))


def design_cell(r) -> str:
    """The "scenes × seeds" cell of an ``average_table`` row, with its runs where some (scene, seed) has none."""
    seeds = int(r.get("seeds", 1)) if "seeds" in r and r["seeds"] == r["seeds"] else 1
    cell = f"{int(r['scenes'])} × {seeds}" if seeds > 1 else str(int(r["scenes"]))
    runs = r.get("runs", math.nan)
    return cell + f" ({int(runs)} runs)" if runs == runs and runs < int(r["scenes"]) * seeds else cell


def markdown_table(table: pd.DataFrame, label_header: str) -> str:
    """A table of ``average_table``: "mean ± half-width" where there is an interval."""
    heads = [(c, h, f) for c, h, f in TABLE_COLUMNS if c in table]
    seeded = "seeds" in table and (table["seeds"] > 1).any()
    lines = [
        "| " + " | ".join([label_header, "scenes × seeds" if seeded else "scenes"] + [h for _, h, _ in heads]) + " |",
        "|" + "---|" * (len(heads) + 2),
    ]
    for label, r in table.iterrows():
        trained = {c: not math.isnan(r.get(c.replace("lpips", "psnr"), math.nan)) for c, _, _ in heads}
        cells = []
        for c, _, f in heads:
            # a trained row without LPIPS: "n/a", its reason listed under the table ("n/a cells: ...")
            cell = "n/a" if c.startswith("lpips") and math.isnan(r[c]) and trained[c] else _fmt(r[c], f)
            hw = r.get(f"{c}_hw", math.nan)
            if cell != "n/a" and not math.isnan(hw):
                cell += f" ± {_fmt(hw, f)}"
            cells.append(cell)
        lines.append("| " + " | ".join([str(label), design_cell(r)] + cells) + " |")
    return "\n".join(lines)


def primary_metric(frame: pd.DataFrame) -> tuple[str, str, bool] | None:
    """(column, axis label, higher is better) of the number a suite is judged by: held-out PSNR, else
    pseudo-label PSNR (rows that train), else AbsRel; None when no run has any of them."""
    for col, name, hib in (
        ("psnr_ho", "held-out PSNR (dB)", True),
        ("psnr_pl", "pseudo-label PSNR (dB)", True),
        ("abs_rel", "AbsRel (median-aligned)", False),
    ):
        if col in frame and pd.to_numeric(frame[col], errors="coerce").notna().any():
            return col, name, hib
    return None


def _diff_cell(iv, fmt: str, v: str) -> str:
    if math.isnan(iv.estimate):
        return "n/a"
    est = fmt.format(iv.estimate).replace("-", "−")
    if math.isnan(iv.low):
        return f"{est} ({v})"
    return f"{'+' if iv.estimate >= 0 else ''}{est} ± {fmt.format(iv.half_width)} {v}"


def paper_difference(paper: dict | None, column: str, label: str, reference: str) -> float:
    """The paper's own difference ``label − reference`` on ``column`` (``Suite.paper_figures``: metric ->
    {label: value}; a budget column as its metric); NaN when the paper has no figure for either row."""
    figs = (paper or {}).get(column.split("@")[0], {})
    return figs[label] - figs[reference] if label in figs and reference in figs else math.nan


def comparison_rows(
    frame: pd.DataFrame, reference: str, column: str, margins: dict | None = None, paper: dict | None = None
) -> list:
    """``stats.compare`` of every other label against ``reference`` on ``column`` (suite order), with the
    suite's equivalence ``margins`` and the paper's difference for each pair (``paper_difference``)."""
    from .stats import compare

    return [
        compare(frame, column, label, reference, margins, paper_difference(paper, column, label, reference))
        for label in dict.fromkeys(frame["label"])
        if label != reference
    ]


COMPARISON_NOTE = (
    "Paired differences (row − {ref}, run by run on the same scene and seed: the same teacher noise and "
    "held-out views) with 95 % intervals. *These scenes*: scenes fixed, seeds resampled (could other seeds "
    "change it?). *New scenes*: scenes as a sample, seeds nested (would it hold on other scenes like these?). "
    "*Equivalent (±m)*: the interval lies inside ±m, the suite's margin for that metric (TOST at 2.5 % a side); "
    "*within ±m*: resolved, but smaller than the margin. *Paper's … ruled out*: the interval excludes the "
    "paper's own difference for the same two rows. *To resolve*: scenes × seeds that would resolve the observed "
    "difference with 80 % power, from the observed spread. Method: `panorecon/evaluation/stats.py`, "
    "docs/guide.md (Intervals and verdicts)."
)


def comparison_tables(
    frame: pd.DataFrame,
    reference: str,
    label_header: str,
    margins: dict | None = None,
    paper: dict | None = None,
) -> list[tuple[list, list]]:
    """The "against the reference" tables as (headers, rows of cells): the primary metric's paired differences
    on these scenes and across new scenes, with verdicts and the scenes × seeds that would resolve them; then
    every metric with a direction, on these scenes; then, where the paper reports both rows (``paper``:
    ``Suite.paper_figures``), its difference beside ours on its protocol (pseudo-label PSNR) and whether ours
    rules it out. ``margins``: the suite's equivalence margins. Empty when the frame has no such metric or no
    reference."""
    from .stats import DIRECTION

    frame = with_seed(frame)
    prim = primary_metric(frame)
    if prim is None or reference not in set(frame["label"]):
        return []
    col, name, _ = prim
    fmt = dict((c, f) for c, _, f in TABLE_COLUMNS).get(col, "{:.4g}")
    heads = [
        (c, h, f)
        for c, h, f in TABLE_COLUMNS
        if c in frame and DIRECTION.get(c, 0) != 0 and pd.to_numeric(frame[c], errors="coerce").notna().any()
    ]
    # every metric's comparisons once; the primary metric (one of them) heads the first table
    metrics = dict.fromkeys([col, *(c for c, _, _ in heads)])
    per_metric = {c: comparison_rows(frame, reference, c, margins, paper) for c in metrics}
    first = (
        [label_header, f"{name}: Δ these scenes", "to resolve", "Δ new scenes", "to resolve"],
        [
            [
                c.label,
                _diff_cell(c.these, fmt, c.says("these")),
                c.to_resolve_these,
                _diff_cell(c.new, fmt, c.says("new")),
                c.to_resolve_new,
            ]
            for c in per_metric[col]
        ],
    )
    labels = [label for label in dict.fromkeys(frame["label"]) if label != reference]
    every = (
        [label_header] + [h for _, h, _ in heads],
        [
            [label] + [_diff_cell(per_metric[c][i].these, f, per_metric[c][i].says("these")) for c, _, f in heads]
            for i, label in enumerate(labels)
        ],
    )
    tables = [first, every]
    against_paper = [c for c in per_metric.get("psnr_pl", []) if not math.isnan(c.paper)]
    if against_paper:
        tables.append(
            (
                [label_header, "paper's Δ PSNR", "ours: Δ these scenes", "ours: Δ new scenes", "paper's size"],
                [
                    [
                        c.label,
                        f"{c.paper:+.2f}".replace("-", "−"),
                        _diff_cell(c.these, "{:.2f}", c.verdict_these),
                        _diff_cell(c.new, "{:.2f}", c.verdict_new),
                        paper_size_cell(c),
                    ]
                    for c in against_paper
                ],
            )
        )
    return tables


def paper_size_cell(c) -> str:
    """Whether a comparison's intervals rule out the paper's own difference: "ruled out (these and new
    scenes)", "ruled out on these scenes", "consistent", or "n/a" without an interval."""
    these, new = c.paper_ruled_out_these, c.paper_ruled_out_new
    if these is None and new is None:
        return "n/a"
    if these and new:
        return "ruled out (these and new scenes)"
    if these or new:
        return "ruled out on " + ("these" if these else "new") + " scenes"
    return "consistent"


def _markdown(headers: list, rows: list) -> str:
    return "\n".join(
        ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
        + ["| " + " | ".join(map(str, r)) + " |" for r in rows]
    )


PAPER_NOTE = (
    "The paper's own differences (row − {ref} in its table: pseudo-label PSNR on its own scenes) against ours on the "
    "same protocol: *ruled out* where our 95 % interval excludes the paper's figure."
)


def comparison_markdown(
    frame: pd.DataFrame, reference: str, label_header: str, margins: dict | None = None, paper: dict | None = None
) -> str:
    """The "against the reference" section of results.md (``comparison_tables``)."""
    tables = comparison_tables(frame, reference, label_header, margins, paper)
    if not tables:
        return ""
    parts = [
        f"## Against the reference: {reference}",
        COMPARISON_NOTE.format(ref=reference),
        _markdown(*tables[0]),
        "Every metric, these scenes (lower is better for LPIPS, the gaps to the oracle, AbsRel, Chamfer, Acc., "
        "Comp., seconds and MB):",
        _markdown(*tables[1]),
    ]
    if len(tables) > 2:
        parts += [PAPER_NOTE.format(ref=reference), _markdown(*tables[2])]
    return "\n\n".join(parts)


def _paper_block(paper: dict) -> str:
    if not paper:
        return ""
    cols = paper.get("columns", [])
    lines = [
        f"**The paper's own numbers, on its own generated scenes** ({paper.get('caption', '')}; not comparable "
        "run for run: other scenes, an RTX 3090, 10,000 iterations):",
        "",
        "| " + " | ".join(["row"] + cols) + " |",
        "|" + "---|" * (len(cols) + 1),
    ]
    for r in paper.get("rows", []):
        match = r.get("match")
        label = r["label"] + (f" (ours: {', '.join(f'{k}={v}' for k, v in match.items())})" if match else "")
        lines.append("| " + " | ".join([label] + [str(v) for v in r["values"]]) + " |")
    return "\n".join(lines)


BUDGET_METRICS = ("psnr_pl", "ssim_pl", "lpips_pl", "psnr_ho", "ssim_ho", "lpips_ho", "sec_train", "gaussians")


def budget_steps(frame: pd.DataFrame) -> list[int]:
    """The training steps every trained run of ``frame`` was fully evaluated at (``psnr_ho@N`` or ``psnr_pl@N``
    columns with a value in every row that has a final one), ascending."""
    steps = sorted({int(c.split("@")[1]) for c in frame.columns if c.startswith(("psnr_ho@", "psnr_pl@"))})
    if not steps or "psnr_pl" not in frame:
        return []
    trained = frame[pd.to_numeric(frame["psnr_pl"], errors="coerce").notna()]
    return [
        n
        for n in steps
        if len(trained)
        and any(f"{m}@{n}" in trained and trained[f"{m}@{n}"].notna().all() for m in ("psnr_ho", "psnr_pl"))
    ]


def at_budget(frame: pd.DataFrame, step: int) -> pd.DataFrame:
    """``frame`` with its metric columns read at training step ``step`` (``psnr_ho@step`` as ``psnr_ho``, ...);
    rows without that budget keep NaN."""
    out = frame.copy()
    for m in BUDGET_METRICS:
        out[m] = pd.to_numeric(frame[f"{m}@{step}"], errors="coerce") if f"{m}@{step}" in frame else math.nan
    return out


def budget_markdown(
    frame: pd.DataFrame,
    reference: str | None,
    label_header: str,
    margins: dict | None = None,
    paper: dict | None = None,
) -> str:
    """The "At each training budget" section of results.md: per step, every row's mean (95 % interval over seeds)
    and, with a reference, its paired difference on these scenes and on new scenes with verdicts (equivalence
    within the suite's ``margins``; the paper's difference where it reports both rows); '' when the runs record
    fewer than two budgets."""
    steps = budget_steps(frame)
    if len(steps) < 2:
        return ""
    has_heldout = any(f"psnr_ho@{n}" in frame and frame[f"psnr_ho@{n}"].notna().any() for n in steps)
    prim = "psnr_ho" if has_heldout else "psnr_pl"
    name = "held-out PSNR (dB)" if prim == "psnr_ho" else "pseudo-label PSNR (dB)"
    parts = [
        "## At each training budget",
        "",
        f"Every run evaluated in full at {', '.join(f'{n:,}' for n in steps)} steps (one run per cell, read at "
        "each budget, so an advantage that is early-only shows as a difference that shrinks). Train s: training "
        f"seconds to that step (median over runs). Δ: paired difference of {name} to the reference, as above. "
        "Plot: `paired_vs_seconds.png`.",
        "",
    ]
    headers = [label_header, name, "SSIM" if prim == "psnr_ho" else "", "train s"]
    headers = [h for h in headers if h]
    if reference:
        headers += ["Δ these scenes", "Δ new scenes"]
    for n in steps:
        b = at_budget(frame, n)
        table = average_table(b)
        comps = {c.label: c for c in comparison_rows(b, reference, prim, margins, paper)} if reference else {}
        rows = []
        for label, r in table.iterrows():
            cell = _fmt(r[prim], "{:.2f}") + (f" ± {r[f'{prim}_hw']:.2f}" if not math.isnan(r[f"{prim}_hw"]) else "")
            ssim_col = prim.replace("psnr", "ssim")
            cells = [str(label), cell]
            if prim == "psnr_ho":
                cells.append(_fmt(r.get(ssim_col, math.nan), "{:.3f}"))
            sec = pd.to_numeric(b.loc[b["label"] == label, "sec_train"], errors="coerce").median()
            cells.append(_fmt(sec, "{:.1f}"))
            if reference:
                c = comps.get(label)
                cells += (
                    ["reference", "reference"]
                    if c is None
                    else [_diff_cell(c.these, "{:.2f}", c.says("these")), _diff_cell(c.new, "{:.2f}", c.says("new"))]
                )
            rows.append(cells)
        parts += [f"### Step {n:,}", "", _markdown(headers, rows), ""]
    return "\n".join(parts)


def mixed_code_notes(frame: pd.DataFrame) -> list[str]:
    """One line per (scene, seed) block whose runs were computed by more than one version of the code (the
    ``code`` column): their pairs across versions are left out of every paired comparison."""
    if "code" not in frame:
        return []
    notes = []
    for (scene, seed), g in with_seed(frame).groupby(["scene", "seed"], sort=False):
        codes = list(dict.fromkeys(g["code"].dropna().astype(str)))
        if len(codes) > 1:
            notes.append(
                f"**Mixed code** in block ({scene}, seed {seed}): its runs were computed by code "
                f"{', '.join(codes)}; pairs across versions are left out of the paired comparisons "
                "(rerun the block to pair them)."
            )
    return notes


def provenance_markdown(frame: pd.DataFrame) -> str:
    """What computed the table: the commits (and code digests) of its runs, the device, the library versions and
    the total compute (CPU hours of the point and training stages, their wall hours, the load average range at
    the start of the training stages). Columns a results.csv lacks are left out."""

    def counted(col: str) -> str | None:
        if col not in frame or frame[col].dropna().empty:
            return None
        counts = frame[col].dropna().astype(str).value_counts()
        return ", ".join(f"`{v}` ({n})" for v, n in counts.items())

    lines = []
    for col, what in (("commit", "commits"), ("code", "code digests"), ("device_name", "device")):
        said = counted(col)
        if said:
            lines.append(f"- {what} (runs): {said}")
    versions = [c for c in frame.columns if c.startswith("version_")]
    if versions:
        said = "; ".join(
            f"{c.removeprefix('version_')} {', '.join(sorted(frame[c].dropna().astype(str).unique()))}"
            for c in versions
        )
        lines.append(f"- versions: {said}")
    cpu = [c for c in ("cpu_points", "cpu_train") if c in frame]
    wall = [c for c in ("sec_points", "sec_train", "sec_eval") if c in frame]
    if cpu:
        runs = frame[frame[cpu].notna().any(axis=1)]
        total = f"- compute: {len(runs)} runs, {runs[cpu].sum().sum() / 3600:.2f} CPU hours"
        if wall:
            total += f", {runs[wall].sum().sum() / 3600:.2f} wall hours of their stages"
        if "load_train" in frame and frame["load_train"].notna().any():
            total += (
                f"; load average at the training stages' start {frame['load_train'].min():.1f}–"
                f"{frame['load_train'].max():.1f}"
            )
        lines.append(total)
    return "## Provenance\n\n" + "\n".join(lines) if lines else ""


def failed_runs_markdown(frame: pd.DataFrame) -> str:
    """The runs that ran and gave nothing ("failed: ..." notes), grouped by row and scene with their seeds; ""
    when none failed."""
    if "unavailable_note" not in frame:
        return ""
    frame = with_seed(frame)
    notes = frame["unavailable_note"].map(_text)
    failed = frame[notes.str.startswith("failed:")]
    if not len(failed):
        return ""
    lines = ["Failed runs (no measurement; left out of the means and of the paired differences):", ""]
    for (label, scene, note), g in failed.groupby(["label", "scene", "unavailable_note"], sort=False):
        seeds = ", ".join(str(int(x)) for x in sorted(g["seed"]))
        lines.append(f"- {label}, {scene}, seed{'s' if len(g) > 1 else ''} {seeds}: {note.removeprefix('failed: ')}")
    return "\n".join(lines)


def write_results_md(frame: pd.DataFrame, suite, out: Path, wall_seconds: float, per_scene: bool = True) -> None:
    """DIR/results.md: the averaged table, the per-scene table, the paper's numbers, notes on n/a cells."""
    frame = with_seed(frame)
    seeds = sorted(set(frame["seed"]))
    cached = sorted(set(frame["cached"].astype(str))) if "cached" in frame else ["unrecorded"]
    head = " / ".join(suite.row_columns)
    reference = getattr(suite, "reference", None)
    parts = [
        f"# {suite.title}",
        "",
        f"Suite `{suite.path}`; {len(frame)} runs over {frame['scene'].nunique()} scenes and {len(seeds)} seed"
        f"{'s' if len(seeds) > 1 else ''} ({', '.join(map(str, seeds))}); this invocation took "
        f"{wall_seconds:.1f} s (cached stages: {', '.join(cached)}). PSNR/SSIM/LPIPS "
        "without a prefix are the pseudo-label protocol (the paper's); held-out = true renders away from the "
        "panorama centre. Seconds and peak MB are those of the process that computed each stage.",
        "",
        "## Averaged over scenes" + (" and seeds" if len(seeds) > 1 else ""),
        "",
        (
            "Mean ± half-width of its 95 % interval over seeds, the scenes fixed (Student t, stratified by scene).\n\n"
            if len(seeds) > 1
            else ""
        )
        + markdown_table(average_table(frame), head),
        "",
    ]
    margins, paper = suite.margins, suite.paper_figures()
    if reference:
        parts += [comparison_markdown(frame, reference, head, margins, paper), ""]
    budgets = budget_markdown(frame, reference, head, margins, paper)
    if budgets:
        parts += [budgets, ""]
    for note in mixed_code_notes(frame):
        parts += [note, ""]
    provenance = provenance_markdown(frame)
    if provenance:
        parts += [provenance, ""]
    failed = failed_runs_markdown(frame)
    if failed:
        parts += [failed, ""]
    notes = sorted(
        {
            v
            for c in frame.columns
            if c.endswith("_note")
            for v in frame[c].dropna().unique()
            if not str(v).startswith("failed:")  # listed above, with their seeds
        }
    )
    if notes:
        parts += ["n/a cells: " + "; ".join(notes), ""]
    if "warning" in frame:
        flagged = frame[frame["warning"].map(_text) != ""]
        for _, r in flagged.iterrows():
            parts += [f"**WARNING** ({r['label']}, {r['scene']}): {r['warning']}", ""]
    paper = _paper_block(suite.paper)
    if paper:
        parts += [paper, ""]
    if per_scene:
        parts += ["## Per scene", ""]
        for scene, g in frame.groupby("scene", sort=False):
            parts += [f"### {scene}", "", markdown_table(average_table(g), head), ""]
    parts += [
        "Plots: `pareto.png` (error against run time), `psnr_vs_iterations.png` (when rows train), "
        "`heldout_psnr_vs_seconds.png` (when they have held-out views).",
        "",
    ]
    with atomic_write(out / "results.md") as tmp:
        Path(tmp).write_text("\n".join(parts))


# label positions tried in turn, in points from the marker: right above, right below, left above, left below,
# then three times as far up or down
_LABEL_OFFSETS = [
    (4, 5, "left", "bottom"),
    (4, -5, "left", "top"),
    (-4, 5, "right", "bottom"),
    (-4, -5, "right", "top"),
]
_LABEL_OFFSETS += [(dx, 3 * dy, ha, va) for dx, dy, ha, va in _LABEL_OFFSETS]


def _annotate(ax, point: tuple[float, float, str, str], offset: tuple, fontsize: float, renderer):
    """-> (annotation of ``point`` = (x, y, text, colour) at ``offset``, its box in display pixels)."""
    x, y, text, colour = point
    dx, dy, ha, va = offset
    t = ax.annotate(text, (x, y), xytext=(dx, dy), textcoords="offset points", ha=ha, va=va)
    t.set(fontsize=fontsize, color=colour)
    return t, t.get_window_extent(renderer)


def place_labels(ax, points: list[tuple[float, float, str, str]], fontsize: float) -> list:
    """Label each (x, y, text, colour) at the first of ``_LABEL_OFFSETS`` whose text box stays inside the axes and
    overlaps no marker and no label placed before it (points taken left to right; the first offset when none is
    free). Call once the axes' limits and layout are final: the boxes are measured in display pixels. -> the
    annotations."""
    from matplotlib.transforms import Bbox

    ax.autoscale_view()
    renderer = ax.figure.canvas.get_renderer()
    frame = ax.get_window_extent(renderer)
    at = ax.transData.transform([(p[0], p[1]) for p in points]) if points else []
    markers = [Bbox.from_extents(u - 4, v - 4, u + 4, v + 4) for u, v in at]  # every point's marker, ~8 px
    boxes, texts = [], []
    for point in sorted(points, key=lambda p: (p[0], p[1])):
        for offset in _LABEL_OFFSETS:
            t, box = _annotate(ax, point, offset, fontsize, renderer)
            inside = frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1
            if inside and not any(box.overlaps(b) for b in boxes + markers):
                break
            t.remove()
        else:  # nowhere free: the first position
            t, box = _annotate(ax, point, _LABEL_OFFSETS[0], fontsize, renderer)
        boxes.append(box)
        texts.append(t)
    return texts


def pareto_plot(
    mean: pd.DataFrame,
    per_run: pd.DataFrame,
    x: str,
    y: str,
    ylabel: str,
    path: Path,
    higher_is_better: bool = False,
    title: str = "",
    label_col: str = "label",
    xlabel: str = "seconds",
) -> None:
    """Two panels of y against x (log ``xlabel``, seconds by default): every run coloured by scene and labelled
    (left), and the per-label means over scenes with their Pareto front (right), with 95 % error bars where
    ``mean`` has ``<x>_hw`` / ``<y>_hw`` half-widths (``average_table``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, (ax_runs, ax_mean) = plt.subplots(1, 2, figsize=(13, 5.2))
    run_labels = []  # (x, y, text, colour), placed once the layout is final
    for k, (scene, g) in enumerate(per_run.groupby("scene", sort=False) if "scene" in per_run else [("runs", per_run)]):
        ax_runs.scatter(g[x], g[y], s=18, color=f"C{k}", label=str(scene))
        run_labels += [(r[x], r[y], str(r[label_col]), f"C{k}") for _, r in g.iterrows()]
    ax_runs.set(xlabel=f"{x} ({xlabel}, log)", ylabel=ylabel, xscale="log", title="every run, by scene")
    ax_runs.legend(fontsize=7)
    sign = -1 if higher_is_better else 1
    pts = list(zip(mean[x], sign * mean[y]))
    front = pareto(pts)
    for i, (_, r) in enumerate(mean.iterrows()):
        ax_mean.scatter(r[x], r[y], s=40, color="C3" if i in front else "C0", zorder=3)
        xe, ye = r.get(f"{x}_hw", math.nan), r.get(f"{y}_hw", math.nan)
        if not (math.isnan(xe) and math.isnan(ye)):
            ax_mean.errorbar(
                r[x],
                r[y],
                xerr=None if math.isnan(xe) else [[min(xe, 0.999 * r[x])], [xe]],  # log axis: stay above 0
                yerr=None if math.isnan(ye) else ye,
                fmt="none",
                ecolor="C3" if i in front else "C0",
                elinewidth=1,
                capsize=3,
                zorder=2,
            )
    fp = sorted((mean[x].iloc[i], mean[y].iloc[i]) for i in front)
    ax_mean.plot([p[0] for p in fp], [p[1] for p in fp], "C3--", lw=1.2, label="Pareto front (red)")
    ax_mean.set(
        xlabel=f"{x} ({xlabel}, log; mean over scenes)",
        ylabel=f"{ylabel}, mean over scenes",
        xscale="log",
        title="averaged"
        + (" (bars: 95 % interval over seeds)" if f"{y}_hw" in mean and mean[f"{y}_hw"].notna().any() else ""),
    )
    ax_mean.legend(fontsize=8)

    class PlainLogFormatter(matplotlib.ticker.LogFormatter):
        """LogFormatter's choice of which ticks to label, written as plain numbers (0.3, 20) not 3e-01 or 2×10¹."""

        def __call__(self, x, pos=None):
            return f"{x:g}" if super().__call__(x, pos) else ""

    for ax in (ax_runs, ax_mean):
        ax.xaxis.set_major_formatter(PlainLogFormatter(labelOnlyBase=False))
        ax.xaxis.set_minor_formatter(PlainLogFormatter(labelOnlyBase=False, minor_thresholds=(2, 0.5)))
    fig.suptitle(title)
    fig.tight_layout()
    place_labels(ax_runs, run_labels, fontsize=6)
    place_labels(ax_mean, [(r[x], r[y], str(label), "black") for label, r in mean.iterrows()], fontsize=8)
    with atomic_write(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def _curve(text: str) -> dict[float, float]:
    """ "a:b;c:d" -> {a: b, c: d}."""
    return dict(tuple(map(float, kv.split(":"))) for kv in text.split(";"))


def write_plots(frame: pd.DataFrame, suite, out: Path) -> None:
    """pareto.png (``primary_metric`` against total seconds, 95 % error bars over seeds), psnr_vs_iterations.png
    from each training run's history (mean over scenes and seeds, 95 % band over seeds) and
    heldout_psnr_vs_seconds.png where runs have held-out views."""
    from .stats import these_scenes

    frame = with_seed(frame)
    trains = "psnr_pl" in frame and frame["psnr_pl"].notna().any()
    prim = primary_metric(frame)
    if prim is not None:
        y, ylabel, hib = prim
        ok = frame[pd.to_numeric(frame[y], errors="coerce").notna()]
        mean = average_table(ok)
        mean = mean[[c for c in ("sec_total", y, "sec_total_hw", f"{y}_hw") if c in mean]]
        pareto_plot(mean, ok, "sec_total", y, ylabel, out / "pareto.png", hib, suite.title)
    if trains and "history" in frame:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7.5, 5))
        banded = False
        for k, (label, g) in enumerate(frame[frame["history"].notna()].groupby("label", sort=False)):
            curves = [(scene, _curve(h)) for scene, h in zip(g["scene"], g["history"]) if h]
            its = sorted(set.intersection(*(set(c) for _, c in curves))) if curves else []
            if not its:
                continue
            ivs = [
                these_scenes(pd.DataFrame({"scene": [s for s, _ in curves], "value": [c[i] for _, c in curves]}))
                for i in its
            ]
            ax.plot(its, [iv.estimate for iv in ivs], color=f"C{k % 10}", label=str(label))
            if not any(math.isnan(iv.low) for iv in ivs):
                ax.fill_between(its, [iv.low for iv in ivs], [iv.high for iv in ivs], color=f"C{k % 10}", alpha=0.2)
                banded = True
        ax.set(
            xlabel="iteration",
            ylabel="training-view PSNR (dB, mean over scenes" + (" and seeds)" if banded else ")"),
            title=suite.title + ("\nbands: 95 % interval over seeds" if banded else ""),
        )
        ax.legend(fontsize=8)
        fig.tight_layout()
        with atomic_write(out / "psnr_vs_iterations.png", suffix=".png") as tmp:
            fig.savefig(tmp, dpi=110)
        plt.close(fig)
    if trains and "history_heldout" in frame and frame["history_heldout"].notna().any():
        heldout_vs_seconds_plot(
            frame[frame["history_heldout"].notna()], out / "heldout_psnr_vs_seconds.png", suite.title
        )
    reference = getattr(suite, "reference", None)
    if trains and reference and len(budget_steps(frame)) >= 2:
        paired_vs_seconds_plot(frame, reference, out / "paired_vs_seconds.png", suite.title)


def paired_vs_seconds_plot(frame: pd.DataFrame, reference: str, path: Path, title: str = "") -> None:
    """Each row's paired difference to ``reference`` (held-out PSNR, else pseudo-label PSNR; these scenes, 95 %
    interval as error bars) at every budget (``budget_steps``), against the row's median training seconds to
    that budget: a line that falls toward 0 is an advantage that is early-only, one that stays is lasting."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = budget_steps(frame)
    prim = "psnr_ho" if f"psnr_ho@{steps[-1]}" in frame and frame[f"psnr_ho@{steps[-1]}"].notna().any() else "psnr_pl"
    fig, ax = plt.subplots(figsize=(7.5, 5))
    ax.axhline(0, color="k", lw=0.8)
    labels = [label for label in dict.fromkeys(frame["label"]) if label != reference]
    for k, label in enumerate(labels):
        xs, ys, errs = [], [], []
        for n in steps:
            b = at_budget(frame, n)
            c = comparison_rows(b[b["label"].isin([label, reference])], reference, prim)
            if not c or math.isnan(c[0].these.estimate):
                continue
            xs.append(float(pd.to_numeric(b.loc[b["label"] == label, "sec_train"], errors="coerce").median()))
            ys.append(c[0].these.estimate)
            errs.append(0.0 if math.isnan(c[0].these.half_width) else c[0].these.half_width)
        if xs:
            ax.errorbar(xs, ys, yerr=errs, color=f"C{k % 10}", marker="o", capsize=3, label=str(label))
    what = "held-out" if prim == "psnr_ho" else "pseudo-label"
    ax.set(
        xlabel="training seconds (median over runs) at each budget",
        ylabel=f"Δ {what} PSNR to {reference} (dB, paired)",
        title=title + "\nbars: 95 % interval over seeds, these scenes",
    )
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_write(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)


def heldout_vs_seconds_plot(frame: pd.DataFrame, path: Path, title: str = "") -> None:
    """Held-out PSNR against training seconds, one line per run (colour: label, line style: scene; a label and
    scene's seeds share both and one legend entry), from the ``history_heldout`` column ("seconds:psnr;...").
    With several seeds the runs are drawn faint and each label gets its mean over scenes and seeds at each
    evaluation (at the runs' mean seconds) with the 95 % band over seeds (``stats.these_scenes``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from .stats import these_scenes

    frame = with_seed(frame)
    seeded = frame.groupby(["label", "scene"])["seed"].nunique().max() > 1
    fig, ax = plt.subplots(figsize=(7.5, 5))
    labels = list(dict.fromkeys(frame["label"]))
    scenes = list(dict.fromkeys(frame["scene"])) if "scene" in frame else [None]
    seen: set = set()
    curves = {}
    for _, r in frame.iterrows():
        pts = [tuple(map(float, kv.split(":"))) for kv in str(r["history_heldout"]).split(";")]
        curves.setdefault(r["label"], []).append((r.get("scene"), pts))
        k, s = labels.index(r["label"]), scenes.index(r.get("scene"))
        ax.plot(
            [p[0] for p in pts],
            [p[1] for p in pts],
            color=f"C{k % 10}",
            ls=("-", "--", ":", "-.")[s % 4],
            alpha=0.3 if seeded else 1.0,
            lw=0.8 if seeded else 1.5,
            label="_nolegend_"
            if (k, s) in seen
            else f"{r['label']}" + (f" / {r['scene']}" if r.get("scene") is not None else ""),
        )
        seen.add((k, s))
    for label, runs in curves.items() if seeded else ():
        if len({len(pts) for _, pts in runs}) != 1:  # evaluated at different steps: no common points
            continue
        at = range(len(runs[0][1]))
        xs = [float(np.mean([pts[i][0] for _, pts in runs])) for i in at]
        ivs = [
            these_scenes(pd.DataFrame({"scene": [s for s, _ in runs], "value": [p[i][1] for _, p in runs]})) for i in at
        ]
        colour = f"C{labels.index(label) % 10}"
        ax.plot(xs, [iv.estimate for iv in ivs], color=colour, lw=2.2, label=f"{label}: mean, 95 % band")
        ax.fill_between(xs, [iv.low for iv in ivs], [iv.high for iv in ivs], color=colour, alpha=0.15)
    ax.set(xlabel="training seconds", ylabel="held-out PSNR (dB)", title=title)
    ax.legend(fontsize=6 if seeded else 7, ncol=2 if seeded else 1)
    fig.tight_layout()
    with atomic_write(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
