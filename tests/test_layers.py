"""Imports point down the layers of docs/architecture.md ("Layers and allowed imports", read from there): every
module of panorecon/ parsed with ``ast``, its imports at any depth (inside functions, under TYPE_CHECKING),
relative and absolute."""

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ARCHITECTURE = ROOT / "docs" / "architecture.md"


def documented_layers(text: str) -> dict[str, int]:
    """unit -> layer from the table under the "Layers and allowed imports" heading: rows ``| N | `unit`, ... | ...``."""
    section = text.split("## Layers and allowed imports", 1)[1].split("\n## ", 1)[0]
    layers = {}
    for line in section.splitlines():
        row = re.match(r"\|\s*(\d+)\s*\|([^|]*)\|", line)
        if row:
            for unit in re.findall(r"`([\w.]+)`", row.group(2)):
                layers[unit] = int(row.group(1))
    return layers


def unit_of(module: str, package: str) -> str:
    """``panorecon.io.depth`` -> ``io``; ``panorecon.cli`` -> ``cli``; the package itself -> ``panorecon``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else package


def imported_units(path: Path, module: str, package: str, units: set[str]) -> list[tuple[int, str]]:
    """(line, unit of ``package``) for every import in the file at ``path`` (module name ``module``)."""
    is_init = path.name == "__init__.py"
    here = module.split(".") if is_init else module.split(".")[:-1]  # the package relative imports start from
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(here[: len(here) - (node.level - 1)] + ([node.module] if node.module else []))
            # `from panorecon import io` imports the unit io; `from panorecon import __version__` the package
            targets = (
                [f"{base}.{a.name}" if a.name in units else base for a in node.names] if base == package else [base]
            )
        else:
            continue
        found += [(node.lineno, unit_of(t, package)) for t in targets if t.split(".")[0] == package]
    return found


def violations(package_dir: Path, layers: dict[str, int]) -> list[str]:
    """One line per import that does not point to a lower layer (or the module's own unit), and per unit that
    the table does not place."""
    package = package_dir.name
    out = []
    for path in sorted(package_dir.rglob("*.py")):
        rel = path.relative_to(package_dir.parent).with_suffix("")
        module = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        unit = unit_of(module, package)
        where = path.relative_to(package_dir.parent)
        if unit not in layers:
            out.append(f"{where}: unit {unit!r} has no layer in docs/architecture.md's table")
            continue
        for line, target in imported_units(path, module, package, set(layers)):
            if target == unit:
                continue
            if target not in layers:
                out.append(f"{where}:{line}: imports {target!r}, which has no layer in the table")
            elif layers[target] >= layers[unit]:
                out.append(
                    f"{where}:{line}: {unit} (layer {layers[unit]}) -> {target} (layer {layers[target]}): "
                    "imports may only point to a lower layer"
                )
    return out


def test_every_import_points_down():
    layers = documented_layers(ARCHITECTURE.read_text())
    assert layers["io"] == 0 and layers["cli"] == max(layers.values())
    bad = violations(ROOT / "panorecon", layers)
    assert not bad, "\n".join(bad)


def test_io_imports_nothing_of_panorecons():
    """io is on the ground floor, beside units that import nothing of panorecon's either (``checks``): no unit
    is lower than io, so ``test_every_import_points_down`` leaves io no import of the package's."""
    layers = documented_layers(ARCHITECTURE.read_text())
    assert layers["io"] == 0 == min(layers.values())
    assert not [u for u, layer in layers.items() if layer == 0 and u not in ("io", "panorecon", "checks")]


@pytest.mark.parametrize(
    "file,source,needle",
    [
        ("io/a.py", "def f():\n    from ..geometry import x\n", "pkg/io/a.py:2: io (layer 0) -> geometry (layer 1)"),
        ("io/__init__.py", "import pkg.cli.main\n", "pkg/io/__init__.py:1: io (layer 0) -> cli (layer 2)"),
        ("geometry/b.py", "from pkg import cli\n", "pkg/geometry/b.py:1: geometry (layer 1) -> cli (layer 2)"),
        ("geometry/c.py", "if True:\n    from pkg.io import y\n    from . import z\n", None),
        ("geometry/d.py", "from .. import __version__\n", "pkg/geometry/d.py:1: geometry (layer 1) -> pkg (layer 1)"),
        ("cli.py", "from .geometry import y\nfrom . import io\n", None),
        ("viz.py", "x = 1\n", "pkg/viz.py: unit 'viz' has no layer"),
    ],
)
def test_the_check_sees_every_kind_of_import(tmp_path, file, source, needle):
    """The checker itself on a throwaway package: upward imports hidden in functions, absolute, `from pkg import
    unit`, and a unit the table does not place are named with their line; downward ones pass."""
    for folder in ("io", "geometry"):
        (tmp_path / "pkg" / folder).mkdir(parents=True, exist_ok=True)
        (tmp_path / "pkg" / folder / "__init__.py").write_text("")
    (tmp_path / "pkg" / "__init__.py").write_text("")
    (tmp_path / "pkg" / file).write_text(source)
    bad = violations(tmp_path / "pkg", {"io": 0, "geometry": 1, "pkg": 1, "cli": 2})
    if needle is None:
        assert bad == []
    else:
        assert len(bad) == 1 and bad[0].startswith(needle), bad


def argparse_importers(package_dir: Path) -> list[str]:
    """Modules of ``package_dir`` (relative paths) that import argparse, at any depth."""
    found = []
    for path in sorted(package_dir.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            if any(n.split(".")[0] == "argparse" for n in names):
                found.append(str(path.relative_to(package_dir)))
                break
    return found


def test_only_the_command_line_modules_import_argparse(tmp_path):
    """The CLI (``cli.py``) and its argparse forms of the checks (``cli_types.py``, which the micro-benchmarks'
    own ``main``s use too) are the only modules that know argparse; every other one gets a typed config."""
    assert argparse_importers(ROOT / "panorecon") == ["cli.py", "cli_types.py"]
    (tmp_path / "a.py").write_text("def f(ns):\n    from argparse import Namespace\n    return Namespace\n")
    (tmp_path / "b.py").write_text("import json\n")
    assert argparse_importers(tmp_path) == ["a.py"]
