"""The journeys a class takes, in a real browser: Debian's chromium driven by Playwright.

Each journey is its own test, so one failure does not hide the rest. One app server serves
the whole session (tiny runs: IFO_LAB_FAST=1; runs in a temporary folder), each test gets a
fresh browser context (so a fresh user id), and every page a test opened is saved as a
full-page screenshot to artifacts/browser/<test name>.png at its end, passed or failed, for a
person to look at. The fixtures and helpers live in tests/browser_support.py.

The tests check what a person sees (headings, counters, charts, buttons, messages, files
they download), never the app's internals.

    SDL_VIDEODRIVER=dummy .venv/bin/python -m pytest -q -m browser tests/test_browser.py
"""
import io
import os
import re
import xml.etree.ElementTree as ET
import zipfile

import numpy as np
import pytest

pytest.register_assert_rewrite("browser_support")
from browser_support import (CHART, LONG_MS, MAIN, OWN_ENV, ROOT, SlowServer, choose, counter, download, error_boxes,
                             go_by_sidebar, iteration_shown, open_app, query, sidebar, step, type_number, user_of,
                             wait_idle)  # noqa: E402
from method_charts import chart_titles  # noqa: E402

from ifo.reproduce import chapter7 as ch7  # noqa: E402

pytest_plugins = ["browser_support"]
pytestmark = pytest.mark.browser

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def expect(*args, **kwargs):
    from playwright.sync_api import expect as _expect

    return _expect(*args, **kwargs)


def is_svg(data: bytes) -> bool:
    return ET.fromstring(data).tag.endswith("svg")


def bordered(page, *texts: str):
    """The innermost bordered box (a run's entry in a list) that shows all of `texts`."""
    box = page.locator(f"{MAIN} [data-testid='stVerticalBlock']")
    for text in texts:
        box = box.filter(has_text=text)
    return box.last


# ----------------------------------------------------------------------------- 1. a vector task
def test_step_iupe_on_cartpole(app, page):
    """IUPE on CartPole: three Steps draw every chart and grow the curves, the loop diagram
    follows the iteration, and a rollout video plays."""
    open_app(page, app)
    expect(page.get_by_role("heading", name="IfO Lab")).to_be_visible()
    page.get_by_role("button", name="Step through a run").click()
    expect(counter(page)).to_have_text("Iteration 0 of 10")
    wait_idle(page)
    expect(sidebar(page).get_by_role("combobox", name="Environment")).to_have_value("CartPole")  # the defaults
    expect(sidebar(page).get_by_role("combobox", name="Method")).to_have_value("BCO(α)")
    expect(page.locator(CHART)).to_have_count(1)  # the loop diagram only
    expect(page.locator(CHART).first).to_contain_text("before the first iteration")

    choose(page, "Method", "IUPE")
    expect(sidebar(page).get_by_role("switch", name="Explore: sample the labels")).to_be_checked()  # IUPE's switches
    expect(page.get_by_text("Current run: IUPE on CartPole, seed 0")).to_be_visible()

    aer_chart = page.locator(CHART).filter(has_text="Average episodic reward")
    charts = 0
    for k in (1, 2, 3):
        step(page, k, 10)
        if k == 1:  # the diagram, AER, Performance, the IDM's panels, sampling, exploration, win probability...
            charts = page.locator(CHART).count()
            assert charts >= 9, charts
        expect(page.locator(CHART)).to_have_count(charts)  # the same panels every iteration
        for chart in page.locator(CHART).all():
            expect(chart).to_be_visible()
        expect(aer_chart.locator(".scatterlayer .trace").first.locator("path.point")).to_have_count(k)  # it grows
        expect(page.locator(CHART).first).to_contain_text(f"iteration {k}")  # the diagram follows
    expect(page.get_by_text("expert's hidden true actions")).to_be_visible()  # the IDM panel's legend
    expect(page.get_by_text("Thesis Fig 6.2b").first).to_be_visible()  # each panel names its figure
    expect(error_boxes(page)).to_have_count(0)

    page.get_by_role("button", name=re.compile(r"Show a rollout of the .*policy")).click()
    wait_idle(page, LONG_MS)
    expect(page.get_by_text("Learner after iteration 3")).to_be_visible()
    video = page.locator("video").first
    expect(video).to_be_visible()
    page.wait_for_function("v => v.readyState >= 2 && v.duration > 0", arg=video.element_handle(), timeout=LONG_MS)
    start = video.evaluate("v => v.currentTime")
    page.wait_for_function("([v, t]) => v.currentTime !== t", arg=[video.element_handle(), start], timeout=LONG_MS)


