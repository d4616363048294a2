"""Open an HTML report in headless Chromium, offline: it renders, turns with the mouse, logs no error, fetches nothing.

Needs Debian's ``chromium`` and ``chromium-driver`` packages (``apt-get install -y chromium chromium-driver``)
and the ``selenium`` package (the ``test`` extra). Skipped with the reason when they are missing, except
under ``CI=true``, where a missing browser is a failure.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import magfit

pytestmark = pytest.mark.external

CHROMIUM = os.environ.get("MAGFIT_CHROMIUM", "/usr/bin/chromium")
CHROMEDRIVER = os.environ.get("MAGFIT_CHROMEDRIVER", "/usr/bin/chromedriver")
# No sandbox (containers run as root), no GPU (WebGL falls back to SwiftShader, in software), and nothing
# that would talk to the network on its own: no QUIC, no background updates, no sync, no first-run pages.
CHROMIUM_FLAGS = (
    "--headless=new",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--enable-unsafe-swiftshader",  # WebGL in software, asked for explicitly (else Chromium warns)
    "--window-size=1400,1000",
)


def _missing(reason: str) -> None:
    if os.environ.get("CI") == "true":
        pytest.fail(f"{reason}; under CI the browser test must run (install chromium and chromium-driver)")
    pytest.skip(reason)


@pytest.fixture(scope="module")
def browser(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Any]:
    """A headless Chromium driven by selenium, with a fresh profile, console and network logs on."""
    for program in (CHROMIUM, CHROMEDRIVER):
        if not (Path(program).is_file() or shutil.which(program)):
            _missing(f"{program} not found: apt-get install -y chromium chromium-driver")
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        _missing("selenium is not installed: pip install selenium (the test extra)")
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in CHROMIUM_FLAGS:
        options.add_argument(flag)
    options.add_argument(f"--user-data-dir={tmp_path_factory.mktemp('chromium-profile')}")
    options.set_capability("goog:loggingPrefs", {"browser": "ALL", "performance": "ALL"})
    driver = webdriver.Chrome(service=Service(CHROMEDRIVER), options=options)
    driver.set_page_load_timeout(60)
    try:
        yield driver
    finally:
        driver.quit()


@pytest.fixture(scope="module")
def report_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A one-section report of the paper's MPU-9250 with a piece of steel, as ``magfit demo --report`` writes."""
    import magfit.report
    from magfit.experiment import run_experiment

    experiment = run_experiment(2000, seed=21, sensors=("mpu9250",), disturbances=("steel",))
    path = tmp_path_factory.mktemp("report") / "report.html"
    magfit.report.write_report(path, magfit.report.experiment_sections(experiment), max_points=1500)
    return path


def _pixels(png: bytes) -> np.ndarray:
    from PIL import Image

    with Image.open(io.BytesIO(png)) as image:
        return np.asarray(image.convert("RGB"), dtype=np.float64)


def _wait_for(driver: Any, script: str, timeout: float = 60.0) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = driver.execute_script(script)
        if value:
            return value
        time.sleep(0.2)
    raise AssertionError(f"timed out after {timeout:.0f} s waiting for: {script}")


