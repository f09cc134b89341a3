"""A teacher's journey in a real browser: Debian's chromium driven by Playwright.

A session-scoped fixture serves the app with `streamlit run` (tiny runs: IFO_LAB_FAST=1) on a
free port. The journey opens the app, goes to the step page, picks IUPE on CartPole, presses
Step three times and checks that the charts are drawn and grow, shows a rollout video,
saves a full-page screenshot to artifacts/browser/step_page.png for a person to look at,
then turns exploration off and checks that a new run starts.
"""
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from scripts.app_server import serve_app

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = ROOT / "artifacts" / "browser"
IDLE = "[data-testid='stApp'][data-test-script-state='notRunning']"
CHART = "[data-testid='stPlotlyChart']"

pytestmark = [
    pytest.mark.browser,
    pytest.mark.skipif(not CHROMIUM.exists(), reason="Debian's chromium (/usr/bin/chromium) is not installed"),
]


@pytest.fixture(scope="session")
def app_url(tmp_path_factory):
    log_path = tmp_path_factory.mktemp("streamlit") / "server.log"
    try:
        with serve_app(log_path, {"IFO_LAB_FAST": "1"}, timeout=60) as url:
            yield url
    except RuntimeError as exc:  # the server did not come up: say why, with its log
        pytest.fail(str(exc))


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


def test_step_through_iupe_on_cartpole(app_url, page):
    from playwright.sync_api import expect

    page.goto(app_url)
    page.wait_for_selector(IDLE)
    expect(page.get_by_role("heading", name="IfO Lab")).to_be_visible()

    page.get_by_role("button", name="Step through a run").click()
    counter = page.locator("[data-testid='stMain'] h4")
    expect(counter).to_have_text("Iteration 0 of 10")
    page.wait_for_selector(IDLE)
    assert "user=" in page.url  # runs autosave under this id
    sidebar = page.locator("[data-testid='stSidebar']")
    expect(sidebar.get_by_role("combobox", name="Environment")).to_have_value("CartPole")  # the defaults
    expect(sidebar.get_by_role("combobox", name="Method")).to_have_value("BCO(α)")
    expect(page.locator(CHART)).to_have_count(1)  # the loop diagram only
    expect(page.locator(CHART).first).to_contain_text("before the first iteration")

    sidebar.get_by_role("combobox", name="Method").click()
    page.get_by_role("option", name="IUPE", exact=True).click()
    page.wait_for_selector(IDLE)
    expect(sidebar.get_by_role("combobox", name="Method")).to_have_value("IUPE")
    expect(sidebar.get_by_role("switch", name="Explore: sample the labels")).to_be_checked()  # IUPE's switches
    assert "step.method=IUPE" in page.url  # the settings are in the link

    aer_chart = page.locator(CHART).filter(has_text="Average episodic reward")
    for k in (1, 2, 3):
        page.get_by_role("button", name="Step", exact=True).click()
        expect(counter).to_have_text(f"Iteration {k} of 10")
        page.wait_for_selector(IDLE)
        # diagram, AER, Performance, IDM, IDM through time, accuracy, sampling, exploration, win probability
        expect(page.locator(CHART)).to_have_count(9)
        for chart in page.locator(CHART).all():
            expect(chart).to_be_visible()
        expect(aer_chart.locator(".scatterlayer .trace").first.locator("path.point")).to_have_count(k)
        expect(page.locator(CHART).first).to_contain_text(f"iteration {k}")  # the diagram follows
    expect(page.get_by_text("expert's hidden true actions")).to_be_visible()  # the IDM panel's legend
    expect(page.get_by_text("Thesis Fig 6.2b").first).to_be_visible()  # each panel names its figure
    assert "run=" in page.url  # autosaved: the link reopens this run

    page.get_by_role("button", name="Show a rollout of the current policy").click()
    page.wait_for_selector(IDLE)
    expect(page.locator("video")).not_to_have_count(0, timeout=60_000)

    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    page.mouse.move(5, 5)  # no tooltip over the screenshot
    page.evaluate("document.activeElement && document.activeElement.blur()")
    page.set_viewport_size({"width": 1400, "height": 4200})  # the app scrolls inside its main pane
    page.wait_for_selector(IDLE)
    page.wait_for_timeout(1500)  # let plotly relayout to the new size, the videos start
    page.screenshot(path=str(ARTIFACTS / "step_page.png"), full_page=True)
    page.set_viewport_size({"width": 1400, "height": 1000})

    # export a chart for slides: rendered on the server by kaleido with Debian's chromium
    for label, check in (("SVG", lambda b: ET.fromstring(b).tag.endswith("svg")),
                         ("PNG", lambda b: b.startswith(b"\x89PNG\r\n\x1a\n"))):
        button = page.locator("[data-testid='stDownloadButton']").filter(has_text=label).first
        with page.expect_download(timeout=120_000) as download:
            button.locator("button").first.click()
        assert check(Path(download.value.path()).read_bytes()), f"the {label} download is not a valid {label}"

    # reload: the autosaved run comes back from the link
    page.reload()
    page.wait_for_selector(IDLE)
    expect(counter).to_have_text("Iteration 3 of 10")
    expect(sidebar.get_by_role("combobox", name="Method")).to_have_value("IUPE")

    # a switch is part of the run: turning exploration of labels off starts a new run
    sidebar.get_by_text("Explore: sample the labels").click()
    expect(counter).to_have_text("Iteration 0 of 10")
    page.wait_for_selector(IDLE)
    expect(sidebar.get_by_role("switch", name="Explore: sample the labels")).not_to_be_checked()
    expect(sidebar.get_by_text("A custom combination of components.")).to_be_visible()
    page.get_by_role("button", name="Step", exact=True).click()
    expect(counter).to_have_text("Iteration 1 of 10")
    page.wait_for_selector(IDLE)
    expect(page.locator(CHART)).to_have_count(9)  # the policy still explores in its runs
