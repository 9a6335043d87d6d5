"""The paper's ablation claims judged on the committed tables (README's "Results" table).

    python eval/claims.py benchmarks/tables [--step N] [--markdown] [--suites eval/suites]

Reads ``DIR/table{2,4,5,6,7}/results.csv``, ``DIR/table5_population/results.csv`` and the tables under the
learned teachers, ``DIR/table{2,4}_learned/results.csv`` (``panorecon ablate eval/suites/NAME.toml --out DIR/NAME``)
and, for each claim of the paper's §3, takes the paired difference that the claim is about (run by run on the
same scene and seed, ``evaluation/stats.py``) on the paper's protocol (pseudo-label PSNR) and on held-out
views, each with its 95 % interval on these scenes and across new scenes. A claim is **confirmed** when every
difference it makes is resolved in its direction, **contradicted** when one is resolved against it,
**equivalent** when none is against it and every one not resolved in its direction lies inside the suite's
equivalence margin (±0.1 dB unless the suite says otherwise), else **not resolved**; a claim whose rows cannot
run here (no weights, no CUDA) is ``n/a`` with the reason. Beside each verdict: whether the intervals rule out
the paper's own difference for the same rows (its figures from the suite's [paper] block, ``eval/suites``;
"n/a" where the paper has no figure for a row, as for the sim: stand-ins). The verdict column is the paper's
protocol on these scenes (bold), the new-scenes verdict beside it; a one-seed table (a population of scenes) has
no interval on these scenes and is judged, and its differences shown, across new scenes. Prints JSON, or the
markdown table with ``--markdown``. ``--step``: read every run at that training budget (default: the last).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import pandas as pd

from panorecon.evaluation.report import at_budget, paper_difference
from panorecon.evaluation.stats import RESOLVED, compare
from panorecon.evaluation.suite import load_suite

SUITES = Path(__file__).resolve().parent / "suites"
LEARNED = "panorecon/teachers/weights"  # the shipped learned teachers, as the suites name them (onnx:...)

# (claim, paper's figure, table, [(row, reference, sign)]: the claim says sign * (row - reference) > 0)
CLAIMS = [
    (
        "Fibonacci initialization is the best of Table 2's rows",
        "42.07 dB, next best 38.64 (COLMAP)",
        "table2",
        [
            (r, "fibonacci", -1)
            for r in ("icosahedral", "latlong", "cube", "moge-merge", "erp-direct", "random", "colmap-sfm")
        ],
    ),
    (
        "The MoGe-2 teacher is best; DPT is far worse (sim: stand-ins here)",
        "42.07 vs 41.67 (VGGT), 32.93 (DPT)",
        "table4",
        [("sim:clean", "sim:relative", -1), ("sim:affine-disparity", "sim:relative", -1)],
    ),
    (
        "Fibonacci initialization is the best of Table 2's rows, under a learned teacher",
        "42.07 dB, next best 38.64 (COLMAP)",
        "table2_learned",
        [(r, "fibonacci", -1) for r in ("icosahedral", "latlong", "cube", "moge-merge", "erp-direct")],
    ),
    (
        "A better depth teacher gives better Gaussians (learned teachers)",
        "42.07 vs 41.67 (VGGT), 32.93 (DPT)",
        "table4_learned",
        [
            (f"onnx:{LEARNED}/learned-w16.onnx", "sim:relative", -1),
            (f"onnx:{LEARNED}/learned-w8.onnx", f"onnx:{LEARNED}/learned-w16.onnx", -1),
        ],
    ),
    (
        "180 pseudo-labels are best",
        "42.37 vs 42.12 / 42.07 / 42.03 / 41.44",
        "table5",
        [(r, "180", -1) for r in ("120", "240", "300", "360")],
    ),
    (
        "180 pseudo-labels beat 120, on a population of new scenes",
        "42.37 vs 42.12",
        "table5_population",
        [("120", "180", -1)],
    ),
    (
        "Fibonacci 20 views beat the icosahedron's 20",
        "42.07 vs 41.67",
        "table6",
        [("Icosahedron (20)", "Fibonacci 20", -1)],
    ),
    ("25 Fibonacci views beat 20", "42.24 vs 42.07", "table6", [("Fibonacci 25", "Fibonacci 20", 1)]),
    (
        "Adaptive pruning beats 3DGS's densify/prune",
        "+0.32 dB (42.07 vs 41.75)",
        "table7",
        [("default", "adaptive", -1)],
    ),
]
NOT_HERE = {
    "colmap-mvs": "n/a: COLMAP MVS needs a CUDA build of pycolmap",
    "real teachers": "n/a: MoGe-2, DPT, Metric3D and VGGT weights cannot be downloaded here; sim: profiles and the "
    "project's own learned teachers stand in",
}


def _cell(c) -> dict:
    def iv(x):
        return None if math.isnan(x.estimate) else {"estimate": x.estimate, "low": x.low, "high": x.high}

    return {
        "these": iv(c.these),
        "new": iv(c.new),
        "verdict_these": c.verdict_these,
        "verdict_new": c.verdict_new,
        "equivalent_these": c.equivalent_these,
        "equivalent_new": c.equivalent_new,
        "margin": c.margin,
        "paper": None if math.isnan(c.paper) else c.paper,
        "paper_ruled_out_these": c.paper_ruled_out_these,
        "paper_ruled_out_new": c.paper_ruled_out_new,
        "to_resolve_these": c.to_resolve_these,
        "to_resolve_new": c.to_resolve_new,
        "pairs": c.pairs,
    }


def _judge(comps: list, signs: list[int], which: str) -> str:
    """A claim's verdict from its comparisons (row − reference, the ``"these"`` or ``"new"`` interval) against
    the claim's signs: contradicted (one resolved against), confirmed (all resolved with it), equivalent (none
    against, and every one not resolved with it inside its margin), else not resolved."""
    if not comps:
        return "n/a: no runs"
    verdicts = [getattr(c, f"verdict_{which}") for c in comps]
    with_claim = [v in RESOLVED and (v == "better") == (s > 0) for v, s in zip(verdicts, signs)]
    if any(v in RESOLVED and not w for v, w in zip(verdicts, with_claim)):
        return "contradicted"
    if all(with_claim):
        return "confirmed"
    if all(w or getattr(c, f"equivalent_{which}") for c, w in zip(comps, with_claim)):
        return "equivalent"
    return "not resolved"


def _paper_size(comps: list, which: str) -> str:
    """Whether a claim's intervals rule out the paper's own differences: "ruled out", "ruled out for ROW, ...",
    "consistent", or "n/a" where the paper reports none of its rows."""
    tested = [(c.label, getattr(c, f"paper_ruled_out_{which}")) for c in comps]
    tested = [(label, r) for label, r in tested if r is not None]
    if not tested:
        return "n/a"
    out = [label for label, r in tested if r]
    if len(out) == len(tested):
        return "ruled out"
    return f"ruled out for {', '.join(out)}" if out else "consistent"


def judge(tables: Path, step: int | None = None, suites: Path = SUITES) -> list[dict]:
    out = []
    for claim, paper, table, diffs in CLAIMS:
        csv = tables / table / "results.csv"
        if not csv.is_file():
            out.append({"claim": claim, "paper": paper, "table": table, "verdict": f"n/a: no {csv}"})
            continue
        suite = load_suite(suites / f"{table}.toml")
        figures = suite.paper_figures()
        frame = pd.read_csv(csv, dtype={"label": str})
        if step is not None:
            frame = at_budget(frame, step)
        rec = {
            "claim": claim,
            "paper": paper,
            "table": table,
            "scenes": int(frame["scene"].nunique()),
            "seeds": int(frame["seed"].nunique()),
        }
        for col, proto in (("psnr_pl", "pseudo_label"), ("psnr_ho", "heldout")):
            comps = [
                (compare(frame, col, row, ref, suite.margins, paper_difference(figures, col, row, ref)), sign)
                for row, ref, sign in diffs
                if row in set(frame["label"])
            ]
            rec[proto] = {c.label: _cell(c) for c, _ in comps}
            for which in ("these", "new"):
                rec[f"verdict_{proto}_{which}"] = _judge([c for c, _ in comps], [s for _, s in comps], which)
                rec[f"paper_size_{proto}_{which}"] = _paper_size([c for c, _ in comps], which)
        # one seed gives no interval on these scenes: such a table (a population of scenes) is judged across them
        rec["judged_on"] = "new" if rec["seeds"] == 1 else "these"
        rec["verdict"] = rec[f"verdict_pseudo_label_{rec['judged_on']}"]
        out.append(rec)
    return out


def _range(cells: dict, which: str = "these") -> str:
    """The differences of a claim as 'row −0.12 [−0.20, −0.04]; ...' (``which``: these or new scenes), each with
    the paper's own difference where it reports one ('paper −0.40'), each equivalent one with its margin
    ('≡ ±0.1'), and each one neither resolved nor equivalent with the scenes × seeds the statistics layer says
    would resolve it (80 % power), e.g. '(needs 1 × 12)'."""
    parts = []
    for label, c in cells.items():
        t = c[which]
        label = _short(label)
        if t is None:
            parts.append(f"{label} n/a")
            continue
        text = f"{label} {t['estimate']:+.2f}"
        if not math.isnan(t["low"]):  # one pair per scene: no interval over seeds
            text += f" [{t['low']:+.2f}, {t['high']:+.2f}]"
        notes = []
        if c["paper"] is not None:
            notes.append(f"paper {c['paper']:+.2f}")
        if c[f"equivalent_{which}"]:
            notes.append(f"≡ ±{c['margin']:g}")
        need = c.get(f"to_resolve_{which}", "n/a")
        if c[f"verdict_{which}"] == "not resolved" and not c[f"equivalent_{which}"] and need not in ("n/a", "resolved"):
            notes.append(f"needs {need}")
        if which == "new":
            notes.append("across new scenes")
        parts.append(text + (f" ({'; '.join(notes)})" if notes else ""))
    return "; ".join(parts)


def _short(label: str) -> str:
    """A shipped learned teacher's row label without its folder: ``learned-w16``."""
    return label.removeprefix(f"onnx:{LEARNED}/").removesuffix(".onnx")