def test_run_n_stops_by_itself_pause_stops_a_play_and_reset_starts_again(app, page):
    """Run N plays N iterations one after another and stops; Run to the end plays until Pause, which stops
    after the iteration in progress; Reset starts the run again. (Each button is pressed inside the part of
    the page that Steps redraw, and each changes the page's timer or its run: the whole page follows.)"""
    open_app(page, app, "step")
    type_number(page, "Iterations in the run", 30, where=sidebar(page))  # room to press Pause mid-Play
    expect(counter(page)).to_have_text("Iteration 0 of 30")
    type_number(page, "N", 2, where=page.locator(MAIN))
    page.get_by_role("button", name="Run N", exact=True).click()
    expect(counter(page)).to_have_text("Iteration 2 of 30", timeout=LONG_MS)
    expect(page.get_by_role("button", name="Run N", exact=True)).to_be_visible(timeout=LONG_MS)  # it stopped
    wait_idle(page, LONG_MS)
    page.wait_for_timeout(1500)
    assert iteration_shown(page) == (2, 30)  # and no timer trains more

    page.get_by_role("button", name="Run to the end", exact=True).click()
    expect(counter(page)).to_have_text(re.compile(r"^Iteration [3-9] of 30$"), timeout=LONG_MS)
    page.get_by_role("button", name="Pause", exact=True).click()
    expect(page.get_by_role("button", name="Run N", exact=True)).to_be_visible(timeout=LONG_MS)
    wait_idle(page, LONG_MS)
    paused_at, _ = iteration_shown(page)
    page.wait_for_timeout(1500)
    assert iteration_shown(page) == (paused_at, 30) and 3 <= paused_at < 30

    page.get_by_role("button", name="Reset", exact=True).click()
    expect(counter(page)).to_have_text("Iteration 0 of 30", timeout=LONG_MS)
    wait_idle(page)
    step(page, 1, 30)  # the new run Steps as usual
    assert not error_boxes(page).count()


# BCO(α) and IUPE are stepped by the tests above; the charts each method shows are in tests/method_charts.py.
OTHER_METHODS = ["bc", "bco", "abco", "cril", "sail", "gail", "gaifo", "ilpo"]


@pytest.mark.parametrize("method_id", OTHER_METHODS)
def test_step_every_other_method_on_cartpole(app, page, method_id):
    """Every method a teacher can choose opens and Steps on a vector task: its settings draw (CRIL's once
    raised an error the moment it was chosen), a Step draws the method's own charts, and no error shows."""
    from ifo.methods import get_method

    method = get_method(method_id).title
    open_app(page, app, "step")
    choose(page, "Method", method)
    expect(page.get_by_text(f"Current run: {method} on CartPole, seed 0")).to_be_visible()
    expect(error_boxes(page)).to_have_count(0)
    step(page, 1)
    expect(error_boxes(page)).to_have_count(0)
    for title in chart_titles(method_id):
        expect(page.locator(CHART).filter(has_text=title).first).to_be_visible()
    expect(page.locator(CHART).filter(has_text="Average episodic reward")).to_have_count(1)


# ----------------------------------------------------------------------------- 2. a maze
MAZE_METHODS = {"bc": "BC", "bco": "BCO", "bco-alpha": "BCO(α)", "abco": "ABCO", "cril": "CRIL", "iupe": "IUPE"}


@pytest.mark.parametrize("method_id", MAZE_METHODS)
def test_step_a_maze(app, page, method_id):
    """Every method that reads the maze's images: Steps on Maze 3×3 (two, or the one pass of BC and BCO),
    no error, Grad-CAM shown. CRIL once crashed at its first Step here."""
    method = MAZE_METHODS[method_id]
    open_app(page, app, "step")
    choose(page, "Environment", "Maze 3x3")
    if method != "BCO(α)":
        choose(page, "Method", method)
    expect(page.get_by_text(f"Current run: {method} on Maze 3x3, seed 0")).to_be_visible()
    expect(counter(page)).to_have_text(re.compile(r"^Iteration 0 of \d+$"))
    _, total = iteration_shown(page)  # the maze's 15, BC's 50 epochs, BCO's one pass
    for k in range(1, min(2, total) + 1):
        step(page, k, total)
        expect(error_boxes(page)).to_have_count(0)
    grad_cam = page.locator(CHART).filter(has_text="Where the policy looks (Grad-CAM)")
    expect(grad_cam).to_have_count(1)
    expect(grad_cam).to_be_visible()
    expect(grad_cam.locator(".heatmaplayer, image, .imagelayer image").first).to_be_attached()  # maps drawn
    expect(page.get_by_text("Grad-CAM of the policy on fixed maze frames")).to_be_visible()


VECTOR_ONLY = {"sail": "SAIL", "gail": "GAIL", "gaifo": "GAIfO", "ilpo": "ILPO"}


@pytest.mark.parametrize("method_id", VECTOR_ONLY)
def test_a_method_that_reads_state_vectors_names_the_maze_setting_it_needs(app, page, snap, method_id):
    """SAIL, GAIL, GAIfO and ILPO read state vectors: chosen on Maze 3×3 the page says so and names the
    setting; the teacher chooses the vector observations among the maze's options, and the run Steps."""
    method = VECTOR_ONLY[method_id]
    open_app(page, app, "step")
    choose(page, "Environment", "Maze 3x3")
    choose(page, "Method", method)
    refusal = error_boxes(page).filter(has_text=f"Could not start a run of {method} on Maze 3x3")
    expect(refusal).to_contain_text('the setting "Maze observations": vector')
    snap(page, "refused")
    choose(page, "Maze observations", "vector")  # beside the maze's other options, in sight
    expect(page.get_by_text(f"Current run: {method} on Maze 3x3, seed 0")).to_be_visible()
    expect(error_boxes(page)).to_have_count(0)
    _, total = iteration_shown(page)  # each method's own count on the maze (GAIL's rounds: 50)
    for k in (1, 2):
        step(page, k, total)
        expect(error_boxes(page)).to_have_count(0)
    expect(page.locator(CHART).filter(has_text="Average episodic reward")).to_have_count(1)