def test_report_renders_offline_turns_with_the_mouse_and_logs_no_error(
    browser: Any, report_file: Path, tmp_path: Path
) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.by import By

    # Offline for real: the browser's network is cut before the page is opened from a file:// URL.
    browser.set_network_conditions(offline=True, latency=0, download_throughput=0, upload_throughput=0)
    browser.get(report_file.resolve().as_uri())
    assert browser.execute_script("return document.readyState") == "complete"

    # Tables and the static figure are there; the PNG decoded to its full size.
    rows = browser.execute_script("return document.querySelectorAll('table.comparison tbody tr').length")
    assert rows == 3  # the paper's three methods
    assert browser.execute_script("return document.querySelectorAll('table.parameters tbody tr').length") == 4
    sizes = browser.execute_script(
        "return Array.from(document.images).map(i => [i.complete, i.naturalWidth, i.naturalHeight])"
    )
    assert sizes == [[True, 1600, 1200]]
    assert "Diagnostics" in browser.find_element(By.CSS_SELECTOR, "section").text

    # The 3-D view is drawn when scrolled to: plotly's container and its WebGL canvases appear.
    view = browser.find_element(By.CSS_SELECTOR, ".view-3d")
    browser.execute_script("arguments[0].scrollIntoView({block: 'center'})", view)
    _wait_for(browser, "return document.querySelector('.view-3d.js-plotly-plot .gl-container canvas') !== null")
    _wait_for(
        browser, "var s = document.querySelector('.view-3d')._fullLayout; return !!(s && s.scene && s.scene._scene)"
    )
    time.sleep(1.0)  # SwiftShader draws the first frames in software

    # Turn the raw-sample scene with the mouse: its camera moves.
    def eye() -> list[float]:
        camera = browser.execute_script(
            "return document.querySelector('.view-3d')._fullLayout.scene._scene.getCamera().eye"
        )
        return [camera["x"], camera["y"], camera["z"]]

    before = eye()
    ActionChains(browser).move_to_element_with_offset(view, -300, 0).click_and_hold().move_by_offset(
        120, 40
    ).release().perform()
    time.sleep(0.5)
    after = eye()
    assert np.linalg.norm(np.subtract(after, before)) > 0.1, (before, after)

    # The screenshot of the view is not blank: points and wireframes on white give a wide spread of greys.
    screenshot = _pixels(browser.get_screenshot_as_png())
    (tmp_path / "report.png").write_bytes(browser.get_screenshot_as_png())
    box = browser.execute_script(
        "var r = arguments[0].getBoundingClientRect(); return [r.left, r.top, r.right, r.bottom]", view
    )
    ratio = browser.execute_script("return window.devicePixelRatio")
    left, top, right, bottom = (int(v * ratio) for v in box)
    region = screenshot[max(top, 0) : bottom, max(left, 0) : right]
    assert region.size > 0 and region.std() > 10, region.std()
    canvas_pixels = np.count_nonzero(region.min(axis=2) < 200)  # non-white pixels: points, lines, labels
    assert canvas_pixels > 0.01 * region.shape[0] * region.shape[1]

    # No JavaScript error in the console (warnings about software WebGL are not errors).
    errors = [entry for entry in browser.get_log("browser") if entry["level"] == "SEVERE"]
    assert errors == [], errors

    # Nothing was fetched over the network, and nothing in the page points outside it.
    requested = []
    for entry in browser.get_log("performance"):
        message = json.loads(entry["message"])["message"]
        if message["method"] == "Network.requestWillBeSent":
            requested.append(message["params"]["request"]["url"])
    assert report_file.resolve().as_uri() in requested  # the log did record the page's own load
    # (chrome:// URLs are the browser's own new-tab page, loaded before ours and never from the network.)
    assert [url for url in requested if url.startswith(("http:", "https:", "ws:", "wss:", "ftp:"))] == []
    external = browser.execute_script(
        "return Array.from(document.querySelectorAll('[src], [href]'))"
        ".map(e => e.getAttribute('src') || e.getAttribute('href'))"
        ".filter(u => !u.startsWith('#') && !u.startsWith('data:'))"
    )
    assert external == []


def test_report_screenshot_of_the_page_top_reads(browser: Any, report_file: Path) -> None:
    """The page opens on its title and the comparison table (a screenshot kept for the eye, and checked)."""
    browser.get(report_file.resolve().as_uri())
    text = browser.find_element("tag name", "body").text
    assert "magfit calibration report" in text
    assert "The paper's comparison (section V)" in text
    pixels = _pixels(browser.get_screenshot_as_png())
    assert pixels.std() > 15
    assert magfit.__version__ in text
