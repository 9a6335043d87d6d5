"""Rows of a results.csv that an ``ablate`` invocation does not produce, and why.

``ablate`` rewrites each suite's results.csv from the suite's rows: a committed row that the invocation does not
produce (run with other ``--set`` settings, under a default that has moved since, or another suite's) would be
dropped. ``check_leftovers`` refuses before anything runs and says which rows, and, where they are the suite's
own rows under the defaults before one moved (``moved_defaults``: an option at the neutral value it declares,
``checks.opt(neutral=...)``, where its default is now another), names those settings and the two ways forward:
pin them in the suite's [pinned], or rerun under today's defaults into another folder.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from pathlib import Path

from ..fusion import FusionOptions
from ..io import PanoreconInputError
from ..pipeline import Row


def moved_defaults() -> dict[str, tuple[str, object, object]]:
    """name -> (where: "train" or "fusion", neutral value, today's default) for every setting whose default is no
    longer the value at which it behaves as before it existed."""
    from ..splat.trainer import TrainConfig

    out = {}
    for where, cls in (("train", TrainConfig), ("fusion", FusionOptions)):
        for f in dataclasses.fields(cls):
            if "neutral" in f.metadata and f.default != f.metadata["neutral"]:
                out[f.name] = (where, f.metadata["neutral"], f.default)
    return out


def _with(row: Row, names: tuple[str, ...], moved: dict) -> Row:
    """``row`` with each setting of ``names`` at its neutral value."""
    train, fusion = dict(row.train or {}), dict(row.fusion or {})
    for n in names:
        where, neutral, _ = moved[n]
        (train if where == "train" else fusion)[n] = neutral
    return dataclasses.replace(row, train=train if row.train is not None else None, fusion=fusion or None)


def explain(rows: list[Row], leftover: dict[str, dict]) -> tuple[dict[tuple[str, ...], list[str]], list[str]]:
    """``leftover`` (run_id -> results.csv record) split into the suite's ``rows`` under older defaults -> ({the
    settings at their neutral value: [run ids]}, [run ids of no row of the suite]). Only settings a row leaves
    at their default are tried, every subset of them (``moved_defaults``: a handful)."""
    moved = moved_defaults()
    found: dict[str, tuple[str, ...]] = {}
    for row in rows:
        free = [n for n in moved if n not in (row.train or {}) and n not in (row.fusion or {})]
        if row.train is None:  # a row that trains nothing: only the fusion settings apply
            free = [n for n in free if moved[n][0] == "fusion"]
        for k in range(1, len(free) + 1):
            for names in itertools.combinations(free, k):
                rid = _with(row, names, moved).run_id()
                if rid in leftover:
                    found.setdefault(rid, names)
    groups: dict[tuple[str, ...], list[str]] = {}
    for rid, names in found.items():
        groups.setdefault(names, []).append(rid)
    return groups, [rid for rid in leftover if rid not in found]


def check_leftovers(suites: list, outs: list[Path], done: list[dict[str, dict]], jobs: int) -> None:
    """PanoreconInputError, before anything runs, when a results.csv under ``outs`` (its records by run id in
    ``done``, one dict per suite) holds runs its suite does not produce here; the message says which and what to
    do. Nothing is written."""
    moved = moved_defaults()
    problems = []
    for suite, out, records in zip(suites, outs, done):
        want = {r.run_id() for r in suite.rows}
        leftover = {rid: rec for rid, rec in records.items() if rid not in want}
        if not leftover:
            continue
        groups, strangers = explain(suite.rows, leftover)
        lines = [
            f"{out / 'results.csv'} holds {len(leftover)} run(s) that {suite.path or suite.name} does not produce "
            "with these settings; rewriting it would drop them, so nothing was run."
        ]
        for names, rids in groups.items():
            said = ", ".join(f"{n} = {_toml(moved[n][1])} (now {_toml(moved[n][2])})" for n in names)
            hours = sum(_num(leftover[r].get("sec_total")) for r in rids) / 3600
            lines.append(
                f"  {len(rids)} are its rows under the defaults before they moved: {said}. Either pin them (in the "
                f"suite's [pinned]: {'; '.join(f'{n} = {_toml(moved[n][1])}' for n in names)}) and this command "
                f"reads them, or rerun under today's defaults into another --out ({len(rids)} runs, about "
                f"{hours:.1f} CPU h as these took, {hours / jobs:.1f} h at --jobs {jobs})."
            )
        if suite.pinned and suite.unpinned:
            lines.append(
                f"  --unpinned leaves out the suite's [pinned] settings ({_pins(suite.pinned)}): give it another --out."
            )
        if strangers:
            lines.append(
                f"  {len(strangers)} are no row of this suite (other --set settings, another suite's rows, or a "
                "default that moved without a declared neutral value): run the command that made them, or give "
                "another --out."
            )
        problems.append("\n".join(lines))
    if problems:
        raise PanoreconInputError("ablate: " + "\n".join(problems))


def _pins(pinned: dict) -> str:
    return ", ".join(f"{k} = {_toml(v)}" for k, v in pinned.items())


def _toml(v) -> str:
    return str(v).lower() if isinstance(v, bool) else repr(v) if isinstance(v, str) else str(v)


def _num(v) -> float:
    try:
        v = float(v)
    except (TypeError, ValueError):
        return 0.0
    return v if math.isfinite(v) else 0.0