def test_the_teachers_next_step_on_cartpole_is_ready_after_arriving_by_the_sidebar(app, page):
    """The same on a vector task, arriving as a teacher does from the landing page by the sidebar: IUPE on
    CartPole (a seed of its own: the server's iteration cache is shared by every journey)."""
    open_app(page, app)
    go_by_sidebar(page, "Step through a run")
    choose(page, "Method", "IUPE")
    type_number(page, "Seed", 18, where=sidebar(page))
    expect(page.get_by_text("Current run: IUPE on CartPole, seed 18")).to_be_visible()
    ready = page.get_by_text(re.compile(r"Iteration \d+ was ready when Step was pressed"))
    step(page, 1)
    expect(ready).to_have_count(0)  # the first Step of a run trains
    page.wait_for_timeout(6000)  # the teacher talks
    step(page, 2)
    expect(page.get_by_text("Iteration 2 was ready when Step was pressed")).to_be_visible()
    expect(error_boxes(page)).to_have_count(0)
    expect(page.locator(CHART).filter(has_text="Average episodic reward")).to_have_count(1)


@pytest.mark.parametrize("box", ["Method", "Preset"])
def test_a_method_then_a_seed_chosen_before_the_page_caught_up_make_that_methods_run(app, page, box):
    """On a busy server a teacher chooses IUPE (by the method, or by the thesis's preset) and types seed 18
    before the first choice's page has come back, so the browser sends the seed beside the switches it
    still shows (BCO(α)'s). The run is IUPE's with IUPE's switches, as the boxes say. It once ran "BCO(α)
    on CartPole, seed 18" under a box saying IUPE: the method's switches, written for it, were lost."""
    slow = SlowServer(page)
    open_app(page, app, "step")
    expect(page.get_by_text("Current run: BCO(α) on CartPole, seed 0")).to_be_visible()
    slow.hold()
    sidebar(page).get_by_role("combobox", name=box).click()
    page.get_by_role("option", name="IUPE", exact=True).click()
    page.wait_for_timeout(2000)  # the server has drawn IUPE's page; the browser has not had it
    seed = sidebar(page).get_by_role("spinbutton", name="Seed")
    seed.fill("18")
    seed.press("Enter")
    page.wait_for_timeout(1000)
    slow.release()
    page.wait_for_timeout(500)
    wait_idle(page, LONG_MS)
    expect(page.get_by_text("Current run: IUPE on CartPole, seed 18")).to_be_visible()
    expect(sidebar(page).get_by_role("combobox", name="Method")).to_have_value("IUPE")
    expect(sidebar(page).get_by_role("switch", name="Explore: sample the labels")).to_be_checked()
    expect(page).to_have_url(re.compile(r"step\.method=IUPE.*step\.seed=18|step\.seed=18.*step\.method=IUPE"))
    step(page, 1)
    expect(error_boxes(page)).to_have_count(0)


def test_the_teachers_next_step_on_a_maze_is_ready_while_the_class_looks(app, page):
    """A teacher Steps IUPE on the maze and talks over the iteration: the next one trains meanwhile, so the
    next Step shows it at once and says so."""
    # a seed no other journey uses: the server's iteration cache is shared by every test's sessions
    open_app(page, app, "step", **{"step.env": "maze3", "step.method": "iupe", "step.seed": "17"})
    expect(page.get_by_text("Current run: IUPE on Maze 3x3, seed 17")).to_be_visible()
    ready = page.get_by_text(re.compile(r"Iteration \d+ was ready when Step was pressed"))
    step(page, 1, 15)
    expect(ready).to_have_count(0)  # the first Step of a run trains
    page.wait_for_timeout(8000)  # the teacher talks
    step(page, 2, 15)
    expect(page.get_by_text("Iteration 2 was ready when Step was pressed")).to_be_visible()
    expect(error_boxes(page)).to_have_count(0)
    expect(page.locator(CHART).filter(has_text="Where the policy looks (Grad-CAM)")).to_have_count(1)


def test_a_link_naming_the_maze_and_method_as_the_cli_does_opens_them(app, page):
    """`/step?step.env=maze3&step.method=iupe` (the configuration's names, as in the CLI) opens IUPE on the
    3x3 maze, as a link with the page's own labels does; once it opened CartPole without a word."""
    open_app(page, app, "step", **{"step.env": "maze3", "step.method": "iupe"})
    expect(page.get_by_text("Current run: IUPE on Maze 3x3, seed 0")).to_be_visible()
    step(page, 1, 15)
    expect(error_boxes(page)).to_have_count(0)
    page.reload()
    wait_idle(page)
    expect(page.get_by_text("Current run: IUPE on Maze 3x3, seed 0")).to_be_visible()
    expect(counter(page)).to_have_text("Iteration 1 of 15")
    expect(page.locator(CHART).filter(has_text="Where the policy looks (Grad-CAM)")).to_be_visible()


