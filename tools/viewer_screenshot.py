"""The README's viewer screenshot: a run folder in the viewer, side by side, at a frame of the
held-out sequence, taken by headless Chromium (Debian's `chromium` + `chromium-driver`).

    python tools/viewer_screenshot.py [--run runs/edit] [--out docs/viewer.png] [--size 384]
"""

from __future__ import annotations

import argparse
import time

from gae_jax.viewer import app, source

SETTLE_S = 12.0  # the first picture of a size compiles


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--run", default="runs/edit")
    p.add_argument("--out", default="docs/viewer.png")
    p.add_argument("--size", type=int, default=384)
    p.add_argument("--sequence", default="mix")
    p.add_argument("--frame", type=int, default=5)
    args = p.parse_args(argv)
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    viewer = app.Viewer(source.from_run(args.run), port=0, size=args.size)
    options = webdriver.ChromeOptions()
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync", "--window-size=1280,720"):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=options)
    try:
        driver.get(f"http://127.0.0.1:{viewer.port}")
        time.sleep(SETTLE_S)
        viewer.show.value = app.BOTH
        viewer.sequence.value = args.sequence
        viewer.frame.value = max(args.frame - 1, 0)
        time.sleep(SETTLE_S)
        viewer.frame.value = args.frame  # a second render, so the status shows a warm one
        time.sleep(3.0)
        # Chromium without a GPU shows a "software WebGL" notice; close it for the picture.
        driver.execute_script("document.querySelectorAll('button[aria-label=\"Close\"], "
                              ".mantine-Notification-closeButton').forEach(b => b.click())")
        time.sleep(1.0)
        driver.save_screenshot(args.out)
        print(f"{args.out}: {viewer.status.content}")
    finally:
        driver.quit()
        viewer.stop()


if __name__ == "__main__":
    main()
