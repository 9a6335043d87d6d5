"""``panorecon scenes check``: does a dataset copy's geometry hold together? Run once before trusting any table.

For every fully posed panorama with a depth (position and orientation, see ``datasets.py``), its pixels are
placed in the dataset's world (world point = position + rotation @ (distance * direction)) and tested against

- the other panoramas of its space: a point X of panorama i, seen from panorama j at distance r, *agrees* when
  j's own true distance along that direction is within ``AGREE_REL_TOL`` of r, *contradicts* when j sees
  farther (j looks through where i says a surface is), and is left out when j sees nearer (X is occluded from
  j). A pair's agreement is agree / (agree + contradict) over both directions, counted when at least
  ``MIN_PAIR_PIXELS`` pixels were compared; a panorama's ``agreement`` is its best pair's, its ``agreeing`` the
  fraction of its pixels that some other panorama confirms;
- the dataset's own geometry where it ships some (Structured3D ``annotation_3d.json``): the fraction of its
  wall-band pixels (|latitude| < ``WALL_BAND_DEG``) within ``PLANE_TOL_M`` of an annotated wall plane.

Two questions, answered apart:

- **The convention** (the adapter's orientation and depth unit) belongs to the dataset, not to one panorama, so
  it is judged over a whole space (``MEASURES``): ``agreeing``, the median over its panoramas, and ``walls``,
  pooled over all their wall-band pixels, under the adapter's convention and under each alternative
  (``ALTERNATIVES``: the seven other quarter turns and mirrors about the panorama's vertical axis, applied to
  every panorama; ``DEPTH_UNITS``: every depth read in another unit). ``margin`` = the adapter's value minus the
  best alternative's; the convention is flagged when an alternative beats it by more than ``CONVENTION_MARGIN``
  on either measure (on ``agreeing``, an alternative under which the panoramas agree: median best-pair
  agreement at least ``AGREE_MIN``). A furnished wall band lowers one room's wall fraction under every
  convention alike, so a single room is never judged by it.
- **A panorama** is flagged only for what can be wrong with that one panorama (its pose or its depth file): an
  agreement below ``AGREE_MIN`` with every other panorama that sees the same surfaces, while the convention of
  its space is not flagged (under a flagged convention every panorama disagrees, and the convention is the
  finding).

Depth and directions are float64; the panoramas are read at ``width`` (nearest-neighbour depth); the
convention comparison uses every k-th valid pixel of each panorama, k the smallest that keeps at most
``CONVENTION_POINTS`` (the tested panorama's depth is looked up at full ``width``).
"""

from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..geometry import erp_directions, sample_erp
from ..io.depth import PLAUSIBLE_MEDIAN_M, default_depth_scale
from .datasets import DATASETS, load_dataset_scene, structured3d_planes

AGREE_REL_TOL = 0.05
MIN_PAIR_PIXELS = 256
AGREE_MIN = 0.9
WALL_BAND_DEG = 17.0
PLANE_TOL_M = 0.05
CONVENTION_MARGIN = 0.05
CONVENTION_POINTS = 32768
# metres per stored unit of the depth-unit alternatives (the field's usual units, io/depth.py UNIT_CONVENTIONS); one
# is tried when it puts the space's median distance within io/depth.py PLAUSIBLE_MEDIAN_M (a depth read 1000x too
# far makes any two panoramas look as if taken at one point, and two look-alike rooms agree)
DEPTH_UNITS = (("m", 1.0), ("cm", 1e-2), ("mm", 1e-3), ("1/512 m", 1 / 512), ("1/4000 m", 1 / 4000))
MEASURES = ("agreeing", "walls")  # what a convention is judged by (``_score``)
_MIRROR = np.diag([1.0, -1.0, 1.0])  # the image flipped left-right about its centre column


def _yaw(quarter_turns: int) -> np.ndarray:
    c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][quarter_turns % 4]
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


# (label, A [3, 3]): a panorama-frame direction d is placed at rotation @ A @ d; A = I is the adapter's own
ALTERNATIVES = tuple(
    (
        ", ".join(["mirrored"] * m + [f"yaw {['0°', '+90°', '180°', '-90°'][k]}"] * (k > 0)),
        _yaw(k) @ (_MIRROR if m else np.eye(3)),
    )
    for m in (False, True)
    for k in range(4)
)[1:]


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