def test_a_setting_that_multiplies_the_work_warns_in_the_sidebar(app, page, snap):
    """By the sidebar to the Step page on CartPole, 1,000 evaluation episodes typed into "More settings":
    the sidebar warns (10x the evaluation) before anyone presses Step, and the expander closed keeps it."""
    open_app(page, app)
    go_by_sidebar(page, "Step through a run")
    sidebar(page).get_by_text("More settings").click()
    type_number(page, "Eval episodes", 1000, where=sidebar(page))
    warning = sidebar(page).get_by_text("Slower Steps ahead")
    expect(warning).to_contain_text("against the default 100 (up to ×10 the work")
    sidebar(page).get_by_text("More settings").click()  # closed: the warning is outside it
    expect(warning).to_be_visible()
    expect(error_boxes(page)).to_have_count(0)
    snap(page, "cartpole")


def test_a_link_to_a_maze_with_larger_images_warns_in_the_sidebar(app, page, snap):
    """`/step?step.env=maze3&step.image_size=64` opens the 3x3 maze with 64-pixel images and says, before
    the first Step, that each image is about 4x the networks' work; a Step still trains."""
    open_app(page, app, "step", **{"step.env": "maze3", "step.method": "iupe", "step.image_size": "64"})
    expect(page.get_by_text("Current run: IUPE on Maze 3x3, seed 0")).to_be_visible()
    expect(sidebar(page).get_by_text("Slower Steps ahead")).to_contain_text(
        "Image size 64 against the default 32 (up to ×4 the work")
    step(page, 1, 15)
    expect(error_boxes(page)).to_have_count(0)
    snap(page, "maze")


def test_a_link_opens_the_resilience_study_on_the_environment_it_names(app, page):
    """`/resilience?resilience.env=acrobot` opens the study on Acrobot (it used to open CartPole); choosing
    another environment writes it into the address bar, so a reload keeps it."""
    open_app(page, app, "resilience", **{"resilience.env": "acrobot"})
    expect(page.get_by_role("heading", name="Resilience to sub-optimal experts")).to_be_visible()
    expect(page.locator(MAIN).get_by_role("combobox", name="Environment")).to_have_value("Acrobot")
    expect(page.locator(CHART).first).to_contain_text("GAIL")  # Acrobot's shipped results drawn
    choose(page, "Environment", "MountainCar", where=page.locator(MAIN))
    expect(page).to_have_url(re.compile(r"resilience\.env=Mountain"))
    page.reload()
    wait_idle(page)
    expect(page.locator(MAIN).get_by_role("combobox", name="Environment")).to_have_value("MountainCar")
    expect(error_boxes(page)).to_have_count(0)


# ----------------------------------------------------------------------------- 3. an example run
def test_open_an_example_run_and_continue_it(app, page, snap):
    """"Open a copy" of a shipped example run: it opens finished on the step page; one more
    iteration in the sidebar, one Step, and the copy in Your runs has it."""
    open_app(page, app)
    go_by_sidebar(page, "Your runs")
    expect(page.get_by_text("No saved runs yet.")).to_be_visible()
    example = bordered(page, "BCO(α) on CartPole", "Open a copy")
    expect(example).to_contain_text("10 of 10 iterations")
    example.get_by_role("button", name="Open a copy").click()

    expect(page.get_by_role("heading", name="Step through a run")).to_be_visible()
    expect(counter(page)).to_have_text("Iteration 10 of 10")
    wait_idle(page)
    run_id = query(page).get("run", "")
    assert run_id.startswith("cartpole-bco-alpha-"), page.url  # the copy, not the example itself
    expect(page.get_by_text("The run has done all 10 iterations")).to_be_visible()
    expect(page.get_by_role("button", name="Step", exact=True)).to_be_disabled()
    expect(page.locator(CHART)).not_to_have_count(0)

    type_number(page, "Iterations in the run", 11, where=sidebar(page))
    expect(counter(page)).to_have_text("Iteration 10 of 11")
    step(page, 11, 11)
    expect(error_boxes(page)).to_have_count(0)
    expect(page.locator("[data-testid='stAlertContentWarning']")).to_have_count(0)  # the autosave worked
    expect(page.get_by_text("The run has done all 11 iterations")).to_be_visible()
    snap(page, "continued")

    go_by_sidebar(page, "Your runs")
    expect(bordered(page, "BCO(α) on CartPole", "Open", "ZIP")).to_contain_text("11 of 11 iterations")


# ----------------------------------------------------------------------------- 4. the sidebar
def test_the_sidebar_keeps_the_same_user_and_run(app, page):
    """Welcome → Step through a run → Step → Your runs → Step through a run, all by the sidebar:
    the run just trained is listed, comes back, and `?user=` never changes."""
    open_app(page, app)
    user = user_of(page)
    assert user, f"no ?user= on the landing page: {page.url}"

    go_by_sidebar(page, "Step through a run")
    expect(counter(page)).to_have_text("Iteration 0 of 10")
    assert user_of(page) == user, page.url
    step(page, 1, 10)
    expect(page).to_have_url(re.compile(r"[?&]run="))
    run_id = query(page)["run"]
    assert user_of(page) == user, page.url

    go_by_sidebar(page, "Your runs")
    assert user_of(page) == user, page.url
    expect(page.get_by_text(f"(user {user})")).to_be_visible()
    entry = bordered(page, "BCO(α) on CartPole, seed 0", "Open", "ZIP")
    expect(entry).to_contain_text("1 of 10 iterations")
    expect(page.get_by_role("button", name="Open", exact=True)).to_have_count(1)  # one run, this one

    go_by_sidebar(page, "Step through a run")
    expect(counter(page)).to_have_text("Iteration 1 of 10")  # the same run, not a new one
    expect(page).to_have_url(re.compile(rf"[?&]run={re.escape(run_id)}"))
    assert user_of(page) == user, page.url
    expect(page.locator(CHART)).not_to_have_count(1)  # its charts, not an empty page


