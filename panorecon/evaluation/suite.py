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

Row keys: scene, width, source, teacher, views, train (false: no training), label, depth, depth_scale,
depth_kind (a real panorama's true depth, as the CLI's --depth options), and TrainConfig fields.
``{root}`` in a scene or depth is the dataset root (``load_suite(root=...)``, ``ablate --root``, else
$PANORECON_DATASET_ROOT); a dataset scene whose key has a ``*`` (``stanford2d3d:{root}/area_3/*``) stands for
every panorama under the root that matches it.
"""
from __future__ import annotations

import dataclasses
import fnmatch
import itertools
import os
from dataclasses import dataclass, field
from pathlib import Path

from ..io import PanoreconInputError
from ..pipeline import Row

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROW_KEYS = {"scene", "width", "source", "teacher", "views", "train", "label", "depth", "depth_scale", "depth_kind"}
ROOT_ENV = "PANORECON_DATASET_ROOT"


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


def _with_root(value, root: str | None, path: Path):
    if not isinstance(value, str) or "{root}" not in value:
        return value
    if not root:
        raise PanoreconInputError(f"suite {path}: {value!r} needs the dataset root: give --root DIR or set ${ROOT_ENV}")
    return value.replace("{root}", str(root))


def _expand_scene(scene: str, path: Path) -> list[str]:
    """A dataset scene with a ``*`` in its key -> the matching panoramas under its root (sorted), else [scene]."""
    from ..scenes.datasets import is_dataset_name, split_name

    if "*" not in scene or not is_dataset_name(scene):
        return [scene]
    ds, root, pattern = split_name(scene)
    if not root.is_dir():
        raise PanoreconInputError(f"suite {path}: dataset root {root} of {scene!r} is not a folder")
    found = [f"{ds.prefix}:{root / k}" for k in ds.keys(root) if fnmatch.fnmatch(k, pattern)]
    if not found:
        raise PanoreconInputError(f"suite {path}: no {ds.prefix} panorama under {root} matches {scene!r}")
    return found


def load_suite(path, root: str | None = None) -> Suite:
    """Read and check a suite file -> Suite with one Row per grid point (one clear error for a bad file).
    ``root``: the dataset root for ``{root}`` (default $PANORECON_DATASET_ROOT)."""
    path = Path(path)
    root = root or os.environ.get(ROOT_ENV)
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
            depth = _with_root(spec.get("depth"), root, path)
            if depth is None and ("depth_scale" in spec or "depth_kind" in spec):
                raise PanoreconInputError(f"suite {path}: depth_scale / depth_kind without a depth file")
            depth = (depth, spec.get("depth_scale"), spec.get("depth_kind", "distance")) if depth else None
            for scene in _expand_scene(_with_root(spec["scene"], root, path), path):
                rows.append(Row(scene=scene, width=int(spec.get("width", 512)), source=spec["source"],
                                teacher=spec.get("teacher"), views=spec.get("views"),
                                train=train_cfg if spec.get("train", True) else None, label=label, depth=depth,
                                extra={**extra, **{k: spec[k] for k in ("strategy", "labels", "iters", "res")
                                                   if k in spec}}))
    if not rows:
        raise PanoreconInputError(f"suite {path}: the grid is empty")
    return Suite(path.stem, data.get("title", path.stem), rows, row_columns, data.get("paper", {}), path)
