"""Ablation suites as TOML files (``eval/suites/*.toml``).

    title = "Table 2: point-cloud initialization"
    rows = ["source"]                 # the columns that name one table row (averaged over scenes)
    [defaults]                        # applies to every row
    width = 512
    teacher = "sim:relative"
    iters = 300                       # any TrainConfig field (iters, res, labels, strategy, ...)
    [grid]                            # the cross product of these lists
    scene = ["bedroom", "beach"]
    source = ["fibonacci", "random"]
    [[variants]]                      # optional: named settings, crossed with the grid
    label = "Fibonacci 15"
    views = 15
    [paper]                           # the paper's published numbers, shown beside ours
    caption = "..."
    columns = ["PSNR", "SSIM", "LPIPS", "Time"]
    rows = [{label = "Our study", values = [42.07, 0.992, 0.020, "8 min 21 s"], match = {source = "fibonacci"}}]

Row keys: scene, width, source, teacher, views, train (false: no training), label, and TrainConfig fields.
"""
from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass, field
from pathlib import Path

from ..io import PanoreconInputError
from ..pipeline import Row

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROW_KEYS = {"scene", "width", "source", "teacher", "views", "train", "label"}


@dataclass
class Suite:
    name: str
    title: str
    rows: list[Row]
    row_columns: list[str]
    paper: dict = field(default_factory=dict)
    path: Path | None = None


def _train_fields() -> set[str]:
    from ..splat.trainer import TrainConfig

    return {f.name for f in dataclasses.fields(TrainConfig)}


def load_suite(path) -> Suite:
    """Read and check a suite file -> Suite with one Row per grid point (one clear error for a bad file)."""
    path = Path(path)
    if not path.is_file():
        raise PanoreconInputError(f"suite {path}: no such file (the shipped suites are in eval/suites/)")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise PanoreconInputError(f"suite {path}: not valid TOML ({e})") from None
    train_fields = _train_fields()
    allowed = ROW_KEYS | train_fields
    defaults, grid, variants = data.get("defaults", {}), data.get("grid", {}), data.get("variants", [{}])
    for where, keys in [("[defaults]", defaults), ("[grid]", grid)] + [(f"[[variants]] {i + 1}", v) for i, v in enumerate(variants)]:
        unknown = set(keys) - allowed
        if unknown:
            raise PanoreconInputError(f"suite {path}: unknown key(s) {sorted(unknown)} in {where}; expected some of {sorted(allowed)}")
    for k, v in grid.items():
        if not isinstance(v, list) or not v:
            raise PanoreconInputError(f"suite {path}: [grid] {k} must be a non-empty list, got {v!r}")
    row_columns = list(data.get("rows", ["source"]))
    rows = []
    for variant in variants:
        for combo in itertools.product(*grid.values()):
            spec = {**defaults, **dict(zip(grid, combo)), **variant}
            for need in ("scene", "source"):
                if need not in spec:
                    raise PanoreconInputError(f"suite {path}: no {need!r} in [defaults], [grid] or [[variants]]")
            train_cfg = {k: v for k, v in spec.items() if k in train_fields}
            label = spec.get("label") or " / ".join(str(spec.get(c, "")) for c in row_columns)
            extra = {c: spec.get(c) for c in row_columns if c not in ROW_KEYS}
            rows.append(Row(scene=spec["scene"], width=int(spec.get("width", 512)), source=spec["source"],
                            teacher=spec.get("teacher"), views=spec.get("views"),
                            train=train_cfg if spec.get("train", True) else None, label=label,
                            extra={**extra, **{k: spec[k] for k in ("strategy", "labels", "iters", "res") if k in spec}}))
    if not rows:
        raise PanoreconInputError(f"suite {path}: the grid is empty")
    return Suite(path.stem, data.get("title", path.stem), rows, row_columns, data.get("paper", {}), path)