# ----------------------------------------------------------------------------- 5. reload
def test_reload_brings_the_run_back(app, page):
    """Two Steps, then the browser's reload: the same run at the same iteration."""
    open_app(page, app, "step")
    step(page, 1, 10)
    step(page, 2, 10)
    expect(page).to_have_url(re.compile(r"[?&]run="))
    before = query(page)
    page.reload()
    wait_idle(page)
    expect(counter(page)).to_have_text("Iteration 2 of 10")  # (its toast may be gone by now: not checked)
    after = query(page)
    assert (after.get("user"), after.get("run")) == (before["user"], before["run"]), page.url
    aer_chart = page.locator(CHART).filter(has_text="Average episodic reward")
    expect(aer_chart.locator(".scatterlayer .trace").first.locator("path.point")).to_have_count(2)
    step(page, 3, 10)  # and it trains on from there
    expect(error_boxes(page)).to_have_count(0)


# ----------------------------------------------------------------------------- 6. two tabs
def refused_save(app, page):
    """The same `?user=&run=` link in two tabs; Step in the first, then in the second, whose save is
    refused (it trained its own iteration 2 from iteration 1). Returns the second tab."""
    open_app(page, app, "step")
    step(page, 1, 10)
    expect(page).to_have_url(re.compile(r"[?&]run="))
    other = page.context.new_page()
    other.goto(page.url)
    wait_idle(other)
    expect(counter(other)).to_have_text("Iteration 1 of 10")  # both show the run
    expect(counter(page)).to_have_text("Iteration 1 of 10")
    step(page, 2, 10)  # the first tab saves iteration 2
    expect(page.locator("[data-testid='stAlertContentWarning']")).to_have_count(0)
    step(other, 2, 10)
    return other


def test_two_tabs_on_one_run_never_lose_it(app, context, page):
    """The same run in two tabs: stepping in one, then in the other, must not lose or corrupt it:
    the second writer is told, the first goes on saving, and Your runs still lists the run."""
    other = refused_save(app, page)
    user, run_id = user_of(page), query(page)["run"]
    warning = other.locator("[data-testid='stAlertContentWarning']")
    expect(warning).to_have_count(1)
    expect(warning).to_contain_text("Another tab or session saved this run meanwhile")
    expect(error_boxes(other)).to_have_count(0)

    step(page, 3, 10)  # the first tab goes on saving
    expect(page.locator("[data-testid='stAlertContentWarning']")).to_have_count(0)

    listing = context.new_page()
    open_app(listing, app, "runs", user=user)
    entry = bordered(listing, "BCO(α) on CartPole, seed 0", "Open", "ZIP")
    expect(entry).to_have_count(1)
    expect(entry).to_contain_text("3 of 10 iterations")
    expect(listing.get_by_text("damaged")).to_have_count(0)
    expect(listing.get_by_role("button", name="Open", exact=True)).to_have_count(1)

    # opening the run again (a fresh tab) finds the first tab's iteration 3, intact
    again = context.new_page()
    open_app(again, app, "step", user=user, run=run_id)
    expect(counter(again)).to_have_text("Iteration 3 of 10")
    expect(error_boxes(again)).to_have_count(0)


def test_a_refused_save_says_what_to_do_and_a_reload_recovers(app, page):
    """The second writer is told what happened in words (no server folders, no checkpoint names), and
    reloading that tab, or its "Reopen the latest save" button, reopens the saved run; "Keep mine as a copy"
    saves what it has as a run of its own."""
    other = refused_save(app, page)
    run_id = query(page)["run"]
    text = other.locator("[data-testid='stAlertContentWarning']").inner_text()
    assert str(app.runs) not in text and "ckpt-" not in text, text
    other.get_by_role("button", name="Keep mine as a copy").click()
    wait_idle(other)
    expect(other.locator("[data-testid='stAlertContentWarning']")).to_have_count(0)
    assert query(other).get("run") != run_id  # its own run now
    other.goto(page.url)  # the shared link again
    wait_idle(other)
    expect(counter(other)).to_have_text("Iteration 2 of 10")
    assert query(other).get("run") == run_id


# ----------------------------------------------------------------------------- 7. export
def test_export_a_chart_and_the_slide_pack(app, page):
    """A chart's SVG and PNG buttons download valid files; the slide pack is a ZIP with every
    figure as SVG, metrics.csv and config.json."""
    open_app(page, app, "step")
    step(page, 1, 10)
    step(page, 2, 10)
    buttons = page.locator("[data-testid='stDownloadButton']")
    assert not buttons.filter(has_text="SVG").count()  # off until asked for: the slide pack holds every chart
    page.get_by_text("Slide downloads under each chart").click()
    wait_idle(page)
    svg = download(page, buttons.filter(has_text="SVG").first)
    assert is_svg(svg), svg[:200]
    png = download(page, buttons.filter(has_text="PNG").first)
    assert png.startswith(PNG_MAGIC), png[:20]

    pack = download(page, buttons.filter(has_text="Slide pack (ZIP)"), timeout=2 * LONG_MS)
    with zipfile.ZipFile(io.BytesIO(pack)) as z:
        names = z.namelist()
        figures = [n for n in names if re.fullmatch(r"figures/[^/]+\.svg", n)]
        assert figures and {"metrics.csv", "config.json"} <= set(names), names
        assert all(is_svg(z.read(n)) for n in figures)
        rows = z.read("metrics.csv").decode().strip().splitlines()
        assert len(rows) == 3, rows  # a header and one row per iteration
        assert '"method": "bco-alpha"' in z.read("config.json").decode().replace("\n", " ").replace("  ", " ")


