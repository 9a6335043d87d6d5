"""Ablation suites as TOML files (``eval/suites/*.toml``).

    extends = "table2.toml"           # optional: that suite, with this file's tables over it ([defaults] and
                                      # [pinned] key by key)
    title = "Table 2: point-cloud initialization"
    rows = ["source"]                 # the columns that name one table row (averaged over scenes)
    [defaults]                        # applies to every row
    width = 512
    teacher = "sim:relative"
    iters = 300                       # any TrainConfig field (iters, res, labels, strategy, ...)
    [grid]                            # the cross product of these lists
    scene = ["bedroom", "beach"]
    source = ["fibonacci", "random"]
    seeds = [0, 1, 2]                 # optional: every row runs once per seed (training, teacher noise, random source)
    reference = { source = "fibonacci" }  # optional: the row every other row is compared with, pair by pair
    [[variants]]                      # optional: named settings, crossed with the grid
    label = "Fibonacci 15"
    views = 15
    margins = { psnr_pl = 0.1 }       # optional: equivalence margins per metric (default: 0.1 dB for a PSNR)
    [pinned]                          # optional: settings whose defaults moved since the committed table ran,
    flatten_every = 0                 # at the values it ran with (as [defaults]; `ablate --unpinned` leaves them out)
    [paper]                           # the paper's published numbers, shown beside ours
    caption = "..."
    columns = ["PSNR", "SSIM", "LPIPS", "Time"]
    rows = [{label = "Our study", values = [42.07, 0.992, 0.020, "8 min 21 s"], match = {source = "fibonacci"}}]

Row keys: scene, width, source, teacher, views, train (false: no training), label, depth, depth_scale,
depth_kind (a real panorama's true depth, as the CLI's --depth options), and TrainConfig fields.
``{root}`` in a scene or depth is the dataset root (``load_suite(root=...)``, ``ablate --root``, else
$PANORECON_DATASET_ROOT); a dataset scene whose key has a ``*`` (``stanford2d3d:{root}/area_3/*``) stands for
every panorama under the root that matches it, and ``bedroom@1..10`` for the variants bedroom@1, ..., bedroom@10
of a synthetic scene (``scenes/synthetic.py``).

``seeds``: each seed sets the training seed (TrainConfig.seed) and seeds the simulated teacher's errors and the
random point source (``Row.seed``); a stage the seed does not change (a real teacher's depth) is shared between
seeds. ``reference``: keys and values (as in [defaults]; ``label`` is the row's table label) that pick exactly
one table row; results.md compares every other row with it on the same scene and seed (``evaluation/stats.py``).
Without ``seeds`` a row's seed is its ``seed`` setting (default 0). ``margins``: metric column -> the
difference (in the metric's unit) within which two rows count as equivalent (``evaluation/stats.py``). A
[paper] row's ``match`` picks exactly one of our table rows, as ``reference`` does; its PSNR / SSIM / LPIPS are
then the paper's figures for that row, and the paper's difference between two matched rows is tested against
ours (``Suite.paper_figures``).

The file is checked before anything runs: unknown tables and keys are errors that name the closest valid one,
every row value is checked by the declaration of the config field of its name (``row_settings``: the same
declarations make the CLI's options), each row's training settings build a ``TrainConfig``, and
``resolve_names`` checks every
scene, source and teacher a row names (``run_suite`` calls it before the first stage).
"""

from __future__ import annotations

import dataclasses
import difflib
import fnmatch
import itertools
import math
import os
from dataclasses import dataclass, field
from pathlib import Path

from .. import checks as C
from ..checks import Setting, problem, settings
from ..fusion import FusionOptions
from ..io import PanoreconInputError
from ..pipeline import Row

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

FUSION_KEYS = {f.name for f in dataclasses.fields(FusionOptions)}
ROW_KEYS = {"scene", "width", "source", "teacher", "views", "train", "label", "depth", "depth_scale", "depth_kind"}
ROW_KEYS |= FUSION_KEYS
ROOT_ENV = "PANORECON_DATASET_ROOT"
TOP_KEYS = {
    "extends": str,
    "pinned": dict,
    "title": str,
    "rows": list,
    "defaults": dict,
    "grid": dict,
    "variants": list,
    "paper": dict,
    "seeds": list,
    "reference": dict,
    "margins": dict,
}
PAPER_KEYS = {"caption": str, "columns": list, "rows": list}
PAPER_ROW_KEYS = {"label": str, "values": list, "match": dict}
PAPER_METRICS = {"PSNR": "psnr_pl", "SSIM": "ssim_pl", "LPIPS": "lpips_pl"}  # [paper] column -> our metric


