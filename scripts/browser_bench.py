"""How responsive the app feels in a real browser: Debian's chromium driven by Playwright.

    python scripts/browser_bench.py [--repeats N] [--fast | --both]

Serves the app (scripts/app_server.py; runs in a temporary folder; IFO_LAB_FAST=1 with --fast,
unset by default, both one after the other with --both), opens the step page and measures, each
`--repeats` times:

- Step: from the click on Step until the page is idle again, minus the training time of that
  iteration. The training time is the iteration's own `seconds.total` (every phase of the
  iteration: IDM, labels, policy, rollouts, evaluation), read from the run the app autosaved
  (ifo.checkpoint.read_records on the run folder named by the page's ?user= and ?run=): the same
  number the page shows as "Seconds per iteration", without its rounding to 0.1 s.
- scrub: the "Show iteration" slider moved by one (an arrow key on the focused slider) until idle.
- page change: a click on a sidebar link until the new page is idle: to "Your runs", and back to
  "Step through a run" (with its charts).

Wall times are taken in the page (performance.now()): from the input event (pointerdown/keydown,
caught before the app sees it) to the last change of the app's `data-test-script-state` to
"notRunning" (the page is idle). The server's own time is read from the websocket frames as the
browser's network stack timestamps them (DevTools protocol, so a page busy drawing charts does not
delay them): a script run starts at a ForwardMsg.new_session and ends at a
ForwardMsg.script_finished; their differences, summed, are the server's time, and the wall time
minus that is the network and the browser drawing the page.
It also reports the CPU seconds the server and the browser spent on each action (from /proc):
on a busy machine wall times stretch, CPU seconds much less.

Targets (issue "A teacher's journey that never breaks", on an idle machine): overhead per Step
<= 0.5 s beyond training, scrubbing <= 0.3 s, page change <= 1 s. Nothing here asserts them: the
machine this runs on may be busy, and the browser shares its cores with the server (in a class
the browsers run on the students' laptops), so read the numbers with `uptime` beside them.
"""
from __future__ import annotations

import argparse
import base64
import os
import statistics
import sys
import tempfile
import time
import urllib.parse
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from scripts.app_server import serve_app  # noqa: E402

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]
IDLE = "[data-testid='stApp'][data-test-script-state='notRunning']"
TIMEOUT_MS = 300_000
SETTLE_S = 0.6  # idle this long with no new script run: the action is over

# Installed in every page before the app's own scripts: records input events and the app's script
# state on performance.now().
RECORDER = """
(() => {
  const log = window.__bench = {inputs: [], states: []};
  for (const type of ['pointerdown', 'keydown'])
    window.addEventListener(type, () => log.inputs.push(performance.now()), true);
  new MutationObserver(records => {
    for (const r of records) {
      const state = r.target.getAttribute('data-test-script-state');
      const last = log.states[log.states.length - 1];
      if (state && (!last || last[1] !== state)) log.states.push([performance.now(), state]);
    }
  }).observe(document, {attributes: true, subtree: true, attributeFilter: ['data-test-script-state']});
})();
"""
NEW_SESSION, SCRIPT_FINISHED = 4, 6  # ForwardMsg's fields: a script run starts / ends


def top_fields(data: bytes) -> list[int]:
    """The field numbers at the top level of a protobuf message (enough to tell ForwardMsg kinds apart)."""
    out, i = [], 0

    def varint() -> int:
        nonlocal i
        value = shift = 0
        while True:
            byte = data[i]
            i += 1
            value |= (byte & 0x7F) << shift
            shift += 7
            if not byte & 0x80:
                return value

    try:
        while i < len(data):
            key = varint()
            field, wire = key >> 3, key & 7
            out.append(field)
            if wire == 0:
                varint()
            elif wire == 2:
                length = varint()  # (not `i += varint()`: that would add to the old i)
                i += length
            elif wire in (1, 5):
                i += 8 if wire == 1 else 4
            else:
                break
    except IndexError:  # DevTools cut a large frame short: its first fields are enough
        pass
    return out