@dataclass
class ConventionCheck:
    """One space's convention against the alternatives. ``candidates``: one dict per convention, the adapter's
    first (convention, depth_unit, agreeing, agreement, compared, walls, wall_pixels: ``_score``); ``margin`` and
    ``best_alternative`` per measure of MEASURES: the adapter's value minus the best alternative's, and that
    alternative's label (None where the measure had nothing to measure); ``verdict``: ok, FLAGGED, unconfirmed
    (no measure tells the adapter's convention from an alternative by the margin) or "-" (nothing measured)."""

    group: str
    panoramas: int
    candidates: list = field(default_factory=list)
    margin: dict = field(default_factory=dict)
    best_alternative: dict = field(default_factory=dict)
    verdict: str = "-"
    flags: list = field(default_factory=list)
    note: str = ""


@dataclass
class CheckReport:
    conventions: list[ConventionCheck]
    panoramas: list[PanoramaCheck]

    @property
    def flagged(self) -> bool:
        return any(c.flags for c in self.conventions) or any(p.flags for p in self.panoramas)

    def to_dict(self) -> dict:
        return {
            "convention_margin": CONVENTION_MARGIN,
            "agree_min": AGREE_MIN,
            "conventions": [dataclasses.asdict(c) for c in self.conventions],
            "panoramas": [dataclasses.asdict(p) for p in self.panoramas],
        }


@dataclass(frozen=True)
class _Posed:
    """A panorama placed in the world: centre [3], rotation [3, 3] (world direction of a panorama-frame
    direction; an alternative may be a mirror), ray distance [H, W] float32 metres (NaN unknown)."""

    name: str
    position: np.ndarray
    rotation: np.ndarray
    distance: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.distance) & (self.distance > 0)

    def points(self, mask: np.ndarray) -> np.ndarray:
        """World points [N, 3] float64 of the pixels of ``mask`` [H, W] (valid ones only)."""
        local = self.distance.astype(np.float64)[mask][:, None] * _directions(*self.distance.shape)[mask]
        return self.position + local @ self.rotation.T


@functools.lru_cache(maxsize=8)
def _directions(height: int, width: int) -> np.ndarray:
    d = erp_directions(height, width)
    d.flags.writeable = False
    return d


def _posed(scene, turn: np.ndarray | None = None, factor: float = 1.0) -> _Posed:
    rot = np.asarray(scene.meta["rotation"], np.float64)
    return _Posed(
        scene.name,
        np.asarray(scene.meta["position"], np.float64),
        rot if turn is None else rot @ turn,
        scene.distance if factor == 1.0 else (scene.distance * np.float32(factor)),
    )


def world_points(scene) -> tuple[np.ndarray, np.ndarray]:
    """A posed dataset scene's valid pixels -> (world points [N, 3] float64 metres, their [H, W] bool mask)."""
    p = _posed(scene)
    return p.points(p.valid), p.valid