@dataclass
class Suite:
    name: str
    title: str
    rows: list[Row]
    row_columns: list[str]
    paper: dict = field(default_factory=dict)
    path: Path | None = None
    seeds: list[int] = field(default_factory=lambda: [0])
    reference: str | None = None  # the label of the reference row
    margins: dict = field(default_factory=dict)  # metric column -> equivalence margin (``stats.margin_for``)
    paper_labels: dict = field(default_factory=dict)  # our row label -> index of its [paper] row (``match``)
    pinned: dict = field(default_factory=dict)  # [pinned]: the settings the committed table ran with
    unpinned: bool = False  # read without [pinned]: today's defaults

    def paper_figures(self) -> dict[str, dict[str, float]]:
        """The paper's figures of our rows: metric column (``psnr_pl``, ``ssim_pl``, ``lpips_pl``: the paper's
        protocol) -> {our label: value}, from the [paper] rows a ``match`` ties to one of ours."""
        cols = self.paper.get("columns", [])
        rows = self.paper.get("rows", [])
        out = {}
        for name, metric in PAPER_METRICS.items():
            if name in cols:
                j = cols.index(name)
                out[metric] = {
                    label: float(rows[i]["values"][j])
                    for label, i in self.paper_labels.items()
                    if j < len(rows[i]["values"]) and isinstance(rows[i]["values"][j], (int, float))
                }
        return out


def row_settings() -> dict[str, Setting]:
    """Every key a row may set -> its declaration: the scene and depth (``configs.SceneArgs``), the point source
    (``configs.SourceArgs``), every ``TrainConfig`` field, and ``train`` / ``label``; the CLI's options are made
    from the same declarations, so a key and its option share name, default and check."""
    from ..configs import SceneArgs, SourceArgs
    from ..splat.trainer import TrainConfig

    own = {
        "train": Setting("train", True, "bool", {"help": "false: the row's point cloud only, no training"}),
        "label": Setting("label", None, "str | None", {"help": "the row's table label"}),
    }
    return {s.name: s for cls in (SceneArgs, SourceArgs, TrainConfig) for s in settings(cls)} | own


def _unknown(path: Path, where: str, key: str, valid) -> PanoreconInputError:
    close = difflib.get_close_matches(key, sorted(valid), n=1, cutoff=0.5)
    hint = f"did you mean {close[0]!r}?" if close else f"expected one of {', '.join(sorted(valid))}"
    return PanoreconInputError(f"suite {path}: unknown key {key!r} in {where}; {hint}")


def _type_name(t) -> str:
    return {
        str: "a string",
        int: "an integer",
        float: "a number",
        bool: "true or false",
        list: "a list",
        dict: "a table",
    }[t]


def check_value(path: Path, where: str, key: str, value, schema: dict[str, Setting]) -> None:
    """Raise PanoreconInputError unless ``value`` has ``key``'s type and passes its check (``checks.problem``)."""
    why = problem(schema[key], value)
    if why:
        raise PanoreconInputError(f"suite {path}: {where} {key} = {value!r}{why}")


def _check_table(path: Path, where: str, table: dict, schema: dict, listed: bool = False) -> None:
    for k, v in table.items():
        if k not in schema:
            raise _unknown(path, where, k, schema)
        if listed:
            if not isinstance(v, list) or not v:
                raise PanoreconInputError(f"suite {path}: [grid] {k} must be a non-empty list, got {v!r}")
            for item in v:
                check_value(path, where, k, item, schema)
        else:
            check_value(path, where, k, v, schema)


