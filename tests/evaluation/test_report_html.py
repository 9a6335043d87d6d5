"""report.html: self-contained, sortable, with plots and thumbnails; loaded in a real headless Chromium."""

import re

import numpy as np
import pandas as pd
import pytest
from PIL import Image

from panorecon.evaluation.report_html import RowAssets, write_report_html
from panorecon.evaluation.suite import Suite
from panorecon.geometry import PointCloud


def _png(path, colour, size=(64, 32)):
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full((size[1], size[0], 3), colour, np.uint8)).save(path)
    return path


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    d = tmp_path_factory.mktemp("report")
    frame = pd.DataFrame(
        {
            "label": ["fibonacci", "random", "fibonacci", "random"],
            "scene": ["bedroom", "bedroom", "library", "library"],
            "psnr_pl": [20.0, 14.0, 22.0, 12.0],
            "psnr_ho": [18.0, 13.0, np.nan, np.nan],
            "chamfer": [0.03, 0.5, 0.04, 0.6],
            "sec_total": [10.0, 5.0, 12.0, 6.0],
        }
    )
    _png(d / "out" / "pareto.png", (200, 30, 30), (300, 200))
    rng = np.random.default_rng(0)
    cloud = d / "cloud.ply"
    PointCloud(rng.normal(size=(500, 3)), rng.uniform(size=(500, 3))).save_ply(cloud)
    assets = []
    for k in range(4):
        renders = d / f"run{k}" / "renders"
        _png(renders / "label_0.png", (30, 200, 30))
        _png(renders / "heldout_0.png", (30, 30, 200))
        assets.append(RowAssets(renders, cloud if k == 0 else None, "points0"))
    suite = Suite(name="tiny", title="a tiny <suite>", rows=[], row_columns=["source"], path=d / "tiny.toml")
    return write_report_html(frame, suite, d / "out", assets, wall_seconds=1.5)


def test_report_is_self_contained(report):
    text = report.read_text()
    assert "a tiny &lt;suite&gt;" in text  # escaped
    # every image is inline; nothing is fetched from anywhere
    assert not re.search(r"""(src|href)=['"](?!data:)""", text)
    assert text.count("data:image/png;base64,") == 1 + 4 * 2 + 1  # pareto, 4 strips of two, one cloud shot
    assert "psnr_vs_iterations" not in text  # absent plots are left out, not linked


def test_report_in_browser_loads_sorts_and_shows(report, browser, tmp_path):
    page = browser.new_page(viewport={"width": 1200, "height": 900})
    errors, requests = [], []
    page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(str(e)))
    page.on("request", lambda r: requests.append(r.url))
    page.goto(report.as_uri())
    page.wait_for_load_state("load")
    assert errors == []
    assert all(u.startswith(("file:", "data:")) for u in requests), requests
    imgs = page.eval_on_selector_all("img", "els => els.map(e => e.complete && e.naturalWidth > 0)")
    assert len(imgs) == 10 and all(imgs)
    shot = tmp_path / "report.png"
    page.screenshot(path=str(shot), full_page=True)
    a = np.asarray(Image.open(shot).convert("RGB")).astype(float)
    assert a.std() > 10 and (np.abs(a - a[0, 0]).sum(-1) > 30).mean() > 0.02  # not a blank page

    first_col = "els => els.map(e => e.cells[0].textContent)"
    table = "table.sortable >> nth=0"
    psnr = page.locator(f"{table} >> th", has_text=re.compile("^PSNR$"))
    psnr.click()
    asc = page.eval_on_selector_all("table.sortable:first-of-type tbody tr", first_col)
    psnr.click()
    desc = page.eval_on_selector_all("table.sortable:first-of-type tbody tr", first_col)
    assert asc == ["random", "fibonacci"] and desc == ["fibonacci", "random"]
    page.close()
