"""results.md tables shaped like the paper's, and the plots: error against run time (Pareto), PSNR against steps."""

from __future__ import annotations

import math
from pathlib import Path

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


def average_table(frame: pd.DataFrame) -> pd.DataFrame:
    """Mean over scenes of every numeric table column, one row per label (in the suite's order)."""
    cols = [c for c, *_ in TABLE_COLUMNS if c in frame]
    order = list(dict.fromkeys(frame["label"]))
    mean = frame.groupby("label", sort=False)[cols].mean(numeric_only=True).reindex(order)
    mean.insert(0, "scenes", frame.groupby("label", sort=False)["scene"].nunique().reindex(order))
    return mean


def markdown_table(table: pd.DataFrame, label_header: str) -> str:
    heads = [(c, h, f) for c, h, f in TABLE_COLUMNS if c in table]
    lines = [
        "| " + " | ".join([label_header, "scenes"] + [h for _, h, _ in heads]) + " |",
        "|" + "---|" * (len(heads) + 2),
    ]
    for label, r in table.iterrows():
        trained = {c: not math.isnan(r.get(c.replace("lpips", "psnr"), math.nan)) for c, _, _ in heads}
        # a trained row without LPIPS: "n/a", its reason listed under the table ("n/a cells: ...")
        cells = [
            ("n/a" if c.startswith("lpips") and math.isnan(r[c]) and trained[c] else _fmt(r[c], f)) for c, _, f in heads
        ]
        lines.append("| " + " | ".join([str(label), str(int(r["scenes"]))] + cells) + " |")
    return "\n".join(lines)


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