# ----------------------------------------------------------------------------- 8. compare
def queue_two_methods_and_wait(page, iterations: int, ended: int) -> None:
    """On Compare and ablate: `iterations` per run, queue the two methods chosen, wait until the queue holds
    `ended` ended jobs, both new ones finished and no error."""
    type_number(page, "Iterations per run", iterations)
    page.get_by_role("button", name="Queue these methods").click()
    expect(page.get_by_text("Queued 2 runs.")).to_be_visible()
    # .first: while the queue's fragment reruns, Streamlit may show its previous copy beside the new one
    expect(page.get_by_text(re.compile(rf"0 waiting or training, {ended} ended")).first).to_be_visible(
        timeout=2 * LONG_MS)
    wait_idle(page)
    expect(page.get_by_text(f"finished after {iterations} of {iterations} iterations")).to_have_count(2)
    expect(error_boxes(page)).to_have_count(0)


def test_compare_two_methods(app, page):
    """Queue BCO(α) and IUPE on the compare page, wait for both, read their curves and the table."""
    open_app(page, app)
    go_by_sidebar(page, "Compare and ablate")
    expect(page.get_by_text("Nothing queued yet")).to_be_visible()
    chosen = page.locator("[data-testid='stMultiSelect']").filter(has_text="Methods").first
    expect(chosen).to_contain_text("BCO(α)")
    expect(chosen).to_contain_text("IUPE")
    queue_two_methods_and_wait(page, iterations=3, ended=2)

    charts = page.locator(CHART)
    expect(charts).to_have_count(2)  # Performance and AER on shared axes
    for chart in charts.all():
        expect(chart).to_be_visible()
        expect(chart).to_contain_text("BCO(α)")  # the legend names both runs
        expect(chart).to_contain_text("IUPE")
        expect(chart.locator(".scatterlayer .trace")).to_have_count(2)
    table = page.locator("[data-testid='stDataFrame']")
    expect(table).to_be_visible()
    # the grid is drawn on a canvas; focusing it (as a keyboard or screen-reader user does) gives its cells
    table.locator("canvas[data-testid='data-grid-canvas']").focus()
    rows = table.locator("tbody tr")
    expect(rows).to_have_count(2)  # one row per configuration
    expect(rows.nth(0)).to_contain_text("BCO(α) · CartPole · 3 it.")
    expect(rows.nth(1)).to_contain_text("IUPE · CartPole · 3 it.")
    for row in rows.all():
        expect(row).to_contain_text("1/1 finished")
        expect(row.locator("td").nth(3)).to_have_text(re.compile(r"^-?\d+\.\d+"))  # P (ours): a number


# ----------------------------------------------------------------------------- 9. uploads
def good_demos() -> bytes:
    """The first two episodes of the shipped CartPole demonstrations, as a person would cut them."""
    with np.load(ROOT / "assets" / "demos" / "cartpole.npz") as d:
        end = np.flatnonzero(d["episode_starts"])[2]
        arrays = {k: d[k][:end] for k in ("obs", "next_obs", "rewards", "episode_starts")}
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


def test_upload_a_bad_file_then_a_good_one(app, page, snap):
    """Random bytes named demos.npz: one clear error, nothing saved. Then a real file: listed."""
    open_app(page, app)
    go_by_sidebar(page, "Your runs")
    form = page.locator("[data-testid='stForm']")
    chooser = form.locator("[data-testid='stFileUploaderDropzoneInput']")

    chooser.set_input_files({"name": "demos.npz", "mimeType": "application/octet-stream",
                             "buffer": os.urandom(4096)})
    expect(form.get_by_text("demos.npz")).to_be_visible()
    form.get_by_role("button", name="Check and save").click()
    wait_idle(page)
    expect(error_boxes(page)).to_have_count(1)
    expect(error_boxes(page)).to_contain_text("demos.npz")
    expect(page.get_by_text("Nothing was saved")).to_be_visible()
    expect(page.get_by_role("button", name="Train")).to_have_count(0)  # no demonstrations listed
    snap(page, "bad-file")

    chooser.set_input_files({"name": "two-episodes.npz", "mimeType": "application/octet-stream",
                             "buffer": good_demos()})
    expect(form.get_by_text("two-episodes.npz")).to_be_visible()
    form.get_by_role("button", name="Check and save").click()
    wait_idle(page)
    expect(error_boxes(page)).to_have_count(0)
    expect(page.get_by_text(re.compile(r"Saved cartpole-two-episodes: 2 episodes"))).to_be_visible()
    entry = bordered(page, "cartpole-two-episodes", "Train")
    expect(entry).to_contain_text("from two-episodes.npz · 2 episodes")
    expect(page.get_by_role("button", name="Train")).to_have_count(1)


