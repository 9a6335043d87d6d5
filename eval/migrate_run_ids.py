"""Migrate a committed results.csv to today's run identities, proving that each old row is exactly one run.

Until run identities left out options at their neutral value (``checks.identity``), ``Row.run_id`` hashed every
``TrainConfig`` field that existed when the row ran, and no fusion setting. This script recomputes, for every row
of the suite (its [pinned] settings in force), the identity it had under the code of each commit named in the
results.csv's ``commit`` column: the same settings hashed the old way, with the ``TrainConfig`` fields of that
commit (read from git: ``git show COMMIT:panorecon/splat/trainer.py``). It then checks that every row of the
results.csv is the old identity of exactly one suite row, and no two rows the same one, and only then (``--write``)
replaces the ``run_id`` column, atomically, leaving every other byte of each row as it was.

    python eval/migrate_run_ids.py eval/suites/table7_flatten.toml benchmarks/tables/table7_flatten [--write]
"""

from __future__ import annotations

import argparse
import ast
import csv
import hashlib
import io
import json
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def config_fields_at(commit: str) -> list[str]:
    """The field names of ``TrainConfig`` in ``panorecon/splat/trainer.py`` at ``commit``."""
    try:
        text = subprocess.run(
            ["git", "-C", str(REPO), "show", f"{commit}:panorecon/splat/trainer.py"],
            check=True,
            capture_output=True,
            text=True,
        ).stdout
    except subprocess.CalledProcessError as e:
        raise SystemExit(f"commit {commit}: not in this clone's history ({e.stderr.strip()}); fetch it first") from None
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.ClassDef) and node.name == "TrainConfig":
            return [s.target.id for s in node.body if isinstance(s, ast.AnnAssign)]
    raise SystemExit(f"commit {commit}: no TrainConfig in panorecon/splat/trainer.py")


def old_run_id(row, fields: list[str]) -> str:
    """``row``'s identity as ``Row.run_id`` computed it before ``checks.identity``: every field of ``fields``
    (as ``dataclasses.asdict`` gives it) in the training config, no fusion settings in the points stage."""
    import dataclasses

    params = {k: v for k, v in row._points_params().items() if k != "fusion"}
    train = None
    if row.train is not None:
        config = dataclasses.asdict(row.train_config())
        missing = [f for f in fields if f not in config]
        if missing:
            raise SystemExit(f"fields {missing} of the old TrainConfig are gone: this script cannot rebuild its ids")
        train = {**row._train_params(), "config": {f: config[f] for f in fields}}
    text = json.dumps({"points": params, "train": train}, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:20]


def migrate(suite_path: Path, folder: Path, write: bool) -> int:
    from panorecon.evaluation.suite import load_suite
    from panorecon.io import atomic_write

    suite = load_suite(suite_path)
    csv_path = folder / "results.csv"
    text = csv_path.read_text()
    records = list(csv.DictReader(io.StringIO(text)))
    commits = sorted({r["commit"] for r in records})
    mapping: dict[tuple[str, str], str] = {}  # (commit, old id) -> new id
    for commit in commits:
        fields = config_fields_at(commit)
        olds: dict[str, str] = {}
        for row in suite.rows:
            old = old_run_id(row, fields)
            if old in olds and olds[old] != row.run_id():
                raise SystemExit(f"commit {commit}: two suite rows had the same old identity {old}")
            olds[old] = row.run_id()
        mapping.update({(commit, k): v for k, v in olds.items()})
        print(f"commit {commit[:10]}: TrainConfig had {len(fields)} fields; {len(olds)} old identities")
    want = {row.run_id() for row in suite.rows}
    new_ids, unmatched = [], []
    for r in records:  # a row already under today's identity maps to itself
        new = r["run_id"] if r["run_id"] in want else mapping.get((r["commit"], r["run_id"]))
        (unmatched.append(r["run_id"]) if new is None else new_ids.append(new))
    print(
        f"{csv_path}: {len(records)} rows; {len(new_ids)} matched one suite row each, {len(unmatched)} unmatched; "
        f"{len(set(new_ids))} distinct new identities; suite rows without a committed row: {len(want - set(new_ids))}"
    )
    if unmatched or len(set(new_ids)) != len(new_ids) or set(new_ids) != want:
        print("not a one-to-one map onto the suite: nothing written", file=sys.stderr)
        return 1
    if sum(r["run_id"] != n for r, n in zip(records, new_ids)) == 0:
        print("identities already current: nothing to write")
        return 0
    lines = text.splitlines(keepends=True)
    header, body = lines[0], lines[1:]
    if header.split(",")[0] != "run_id" or len(body) != len(records):
        raise SystemExit(f"{csv_path}: expected run_id as the first column and one line per row")
    out = [header] + [n + line[len(r["run_id"]) :] for r, n, line in zip(records, new_ids, body)]
    if write:
        with atomic_write(csv_path) as tmp:
            Path(tmp).write_text("".join(out))
        print(f"{csv_path}: run_id rewritten ({len(new_ids)} rows)")
    else:
        print("dry run: pass --write to rewrite the run_id column")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("suite", type=Path, help="the table's suite file (with its [pinned] settings)")
    ap.add_argument("folder", type=Path, help="the folder holding the table's results.csv")
    ap.add_argument("--write", action="store_true", help="rewrite the run_id column (default: check only)")
    a = ap.parse_args(argv)
    return migrate(a.suite, a.folder, a.write)


if __name__ == "__main__":
    sys.exit(main())
