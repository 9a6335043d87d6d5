"""Shared fixtures: the real data folder, dtypes, and a fixed hypothesis profile for CI."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

settings.register_profile(
    "ci", max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True
)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"


@pytest.fixture(scope="session", autouse=True)
def tree_entry_points(tmp_path_factory):
    """The ``panorecon.sources`` entry points as this checkout's pyproject.toml declares them, put first on
    sys.path as the panorecon distribution's metadata: the tests see the plug-ins of the tree under test, not
    those of whatever panorecon was last installed into the environment (spawned workers inherit sys.path,
    other subprocesses such as notebook kernels get it through PYTHONPATH)."""
    from panorecon.sources import registry

    project = tomllib.loads(PYPROJECT.read_text())["project"]
    dist = tmp_path_factory.mktemp("metadata") / f"panorecon-{project['version']}.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text(f"Metadata-Version: 2.1\nName: panorecon\nVersion: {project['version']}\n")
    eps = project["entry-points"]["panorecon.sources"]
    (dist / "entry_points.txt").write_text("[panorecon.sources]\n" + "".join(f"{k} = {v}\n" for k, v in eps.items()))
    sys.path.insert(0, str(dist.parent))
    old_env = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join([str(dist.parent)] + ([old_env] if old_env else []))  # subprocesses
    registry._loaded_entry_points = False
    yield eps
    sys.path.remove(str(dist.parent))
    if old_env is None:
        os.environ.pop("PYTHONPATH")
    else:
        os.environ["PYTHONPATH"] = old_env


@pytest.fixture(scope="session")
def real_data() -> Path:
    if not REAL_DATA.is_dir():
        pytest.skip(f"real panoramas not found at {REAL_DATA} (shared/ must sit beside the checkout)")
    return REAL_DATA


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def float_dtype(request):
    return request.param


CHROMIUM = Path("/usr/bin/chromium")  # Debian's package, installed by `scripts/setup.sh dev`
CHROMIUM_ARGS = [
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
    "--disable-extensions",
    "--disable-component-update",
    "--disable-default-apps",
    "--no-first-run",
]


@pytest.fixture(scope="session")
def browser():
    """A headless Chromium (software WebGL) driven by playwright; skipped only where chromium is missing."""
    if not CHROMIUM.exists():
        pytest.skip(f"{CHROMIUM} not found: `bash scripts/setup.sh dev` installs Debian's chromium")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield b
        b.close()