def _check_top(path: Path, data: dict) -> None:
    for k, v in data.items():
        if k not in TOP_KEYS:
            raise _unknown(path, "the top level", k, TOP_KEYS)
        if not isinstance(v, TOP_KEYS[k]):
            raise PanoreconInputError(f"suite {path}: {k} must be {_type_name(TOP_KEYS[k])}, got {v!r}")
    if any(not isinstance(v, dict) for v in data.get("variants", [])):
        raise PanoreconInputError(f"suite {path}: variants must be [[variants]] tables")
    if any(not isinstance(c, str) for c in data.get("rows", [])):
        raise PanoreconInputError(f"suite {path}: rows must be a list of column names")
    paper = data.get("paper", {})
    for k, v in paper.items():
        if k not in PAPER_KEYS:
            raise _unknown(path, "[paper]", k, PAPER_KEYS)
        if not isinstance(v, PAPER_KEYS[k]):
            raise PanoreconInputError(f"suite {path}: [paper] {k} must be {_type_name(PAPER_KEYS[k])}, got {v!r}")
    for i, r in enumerate(paper.get("rows", [])):
        if not isinstance(r, dict):
            raise PanoreconInputError(f"suite {path}: [paper] rows[{i + 1}] must be a table")
        for k, v in r.items():
            if k not in PAPER_ROW_KEYS:
                raise _unknown(path, f"[paper] rows[{i + 1}]", k, PAPER_ROW_KEYS)
            if not isinstance(v, PAPER_ROW_KEYS[k]):
                raise PanoreconInputError(
                    f"suite {path}: [paper] rows[{i + 1}] {k} must be {_type_name(PAPER_ROW_KEYS[k])}, got {v!r}"
                )


def _check_seeds(path: Path, data: dict, tables: list[dict]) -> list[int] | None:
    """The suite's ``seeds`` (distinct integers in the seed range), or None when it names none."""
    if "seeds" not in data:
        return None
    seeds = data["seeds"]
    if not seeds or any(not isinstance(x, int) or isinstance(x, bool) for x in seeds):
        raise PanoreconInputError(f"suite {path}: seeds = {seeds!r}: expected a non-empty list of integers")
    for x in seeds:
        try:
            C.SEED.check(x)
        except C.CheckError as e:
            raise PanoreconInputError(f"suite {path}: seeds: {e}") from None
    if len(set(seeds)) != len(seeds):
        raise PanoreconInputError(f"suite {path}: seeds = {seeds!r} repeats a seed")
    if any("seed" in t for t in tables):
        raise PanoreconInputError(f"suite {path}: give the seeds once: seeds = [...] or a seed setting, not both")
    return list(seeds)


def _check_row_pick(path: Path, where: str, pick: dict | None, schema: dict) -> dict | None:
    """A table that picks one table row by its settings (``reference``, a [paper] row's ``match``), checked:
    non-empty, row keys only (not scene or seed), each value checked by its declaration."""
    if pick is None:
        return None
    allowed = {k: v for k, v in schema.items() if k not in ("scene", "seed")}
    if not pick:
        raise PanoreconInputError(f"suite {path}: {where} is empty; expected e.g. {where} = {{ source = ... }}")
    for k, v in pick.items():
        if k not in allowed:
            hint = f"; {where} picks a table row, compared on every scene and seed" if k in schema else ""
            raise PanoreconInputError(str(_unknown(path, where, k, allowed)) + hint)
        check_value(path, where, k, v, schema)
    return pick


def _check_margins(path: Path, data: dict) -> dict:
    """``margins = { metric = value }``: metrics with a direction (``stats.DIRECTION``), positive finite values."""
    from .stats import DIRECTION

    margins = data.get("margins", {})
    for k, v in margins.items():
        if not DIRECTION.get(k):
            raise _unknown(path, "margins", k, {c for c, d in DIRECTION.items() if d})
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (0 < v < float("inf")):
            raise PanoreconInputError(f"suite {path}: margins {k} = {v!r}: expected a positive number (metric's unit)")
    return {k: float(v) for k, v in margins.items()}


def _one_row(path: Path, where: str, pick: dict, labels: list[str], all_labels: list[str]) -> str:
    """The one table label that ``pick`` matched, else one error naming what it matched."""
    if len(labels) == 1:
        return labels[0]
    said = ", ".join(f"{k} = {v!r}" for k, v in pick.items())
    raise PanoreconInputError(
        f"suite {path}: {where} {{ {said} }} matches "
        + (
            f"{len(labels)} rows ({', '.join(labels)}); add keys to pick one"
            if labels
            else f"no row; the rows are {', '.join(dict.fromkeys(all_labels))}"
        )
    )


