"""What the browser journeys (tests/test_browser.py) share: one app server per test session,
one headless chromium per session, a fresh browser context (cookies, storage, user id) per
test, a full-page screenshot of every page a test opened saved to artifacts/browser/ at the
end of the test (passed or failed), and small helpers that read the page as a person does.

Loaded as a pytest plugin (`pytest_plugins = ["browser_support"]` in the test file), so its
fixtures are available to the tests without touching the shared conftest.py.

    app       the served app: .url, .runs (its IFO_LAB_RUNS folder), .log (the server log)
    browser   Debian's chromium, launched once
    context   a new browser context per test; `page` is its first page
    page      a page of `context`, default timeout 90 s; screenshots at teardown
    snap      snap(page, "label"): one more screenshot in the middle of a test

The server runs tiny runs (IFO_LAB_FAST=1) and keeps its runs in a temporary folder; its log
is copied to artifacts/browser/server.log at the end of the session. Its first
browser session is opened (and closed) by the `app` fixture itself: Streamlit shows a
"Page not found" dialog on a deep link in a server's first session (streamlit#9992), which a
test should not have to know about; `dismiss_page_not_found` is there for the rest.
"""
from __future__ import annotations

import re
import shutil
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

import pytest

from scripts.app_server import serve_app

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = ROOT / "artifacts" / "browser"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]
VIEWPORT = {"width": 1400, "height": 1000}
TIMEOUT_MS = 90_000  # the machine is shared and busy: generous everywhere
LONG_MS = 240_000  # server-side exports, background training

IDLE = "[data-testid='stApp'][data-test-script-state='notRunning']"
CHART = "[data-testid='stPlotlyChart']"
MAIN = "[data-testid='stMain']"
SIDEBAR = "[data-testid='stSidebar']"


@dataclass
class App:
    url: str
    runs: Path
    log: Path


# ----------------------------------------------------------------------------- fixtures
OWN_ENV = "examples.parking:parking"  # a researcher's own environment, offered beside IfO Lab's


# Module-scoped, not session-scoped: Playwright's sync API keeps its event loop marked running in this thread
# until it stops, and a later test file in the same worker calling asyncio.run() would fail ("never awaited").
@pytest.fixture(scope="module")
def app(tmp_path_factory, browser) -> App:
    if not CHROMIUM.exists():
        pytest.skip("Debian's chromium (/usr/bin/chromium) is not installed")
    folder = tmp_path_factory.mktemp("streamlit")
    runs, log = folder / "runs", folder / "server.log"
    try:
        # .streamlit/config.toml turns the file watcher off, as for a class: no "File change" banner
        # or rerun in the middle of a journey while someone edits this checkout
        with serve_app(log, {"IFO_LAB_FAST": "1", "IFO_LAB_RUNS": str(runs), "IFO_LAB_ENVS": OWN_ENV},
                       timeout=120) as url:
            served = App(url, runs, log)
            warm_up(browser, url)
            yield served
    except RuntimeError as exc:  # the server did not come up: say why, with its log
        pytest.fail(str(exc))
    finally:  # beside the screenshots: pytest soon deletes its temporary folders
        if log.exists():
            ARTIFACTS.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(log, ARTIFACTS / "server.log")


@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM.exists():
        pytest.skip("Debian's chromium (/usr/bin/chromium) is not installed")
    from playwright.sync_api import expect, sync_playwright

    expect.set_options(timeout=TIMEOUT_MS)
    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield chromium
        chromium.close()


@pytest.fixture
def context(browser, request):
    ctx = browser.new_context(viewport=VIEWPORT, accept_downloads=True)
    ctx.set_default_timeout(TIMEOUT_MS)
    yield ctx
    for k, pg in enumerate(ctx.pages):  # every tab the test opened, passed or failed
        suffix = "" if k == 0 else f"-tab{k + 1}"
        save_screenshot(pg, ARTIFACTS / f"{file_name(request.node.name)}{suffix}.png")
    ctx.close()


