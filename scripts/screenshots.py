"""Screenshots for docs/images: `panorecon view RUN` and an ablation's report.html in headless Chromium.

    python scripts/screenshots.py out/demo out/bench docs/images

needs Debian's chromium (scripts/setup.sh dev) and playwright; software WebGL (SwiftShader).
"""

import sys
import time
from pathlib import Path

from playwright.sync_api import sync_playwright

from panorecon.viewer import serve

ARGS = [
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--disable-background-networking",
]


def main(run: str, ablation: str, out: str) -> None:
    out_dir = Path(out)
    out_dir.mkdir(parents=True, exist_ok=True)
    server = serve(run, 8765, "127.0.0.1")
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto("http://127.0.0.1:8765/")
        page.wait_for_selector("canvas", timeout=120_000)
        time.sleep(40)  # scene upload and a few software-rendered frames
        page.screenshot(path=str(out_dir / "viewer.png"))
        page = browser.new_page(viewport={"width": 1280, "height": 900})
        page.goto((Path(ablation) / "report.html").resolve().as_uri())
        page.screenshot(path=str(out_dir / "report.png"), full_page=True)
        browser.close()
    server.stop()
    print(f"-> {out_dir / 'viewer.png'}, {out_dir / 'report.png'}")


if __name__ == "__main__":
    main(*sys.argv[1:4])