def write_results_md(frame: pd.DataFrame, suite, out: Path, wall_seconds: float, per_scene: bool = True) -> None:
    """DIR/results.md: the averaged table, the per-scene table, the paper's numbers, notes on n/a cells."""
    parts = [
        f"# {suite.title}",
        "",
        f"Suite `{suite.path}`; {len(frame)} runs over {frame['scene'].nunique()} scenes; this invocation took "
        f"{wall_seconds:.1f} s (cached stages: {', '.join(sorted(set(frame['cached'])))}). PSNR/SSIM/LPIPS "
        "without a prefix are the pseudo-label protocol (the paper's); held-out = true renders away from the "
        "panorama centre. Seconds and peak MB are those of the process that computed each stage.",
        "",
        "## Averaged over scenes",
        "",
        markdown_table(average_table(frame), " / ".join(suite.row_columns)),
        "",
    ]
    notes = sorted({v for c in frame.columns if c.endswith("_note") for v in frame[c].dropna().unique()})
    if notes:
        parts += ["n/a cells: " + "; ".join(notes), ""]
    if "warning" in frame:
        flagged = frame[frame["warning"].fillna("").astype(str) != ""]
        for _, r in flagged.iterrows():
            parts += [f"**WARNING** ({r['label']}, {r['scene']}): {r['warning']}", ""]
    paper = _paper_block(suite.paper)
    if paper:
        parts += [paper, ""]
    if per_scene:
        parts += ["## Per scene", ""]
        for scene, g in frame.groupby("scene", sort=False):
            parts += [f"### {scene}", "", markdown_table(average_table(g), " / ".join(suite.row_columns)), ""]
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
) -> None:
    """Two panels of y against x (log seconds): every run coloured by scene and labelled (left), and the
    per-label means over scenes with their Pareto front (right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    fig, (ax_runs, ax_mean) = plt.subplots(1, 2, figsize=(13, 5.2))
    run_labels = []  # (x, y, text, colour), placed once the layout is final
    for k, (scene, g) in enumerate(per_run.groupby("scene", sort=False) if "scene" in per_run else [("runs", per_run)]):
        ax_runs.scatter(g[x], g[y], s=18, color=f"C{k}", label=str(scene))
        run_labels += [(r[x], r[y], str(r[label_col]), f"C{k}") for _, r in g.iterrows()]
    ax_runs.set(xlabel=f"{x} (seconds, log)", ylabel=ylabel, xscale="log", title="every run, by scene")
    ax_runs.legend(fontsize=7)
    sign = -1 if higher_is_better else 1
    pts = list(zip(mean[x], sign * mean[y]))
    front = pareto(pts)
    for i, (_, r) in enumerate(mean.iterrows()):
        ax_mean.scatter(r[x], r[y], s=40, color="C3" if i in front else "C0", zorder=3)
    fp = sorted((mean[x].iloc[i], mean[y].iloc[i]) for i in front)
    ax_mean.plot([p[0] for p in fp], [p[1] for p in fp], "C3--", lw=1.2, label="Pareto front (red)")
    ax_mean.set(
        xlabel=f"{x} (seconds, log; mean over scenes)",
        ylabel=f"{ylabel}, mean over scenes",
        xscale="log",
        title="averaged",
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


def write_plots(frame: pd.DataFrame, suite, out: Path) -> None:
    """pareto.png (held-out PSNR, else pseudo-label PSNR, else AbsRel, against total seconds),
    psnr_vs_iterations.png from each training run's history and heldout_psnr_vs_seconds.png where runs have
    held-out views."""
    trains = "psnr_pl" in frame and frame["psnr_pl"].notna().any()
    y, ylabel, hib = (
        ("psnr_ho", "held-out PSNR (dB)", True)
        if trains and frame.get("psnr_ho") is not None and frame["psnr_ho"].notna().any()
        else ("psnr_pl", "pseudo-label PSNR (dB)", True)
        if trains
        else ("abs_rel", "AbsRel (median-aligned)", False)
    )
    ok = frame[frame[y].notna()]
    if len(ok):
        mean = ok.groupby("label", sort=False)[["sec_total", y]].mean()
        pareto_plot(mean, ok, "sec_total", y, ylabel, out / "pareto.png", hib, suite.title)
    if trains and "history" in frame:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(7.5, 5))
        for label, g in frame[frame["history"].notna()].groupby("label", sort=False):
            curves = [dict(tuple(map(float, kv.split(":"))) for kv in h.split(";")) for h in g["history"] if h]
            its = sorted(set.intersection(*(set(c) for c in curves))) if curves else []
            if its:
                ax.plot(its, [sum(c[i] for c in curves) / len(curves) for i in its], label=str(label))
        ax.set(xlabel="iteration", ylabel="training-view PSNR (dB, mean over scenes)", title=suite.title)
        ax.legend(fontsize=8)
        fig.tight_layout()
        with atomic_write(out / "psnr_vs_iterations.png", suffix=".png") as tmp:
            fig.savefig(tmp, dpi=110)
        plt.close(fig)
    if trains and "history_heldout" in frame and frame["history_heldout"].notna().any():
        heldout_vs_seconds_plot(
            frame[frame["history_heldout"].notna()], out / "heldout_psnr_vs_seconds.png", suite.title
        )


def heldout_vs_seconds_plot(frame: pd.DataFrame, path: Path, title: str = "") -> None:
    """Held-out PSNR against training seconds, one line per run (colour: label, line style: scene), from the
    ``history_heldout`` column ("seconds:psnr;...")."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 5))
    labels = list(dict.fromkeys(frame["label"]))
    scenes = list(dict.fromkeys(frame["scene"])) if "scene" in frame else [None]
    for _, r in frame.iterrows():
        pts = [tuple(map(float, kv.split(":"))) for kv in str(r["history_heldout"]).split(";")]
        k, s = labels.index(r["label"]), scenes.index(r.get("scene"))
        ax.plot(
            [p[0] for p in pts],
            [p[1] for p in pts],
            color=f"C{k % 10}",
            ls=("-", "--", ":", "-.")[s % 4],
            label=f"{r['label']}" + (f" / {r['scene']}" if r.get("scene") is not None else ""),
        )
    ax.set(xlabel="training seconds", ylabel="held-out PSNR (dB)", title=title)
    ax.legend(fontsize=7)
    fig.tight_layout()
    with atomic_write(path, suffix=".png") as tmp:
        fig.savefig(tmp, dpi=110)
    plt.close(fig)