def _with_root(value, root: str | None, path: Path):
    if not isinstance(value, str) or "{root}" not in value:
        return value
    if not root:
        raise PanoreconInputError(f"suite {path}: {value!r} needs the dataset root: give --root DIR or set ${ROOT_ENV}")
    return value.replace("{root}", str(root))


def _expand_scene(scene: str, path: Path) -> list[str]:
    """A population of synthetic variants ``NAME@A..B`` -> NAME@A, ..., NAME@B; a dataset scene with a ``*`` in
    its key -> the matching panoramas under its root (sorted); else [scene]."""
    from ..scenes.catalog import VARIANT_SEP
    from ..scenes.datasets import is_dataset_name, split_name

    if VARIANT_SEP in scene and ".." in scene.rpartition(VARIANT_SEP)[2] and not is_dataset_name(scene):
        return _expand_variants(scene, path)
    if "*" not in scene or not is_dataset_name(scene):
        return [scene]
    ds, root, pattern = split_name(scene)
    if not root.is_dir():
        raise PanoreconInputError(f"suite {path}: dataset root {root} of {scene!r} is not a folder")
    found = [f"{ds.prefix}:{root / k}" for k in ds.keys(root) if fnmatch.fnmatch(k, pattern)]
    if not found:
        raise PanoreconInputError(f"suite {path}: no {ds.prefix} panorama under {root} matches {scene!r}")
    return found


def _rendered_folder(scene: str, scene_dir: Path, spec: dict, width: int, seeds: list[int], path: Path) -> str:
    """``scene_dir/scene``, checked to be a ``panorecon render`` folder ``width`` px wide whose held-out views
    were recorded at the row's label size for every seed (what ``scenes.rendered.load_rendered`` replays)."""
    import json

    from PIL import Image

    from ..scenes.rendered import HELDOUT_FILE
    from ..splat.trainer import TrainConfig

    folder, train = scene_dir / scene, TrainConfig()
    heldout, res = spec.get("heldout", train.heldout), spec.get("res", train.res)
    make = (
        f"write it with `panorecon render {scene} --width {width} --heldout {heldout} --heldout-res {res} "
        f"--heldout-seeds {' '.join(map(str, seeds))} --out {folder}`"
    )
    if not (folder / "scene.json").is_file() or not (folder / "pano.png").is_file():
        raise PanoreconInputError(f"suite {path}: --scene-dir: {folder} is not a `panorecon render` folder; {make}")
    with Image.open(folder / "pano.png") as im:
        if im.width != width:
            raise PanoreconInputError(
                f"suite {path}: --scene-dir: {folder} is {im.width} px wide, the rows {width}; {make}"
            )
    if heldout:
        recorded = json.loads((folder / "scene.json").read_text()).get("heldout_seeds", [0])
        missing = [s for s in seeds if s not in recorded]
        if not (folder / HELDOUT_FILE.format(res=res)).is_file() or missing:
            raise PanoreconInputError(
                f"suite {path}: --scene-dir: {folder} has no held-out views at {res} px for seed(s) "
                f"{', '.join(map(str, missing or seeds))}; {make}"
            )
    return str(folder)


def _variant_span(scene: str, path: Path) -> tuple[str, int, int]:
    """``bedroom@1..10`` -> ("bedroom", 1, 10), checked (integers 1 <= A <= B, a synthetic scene's variant)."""
    from ..scenes.catalog import VARIANT_SEP
    from ..scenes.registry import parse_variant

    base, _, span = scene.rpartition(VARIANT_SEP)
    first, _, last = span.partition("..")
    if not all(k.isascii() and k.isdigit() and str(int(k)) == k for k in (first, last)) or not (
        1 <= int(first) <= int(last)
    ):
        raise PanoreconInputError(
            f"suite {path}: scene {scene!r}: expected a population NAME{VARIANT_SEP}A..B with integers "
            f"1 <= A <= B, e.g. bedroom{VARIANT_SEP}1..10"
        )
    try:
        parse_variant(f"{base}{VARIANT_SEP}{first}")
    except PanoreconInputError as e:
        raise PanoreconInputError(f"suite {path}: {e}") from None
    return base, int(first), int(last)


