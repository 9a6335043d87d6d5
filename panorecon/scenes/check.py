"""``panorecon scenes check``: does a dataset copy's geometry hold together? Run once before trusting any table.

For every fully posed panorama (position and orientation, see ``datasets.py``), its pixels are placed in the
dataset's world (world point = position + rotation @ (distance * direction)) and tested against

- the other panoramas of its space: a point X of panorama i, seen from panorama j at distance r, *agrees* when
  j's own true distance along that direction is within ``AGREE_REL_TOL`` of r, *contradicts* when j sees
  farther (j looks through where i says a surface is), and is left out when j sees nearer (X is occluded from
  j). A pair's agreement is agree / (agree + contradict) over both directions, counted when at least
  ``MIN_PAIR_PIXELS`` pixels were compared; a panorama's ``agreement`` is its best pair's (a mis-posed,
  mis-rotated or wrong-unit panorama agrees with none, while the others still agree with each other);
- the dataset's own geometry where it ships some (Structured3D ``annotation_3d.json``): the fraction of its
  wall-band pixels (|latitude| < ``WALL_BAND_DEG``) within ``PLANE_TOL_M`` of an annotated wall plane.

A panorama is flagged when its agreement is below ``AGREE_MIN`` or its wall fraction below ``PLANE_MIN``.
Depth and directions are float64; the panoramas are read at ``width`` (nearest-neighbour depth).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry import erp_directions, sample_erp
from .datasets import DATASETS, load_dataset_scene, structured3d_planes

AGREE_REL_TOL = 0.05
MIN_PAIR_PIXELS = 256
AGREE_MIN = 0.9
WALL_BAND_DEG = 17.0
PLANE_TOL_M = 0.05
PLANE_MIN = 0.7


@dataclass
class PanoramaCheck:
    """One panorama's result; fractions in [0, 1] or None where there was nothing to measure."""

    name: str
    group: str
    orientation: str
    valid_pixels: int = 0
    agreement: float | None = None
    agrees_best_with: str | None = None
    agree_fraction: float | None = None
    pairs: dict = field(default_factory=dict)
    wall_on_planes: float | None = None
    wall_pixels: int = 0
    flags: list = field(default_factory=list)
    note: str = ""


def world_points(scene) -> tuple[np.ndarray, np.ndarray]:
    """A posed dataset scene's valid pixels -> (world points [N, 3] float64 metres, their [H, W] bool mask)."""
    rot = np.asarray(scene.meta["rotation"], np.float64)
    pos = np.asarray(scene.meta["position"], np.float64)
    valid = scene.valid
    local = scene.distance.astype(np.float64)[valid][:, None] * erp_directions(scene.height, scene.width)[valid]
    return pos + local @ rot.T, valid