class ServerMessages:
    """When script runs start and end, from the websocket frames as the browser's network stack
    timestamps them (Chrome DevTools Protocol), not when the page's busy main thread gets to them."""

    def __init__(self, page):
        self.frames: list[tuple[float, int]] = []  # (seconds, NEW_SESSION or SCRIPT_FINISHED)
        cdp = page.context.new_cdp_session(page)
        cdp.on("Network.webSocketFrameReceived", self._frame)
        cdp.send("Network.enable")

    def _frame(self, event: dict) -> None:
        response = event["response"]
        if response.get("opcode") != 2:  # binary frames only: ForwardMsg protobufs
            return
        for field in top_fields(base64.b64decode(response["payloadData"])):
            if field in (NEW_SESSION, SCRIPT_FINISHED):
                self.frames.append((event["timestamp"], field))

    def script_seconds(self, since: int) -> tuple[float, int]:
        """Seconds spent in script runs (start to end, summed) and their number, in frames[since:]."""
        total, opened, runs = 0.0, None, 0
        for t, field in self.frames[since:]:
            if field == NEW_SESSION:
                opened, runs = t, runs + 1
            elif opened is not None:
                total, opened = total + t - opened, None
        return total, runs


def cpu_seconds() -> tuple[float, float]:
    """CPU seconds (user + system, all threads) used so far by the app server and by chromium (every
    chromium process; not Playwright's driver): descendants of this process, from /proc. Unlike wall
    times, these hardly depend on how busy the machine is."""
    tick = os.sysconf("SC_CLK_TCK")
    procs = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
            cmdline = (stat.parent / "cmdline").read_bytes().split(b"\0")[0]
        except OSError:  # gone meanwhile
            continue
        fields = text[text.rindex(")") + 2:].split()  # after "pid (name) "
        kind = "server" if b"python" in cmdline else "browser" if b"chromium" in cmdline else None
        procs[int(stat.parent.name)] = (int(fields[1]), (int(fields[11]) + int(fields[12])) / tick, kind)
    mine, frontier = set(), {os.getpid()}
    while frontier:
        frontier = {pid for pid, (ppid, _, _) in procs.items() if ppid in frontier} - mine
        mine |= frontier
    server = sum(procs[pid][1] for pid in mine if procs[pid][2] == "server")
    browser = sum(procs[pid][1] for pid in mine if procs[pid][2] == "browser")
    return server, browser


class Probe:
    """Times one action on a page from the browser's own records (and the CPU it cost, from /proc)."""

    def __init__(self, page):
        self.page = page
        self.server = ServerMessages(page)

    def counts(self) -> dict:
        counts = self.page.evaluate("() => ({i: __bench.inputs.length, s: __bench.states.length})")
        return {**counts, "m": len(self.server.frames)}

    def settle(self, since: dict, timeout: float = TIMEOUT_MS / 1000) -> dict:
        """Wait until the page is idle and has had no new script run for SETTLE_S; the records since `since`."""
        deadline = time.monotonic() + timeout
        last = None
        while time.monotonic() < deadline:
            self.page.wait_for_selector(IDLE, timeout=TIMEOUT_MS)
            now = self.counts()
            if now == last:
                break
            last = now
            time.sleep(SETTLE_S)
        return self.page.evaluate("(c) => ({inputs: __bench.inputs.slice(c.i), states: __bench.states.slice(c.s)})",
                                  since)

    def measure(self, act, done) -> dict:
        """Run `act()` (one input), wait for `done()` and for the page to settle; wall and server seconds."""
        since = self.counts()
        cpu_before = cpu_seconds()
        act()
        done()
        rec = self.settle(since)
        cpu_after = cpu_seconds()
        if not rec["inputs"]:
            raise RuntimeError("no input event was seen: the action did not reach the page")
        start = rec["inputs"][0]
        idle = [t for t, s in rec["states"] if s == "notRunning" and t >= start]
        end = idle[-1] if idle else start  # never left idle: nothing ran
        server, runs = self.server.script_seconds(since["m"])
        return {"wall": (end - start) / 1000, "server": server, "runs": runs,
                "server_cpu": cpu_after[0] - cpu_before[0], "browser_cpu": cpu_after[1] - cpu_before[1]}


