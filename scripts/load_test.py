"""Many students at once: N browser sessions press Step K times on the same server.

    PYTHONPATH=. .venv/bin/python scripts/load_test.py --sessions 10 --steps 3 [--url http://127.0.0.1:8501]
    PYTHONPATH=. .venv/bin/python scripts/load_test.py --mode lesson --sessions 30 --lead 2 --full
    PYTHONPATH=. .venv/bin/python scripts/load_test.py --mode free --sessions 10 --full
    PYTHONPATH=. .venv/bin/python scripts/load_test.py --client protocol --mode lesson --sessions 30 --lead 3 --think 5 --full
    PYTHONPATH=. .venv/bin/python scripts/load_test.py --client protocol --mode lesson --sessions 30 --lead 3 --full --env maze5
    PYTHONPATH=. .venv/bin/python scripts/load_test.py --client protocol --mode watch --sessions 31 --think 3 --full

Modes: "lesson" (every session on the same configuration and seed, the teacher's session starting
`--lead` Steps ahead: students' iterations come from the shared iteration cache) and "free" (every
session its own seed: nothing to share, the bounded queue of trainings decides) and "watch" (protocol
clients: the teacher's session Steps and shares its run, the other sessions follow it on the read-only
watch page; `--think` is then the teacher's pause between Steps). `--full` uses the
real sizes (default: IFO_LAB_FAST's tiny runs). The report gives Step latency percentiles, the
steps completed, and the server's peak memory (VmHWM) when it served the app itself.

`--client protocol` replaces the browsers by sessions that speak Streamlit's own websocket protocol
(the messages a browser's page sends and receives, nothing drawn): what the server alone costs, as
in a class whose students' browsers run on their own computers. `--think S` (protocol clients) has each
session read the page for a random 0..2S seconds before every Step (its own seeded draws), instead of
every session pressing at the same instant; the latency still runs from the click. `--client browser` (the default)
is the whole experience, browsers included, all on this machine.

Without --url it serves the app itself (`streamlit run app.py` on a free loopback port, with
IFO_LAB_FAST=1 and a throw-away IFO_LAB_RUNS). It opens N pages in one headless Debian
chromium (Playwright; never downloads a browser), each in its own browser context, i.e. its
own Streamlit session. Every page opens the landing page, goes to *Step through a run*
and presses Step K times; for each press it measures the time until the page's counter
shows the new iteration. It prints latency percentiles and how many steps completed as a
markdown table. Only loopback addresses are accepted; the whole test is bounded by
--timeout seconds.
"""
from __future__ import annotations

import argparse
import asyncio
import os
import re
import sys
import tempfile
import time
import urllib.parse
import subprocess
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from ifo.envs import ENV_NAMES  # noqa: E402
from scripts.app_server import healthy, serve_app  # noqa: E402
CHROMIUM = "/usr/bin/chromium"
IDLE = "[data-testid='stApp'][data-test-script-state='notRunning']"
LOOPBACK = {"127.0.0.1", "localhost", "::1"}


LESSON = {"step.method": "IUPE"}  # what every session of a lesson opens (CartPole, seed 0; `--env` sets step.env)


def step_query(mode: str, k: int) -> str:
    """Session k's settings in the step page's URL: the lesson's, or (free) a seed of its own."""
    settings = dict(LESSON)
    if mode == "free":
        settings["step.seed"] = str(100 + k)  # a configuration of its own
    return urllib.parse.urlencode(settings)


def step_url(url: str, mode: str, k: int) -> str:
    return f"{url}/step?{step_query(mode, k)}"


