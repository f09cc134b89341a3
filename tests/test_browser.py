"""A teacher's journey in a real browser: Debian's chromium driven by Playwright.

A session-scoped fixture serves the app with `streamlit run` (tiny runs: IFO_LAB_FAST=1) on a
free port. The journey opens the app, goes to the step page, presses Step three times and
checks that the charts are drawn and grow; it saves a full-page screenshot to
artifacts/browser/step_page.png for a person to look at.
"""
import os
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = ROOT / "artifacts" / "browser"
IDLE = "[data-testid='stApp'][data-test-script-state='notRunning']"
CHART = "[data-testid='stPlotlyChart']"

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not CHROMIUM.exists(), reason="Debian's chromium (/usr/bin/chromium) is not installed"),
]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _healthy(url: str) -> bool:
    try:
        with urllib.request.urlopen(f"{url}/_stcore/health", timeout=2) as r:
            return r.read().decode().strip() == "ok"
    except OSError:
        return False


@pytest.fixture(scope="session")
def app_url(tmp_path_factory):
    port = _free_port()
    log_path = tmp_path_factory.mktemp("streamlit") / "server.log"
    env = {**os.environ, "IFO_LAB_FAST": "1", "PYTHONPATH": str(ROOT)}
    with open(log_path, "w") as log:
        proc = subprocess.Popen(
            [sys.executable, "-m", "streamlit", "run", "app.py", "--server.headless", "true",
             "--server.port", str(port), "--browser.gatherUsageStats", "false"],
            cwd=ROOT, env=env, stdout=log, stderr=subprocess.STDOUT)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while not _healthy(url):
            if proc.poll() is not None:
                pytest.fail(f"streamlit exited with code {proc.returncode}:\n{log_path.read_text()}")
            if time.monotonic() > deadline:
                pytest.fail(f"streamlit was not healthy within 60 s:\n{log_path.read_text()}")
            time.sleep(0.5)
        yield url
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.fixture
def page():
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        browser = p.chromium.launch(
            executable_path=str(CHROMIUM),
            args=["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"])
        page = browser.new_page(viewport={"width": 1400, "height": 1000})
        page.set_default_timeout(60_000)
        yield page
        browser.close()


def test_step_through_cartpole_three_times(app_url, page):
    from playwright.sync_api import expect

    page.goto(app_url)
    page.wait_for_selector(IDLE)
    expect(page.get_by_role("heading", name="IfO Lab")).to_be_visible()

    page.get_by_role("button", name="Step through a run").click()
    counter = page.locator("[data-testid='stMain'] h4")
    expect(counter).to_have_text("Iteration 0 of 10")
    page.wait_for_selector(IDLE)
    sidebar = page.locator("[data-testid='stSidebar']")
    expect(sidebar.get_by_role("combobox", name="Environment")).to_have_value("CartPole")  # the defaults
    expect(sidebar.get_by_role("combobox", name="Method")).to_have_value("BCO(α)")
    expect(page.locator(CHART)).to_have_count(0)

    aer_chart = page.locator(CHART).filter(has_text="Average episodic reward")
    for k in (1, 2, 3):
        page.get_by_role("button", name="Step", exact=True).click()
        expect(counter).to_have_text(f"Iteration {k} of 10")
        page.wait_for_selector(IDLE)
        # AER, Performance, IDM predictions, accuracy, win probability, IDM predictions through time
        expect(page.locator(CHART)).to_have_count(6)
        for chart in page.locator(CHART).all():
            expect(chart).to_be_visible()
        # the AER curve has one point per iteration
        expect(aer_chart.locator(".scatterlayer .trace").first.locator("path.point")).to_have_count(k)
    expect(page.get_by_text("expert's hidden true actions")).to_be_visible()  # the IDM panel's legend

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.mouse.move(5, 5)  # no tooltip over the screenshot
    page.evaluate("document.activeElement && document.activeElement.blur()")
    page.set_viewport_size({"width": 1400, "height": 2600})  # the app scrolls inside its main pane
    page.wait_for_selector(IDLE)
    page.wait_for_timeout(500)  # let plotly relayout to the new size
    page.screenshot(path=str(ARTIFACTS / "step_page.png"), full_page=True)

    # Run N trains the next N iterations, one per rerun of the page's fragment, then stops
    page.set_viewport_size({"width": 1400, "height": 1000})
    n_input = page.get_by_role("spinbutton", name="N", exact=True)
    n_input.fill("2")
    n_input.press("Enter")
    page.wait_for_selector(IDLE)
    page.get_by_role("button", name="Run N", exact=True).click()
    expect(counter).to_have_text("Iteration 5 of 10")
    expect(page.get_by_role("button", name="Run N", exact=True)).to_be_visible()  # Pause is gone: it stopped
    page.wait_for_selector(IDLE)
    expect(counter).to_have_text("Iteration 5 of 10")
    expect(aer_chart.locator(".scatterlayer .trace").first.locator("path.point")).to_have_count(5)