def query(page) -> dict:
    return {k: v[-1] for k, v in urllib.parse.parse_qs(urllib.parse.urlparse(page.url).query).items()}


def training_seconds(runs: Path, page, iteration: int) -> float:
    """The iteration's own training time, from the run the app autosaved (see the module's docstring)."""
    from ifo import checkpoint

    q = query(page)
    deadline = time.monotonic() + 30
    while True:  # the autosave may land a moment after the page shows the iteration
        try:
            records = checkpoint.read_records(runs / q["user"] / q["run"])
            return next(r for r in records if r["iteration"] == iteration)["seconds"]["total"]
        except (checkpoint.CheckpointError, OSError, StopIteration, KeyError):
            if time.monotonic() > deadline:
                raise
            time.sleep(0.5)


def bench(fast: bool, repeats: int) -> dict[str, list[dict]]:
    """Every measurement, by kind: step, scrub, to_runs, to_step."""
    from playwright.sync_api import expect, sync_playwright

    expect.set_options(timeout=TIMEOUT_MS)
    folder = Path(tempfile.mkdtemp(prefix="ifo-browser-bench-"))
    runs, log = folder / "runs", folder / "server.log"
    env = {"IFO_LAB_RUNS": str(runs), "IFO_LAB_FAST": "1" if fast else ""}
    results: dict[str, list[dict]] = {"step": [], "scrub": [], "to_runs": [], "to_step": []}
    with serve_app(log, env, timeout=180) as url, \
            sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS)
        context = browser.new_context(viewport={"width": 1400, "height": 1000})
        context.set_default_timeout(TIMEOUT_MS)
        context.add_init_script(RECORDER)
        page = context.new_page()
        page.goto(url)  # the server's first session on its main page (no "Page not found" dialog)
        page.wait_for_selector(IDLE)
        probe = Probe(page)
        nav = page.locator("[data-testid='stSidebarNavLink']")
        probe.measure(lambda: nav.filter(has_text="Step through a run").click(),
                      lambda: expect(page.get_by_role("button", name="Step", exact=True)).to_be_visible())
        counter = page.locator("[data-testid='stMain'] h4").filter(has_text="Iteration ")
        total = int(counter.inner_text().split(" of ")[1])
        if total < repeats + 1:  # room for every Step
            box = page.locator("[data-testid='stSidebar']").get_by_role("spinbutton", name="Iterations in the run")
            box.fill(str(repeats + 1))
            box.press("Enter")
            expect(counter).to_have_text(f"Iteration 0 of {repeats + 1}")
            probe.settle(probe.counts())
        step = page.get_by_role("button", name="Step", exact=True)
        slider = page.get_by_role("slider", name="Show iteration")  # an <input type="range">
        for k in range(1, repeats + 2):
            m = probe.measure(step.click, lambda: expect(counter).to_contain_text(f"Iteration {k} of"))
            m["training"] = training_seconds(runs, page, k)
            if k > 1:  # the first Step also loads the models' code and warms the caches: not a fair repeat
                results["step"].append(m)
            print(f"  step {k}: wall {m['wall']:.2f} s, server {m['server']:.2f} s, training {m['training']:.2f} s, "
                  f"CPU server {m['server_cpu']:.2f} s, browser {m['browser_cpu']:.2f} s", file=sys.stderr)
        for k in range(repeats):
            # one to the left, then back to the right: from the latest iteration and back to it
            key = "ArrowLeft" if k % 2 == 0 else "ArrowRight"
            target = str(repeats + (0 if k % 2 == 0 else 1))
            slider.focus()
            m = probe.measure(lambda: slider.press(key), lambda: expect(slider).to_have_value(target))
            results["scrub"].append(m)
            print(f"  scrub {k + 1}: wall {m['wall']:.2f} s, server {m['server']:.2f} s, "
                  f"CPU server {m['server_cpu']:.2f} s, browser {m['browser_cpu']:.2f} s", file=sys.stderr)
        for k in range(repeats):
            for title, kind in (("Your runs", "to_runs"), ("Step through a run", "to_step")):
                m = probe.measure(lambda: nav.filter(has_text=title).click(),
                                  lambda: expect(page.get_by_role("heading", name=title, exact=True)).to_be_visible())
                results[kind].append(m)
                print(f"  page change to {title}: wall {m['wall']:.2f} s, server {m['server']:.2f} s, "
                      f"CPU server {m['server_cpu']:.2f} s, browser {m['browser_cpu']:.2f} s", file=sys.stderr)
        browser.close()
    return results