async def session(browser, url: str, k: int, steps: int, step_timeout: float, results: dict,
                  shots: str | None = None, mode: str = "classic", start_after: asyncio.Event | None = None,
                  ready: asyncio.Event | None = None, lead: int = 0) -> None:
    context = await browser.new_context(viewport={"width": 1280, "height": 900})
    page = await context.new_page()
    page.set_default_timeout(step_timeout * 1000)
    latencies, errors = [], []
    where = "opening the step page"
    try:
        counter = page.locator("[data-testid='stMain'] h4").filter(has_text=re.compile(r"^Iteration \d+ of \d+$"))
        if start_after is not None:
            await start_after.wait()  # students start once the teacher is `lead` Steps ahead
        if mode == "classic":
            await page.goto(url)
            await page.wait_for_selector(IDLE)
            await page.get_by_role("button", name="Step through a run").click()
        else:
            await page.goto(step_url(url, mode, k))
            await page.wait_for_selector(IDLE)
            dialog = page.get_by_role("dialog").filter(has_text="Page not found")  # streamlit#9992, first session
            if await dialog.count():
                await page.keyboard.press("Escape")
                await dialog.wait_for(state="hidden")
        await counter.filter(has_text=re.compile(r"^Iteration 0 of")).wait_for()
        await page.wait_for_selector(IDLE)
        step = page.get_by_role("button", name="Step", exact=True)
        for i in range(1, steps + lead + 1):
            where = f"step {i}"
            await step.wait_for()
            start = time.perf_counter()
            await step.click()
            await counter.filter(has_text=re.compile(rf"^Iteration {i} of")).wait_for(timeout=step_timeout * 1000)
            if ready is None or i > lead:  # (the teacher's lead Steps are not the class's latency)
                latencies.append(time.perf_counter() - start)
            await page.wait_for_selector(IDLE)
            if ready is not None and i == lead:
                ready.set()
    except Exception as e:  # noqa: BLE001 - a failed session is counted, not fatal
        errors.append(f"session {k}, {where}: {type(e).__name__}: {str(e).splitlines()[0][:200]}")
        if shots:
            try:
                await page.screenshot(path=str(Path(shots) / f"session-{k}.png"), full_page=True)
            except Exception:  # noqa: BLE001
                pass
    finally:
        results[k] = (latencies, errors)
        await context.close()


