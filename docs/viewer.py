"""The README's screenshot of ``reach view``, taken by headless Chromium (Debian's, through Selenium).

Usage: python docs/viewer.py [ATLAS] [-o docs/figures/viewer.png]

Opens the viewer on the atlas (out/demo by default), shows the right arm's
and the upper body's boundary cells cut by a slice plane at z = 1.2 m with
the body answering a goal, and saves what the browser draws.
"""

from __future__ import annotations

import argparse
import socket
import tempfile
import time
from pathlib import Path

import numpy as np

from reach.maps.atlas import load_atlas
from reach.tools.view import Viewer

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("atlas", nargs="?", default=str(ROOT / "out" / "demo"))
    parser.add_argument("-o", "--output", default=str(ROOT / "docs" / "figures" / "viewer.png"))
    args = parser.parse_args()
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    viewer = Viewer([load_atlas(args.atlas)], port=port)
    viewer.show_strategy("right_upper_body", True)
    viewer.slice_axis.value, viewer.slice_at.value = "z", 1.2
    viewer.set_goal(np.array([0.55, -0.45, 1.25]))
    opts = webdriver.ChromeOptions()
    opts.binary_location = "/usr/bin/chromium"
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--window-size=1400,850", "--use-angle=swiftshader",
                 "--enable-unsafe-swiftshader", f"--user-data-dir={tempfile.mkdtemp(prefix='reach-chromium-')}"):
        opts.add_argument(flag)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=opts)
    try:
        driver.get(viewer.url)
        time.sleep(8)
        # The page's "software WebGL" notice is the headless browser's, not the viewer's: close it.
        for button in driver.find_elements("css selector", "button.mantine-Notification-closeButton, "
                                                           "button[aria-label='Close']"):
            try:
                button.click()
            except Exception:  # noqa: BLE001, S110 - a notice already gone
                pass
        time.sleep(1)
        Path(args.output).parent.mkdir(parents=True, exist_ok=True)
        driver.save_screenshot(args.output)
        print(args.output)
    finally:
        driver.quit()
        viewer.close()


if __name__ == "__main__":
    main()