def test_your_own_environment_from_its_demonstrations_to_the_step_page(app, page, snap):
    """A researcher's environment named in IFO_LAB_ENVS (examples/parking.py): its demonstrations uploaded on
    Your runs, trained there, the trained run opened on the Step page with its own charts and names, then
    two methods compared on the same upload."""
    import examples.parking as parking

    open_app(page, app, "step", **{"step.env": OWN_ENV})  # a link naming it, before any upload
    expect(error_boxes(page)).to_contain_text("upload yours on Your runs")
    snap(page, "by-link")
    go_by_sidebar(page, "Your runs")
    form = page.locator("[data-testid='stForm']")
    choose(page, "Environment the demonstrations come from", "Parking", where=form)
    buffer = io.BytesIO()
    np.savez(buffer, **parking.demonstrations(30))
    form.locator("[data-testid='stFileUploaderDropzoneInput']").set_input_files(
        {"name": "parking.npz", "mimeType": "application/octet-stream", "buffer": buffer.getvalue()})
    form.get_by_role("button", name="Check and save").click()
    wait_idle(page)
    expect(page.get_by_text(re.compile(r"Saved parking-parking: 30 episodes"))).to_be_visible()
    bordered(page, "parking-parking", "Train").get_by_role("button", name="Train").click()
    wait_idle(page)
    trained = bordered(page, "IUPE on Parking", "ZIP", "Rename")  # its entry in the run list
    expect(trained).to_contain_text("10 of 10 iterations", timeout=LONG_MS)
    trained.get_by_role("button", name=re.compile(r"\bOpen$")).click()

    expect(page.get_by_role("heading", name="Step through a run")).to_be_visible()
    expect(counter(page)).to_have_text("Iteration 10 of 10")
    wait_idle(page)
    assert query(page).get("env", OWN_ENV) == OWN_ENV and query(page).get("run", "").startswith("parking-iupe-")
    expect(error_boxes(page)).to_have_count(0)
    expect(page.locator(CHART)).not_to_have_count(0)
    expect(page.get_by_text("brake").first).to_be_visible()  # its own action names in the IDM's charts

    # Compare and ablate asks which upload its runs learn from, and trains two methods on it
    go_by_sidebar(page, "Compare and ablate")
    choose(page, "Environment", "Parking", where=page.locator(MAIN))
    expect(page.get_by_role("combobox", name="Demonstrations")).to_have_value("parking-parking (from parking.npz)")
    queue_two_methods_and_wait(page, iterations=2, ended=3)  # the third: the run trained from Your runs
    expect(page.locator(CHART)).to_have_count(2)
    snap(page, "compare")


# ----------------------------------------------------------------------------- 10. a read-only share
def test_share_read_only_and_watch_from_another_browser(app, browser, page):
    """The teacher's "Share read-only" link, opened in another browser context (a student's laptop):
    the run is shown, nothing can change it, the teacher's next Step appears, and a copy is the student's own."""
    open_app(page, app, "step")
    step(page, 1, 10)
    step(page, 2, 10)
    page.get_by_role("button", name="Share read-only").click()
    link = page.locator("[data-testid='stCode']").filter(has_text="/watch?share=").inner_text().strip()
    assert "user=" not in link
    teacher = user_of(page)

    student = browser.new_context(viewport={"width": 1400, "height": 1000}).new_page()
    student.set_default_timeout(LONG_MS)
    student.goto(link)
    wait_idle(student)
    expect(student.get_by_role("heading", name="Watch a shared run")).to_be_visible()
    expect(counter(student)).to_have_text("Iteration 2 of 10")
    expect(student.get_by_role("button", name="Step", exact=True)).to_have_count(0)  # read-only
    assert user_of(student) != teacher

    page.keyboard.press("Escape")
    step(page, 3, 10)  # the teacher goes on: the student's page follows
    expect(counter(student)).to_have_text("Iteration 3 of 10", timeout=LONG_MS)

    student.get_by_role("button", name="Make my own copy").click()
    wait_idle(student)
    expect(counter(student)).to_have_text("Iteration 3 of 10")
    expect(student.get_by_role("button", name="Step", exact=True)).to_be_enabled()
    assert user_of(student) != teacher
    student.context.close()