class ProtocolSession:
    """One session of the step page spoken to over Streamlit's websocket, as a browser's page would: reruns
    with the Step button's trigger, reading the deltas for the counter. Nothing is drawn."""

    COUNTER = re.compile(r"^#### Iteration (\d+) of \d+$")
    PAGE = "step"
    RETRY = "Try again"  # the button views/step_through.py draws when a run could not start

    def __init__(self, ws, query: str):
        self.ws, self.query = ws, query
        self.buttons: dict[str, tuple[str, str]] = {}  # label -> (widget id, the fragment it is drawn in or "")
        self.counter: int | None = None
        self.finished = False
        self.page_hash = ""  # the page's script hash once the server named it (a browser sends it back)
        self.fragment: tuple[float, str] | None = None  # (interval, id) of a fragment the server asks to rerun
        self.said: list[str] = []  # the last texts and alerts the page drew (what a timeout reports)
        self.messages = 0  # how many the server sent (a timeout reports it)
        self.gave_up = False  # this script run drew the page that could not start a run ("Try again")

    @staticmethod
    async def connect(url: str, timeout: float):
        import websockets

        return await websockets.connect(url.replace("http", "ws", 1) + "/_stcore/stream", subprotocols=["streamlit"],
                                        max_size=None, open_timeout=timeout, ping_interval=None)

    @classmethod
    async def open(cls, url: str, query: str, timeout: float) -> "ProtocolSession":
        session = cls(await cls.connect(url, timeout), query)
        await session.rerun()
        await session.until(lambda: session.finished and session.counter is not None and "Step" in session.buttons,
                            timeout)
        return session

    async def rerun(self, trigger: str | None = None, fragment: str | None = None, timer: bool = False) -> None:
        from streamlit.proto.BackMsg_pb2 import BackMsg

        msg = BackMsg()
        msg.rerun_script.query_string, msg.rerun_script.page_name = self.query, self.PAGE
        msg.rerun_script.page_script_hash = self.page_hash
        if trigger is not None:  # a click: only the button's state; the others keep theirs on the server
            widget = msg.rerun_script.widget_states.widgets.add()
            widget.id, widget.trigger_value = trigger, True
        if fragment:  # a fragment's timer, or a click on a widget drawn in a fragment: that fragment only
            msg.rerun_script.fragment_id, msg.rerun_script.is_auto_rerun = fragment, timer
        self.finished = self.gave_up = False
        await self.ws.send(msg.SerializeToString())

    async def receive(self, timeout: float | None = None) -> None:
        """Read one message from the server and keep what a page would: its URL, the buttons, the counter."""
        from streamlit.proto.ForwardMsg_pb2 import ForwardMsg

        msg = ForwardMsg()
        msg.ParseFromString(await asyncio.wait_for(self.ws.recv(), timeout))
        self.messages += 1
        kind = msg.WhichOneof("type")
        if kind == "page_info_changed":
            self.query = msg.page_info_changed.query_string  # ?user= and the settings, kept like a URL
        elif kind == "navigation":
            self.page_hash = msg.navigation.page_script_hash
        elif kind == "auto_rerun":
            self.fragment = (msg.auto_rerun.interval, msg.auto_rerun.fragment_id)
        elif kind == "script_finished":
            self.finished = True
        elif kind == "delta" and msg.delta.WhichOneof("type") == "new_element":
            element = msg.delta.new_element
            what = element.WhichOneof("type")
            if what == "button":
                self.buttons[element.button.label] = (element.button.id, msg.delta.fragment_id)
                self.gave_up |= element.button.label == self.RETRY
            elif what == "markdown" and (m := self.COUNTER.match(element.markdown.body.strip())):
                self.counter = int(m.group(1))
                self.shown(self.counter)
            elif what in ("alert", "exception", "markdown"):
                body = getattr(element, what)
                text = body.message if what == "exception" else body.body
                self.said = (self.said + [f"{what}: {text.strip()[:120]}"])[-3:]

    def shown(self, iteration: int) -> None:
        """The counter shows `iteration` (a watching session notes when)."""

    async def until(self, done, timeout: float) -> None:
        deadline = time.monotonic() + timeout
        while not done():
            if self.finished and self.gave_up:  # the page will not change by itself: say so now, not at the timeout
                raise RuntimeError(f"the page could not start the run: last drawn {self.said}")
            try:
                await self.receive(max(0.01, deadline - time.monotonic()))
            except TimeoutError:  # say what the page showed instead, for the report
                raise TimeoutError(f"after {timeout:.0f} s: {self.messages} messages, script "
                                   f"{'finished' if self.finished else 'not finished'}, counter {self.counter}, "
                                   f"buttons {sorted(self.buttons)[:6]}, last drawn {self.said}") from None

    async def step(self, timeout: float) -> None:
        want = (self.counter or 0) + 1
        button, fragment = self.buttons["Step"]
        await self.rerun(button, fragment=fragment)
        await self.until(lambda: self.counter == want and self.finished, timeout)

    async def close(self) -> None:
        await self.ws.close()


class WatchSession(ProtocolSession):
    """A student on the watch page of the teacher's shared run (`/watch?share=...`), spoken to as a browser's
    page would: the page's fragment is rerun on the timer the server asks for (its `auto_rerun` message, every
    FOLLOW_SECONDS of views/watch.py), and the whole page is redrawn when the teacher's run has a newer
    checkpoint. `seen[i]` is when the counter first showed iteration i."""

    PAGE = "watch"

    def __init__(self, ws, query: str):
        super().__init__(ws, query)
        self.seen: dict[int, float] = {}

    def shown(self, iteration: int) -> None:
        self.seen.setdefault(iteration, time.perf_counter())

    async def listen(self) -> None:
        """Read the server's messages for as long as the session lives (a task of its own)."""
        while True:
            await self.receive()

    async def follow(self) -> None:
        """The browser's timer: the fragment asks again every interval (not while a run is still going)."""
        while True:
            await asyncio.sleep(self.fragment[0] if self.fragment else 1.0)
            if self.fragment is not None and self.finished:
                await self.rerun(fragment=self.fragment[1], timer=True)


