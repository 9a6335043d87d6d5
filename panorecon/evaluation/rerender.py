"""``panorecon ablate --from-csv results.csv --out DIR``: results.md, report.html and the plots again from a
results.csv, without running a stage (new statistics, a fixed report, or someone else's runs).

The CSV is checked first (one clear error, nothing written): it parses, has the columns the tables need
(label, scene; seed, where absent, is 0), at least one metric, integer seeds and no run twice; the reference
(the suite's, or the CSV's ``reference`` column) names one row of it; and no output would overwrite it.
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

import pandas as pd

from ..io import PanoreconInputError
from .report import TABLE_COLUMNS
from .suite import Suite

OUTPUTS = ("results.csv", "results.md", "report.html", "pareto.png", "psnr_vs_iterations.png")
OUTPUTS += ("heldout_psnr_vs_seconds.png",)


def load_results(csv) -> pd.DataFrame:
    """Read and check a results.csv (see the module docstring) -> its frame, with a ``seed`` column."""
    csv = Path(csv)
    if not csv.is_file():
        raise PanoreconInputError(f"--from-csv {csv}: no such file")
    try:
        frame = pd.read_csv(csv)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError, ValueError) as e:
        raise PanoreconInputError(f"--from-csv {csv}: not a CSV table ({str(e).splitlines()[0]})") from None
    missing = [c for c in ("label", "scene") if c not in frame]
    if missing:
        raise PanoreconInputError(
            f"--from-csv {csv}: no column {', '.join(missing)}; expected a results.csv written by `panorecon ablate`"
        )
    metrics = [c for c, *_ in TABLE_COLUMNS if c in frame and pd.to_numeric(frame[c], errors="coerce").notna().any()]
    if not metrics:
        raise PanoreconInputError(
            f"--from-csv {csv}: no metric column with a number (expected some of "
            f"{', '.join(c for c, *_ in TABLE_COLUMNS[:6])}, ...)"
        )
    if "seed" not in frame:
        frame["seed"] = 0
    seeds = pd.to_numeric(frame["seed"], errors="coerce")
    if seeds.isna().any() or (seeds != seeds.round()).any():
        bad = frame["seed"][seeds.isna() | (seeds != seeds.round())].iloc[0]
        raise PanoreconInputError(f"--from-csv {csv}: seed {bad!r} is not an integer")
    frame["seed"] = seeds.astype(int)
    frame["label"] = frame["label"].astype(str)
    dup = frame.duplicated(["label", "scene", "seed"], keep=False)
    if dup.any():
        r = frame[dup].iloc[0]
        times = int(
            ((frame["label"] == r["label"]) & (frame["scene"] == r["scene"]) & (frame["seed"] == r["seed"])).sum()
        )
        raise PanoreconInputError(
            f"--from-csv {csv}: run {r['label']!r} on scene {r['scene']!r} with seed {r['seed']} appears "
            f"{times} times; expected one row per run"
        )
    return frame


def _reference(frame: pd.DataFrame, csv: Path, suite: Suite | None) -> str | None:
    if suite is not None and suite.reference:
        if suite.reference not in set(frame["label"]):
            raise PanoreconInputError(
                f"--from-csv {csv}: the suite's reference row {suite.reference!r} is not in it (its rows: "
                f"{', '.join(dict.fromkeys(frame['label']))})"
            )
        return suite.reference
    if "reference" not in frame:
        return None
    flags = frame["reference"].astype(str).str.lower()
    if not flags.isin(["true", "false"]).all():
        raise PanoreconInputError(f"--from-csv {csv}: column reference must be True or False in every row")
    labels = list(dict.fromkeys(frame.loc[flags == "true", "label"]))
    if len(labels) > 1:
        raise PanoreconInputError(f"--from-csv {csv}: column reference marks {len(labels)} rows ({', '.join(labels)})")
    return labels[0] if labels else None


def rerender(csv, out, suite: Suite | None = None) -> pd.DataFrame:
    """Write DIR's results.csv (the input's rows, with ``seed`` and ``reference``), results.md, report.html and
    plots from ``csv``. ``suite`` (optional) gives the title, row header, paper numbers and reference; without
    it the CSV's ``reference`` column names the reference."""
    from .ablate import write_outputs

    t0 = time.perf_counter()
    csv, out = Path(csv), Path(out)
    frame = load_results(csv)
    ref = _reference(frame, csv, suite)
    if csv.resolve() in {(out / name).resolve() for name in OUTPUTS}:
        raise PanoreconInputError(f"--out {out}: its {csv.name} is the input --from-csv {csv}; give another folder")
    if out.exists() and not out.is_dir():
        raise PanoreconInputError(f"--out {out}: exists and is not a folder")
    if suite is None:
        suite = Suite(csv.stem, f"Re-rendered from {csv}", [], ["row"], path=csv)
    suite = dataclasses.replace(suite, seeds=sorted(set(frame["seed"])), reference=ref)
    if ref:
        frame["reference"] = frame["label"] == ref
    out.mkdir(parents=True, exist_ok=True)
    write_outputs(frame, suite, out, None, t0)
    return frame
