"""Seam scores (``panorecon.metrics.seam``) of the real panoramas in ../shared/data/real and of any
generated panoramas given on the command line, as JSON.

    python eval/seam_scores.py [--real-dir ../shared/data/real] [PANO.png ...]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from panorecon.io import read_image
from panorecon.metrics.seam import seam_discontinuity


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--real-dir", default=str(Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"))
    ap.add_argument("panoramas", nargs="*")
    args = ap.parse_args(argv)
    real = sorted(p for p in Path(args.real_dir).glob("*.png") if "depth" not in p.name)
    out = {str(p): seam_discontinuity(read_image(p, erp=True)) for p in [*real, *map(Path, args.panoramas)]}
    print(json.dumps(out, indent=2))
    return out


if __name__ == "__main__":
    main()