def _expand_variants(scene: str, path: Path) -> list[str]:
    """``bedroom@1..10`` -> ["bedroom@1", ..., "bedroom@10"] (both ends included), each name checked."""
    from ..scenes.catalog import VARIANT_SEP

    base, first, last = _variant_span(scene, path)
    return [f"{base}{VARIANT_SEP}{k}" for k in range(first, last + 1)]


def _scene_count(scene: str, path: Path) -> int:
    """How many scenes ``_expand_scene(scene, path)`` gives, without building a population's names (a dataset
    pattern is listed: its size is the dataset's)."""
    from ..scenes.catalog import VARIANT_SEP
    from ..scenes.datasets import is_dataset_name

    if VARIANT_SEP in scene and ".." in scene.rpartition(VARIANT_SEP)[2] and not is_dataset_name(scene):
        _, first, last = _variant_span(scene, path)
        return last - first + 1
    return len(_expand_scene(scene, path))


def count_rows(
    path: Path, defaults: dict, grid: dict, variants: list[dict], seeds: list[int] | None, root: str | None
) -> int:
    """The number of rows ``load_suite`` expands a checked suite to, from the sizes alone: per variant, the
    product of the [grid] lists' lengths, times the scenes each scene value stands for (a population
    ``NAME@A..B`` is B - A + 1 scenes, a dataset pattern its matching panoramas), times the seeds. No row is
    built: a suite of 10^6 rows is counted in microseconds (``load_suite(max_runs=...)`` refuses it before)."""
    cache: dict = {}

    def scenes(value) -> int:
        if value not in cache:
            cache[value] = _scene_count(_with_root(value, root, path), path)
        return cache[value]

    total = 0
    for variant in variants:
        others = math.prod(len(v) for k, v in grid.items() if k != "scene" or "scene" in variant)
        if "scene" in variant:
            total += others * scenes(variant["scene"])
        elif "scene" in grid:
            total += others * sum(scenes(v) for v in grid["scene"])
        else:  # no scene anywhere: load_suite names the missing key when it builds the first row
            total += others * (scenes(defaults["scene"]) if "scene" in defaults else 1)
    return total * (len(seeds) if seeds else 1)