def _test(points: np.ndarray, other: _Posed) -> tuple[np.ndarray, np.ndarray]:
    """World points [N, 3] tested against ``other``'s true distance -> (agree [N] bool, contradict [N] bool)."""
    v = (points - other.position) @ other.rotation  # rotation.T @ (X - c) row-wise; orthogonal, mirrors too
    r = np.linalg.norm(v, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        seen = sample_erp(other.distance.astype(np.float32), (v / r[:, None])[None], "nearest")[0].astype(np.float64)
        ok = np.isfinite(seen) & (r > 0)
        agree = ok & (np.abs(seen - r) <= AGREE_REL_TOL * r)
        contra = ok & (seen > (1 + AGREE_REL_TOL) * r)
    return agree, contra


def _wall_band(height: int, width: int) -> np.ndarray:
    lat = np.degrees((0.5 - (np.arange(height) + 0.5) / height) * np.pi)
    return (np.abs(lat) < WALL_BAND_DEG)[:, None].repeat(width, 1)


def _on_planes(points: np.ndarray, planes: np.ndarray) -> int:
    if not len(points) or not len(planes):
        return 0
    return int((np.abs(points @ planes[:, :3].T + planes[:, 3]).min(1) <= PLANE_TOL_M).sum())


def wall_fraction(scene, planes: np.ndarray) -> tuple[float | None, int]:
    """Fraction of a posed scene's valid wall-band pixels within PLANE_TOL_M of one of ``planes`` [P, 4]
    (unit normal, offset: n . x + offset = 0, metres), and how many such pixels there were."""
    p = _posed(scene)
    band = p.valid & _wall_band(scene.height, scene.width)
    if not band.any() or len(planes) == 0:
        return None, int(band.sum())
    return _on_planes(p.points(band), planes) / int(band.sum()), int(band.sum())


def _depth_scale(scene) -> float:
    """Metres per stored unit the adapter read the scene's depth file with."""
    scale = scene.meta.get("depth_scale")
    return float(scale) if scale is not None else default_depth_scale(scene.meta["depth"])


def _sample(valid: np.ndarray) -> np.ndarray:
    """Every k-th valid pixel [H, W] bool, k the smallest keeping at most CONVENTION_POINTS."""
    idx = np.flatnonzero(valid)
    out = np.zeros(valid.size, bool)
    out[idx[:: max(1, -(-len(idx) // CONVENTION_POINTS))]] = True
    return out.reshape(valid.shape)


def _score(posed: list[_Posed], samples: list[np.ndarray], planes: np.ndarray | None) -> dict:
    """One convention's placement of a space scored on the sampled pixels, each a median over its panoramas so
    that one wrong panorama does not outvote the others: ``agreeing``, the fraction of a panorama's pixels that
    some other panorama confirms (as ``PanoramaCheck.agree_fraction``; None for a lone panorama); ``agreement``,
    a panorama's best pair agreement (as ``PanoramaCheck.agreement``, over the panoramas that have a pair to
    measure: ``compared`` of them); and ``walls``, the wall-band fraction pooled over all of them
    (``wall_pixels``)."""
    pts = [p.points(m) for p, m in zip(posed, samples)]
    counts, confirmed = {}, [np.zeros(len(p), bool) for p in pts]  # (i, j) -> (agree, contradict) of i against j
    for i, p in enumerate(pts):
        for j, q in enumerate(posed):
            if i != j:
                a, c = _test(p, q)
                counts[i, j] = (int(a.sum()), int(c.sum()))
                confirmed[i] |= a
    best = []
    for i in range(len(posed)):
        others = [j for j in range(len(posed)) if j != i]
        pairs = [(counts[i, j][0] + counts[j, i][0], sum(counts[i, j]) + sum(counts[j, i])) for j in others]
        scored = [a / n for a, n in pairs if n >= MIN_PAIR_PIXELS]
        if scored:
            best.append(max(scored))
    agreeing = [float(c.mean()) for c in confirmed if len(c)] if len(posed) > 1 else []
    out = {
        "agreeing": float(np.median(agreeing)) if agreeing else None,
        "agreement": float(np.median(best)) if best else None,
        "compared": len(best),
        "walls": None,
        "wall_pixels": 0,
    }
    if planes is not None and len(planes):
        on = 0
        for p, m in zip(posed, samples):
            band = m & _wall_band(*m.shape)
            on += _on_planes(p.points(band), planes)
            out["wall_pixels"] += int(band.sum())
        out["walls"] = on / out["wall_pixels"] if out["wall_pixels"] else None
    return out


def check_convention(group: str, scenes: list, planes: np.ndarray | None) -> ConventionCheck:
    """The adapter's convention of one space's posed ``scenes`` against ALTERNATIVES and DEPTH_UNITS (module doc)."""
    res = ConventionCheck(group, len(scenes))
    samples = [_sample(s.valid) for s in scenes]
    scales = [_depth_scale(s) for s in scenes]
    runs = [("the adapter's", "as read", None, [1.0] * len(scenes))]
    runs += [(label, "as read", turn, [1.0] * len(scenes)) for label, turn in ALTERNATIVES]
    sampled = [s.distance[m].astype(np.float64) for s, m in zip(scenes, samples)]
    for unit, u in DEPTH_UNITS:
        factors = [u / s for s in scales]
        median = float(np.median(np.concatenate([d * f for d, f in zip(sampled, factors)])))
        if PLAUSIBLE_MEDIAN_M[0] <= median <= PLAUSIBLE_MEDIAN_M[1] and not np.allclose(factors, 1.0):
            runs.append((f"depth in {unit}", unit, None, factors))
    for label, unit, turn, factors in runs:
        posed = [_posed(s, turn, f) for s, f in zip(scenes, factors)]
        res.candidates.append({"convention": label, "depth_unit": unit, **_score(posed, samples, planes)})
    own, alts = res.candidates[0], res.candidates[1:]
    clear = False
    for measure in MEASURES:
        scored = [c for c in alts if c[measure] is not None]
        best = max(scored, key=lambda c: c[measure]) if scored else None
        if own[measure] is None or best is None or max(own[measure], best[measure]) == 0:  # nothing measured
            res.margin[measure] = res.best_alternative[measure] = None
            continue
        res.margin[measure] = own[measure] - best[measure]
        res.best_alternative[measure] = best["convention"]
        clear |= res.margin[measure] >= CONVENTION_MARGIN
        # a convention under which the panoramas contradict each other confirms a few pixels by chance only
        winners = [
            c
            for c in scored
            if c[measure] - own[measure] > CONVENTION_MARGIN
            and (measure != "agreeing" or (c["agreement"] or 0) >= AGREE_MIN)
        ]
        if winners:
            w = max(winners, key=lambda c: c[measure])
            res.flags.append(
                f"{measure}: {w['convention']} gives {w[measure]:.3f} against the adapter's {own[measure]:.3f}"
                f" (beats it by more than {CONVENTION_MARGIN}): the dataset's orientation or depth unit is not the "
                "adapter's"
            )
    if res.flags:
        res.verdict = "FLAGGED"
    elif clear:
        res.verdict = "ok"
    elif any(v is not None for v in res.margin.values()):
        res.verdict = "unconfirmed"
        res.note = f"no measure tells the adapter's convention from an alternative by {CONVENTION_MARGIN}"
    else:
        res.note = "nothing to compare: no two panoramas see the same surfaces and no annotated planes"
    return res


def check_root(root: Path, width: int = 512) -> CheckReport:
    """Every panorama under ``root`` that an adapter recognises, checked (see the module doc)."""
    root = Path(root)
    report = CheckReport([], [])
    for ds in DATASETS.values():
        groups: dict[str, list[str]] = {}
        for key in ds.keys(root):
            groups.setdefault(ds.group(key), []).append(key)
        for group, keys in sorted(groups.items()):
            label = f"{ds.prefix}:{group}"
            scenes = [load_dataset_scene(f"{ds.prefix}:{root / k}", width) for k in keys]
            posed = [s for s in scenes if s.meta["rotation"] is not None and s.distance is not None]
            results = {s.name: PanoramaCheck(s.name, label, s.meta["orientation"], int(s.valid.sum())) for s in scenes}
            for s in scenes:
                if s.meta["rotation"] is None:
                    results[s.name].note += f"not checked: no full pose ({s.meta['orientation']}); "
                elif s.distance is None:
                    results[s.name].note += "not checked: no depth file; "
            _agreement(posed, results)
            planes = structured3d_planes(root, group) if ds.prefix == "structured3d" else None
            if ds.prefix == "structured3d":
                for s in posed:
                    if planes is None:
                        results[s.name].note += f"no {group}/annotation_3d.json: wall planes not checked; "
                    else:
                        results[s.name].wall_on_planes, results[s.name].wall_pixels = wall_fraction(s, planes)
            convention = check_convention(label, posed, planes) if posed else None
            for r in results.values():
                if r.agreement is not None and r.agreement < AGREE_MIN:
                    if convention is not None and convention.flags:
                        r.note += "its low agreement is the flagged convention's, not judged alone; "
                    else:
                        r.flags.append(
                            f"agrees with no other panorama of its space (best {r.agreement:.2f} < {AGREE_MIN}): "
                            "its pose or its depth file is wrong"
                        )
                r.note = r.note.rstrip("; ")
            if convention is not None:
                report.conventions.append(convention)
            report.panoramas += results.values()
    return report


def _agreement(posed, results) -> None:
    placed = [_posed(s) for s in posed]
    pts = {p.name: p.points(p.valid) for p in placed}
    tests = {}  # (i, j) -> (agree, contradict) of i's points against j
    for i in placed:
        for j in placed:
            if i is not j:
                tests[i.name, j.name] = _test(pts[i.name], j)
    for i in placed:
        r = results[i.name]
        any_agree = np.zeros(len(pts[i.name]), bool)
        for j in placed:
            if i is j:
                continue
            a1, c1 = tests[i.name, j.name]
            a2, c2 = tests[j.name, i.name]
            any_agree |= a1
            agree, n = int(a1.sum() + a2.sum()), int(a1.sum() + a2.sum() + c1.sum() + c2.sum())
            r.pairs[j.name] = {"compared": n, "agreement": agree / n if n >= MIN_PAIR_PIXELS else None}
            if n >= MIN_PAIR_PIXELS and (r.agreement is None or agree / n > r.agreement):
                r.agreement, r.agrees_best_with = agree / n, j.name
        if len(placed) > 1 and len(pts[i.name]):
            r.agree_fraction = float(any_agree.mean())
        if r.agreement is None and len(placed) > 1:
            r.note += f"no other panorama shares {MIN_PAIR_PIXELS} compared pixels with it; "


def _f(v, sign=False):
    return "n/a" if v is None else (f"{v:+.3f}" if sign else f"{v:.3f}")


def report_table(report: CheckReport) -> str:
    """Plain text: one line per space's convention (the adapter's value, the best alternative's and the margin
    per measure), then one line per panorama, flags spelt out beneath."""
    lines = []
    for c in report.conventions:
        own = c.candidates[0]
        parts = [
            f"{m} {_f(own[m])} vs {_f(max((x[m] for x in c.candidates[1:] if x[m] is not None), default=None))}"
            f" ({c.best_alternative[m]}; margin {_f(c.margin[m], True)})"
            if c.best_alternative[m]
            else f"{m} {_f(own[m])}"
            for m in MEASURES
        ]
        lines.append(f"convention of {c.group} ({c.panoramas} panoramas): {', '.join(parts)}: {c.verdict}")
        lines += [f"    {x}" for x in c.flags] + ([f"    {c.note}"] if c.note else [])
    results = report.panoramas
    w = max([len(r.name) for r in results] + [9])
    lines.append(f"{'panorama':<{w}}  {'agreement':>9}  {'agreeing':>8}  {'walls':>6}  verdict")
    for r in results:
        verdict = "FLAGGED" if r.flags else ("ok" if r.agreement is not None and r.agreement >= AGREE_MIN else "-")
        lines.append(
            f"{r.name:<{w}}  {_f(r.agreement):>9}  {_f(r.agree_fraction):>8}  {_f(r.wall_on_planes):>6}  {verdict}"
        )
        lines += [f"    {x}" for x in r.flags] + ([f"    {r.note}"] if r.note else [])
    return "\n".join(lines)


def summary_line(report: CheckReport) -> str:
    return (
        f"{len(report.panoramas)} panoramas, {sum(bool(p.flags) for p in report.panoramas)} flagged; "
        f"{len(report.conventions)} spaces, {sum(bool(c.flags) for c in report.conventions)} conventions flagged "
        f"(a space's convention against the {len(ALTERNATIVES)} other quarter turns and mirrors and the other depth "
        f"units, flagged when one beats it by more than {CONVENTION_MARGIN} in agreeing or walls; a panorama "
        f"flagged below {AGREE_MIN} agreement: true distances within {AGREE_REL_TOL:.0%} where two panoramas see "
        f"the same surface; walls: wall-band pixels within {PLANE_TOL_M * 100:.0f} cm of an annotated plane)"
    )
