"""Held-out PSNR against Gaussians and against seconds from an ablation's results.csv: the report module's
Pareto plots (``evaluation.report.pareto_plot``, means over scenes with 95 % intervals over seeds), one PNG each.

    python eval/pareto_gaussians.py DIR/results.csv OUT_PREFIX [--title TEXT]

writes OUT_PREFIX_gaussians.png and OUT_PREFIX_seconds.png and prints the means they plot as JSON.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def main(argv=None) -> dict:
    import pandas as pd

    from panorecon.evaluation.report import average_table, pareto_plot
    from panorecon.evaluation.rerender import load_results

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("csv", type=Path)
    ap.add_argument("prefix")
    ap.add_argument("--title", default=None, help="the plots' title (default: the results folder's name)")
    args = ap.parse_args(argv)
    frame = load_results(args.csv)
    ok = frame[pd.to_numeric(frame["psnr_ho"], errors="coerce").notna()]
    mean = average_table(ok)
    out, title = {}, args.title or args.csv.parent.name
    for x, unit in (("gaussians", "Gaussians"), ("sec_total", "seconds")):
        cols = [c for c in (x, "psnr_ho", f"{x}_hw", "psnr_ho_hw") if c in mean]
        path = Path(f"{args.prefix}_{'seconds' if x == 'sec_total' else x}.png")
        pareto_plot(mean[cols], ok, x, "psnr_ho", "held-out PSNR (dB)", path, True, title, xlabel=unit)
        out[x] = {str(k): {c: float(v) for c, v in r.items()} for k, r in mean[cols].iterrows()}
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