@pytest.fixture
def page(context):
    return context.new_page()


@pytest.fixture
def snap(request):
    """`snap(page, "label")`: a screenshot in the middle of a test, artifacts/browser/<test>--<label>.png
    (the one at the end is automatic); the page keeps its size afterwards."""
    def take(page, label: str) -> None:
        size = page.viewport_size
        save_screenshot(page, ARTIFACTS / f"{file_name(request.node.name)}--{file_name(label)}.png")
        page.set_viewport_size(size)
    return take


def warm_up(browser, url: str) -> None:
    """Open the app once, so later deep links are not a server's first session (streamlit#9992)."""
    ctx = browser.new_context(viewport=VIEWPORT)
    try:
        pg = ctx.new_page()
        pg.goto(url, timeout=TIMEOUT_MS)
        pg.wait_for_selector(IDLE, timeout=TIMEOUT_MS)
    finally:
        ctx.close()


# ----------------------------------------------------------------------------- screenshots
def file_name(test_name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", test_name).strip("_")


def save_screenshot(page, path: Path) -> None:
    """A full-page screenshot with a viewport as tall as the content: Streamlit scrolls inside its
    main pane, so a plain full_page shot would cut the charts off. Never raises: it runs at the end
    of failed tests too, maybe on a dead page."""
    if page.is_closed():
        return
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        page.mouse.move(5, 5)  # no tooltip over the picture
        page.evaluate("document.activeElement && document.activeElement.blur()")
        height = page.evaluate("""() => Math.max(document.body.scrollHeight,
            ...['stMain', 'stAppViewContainer', 'stSidebarContent', 'stMainBlockContainer']
               .map(id => document.querySelector(`[data-testid='${id}']`))
               .filter(Boolean).map(el => el.scrollHeight))""")
        page.set_viewport_size({"width": VIEWPORT["width"], "height": max(VIEWPORT["height"], min(int(height) + 80, 16000))})
        try:
            page.wait_for_selector(IDLE, timeout=20_000)
        except Exception:  # still running: take the picture anyway, it shows why
            pass
        page.wait_for_timeout(1500)  # plotly relayouts to the new size, videos start
        page.screenshot(path=str(path), full_page=True, timeout=60_000)
    except Exception as exc:  # noqa: BLE001 - a screenshot must never hide the test's own failure
        print(f"could not save the screenshot {path}: {exc}")


# ----------------------------------------------------------------------------- helpers
def wait_idle(page, timeout: float = TIMEOUT_MS) -> None:
    """Wait until the script has finished its run (the page shows its final state)."""
    page.wait_for_selector(IDLE, timeout=timeout)


def dismiss_page_not_found(page) -> None:
    """Close Streamlit's "Page not found" dialog if a deep link in a server's first session showed it."""
    dialog = page.get_by_role("dialog").filter(has_text="Page not found")
    if dialog.count():
        page.keyboard.press("Escape")
        dialog.wait_for(state="hidden", timeout=10_000)


def open_app(page, app: App, path: str = "", **query) -> None:
    """Go to a page of the app (a link someone was given) and wait until it is drawn."""
    link = f"{app.url}/{path}"
    if query:
        link += "?" + urllib.parse.urlencode(query)
    page.goto(link)
    wait_idle(page)
    dismiss_page_not_found(page)


def query(page) -> dict[str, str]:
    """The page's URL parameters, as the address bar shows them."""
    return {k: v[-1] for k, v in urllib.parse.parse_qs(urllib.parse.urlparse(page.url).query).items()}


def user_of(page) -> str | None:
    return query(page).get("user")


def sidebar(page):
    return page.locator(SIDEBAR)


def go_by_sidebar(page, title: str) -> None:
    """Click a page's link in the sidebar's navigation, as a person does, and wait for the new page."""
    from playwright.sync_api import expect

    page.locator("[data-testid='stSidebarNavLink']").filter(has_text=title).click()
    expect(page.locator("[data-testid='stSidebarNavLink'][aria-current='page']")).to_contain_text(title)
    wait_idle(page)


def counter(page):
    """The step page's "Iteration k of n" heading."""
    return page.locator(f"{MAIN} h4").filter(has_text=re.compile(r"Iteration \d+ of \d+"))


def iteration_shown(page) -> tuple[int, int]:
    k, n = re.fullmatch(r"Iteration (\d+) of (\d+)", counter(page).inner_text().strip()).groups()
    return int(k), int(n)


def step(page, to: int, total: int | None = None) -> None:
    """Press Step and wait until the counter says iteration `to` and the page is idle again."""
    from playwright.sync_api import expect

    of = str(total) if total else r"\d+"
    page.get_by_role("button", name="Step", exact=True).click()
    expect(counter(page)).to_have_text(re.compile(rf"^Iteration {to} of {of}$"), timeout=LONG_MS)
    wait_idle(page, LONG_MS)


def choose(page, label: str, option: str, where=None) -> None:
    """Pick `option` in the select box labelled `label` (in the sidebar unless `where` says otherwise)."""
    from playwright.sync_api import TimeoutError as PlaywrightTimeout
    from playwright.sync_api import expect

    box = (where if where is not None else sidebar(page)).get_by_role("combobox", name=label)
    choice = page.get_by_role("option", name=option, exact=True)
    for attempt in range(3):  # a click that lands while the page settles (a chart drawn, an expander opened,
        try:                  # the list still opening) may not open the list or not pick the option: again
            if box.get_attribute("aria-expanded") != "true":
                box.click()
            if attempt:  # type to filter, as a person does in a long list: the option comes to the top
                box.press_sequentially(option)
            choice.wait_for(timeout=10_000)
            choice.click()
            expect(box).to_have_value(option, timeout=10_000)
            break
        except (PlaywrightTimeout, AssertionError):
            if attempt == 2:
                raise
            page.keyboard.press("Escape")  # close a list left open, then start over
    wait_idle(page, LONG_MS)


def type_number(page, label: str, value: int, where=None) -> None:
    """Type a number into the number box labelled `label` (anywhere on the page unless `where` says) and
    press Enter, as a person does; wait for the page to settle."""
    box = (where if where is not None else page).get_by_role("spinbutton", name=label)
    box.fill(str(value))
    box.press("Enter")
    wait_idle(page)


def error_boxes(page):
    """Streamlit's red error boxes (st.error) and exceptions on the page."""
    return page.locator("[data-testid='stAlertContentError'], [data-testid='stException']")


def download(page, button, timeout: float = LONG_MS) -> bytes:
    """Click a download button (a locator of the stDownloadButton) and return the file's bytes."""
    with page.expect_download(timeout=timeout) as info:
        button.locator("button").first.click()
    return Path(info.value.path()).read_bytes()


class SlowServer:
    """The page's connection to the app server, whose messages to the page can be held back: what a page
    meets on a busy server or a slow network, where a second click leaves before the first one's page has
    arrived (the browser then sends the widgets as it still shows them). Playwright's WebSocket routing:
    the page's messages go through at once; `hold()` keeps the server's, `release()` delivers them in order."""

    def __init__(self, page):
        self.holding, self.held, self.route = False, [], None
        page.route_web_socket(re.compile(r".*/_stcore/stream.*"), self._connect)

    def _connect(self, ws) -> None:
        server = ws.connect_to_server()
        self.route = ws
        ws.on_message(server.send)
        server.on_message(lambda message: self.held.append(message) if self.holding else ws.send(message))

    def hold(self) -> None:
        self.holding = True

    def release(self) -> None:
        self.holding = False
        held, self.held = self.held, []
        for message in held:
            self.route.send(message)