async def run_watch_sessions(url: str, runs: Path, sessions: int, steps: int, step_timeout: float,
                             timeout: float, think: float) -> tuple[dict, str]:
    """The teacher (session 0) trains one iteration on the step page and shares the run; sessions 1.. open
    the share link and watch. Then the teacher Steps `steps` times, each once every student has seen the
    last one (or a Step timeout went by) and `think` seconds more; a student's latency for iteration i runs
    from the teacher's click on Step (the training included) to the student's page showing it. Returns the
    students' results and a line on the teacher's own Steps."""
    results: dict[int, tuple[list, list]] = {k: ([], []) for k in range(sessions)}
    behind: list[float] = []
    idle: list[float] = []  # the server's CPU share while the class only watched
    teacher = await ProtocolSession.open(url, step_query("lesson", 0), step_timeout)
    students: list[WatchSession] = []
    tasks: list[asyncio.Task] = []
    try:
        await teacher.step(step_timeout)  # a saved run to share
        params = urllib.parse.parse_qs(teacher.query)
        os.environ["IFO_LAB_RUNS"] = str(runs)  # the server's runs folder: share as the Your runs page does
        from ifo.ui import storage
        token = storage.share_run(params[storage.USER_PARAM][0], params["run"][0])
        for k in range(1, sessions):
            student = WatchSession(await ProtocolSession.connect(url, step_timeout),
                                   urllib.parse.urlencode({storage.SHARE_PARAM: token}))
            students.append(student)
            tasks += [asyncio.create_task(student.listen()), asyncio.create_task(student.follow())]
            await student.rerun()
        deadline = time.monotonic() + timeout
        for i in range(2, steps + 2):
            await asyncio.sleep(think / 2)  # the pages finish drawing the last iteration
            cpu, start = server_cpu_seconds(url), time.perf_counter()
            await asyncio.sleep(think / 2)  # the class watches; the server only answers the pages' asks
            if cpu is not None and think:
                idle.append((server_cpu_seconds(url) - cpu) / (time.perf_counter() - start))
            clicked = time.perf_counter()
            await teacher.step(step_timeout)
            shown = time.perf_counter()
            results[0][0].append(shown - clicked)
            until = min(deadline, time.monotonic() + step_timeout)
            while any(i not in s.seen for s in students) and time.monotonic() < until:
                await asyncio.sleep(0.05)
            for k, s in enumerate(students, start=1):
                if i in s.seen:
                    results[k][0].append(s.seen[i] - clicked)
                    behind.append(s.seen[i] - shown)
                else:
                    results[k][1].append(f"session {k}: did not show iteration {i} within {step_timeout:.0f} s")
    finally:
        for t in tasks:
            t.cancel()
        await asyncio.gather(*tasks, return_exceptions=True)
        await asyncio.gather(*(c.ws.close() for c in [teacher, *students]), return_exceptions=True)
    p50, p95 = np.percentile(behind, [50, 95]) if behind else (np.nan, np.nan)
    note = (f"The teacher's own Steps (training, then the page): median {np.median(results[0][0]):.2f} s. A student's "
            f"page shows the iteration p50 {p50:+.2f} s / p95 {p95:+.2f} s after the teacher's page has (negative: before "
            "the teacher's page has finished drawing it)." + (
                f" Between Steps (the second half of each pause), with {sessions - 1} pages asking, the server used "
                f"{np.mean(idle):.0%} of a core."
                if idle else ""))
    return {k: v for k, v in results.items() if k}, note  # the teacher's own Steps are not the class's latency