def _test(points: np.ndarray, other) -> tuple[np.ndarray, np.ndarray]:
    """World points [N, 3] tested against ``other``'s true distance -> (agree [N] bool, contradict [N] bool)."""
    rot = np.asarray(other.meta["rotation"], np.float64)
    v = (points - np.asarray(other.meta["position"], np.float64)) @ rot  # rot.T @ (X - c), row-wise
    r = np.linalg.norm(v, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        seen = sample_erp(other.distance.astype(np.float32), (v / r[:, None])[None], "nearest")[0].astype(np.float64)
        ok = np.isfinite(seen) & (r > 0)
        agree = ok & (np.abs(seen - r) <= AGREE_REL_TOL * r)
        contra = ok & (seen > (1 + AGREE_REL_TOL) * r)
    return agree, contra


def wall_fraction(scene, planes: np.ndarray) -> tuple[float | None, int]:
    """Fraction of a posed scene's valid wall-band pixels within PLANE_TOL_M of one of ``planes`` [P, 4]
    (unit normal, offset: n . x + offset = 0, metres), and how many such pixels there were."""
    pts, valid = world_points(scene)
    lat = np.degrees((0.5 - (np.arange(scene.height) + 0.5) / scene.height) * np.pi)
    band = (np.abs(lat) < WALL_BAND_DEG)[:, None].repeat(scene.width, 1)[valid]
    if not band.any() or len(planes) == 0:
        return None, int(band.sum())
    d = np.abs(pts[band] @ planes[:, :3].T + planes[:, 3]).min(1)
    return float((d <= PLANE_TOL_M).mean()), int(band.sum())


def check_root(root: Path, width: int = 512) -> list[PanoramaCheck]:
    """Every panorama under ``root`` that an adapter recognises, checked (see the module doc)."""
    root = Path(root)
    out = []
    for ds in DATASETS.values():
        groups: dict[str, list[str]] = {}
        for key in ds.keys(root):
            groups.setdefault(ds.group(key), []).append(key)
        for group, keys in sorted(groups.items()):
            scenes = [load_dataset_scene(f"{ds.prefix}:{root / k}", width) for k in keys]
            posed = [s for s in scenes if s.meta["rotation"] is not None]
            results = {
                s.name: PanoramaCheck(s.name, f"{ds.prefix}:{group}", s.meta["orientation"], int(s.valid.sum()))
                for s in scenes
            }
            for s in scenes:
                if s.meta["rotation"] is None:
                    results[s.name].note += f"not checked: no full pose ({s.meta['orientation']}); "
            _agreement(posed, results)
            if ds.prefix == "structured3d":
                planes = structured3d_planes(root, group)
                for s in posed:
                    if planes is None:
                        results[s.name].note += f"no {group}/annotation_3d.json: wall planes not checked; "
                    else:
                        results[s.name].wall_on_planes, results[s.name].wall_pixels = wall_fraction(s, planes)
            for r in results.values():
                if r.agreement is not None and r.agreement < AGREE_MIN:
                    r.flags.append(f"agrees with no other panorama of its space (best {r.agreement:.2f} < {AGREE_MIN})")
                if r.wall_on_planes is not None and r.wall_on_planes < PLANE_MIN:
                    r.flags.append(
                        f"wall band off the annotated planes ({r.wall_on_planes:.2f} within {PLANE_TOL_M * 100:.0f} cm"
                        f" < {PLANE_MIN})"
                    )
            for r in results.values():
                r.note = r.note.rstrip("; ")
            out += results.values()
    return out


def _agreement(posed, results) -> None:
    pts = {s.name: world_points(s)[0] for s in posed}
    tests = {}  # (i, j) -> (agree, contradict) of i's points against j
    for i in posed:
        for j in posed:
            if i is not j:
                tests[i.name, j.name] = _test(pts[i.name], j)
    for i in posed:
        r = results[i.name]
        any_agree = np.zeros(len(pts[i.name]), bool)
        for j in posed:
            if i is j:
                continue
            a1, c1 = tests[i.name, j.name]
            a2, c2 = tests[j.name, i.name]
            any_agree |= a1
            agree, n = int(a1.sum() + a2.sum()), int(a1.sum() + a2.sum() + c1.sum() + c2.sum())
            r.pairs[j.name] = {"compared": n, "agreement": agree / n if n >= MIN_PAIR_PIXELS else None}
            if n >= MIN_PAIR_PIXELS and (r.agreement is None or agree / n > r.agreement):
                r.agreement, r.agrees_best_with = agree / n, j.name
        if len(posed) > 1 and len(pts[i.name]):
            r.agree_fraction = float(any_agree.mean())
        if r.agreement is None and len(posed) > 1:
            r.note += f"no other panorama shares {MIN_PAIR_PIXELS} compared pixels with it; "


def report_table(results: list[PanoramaCheck]) -> str:
    """A plain-text table: one line per panorama, flags spelt out beneath."""

    def f(v):
        return "n/a" if v is None else f"{v:.3f}"

    w = max([len(r.name) for r in results] + [9])
    lines = [f"{'panorama':<{w}}  {'agreement':>9}  {'agreeing':>8}  {'walls':>6}  verdict"]
    for r in results:
        verdict = "FLAGGED" if r.flags else ("ok" if r.agreement is not None or r.wall_on_planes is not None else "-")
        lines.append(
            f"{r.name:<{w}}  {f(r.agreement):>9}  {f(r.agree_fraction):>8}  {f(r.wall_on_planes):>6}  {verdict}"
        )
        lines += [f"    {x}" for x in r.flags] + ([f"    {r.note}"] if r.note else [])
    return "\n".join(lines)