def row(name: str, values: list[float], target: str, other: list[float] | None = None) -> str:
    """A table row: median and max of `values` (and of `other` after a slash, for two related numbers)."""
    if not values:
        return f"| {name} | n/a | n/a | {target} |"
    med, top = f"{statistics.median(values):.2f}", f"{max(values):.2f}"
    if other:
        med, top = f"{med} / {statistics.median(other):.2f}", f"{top} / {max(other):.2f}"
    return f"| {name} | {med} | {top} | {target} |"


def table(results: dict[str, list[dict]], label: str, repeats: int, load: tuple[float, float]) -> str:
    step, scrub = results["step"], results["scrub"]
    lines = [f"### {label} ({repeats} repeats; 1-minute load average {load[0]:.1f} before, {load[1]:.1f} after, "
             f"on {os.cpu_count()} cores)", "", "| measure (seconds) | median | max | target |", "|---|---|---|---|",
             row("Step: click until idle (wall)", [m["wall"] for m in step], ""),
             row("Step: training (the iteration's seconds.total)", [m["training"] for m in step], ""),
             row("**Step: page overhead = wall - training**", [m["wall"] - m["training"] for m in step], "<= 0.5"),
             row("Step: of which on the server (script runs - training)", [m["server"] - m["training"] for m in step], ""),
             row("Step: of which network and browser (wall - script runs)", [m["wall"] - m["server"] for m in step], ""),
             row("Step: CPU of the server (training included) / of the browser",
                 [m["server_cpu"] for m in step], "", [m["browser_cpu"] for m in step]),
             row("**Scrub one iteration (wall)**", [m["wall"] for m in scrub], "<= 0.3"),
             row("Scrub: on the server (script runs)", [m["server"] for m in scrub], ""),
             row("Scrub: CPU of the server / of the browser",
                 [m["server_cpu"] for m in scrub], "", [m["browser_cpu"] for m in scrub]),
             *(line for page, where in ((results["to_runs"], "to Your runs"), (results["to_step"], "to the step page"))
               for line in (row(f"**Page change by the sidebar {where} (wall)**", [m["wall"] for m in page], "<= 1"),
                            row(f"Page change {where}: on the server (script runs)", [m["server"] for m in page], ""),
                            row(f"Page change {where}: CPU of the server / of the browser",
                                [m["server_cpu"] for m in page], "", [m["browser_cpu"] for m in page])))]
    runs = sorted({m["runs"] for ms in results.values() for m in ms})
    lines += ["", f"Script runs per action: {', '.join(map(str, runs))}."]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=5, help="measurements of each kind (default 5)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--fast", action="store_true", help="tiny runs (IFO_LAB_FAST=1), as the tests use")
    mode.add_argument("--both", action="store_true", help="full-size runs, then tiny runs")
    args = parser.parse_args()
    if not Path(CHROMIUM).exists():
        sys.exit(f"{CHROMIUM} is not installed")
    modes = [False, True] if args.both else [args.fast]
    tables = []
    for fast in modes:
        label = "IFO_LAB_FAST=1 (tiny runs)" if fast else "full-size runs (IFO_LAB_FAST unset)"
        print(f"measuring with {label}...", file=sys.stderr)
        before = os.getloadavg()[0]
        results = bench(fast, args.repeats)
        tables.append(table(results, label, args.repeats, (before, os.getloadavg()[0])))
    print("\n\n".join(tables))


if __name__ == "__main__":
    main()
