"""The viewer in a real browser: headless Chromium opens the page, the head is on it, moving the
page's jaw-open slider changes the picture, and the screenshot button writes a PNG of the head.

Needs Debian's `chromium` and `chromium-driver` (`.ci/run` installs them when missing)."""

import os
import shutil
import time

import cv2
import numpy as np
import pytest

from gae_jax.viewer import app, source
from tests.test_viewer import tiny_run_folder

CHROMIUM, DRIVER = shutil.which("chromium"), shutil.which("chromedriver")
# CI sets GAE_JAX_REQUIRE_BROWSER, so there a missing browser fails the test instead.
pytestmark = pytest.mark.skipif(
    not (CHROMIUM and DRIVER) and not os.environ.get("GAE_JAX_REQUIRE_BROWSER"),
    reason="needs Debian's chromium and chromium-driver (apt-get install chromium "
           "chromium-driver; .ci/run installs them)")
WINDOW = (1100, 700)
TIMEOUT_S = 90.0
HEAD_FRACTION = 0.1  # of the viewport's centre that the head covers at the least
CHANGED_LEVEL = 2.0  # mean absolute change (0-255) of the centre when the jaw opens


def wait_for(predicate, what: str, timeout: float = TIMEOUT_S):
    """The first value of `predicate()` that is neither None, False nor empty."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        value = predicate()
        if value is not None and value is not False and not (isinstance(value, list)
                                                             and not value):
            return value
        time.sleep(0.25)
    raise AssertionError(f"timed out waiting for {what}")


def centre(driver) -> np.ndarray:
    """The middle of the 3D viewport (left of the control panel, below the notifications)."""
    shot = cv2.imdecode(np.frombuffer(driver.get_screenshot_as_png(), np.uint8),
                        cv2.IMREAD_COLOR)
    h, w = shot.shape[:2]
    return shot[int(0.25 * h):int(0.9 * h), int(0.3 * w):int(0.65 * w)].astype(np.float64)


def head_fraction(image: np.ndarray) -> float:
    """Fraction of pixels that are not the white background."""
    return float(np.mean(image.min(axis=-1) < 230))


@pytest.fixture
def browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    # The closed network refuses Chromium's background connections; these flags stop them.
    for flag in ("--headless=new", "--no-sandbox", "--disable-gpu", "--disable-quic",
                 "--no-first-run", "--disable-background-networking",
                 "--disable-component-update", "--disable-sync",
                 f"--window-size={WINDOW[0]},{WINDOW[1]}"):
        options.add_argument(flag)
    driver = webdriver.Chrome(service=Service(DRIVER), options=options)
    try:
        yield driver
    finally:
        driver.quit()


def test_the_page_shows_the_head_and_the_jaw_slider_moves_it(tmp_path, browser):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    run = tiny_run_folder(tmp_path / "run")
    viewer = app.Viewer(source.from_run(str(run)), port=0, size=128,
                         screenshots=str(tmp_path / "shots"))
    try:
        browser.get(f"http://127.0.0.1:{viewer.port}")
        wait_for(lambda: any(c.image is not None for c in viewer.clients.values()),
                 "the first render")
        before = wait_for(lambda: (lambda c: c if head_fraction(c) > HEAD_FRACTION else None)(
            centre(browser)), "the head on the page")

        label = wait_for(lambda: browser.find_elements(
            By.XPATH, "//label[normalize-space(text())='jaw open']"), "the jaw-open slider")[0]
        row = label.find_element(By.XPATH, "ancestor::*[.//*[@role='slider']][1]")
        slider = row.find_element(By.CSS_SELECTOR, "[role=slider]")
        browser.execute_script("arguments[0].scrollIntoView({block: 'center'})", slider)
        slider.click()
        slider.send_keys(Keys.END)
        top = viewer.sliders["jaw/0"].max
        wait_for(lambda: viewer.values["jaw/0"] == pytest.approx(top), "the slider's message")
        after = wait_for(lambda: (lambda c: c if np.abs(c - before).mean() > CHANGED_LEVEL
                                  else None)(centre(browser)), "the picture to change")
        assert head_fraction(after) > HEAD_FRACTION

        button = browser.find_element(By.XPATH, "//button[normalize-space(.)='Screenshot']")
        browser.execute_script("arguments[0].scrollIntoView({block: 'center'})", button)
        button.click()
        def written():  # the finished file, not atomic_write_bytes' temporary one
            folder = tmp_path / "shots"
            names = [n for n in os.listdir(folder) if n.endswith(".png")
                     and not n.startswith(".")] if folder.is_dir() else []
            return names or None

        shots = wait_for(written, "the screenshot file")
        png = cv2.imread(str(tmp_path / "shots" / shots[0]))
        assert png.shape[0] == 128 and head_fraction(png) > HEAD_FRACTION
    finally:
        viewer.stop()