def parse_override(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` (``ablate --set``) -> (key, value), the value read as a TOML value (``iters=10000``,
    ``teacher="sim:clean"``, or a bare word as a string: ``teacher=sim:clean``)."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise PanoreconInputError(f"--set {text!r}: expected KEY=VALUE, e.g. --set iters=10000")
    try:
        parsed = tomllib.loads(f"v = {value}")["v"]
    except tomllib.TOMLDecodeError:
        parsed = value
    return key.strip(), parsed


def _suite_data(path: Path, within: tuple = ()) -> dict:
    """The suite file's top-level tables, checked, with those of the suite it ``extends`` (a path relative to it)
    beneath: [defaults] and [pinned] merged key by key, every other table or value taken whole from ``path``."""
    if not path.is_file():
        where = f" (extended by {within[-1]})" if within else " (the shipped suites are in eval/suites/)"
        raise PanoreconInputError(f"suite {path}: no such file{where}")
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise PanoreconInputError(f"suite {path}: not valid TOML ({e})") from None
    _check_top(path, data)
    if "extends" not in data:
        return data
    base = path.parent / data.pop("extends")
    if base.resolve() in within or base.resolve() == path.resolve():
        raise PanoreconInputError(f"suite {path}: extends {base}, which extends it back")
    parent = _suite_data(base, (*within, path.resolve()))
    return {**parent, **data} | {k: {**parent.get(k, {}), **data.get(k, {})} for k in ("defaults", "pinned")}


def load_suite(
    path,
    root: str | None = None,
    overrides: dict | None = None,
    scene_dir: str | None = None,
    max_runs: int | None = None,
    unpinned: bool = False,
) -> Suite:
    """Read and check a suite file -> Suite with one Row per grid point (one clear error for a bad file).
    ``root``: the dataset root for ``{root}`` (default $PANORECON_DATASET_ROOT). ``overrides``: settings that
    replace the suite's [defaults] (e.g. the paper's iters = 10000 on a GPU), checked as [defaults] are; a key
    that the suite's [grid] or [[variants]] sets is refused (the override would be silently lost).
    ``scene_dir``: each scene NAME is read from its ``panorecon render`` folder ``scene_dir/NAME`` (a machine
    without Open3D); the rows' scene is that folder's path, so their runs and cache entries are their own.
    ``max_runs``: a suite that expands to more rows than this is refused with its exact count (``count_rows``,
    from the grid's sizes) before any row is built. ``unpinned``: the suite without its [pinned] settings (a
    committed table rerun under today's defaults)."""
    path = Path(path)
    root = root or os.environ.get(ROOT_ENV)
    data = _suite_data(path)
    from ..splat.trainer import TrainConfig

    schema = row_settings()
    train_fields = {f.name for f in dataclasses.fields(TrainConfig)}
    defaults, grid, variants = data.get("defaults", {}), data.get("grid", {}), data.get("variants", [{}])
    pinned = data.get("pinned", {})
    _check_table(path, "[defaults]", defaults, schema)
    _check_table(path, "[pinned]", pinned, schema)
    for k in pinned:
        if k in grid or any(k in v for v in variants):
            raise PanoreconInputError(
                f"suite {path}: [pinned] {k}: {k} is a row variable of this suite ([grid] or [[variants]])"
            )
    if not unpinned:
        defaults = {**defaults, **pinned}
    if overrides:
        _check_table(path, "--set", overrides, schema)
        for k in overrides:
            if k in grid or any(k in v for v in variants):
                raise PanoreconInputError(
                    f"suite {path}: --set {k}: {k} is a row variable of this suite ([grid] or [[variants]]); "
                    "only [defaults] can be overridden"
                )
        defaults = {**defaults, **overrides}
    _check_table(path, "[grid]", grid, schema, listed=True)
    for i, v in enumerate(variants):
        _check_table(path, f"[[variants]] {i + 1}", v, schema)
    row_columns = list(data.get("rows", ["source"]))
    for c in row_columns:
        if c not in schema:
            raise _unknown(path, "rows", c, schema)
    seeds = _check_seeds(path, data, [defaults, grid, *variants])
    reference = _check_row_pick(path, "reference", data.get("reference"), schema)
    margins = _check_margins(path, data)
    paper_rows = data.get("paper", {}).get("rows", [])
    paper_picks = {
        i: _check_row_pick(path, f"[paper] rows[{i + 1}] match", r["match"], schema)
        for i, r in enumerate(paper_rows)
        if "match" in r
    }
    if max_runs is not None and (n := count_rows(path, defaults, grid, variants, seeds, root)) > max_runs:
        raise PanoreconInputError(
            f"suite {path} expands to {n} runs, more than --max-runs {max_runs}; pass a larger --max-runs to run it"
        )
    rows, reference_labels = [], []
    paper_found: dict[int, list[str]] = {i: [] for i in paper_picks}
    for variant in variants:
        for combo in itertools.product(*grid.values()):
            spec = {**defaults, **dict(zip(grid, combo)), **variant}
            for need in ("scene", "source"):
                if need not in spec:
                    raise PanoreconInputError(f"suite {path}: no {need!r} in [defaults], [grid] or [[variants]]")
            train_cfg = {k: v for k, v in spec.items() if k in train_fields}
            label = spec.get("label") or " / ".join(str(spec.get(c, "")) for c in row_columns)
            try:  # the settings together (each key alone is checked above)
                TrainConfig(**train_cfg)
            except ValueError as e:
                raise PanoreconInputError(f"suite {path}: row {label!r}: {e}") from None
            named = {**spec, "label": label}  # reference = { label = "..." } names a row by its table label
            for pick, found in [(reference, reference_labels)] + [
                (paper_picks[i], paper_found[i]) for i in paper_picks
            ]:
                if pick and all(named.get(k) == v for k, v in pick.items()) and label not in found:
                    found.append(label)
            extra = {c: spec.get(c) for c in row_columns if c not in ROW_KEYS}
            depth = _with_root(spec.get("depth"), root, path)
            if depth is None and ("depth_scale" in spec or "depth_kind" in spec):
                raise PanoreconInputError(f"suite {path}: depth_scale / depth_kind without a depth file")
            depth = (depth, spec.get("depth_scale"), spec.get("depth_kind", "distance")) if depth else None
            width, row_seeds = int(spec.get("width", 512)), seeds or [spec.get("seed", 0)]
            for scene in _expand_scene(_with_root(spec["scene"], root, path), path):
                if scene_dir is not None:
                    scene = _rendered_folder(scene, Path(scene_dir), spec, width, row_seeds, path)
                for seed in row_seeds:
                    rows.append(
                        Row(
                            scene=scene,
                            width=width,
                            source=spec["source"],
                            teacher=spec.get("teacher"),
                            views=spec.get("views"),
                            train={**train_cfg, **({"seed": seed} if seeds else {})}
                            if spec.get("train", True)
                            else None,
                            label=label,
                            depth=depth,
                            fusion={k: spec[k] for k in sorted(FUSION_KEYS) if k in spec} or None,
                            extra={
                                **extra,
                                **{k: spec[k] for k in ("strategy", "labels", "iters", "res") if k in spec},
                            },
                            seed=seed,
                        )
                    )
    if not rows:
        raise PanoreconInputError(f"suite {path}: the grid is empty")
    labels = [r.label for r in rows]
    if reference:
        _one_row(path, "reference", reference, reference_labels, labels)
    paper_labels = {
        _one_row(path, f"[paper] rows[{i + 1}] match", paper_picks[i], found, labels): i
        for i, found in paper_found.items()
    }
    return Suite(
        path.stem,
        data.get("title", path.stem),
        rows,
        row_columns,
        data.get("paper", {}),
        path,
        seeds or sorted({r.seed for r in rows}),
        reference_labels[0] if reference else None,
        margins,
        paper_labels,
        pinned,
        unpinned,
    )


def resolve_names(suite: Suite) -> None:
    """Check every scene, source and teacher the suite's rows name, before any stage runs: a registered scene,
    an existing image file or ``prompt:<text>`` with $PANORECON_TEXT2PANO_MODEL set; a registered point source
    (one that needs a teacher gets one); a teacher spec that loads. Raises PanoreconInputError naming the
    suite file, the row and the name."""
    import os

    from ..pipeline.stages import PROMPT_PREFIX, TEXT2PANO_MODEL_ENV
    from ..scenes import list_scenes
    from ..scenes.catalog import VARIANT_SEP
    from ..scenes.datasets import is_dataset_name
    from ..scenes.registry import parse_variant
    from ..sources import get_source
    from ..teachers import get_teacher

    where = f"suite {suite.path or suite.name}"
    scenes = {s.name for s in list_scenes() if s.kind != "variant"}
    checked: set = set()
    for row in suite.rows:
        what = f"{where}, row {row.label!r}"
        if row.scene not in scenes and row.scene not in checked:
            if VARIANT_SEP in row.scene and not Path(row.scene).exists() and not is_dataset_name(row.scene):
                try:
                    parse_variant(row.scene)
                except PanoreconInputError as e:
                    raise PanoreconInputError(f"{what}: {e}") from None
            elif row.scene.startswith(PROMPT_PREFIX):
                if not os.environ.get(TEXT2PANO_MODEL_ENV):
                    raise PanoreconInputError(
                        f"{what}: scene {row.scene!r} is a prompt: set ${TEXT2PANO_MODEL_ENV} "
                        "to a local diffusers model folder"
                    )
            elif not (
                Path(row.scene).is_file()
                or Path(row.scene.removeprefix("rendered:")).is_dir()
                or is_dataset_name(row.scene)
            ):
                close = difflib.get_close_matches(row.scene, sorted(scenes), n=1, cutoff=0.5)
                raise PanoreconInputError(
                    f"{what}: unknown scene {row.scene!r}"
                    + (
                        f"; did you mean {close[0]!r}?"
                        if close
                        else "; expected a scene name (see `panorecon scenes list`) or an image"
                    )
                )
            checked.add(row.scene)
        try:
            spec = get_source(row.source)
        except PanoreconInputError as e:
            raise PanoreconInputError(f"{what}: {e}") from None
        if spec.uses_teacher and not row.teacher:
            raise PanoreconInputError(f"{what}: source {row.source!r} needs a teacher")
        if row.teacher and row.teacher not in checked and (spec.uses_teacher or row.train is not None):
            try:
                get_teacher(row.teacher)
            except PanoreconInputError as e:
                if not str(e).startswith("n/a"):  # a teacher that cannot run here gives n/a rows, not an error
                    raise PanoreconInputError(f"{what}: {e}") from None
            checked.add(row.teacher)