async def protocol_session(url: str, k: int, steps: int, step_timeout: float, results: dict, mode: str = "classic",
                           start_after: asyncio.Event | None = None, ready: asyncio.Event | None = None,
                           lead: int = 0, think: float = 0.0) -> None:
    latencies, errors, where, client = [], [], "opening the step page", None
    pause = np.random.default_rng(k)  # this student's reading times (same every run of the test)
    try:
        if start_after is not None:
            await start_after.wait()
        client = await ProtocolSession.open(url, step_query(mode, k), step_timeout)
        for i in range(1, steps + lead + 1):
            where = f"step {i}"
            if think and (ready is None or i > lead):  # reads the page before pressing Step (mean `think` s)
                await asyncio.sleep(pause.uniform(0, 2 * think))
            start = time.perf_counter()
            await client.step(step_timeout)
            if ready is None or i > lead:
                latencies.append(time.perf_counter() - start)
            if ready is not None and i == lead:
                ready.set()
    except Exception as e:  # noqa: BLE001 - a failed session is counted, not fatal
        errors.append(f"session {k}, {where}: {type(e).__name__}: {str(e).splitlines()[0][:600] if str(e) else ''}")
    finally:
        results[k] = (latencies, errors)
        if client is not None:
            await client.close()


async def run_protocol_sessions(url: str, sessions: int, steps: int, step_timeout: float, timeout: float,
                                mode: str = "classic", lead: int = 0, think: float = 0.0) -> dict:
    results: dict[int, tuple[list, list]] = {}
    if mode == "lesson" and lead > 0:
        ahead = asyncio.Event()
        tasks = [asyncio.create_task(protocol_session(url, 0, steps, step_timeout, results, mode, ready=ahead,
                                                      lead=lead, think=think))]
        tasks += [asyncio.create_task(protocol_session(url, k, steps, step_timeout, results, mode, start_after=ahead,
                                                       think=think)) for k in range(1, sessions)]
    else:
        tasks = [asyncio.create_task(protocol_session(url, k, steps, step_timeout, results, mode, think=think))
                 for k in range(sessions)]
    done, pending = await asyncio.wait(tasks, timeout=timeout)
    for t in pending:
        t.cancel()
    await asyncio.gather(*pending, return_exceptions=True)
    for k in range(sessions):
        results.setdefault(k, ([], [f"session {k}: did not finish within --timeout {timeout:.0f} s"]))
    return results


async def run_sessions(url: str, sessions: int, steps: int, step_timeout: float, timeout: float,
                       shots: str | None = None, mode: str = "classic", lead: int = 0) -> dict:
    from playwright.async_api import async_playwright

    results: dict[int, tuple[list, list]] = {}
    async with async_playwright() as p:
        browser = await p.chromium.launch(
            executable_path=CHROMIUM,
            args=["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"])
        try:
            if mode == "lesson" and lead > 0:  # session 0 is the teacher, `lead` Steps ahead of the class
                ahead = asyncio.Event()
                tasks = [asyncio.create_task(session(browser, url, 0, steps, step_timeout, results, shots, mode,
                                                     ready=ahead, lead=lead))]
                tasks += [asyncio.create_task(session(browser, url, k, steps, step_timeout, results, shots, mode,
                                                      start_after=ahead)) for k in range(1, sessions)]
            else:
                tasks = [asyncio.create_task(session(browser, url, k, steps, step_timeout, results, shots, mode))
                         for k in range(sessions)]
            done, pending = await asyncio.wait(tasks, timeout=timeout)
            for t in pending:
                t.cancel()
            await asyncio.gather(*pending, return_exceptions=True)
        finally:
            await browser.close()
    for k in range(sessions):
        results.setdefault(k, ([], [f"session {k}: did not finish within --timeout {timeout:.0f} s"]))
    return results


@contextmanager
def ray_head(cpus: int = 1):
    """A Ray head on this machine for the duration (`ray start --head`), stopped afterwards."""
    ray = str(Path(sys.executable).with_name("ray"))
    subprocess.run([ray, "start", "--head", f"--num-cpus={cpus}", "--include-dashboard=false",
                    "--disable-usage-stats"], check=True, capture_output=True, timeout=120)
    try:
        yield
    finally:
        subprocess.run([ray, "stop", "--force"], capture_output=True, timeout=120)


def server_proc(url: str) -> Path | None:
    """The app server's /proc folder, found by its port (Linux)."""
    port = urllib.parse.urlparse(url).port
    for proc in Path("/proc").glob("[0-9]*"):
        try:
            cmd = (proc / "cmdline").read_bytes().split(b"\0")
            if b"streamlit" in b" ".join(cmd) and str(port).encode() in cmd:
                return proc
        except OSError:
            continue
    return None