def test_a_student_who_looks_elsewhere_comes_back_to_the_watched_run(app, browser, page):
    """A watching student opens another page by the sidebar, then comes back with the browser's Back
    button and by the sidebar: both times the teacher's run is there (the links carry no `?share=`)."""
    teacher = browser.new_context(viewport={"width": 1400, "height": 1000}).new_page()
    teacher.set_default_timeout(LONG_MS)
    open_app(teacher, app, "step")
    step(teacher, 1, 10)
    teacher.get_by_role("button", name="Share read-only").click()
    link = teacher.locator("[data-testid='stCode']").filter(has_text="/watch?share=").inner_text().strip()
    token = link.rsplit("=", 1)[1]

    page.goto(link)  # the student (this test's screenshot)
    wait_idle(page)
    expect(counter(page)).to_have_text("Iteration 1 of 10")
    go_by_sidebar(page, "Your runs")
    expect(page.get_by_role("heading", name="Your runs")).to_be_visible()
    page.go_back()
    wait_idle(page)
    expect(page.get_by_role("heading", name="Watch a shared run")).to_be_visible()
    expect(counter(page)).to_have_text("Iteration 1 of 10")
    expect(page.get_by_text("Open the link your teacher shared")).to_have_count(0)
    expect(page.locator("[data-testid='stSidebarNavLink'][aria-current='page']")).to_have_count(1)
    expect(page.locator("[data-testid='stSidebarNavLink'][aria-current='page']")).to_contain_text("Watch a shared run")
    assert query(page).get("share") == token  # the address bar is the link again

    go_by_sidebar(page, "Welcome")
    go_by_sidebar(page, "Watch a shared run")
    expect(counter(page)).to_have_text("Iteration 1 of 10")
    teacher.keyboard.press("Escape")
    step(teacher, 2, 10)  # still following the teacher
    expect(counter(page)).to_have_text("Iteration 2 of 10", timeout=LONG_MS)
    expect(error_boxes(page)).to_have_count(0)
    teacher.context.close()


# ----------------------------------------------------------------------------- 11. a lesson
def test_a_lesson_from_the_landing_page(app, page):
    """The landing page's first lesson opens the step page with its settings; a Step trains it."""
    open_app(page, app)
    expect(page.get_by_text("Vanishing actions: why IUPE samples")).to_be_visible()
    page.get_by_role("button", name="Open IUPE").first.click()
    wait_idle(page)
    expect(counter(page)).to_have_text("Iteration 0 of 5")
    expect(sidebar(page).get_by_role("combobox", name="Method")).to_have_value("IUPE")
    step(page, 1, 5)
    expect(error_boxes(page)).to_have_count(0)


# ----------------------------------------------------------------------------- 12. sub-optimal experts (Ch. 7)
def test_the_resilience_page_draws_fig_7_1_and_runs_a_cell(app, page):
    """By the sidebar to "Sub-optimal experts": Fig 7.1 from the shipped CartPole results with fidelity
    beside it, the longer budgets, 40 rounds and the thesis's 100 (and the methods or experts a budget has not
    trained yet), and back, its SVG download, the expert levels; then
    one cell (BC on Expert⁵, 1 iteration) queued and finished on the page."""
    open_app(page, app)
    go_by_sidebar(page, "Sub-optimal experts")
    expect(page.get_by_role("heading", name="Resilience to sub-optimal experts")).to_be_visible()
    charts = page.locator(CHART)
    expect(charts).to_have_count(2)  # AER against the expert's AER; fidelity beside it
    expect(charts.first).to_contain_text("expert")
    expect(charts.first).to_contain_text("IUPE")
    ilpo_points = charts.first.locator(".scatterlayer .trace").filter(has=page.locator("path.point")).nth(3) \
        .locator("path.point")  # expert, BC, GAIL, ILPO, IUPE: a point per level
    longer = ch7.in_budget(ch7.load_shipped_results("cartpole"), (40, None))
    page.get_by_text("40 iterations, all demonstrations:").click()  # the shipped longer budget
    expect(page.get_by_text(re.compile(r"iterations per run: 40\."))).to_be_visible()
    expect(charts.first).to_contain_text("GAIL")
    expect(ilpo_points).to_have_count(len({r["level"] for r in longer if r["method"] == "ILPO"}))
    gap_note = page.get_by_text("Not trained with this budget yet")  # a short line is named as a gap, not a result
    expect(gap_note).to_have_count(1 if ch7.missing_cells(longer) else 0)
    page.get_by_text("100 iterations, all demonstrations:").click()  # the thesis's budget, from docs/reproduction/
    expect(page.get_by_text(re.compile(r"iterations per run: 100\."))).to_be_visible()
    expect(page.get_by_text(re.compile(r"trainings from .*cartpole-gail-100-iterations\.jsonl"))).to_be_visible()
    expect(gap_note).to_have_count(1)  # BC and ILPO were not trained for 100 rounds
    page.get_by_text("5 iterations, 20 demonstrations: BC, GAIL, ILPO, IUPE").click()
    expect(page.get_by_text(re.compile(r"iterations per run: 5\."))).to_be_visible()
    expect(ilpo_points).to_have_count(5)
    expect(gap_note).to_have_count(0)
    page.get_by_text("The expert levels (Table 7.1)").click()
    expect(page.get_by_text("Levels 2-5 are earlier checkpoints")).to_be_visible()

    main = page.locator(MAIN)
    expect(main.get_by_role("combobox", name="Method", exact=True)).to_have_value("BC")  # the first method
    wait_idle(page)
    choose(page, "Expert", "Expert⁵", where=main)
    type_number(page, "Iterations", 1, where=main)
    page.get_by_role("button", name="Queue this cell").click()
    expect(page.get_by_text("Queued BC on Expert⁵")).to_be_visible()
    expect(page.get_by_text(re.compile(r"0 waiting or training, 1 ended")).first).to_be_visible(timeout=2 * LONG_MS)
    expect(error_boxes(page)).to_have_count(0)
    svg = download(page, page.locator("[data-testid='stDownloadButton']").filter(has_text="SVG").first)
    assert is_svg(svg) and b"IUPE" in svg, svg[:200]  # Fig 7.1 for slides
