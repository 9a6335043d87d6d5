"""Shared fixtures: the real data folder, dtypes, and a fixed hypothesis profile for CI."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, settings

settings.register_profile("ci", max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow], derandomize=True)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

REAL_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"


@pytest.fixture(scope="session")
def real_data() -> Path:
    if not REAL_DATA.is_dir():
        pytest.skip(f"real panoramas not found at {REAL_DATA} (shared/ must sit beside the checkout)")
    return REAL_DATA


@pytest.fixture(params=[np.float32, np.float64], ids=["f32", "f64"])
def float_dtype(request):
    return request.param


CHROMIUM = Path("/usr/bin/chromium")  # Debian's package, installed by `scripts/setup.sh dev`
CHROMIUM_ARGS = ["--headless=new", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", "--disable-background-networking", "--disable-extensions",
                 "--disable-component-update", "--disable-default-apps", "--no-first-run"]


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