def server_peak_mib(url: str) -> float | None:
    """The app server's peak resident memory (VmHWM)."""
    try:
        for line in (server_proc(url) / "status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    except (OSError, TypeError):
        pass
    return None


def server_cpu_seconds(url: str) -> float | None:
    """CPU seconds the app server has used so far (user + system, all its threads)."""
    try:
        fields = (server_proc(url) / "stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, TypeError, IndexError, ValueError):
        return None


def report(results: dict, sessions: int, steps: int, wall: float, mode: str = "classic",
           peak_mib: float | None = None, client: str = "browser") -> str:
    latencies = np.array([x for lat, _ in results.values() for x in lat])
    errors = [e for _, errs in results.values() for e in errs]
    lines = [f"### Load test ({mode}, {client} clients): {sessions} sessions × {steps} Steps", "",
             "| steps completed | p50 (s) | p95 (s) | p99 (s) | max (s) | mean (s) | wall clock (s) | server peak RSS (MiB) |",
             "|---|---|---|---|---|---|---|---|"]
    rss = "—" if peak_mib is None else f"{peak_mib:.0f}"
    if len(latencies):
        p50, p95, p99 = np.percentile(latencies, [50, 95, 99])
        lines.append(f"| {len(latencies)} / {sessions * steps} | {p50:.2f} | {p95:.2f} | {p99:.2f} "
                     f"| {latencies.max():.2f} | {latencies.mean():.2f} | {wall:.0f} | {rss} |")
    else:
        lines.append(f"| 0 / {sessions * steps} | — | — | — | — | — | {wall:.0f} | {rss} |")
    if mode == "watch":
        lines += ["", "Latency: from the teacher's click on Step (the iteration's training included) until a student's "
                  "watch page shows the new iteration (the page's fragment asks every FOLLOW_SECONDS of views/watch.py, "
                  "on the browser's timer, and redraws the page when the teacher has stepped)."]
    else:
        lines += ["", "Latency: from the click on Step until the page's counter shows the new iteration"
                  + (" (the protocol client: from sending the click until the counter's delta and the end of the "
                     "script run arrive)." if client == "protocol" else ".")]
    if errors:
        lines += ["", "Errors:"] + [f"- {e}" for e in errors]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", type=int, default=10)
    parser.add_argument("--steps", type=int, default=3)
    parser.add_argument("--url", help="a running app on a loopback address (default: start one)")
    parser.add_argument("--timeout", type=float, default=600, help="bound on the whole test, seconds")
    parser.add_argument("--step-timeout", type=float, default=180, help="bound on one Step, seconds")
    parser.add_argument("--screenshots", help="save a screenshot of each failed session into this folder")
    parser.add_argument("--mode", choices=["classic", "lesson", "free", "watch"], default="classic",
                        help="classic: the default settings from the landing page; lesson: every session the same "
                             "configuration, the teacher --lead Steps ahead; free: every session its own seed; "
                             "watch (protocol clients): the teacher Steps, the others watch the shared run")
    parser.add_argument("--lead", type=int, default=0, help="lesson: the teacher's Steps ahead of the class")
    parser.add_argument("--full", action="store_true", help="real sizes (default: IFO_LAB_FAST's tiny runs)")
    parser.add_argument("--env", choices=ENV_NAMES, default="cartpole",
                        help="the task every session steps IUPE on (default: CartPole)")
    parser.add_argument("--ray", action="store_true",
                        help="the app it serves trains on a Ray started for the test on this machine (`ray start "
                             "--head`, IFO_LAB_RAY=auto): trainings in worker processes, not in the server's own")
    parser.add_argument("--no-ahead", action="store_true",
                        help="the app it serves trains every Step on the click (IFO_LAB_AHEAD=0), not the next "
                             "iteration in the background after each Step (ifo.ahead, the app's default)")
    parser.add_argument("--client", choices=["browser", "protocol"], default="browser",
                        help="browser: a headless chromium page per session; protocol: Streamlit's websocket "
                             "messages only (the server's share; the students' browsers are elsewhere)")
    parser.add_argument("--think", type=float, default=0.0,
                        help="protocol: each session reads the page for a random 0..2×THINK seconds before every "
                             "Step, as a class does (default 0: every session presses at once, the worst case)")
    args = parser.parse_args(argv)
    if args.env != "cartpole":
        LESSON["step.env"] = args.env  # the page takes the configuration's names in its URL
    if args.think and args.client != "protocol" or not 0 <= args.think <= 600:
        parser.error("--think is 0..600 seconds, with --client protocol")
    if args.mode == "watch" and (args.client != "protocol" or args.url or args.sessions < 2):
        parser.error("--mode watch needs --client protocol, at least 2 sessions, and no --url (it shares the "
                     "teacher's run in the runs folder of the app it serves)")
    if not 1 <= args.sessions <= 100 or not 1 <= args.steps <= 50:
        parser.error("--sessions must be 1..100 and --steps 1..50")
    if args.client == "browser" and not Path(CHROMIUM).exists():
        parser.error(f"{CHROMIUM} is missing: install Debian's chromium package")
    with tempfile.TemporaryDirectory(prefix="ifo-load-") as tmp:
        if args.url:
            host = urllib.parse.urlparse(args.url).hostname
            if host not in LOOPBACK:
                parser.error(f"--url must be a loopback address ({', '.join(sorted(LOOPBACK))}), got {host!r}")
            if not healthy(args.url.rstrip("/")):
                parser.error(f"no healthy Streamlit app at {args.url}")
            server = nullcontext(args.url.rstrip("/"))
        else:
            server = serve_app(Path(tmp) / "server.log", {"IFO_LAB_FAST": "" if args.full else "1",
                                                           "IFO_LAB_RUNS": str(Path(tmp) / "runs"),
                                                           "IFO_LAB_RAY": "auto" if args.ray else "",
                                                           "IFO_LAB_AHEAD": "0" if args.no_ahead else "1"})
        with ray_head() if args.ray and not args.url else nullcontext(), server as url:  # RuntimeError: the log
            start = time.perf_counter()
            if args.screenshots:
                Path(args.screenshots).mkdir(parents=True, exist_ok=True)
            note = ""
            if args.mode == "watch":
                results, note = asyncio.run(run_watch_sessions(url, Path(tmp) / "runs", args.sessions, args.steps,
                                                               args.step_timeout, args.timeout, args.think))
            elif args.client == "protocol":
                results = asyncio.run(run_protocol_sessions(url, args.sessions, args.steps, args.step_timeout,
                                                            args.timeout, args.mode, args.lead, args.think))
            else:
                results = asyncio.run(run_sessions(url, args.sessions, args.steps, args.step_timeout, args.timeout,
                                                   args.screenshots, args.mode, args.lead))
            peak = None if args.url else server_peak_mib(url)
            print(report(results, len(results), args.steps, time.perf_counter() - start, args.mode, peak,
                         args.client) + (f"\n\n{note}" if note else ""))
            print(f"\nSettings: {'real sizes' if args.full else 'IFO_LAB_FAST tiny runs'}; "
                  f"{'trainings on a local Ray; ' if args.ray else ''}"
                  f"{'every Step trained on the click (IFO_LAB_AHEAD=0); ' if args.no_ahead and not args.url else ''}"
                  f"{'lesson ' + str(LESSON) + f', teacher {args.lead} Steps ahead' if args.mode == 'lesson' else ''}"
                  f"{'each session its own seed' if args.mode == 'free' else ''}"
                  f"{f'the teacher (session 0) Steps, {args.sessions - 1} sessions watch its shared run' if args.mode == 'watch' else ''}"
                  f"{f'; the teacher waits {args.think:g} s between Steps' if args.think and args.mode == 'watch' else ''}"
                  f"{f'; each session reads for 0..{2 * args.think:g} s (mean {args.think:g} s) before a Step' if args.think and args.mode != 'watch' else ''}.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