def markdown(claims: list[dict]) -> str:
    lines = [
        "| claim (paper §3) | paper | Δ pseudo-label PSNR, these scenes (dB, 95 %) | verdict (these / new scenes) "
        "| paper's size (these / new) | held-out (these / new) | paired runs |",
        "|---|---|---|---|---|---|---|",
    ]
    for c in claims:
        if "pseudo_label" not in c:
            lines.append(f"| {c['claim']} | {c['paper']} | — | {c['verdict']} | — | — | — |")
            continue
        these, new = c["verdict_pseudo_label_these"], c["verdict_pseudo_label_new"]
        verdicts = f"**{these}** / {new}" if c["judged_on"] == "these" else f"{these} / **{new}**"
        lines.append(
            f"| {c['claim']} | {c['paper']} | {_range(c['pseudo_label'], c['judged_on'])} | {verdicts} | "
            f"{c['paper_size_pseudo_label_these']} / "
            f"{c['paper_size_pseudo_label_new']} | {c['verdict_heldout_these']} / {c['verdict_heldout_new']} | "
            f"{min((x['pairs'] for x in c['pseudo_label'].values()), default=0)} |"
        )
    lines += ["", "Not run here: " + "; ".join(NOT_HERE.values()) + "."]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("tables", type=Path, help="the folder with table2/ ... table7/ (each with results.csv)")
    ap.add_argument("--step", type=int, default=None, help="read every run at this training budget (default: last)")
    ap.add_argument("--markdown", action="store_true", help="print README's markdown table instead of JSON")
    ap.add_argument("--suites", type=Path, default=SUITES, help="the suite files (their [paper] figures, margins)")
    args = ap.parse_args(argv)
    claims = judge(args.tables, args.step, args.suites)
    print(markdown(claims) if args.markdown else json.dumps(claims, indent=1, default=float))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
