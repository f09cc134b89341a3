"""Many students at once: N browser sessions press Step K times on the same server.

    PYTHONPATH=. .venv/bin/python scripts/load_test.py --sessions 10 --steps 3 [--url http://127.0.0.1:8501]

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
import re
import sys
import tempfile
import time
import urllib.parse
from contextlib import nullcontext
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from scripts.app_server import healthy, serve_app  # noqa: E402
CHROMIUM = "/usr/bin/chromium"
IDLE = "[data-testid='stApp'][data-test-script-state='notRunning']"
LOOPBACK = {"127.0.0.1", "localhost", "::1"}


async def session(browser, url: str, k: int, steps: int, step_timeout: float, results: dict,
                  shots: str | None = None) -> None:
    context = await browser.new_context(viewport={"width": 1280, "height": 900})
    page = await context.new_page()
    page.set_default_timeout(step_timeout * 1000)
    latencies, errors = [], []
    where = "opening the step page"
    try:
        await page.goto(url)
        await page.wait_for_selector(IDLE)
        await page.get_by_role("button", name="Step through a run").click()
        counter = page.locator("[data-testid='stMain'] h4").filter(has_text=re.compile(r"^Iteration \d+ of \d+$"))
        await counter.filter(has_text=re.compile(r"^Iteration 0 of")).wait_for()
        await page.wait_for_selector(IDLE)
        step = page.get_by_role("button", name="Step", exact=True)
        for i in range(1, steps + 1):
            where = f"step {i}"
            await step.wait_for()
            start = time.perf_counter()
            await step.click()
            await counter.filter(has_text=re.compile(rf"^Iteration {i} of")).wait_for(timeout=step_timeout * 1000)
            latencies.append(time.perf_counter() - start)
            await page.wait_for_selector(IDLE)
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


async def run_sessions(url: str, sessions: int, steps: int, step_timeout: float, timeout: float,
                       shots: str | None = None) -> dict:
    from playwright.async_api import async_playwright

    results: dict[int, tuple[list, list]] = {}
    async with async_playwright() as p:
        browser = await p.chromium.launch(
            executable_path=CHROMIUM,
            args=["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"])
        try:
            tasks = [asyncio.create_task(session(browser, url, k, steps, step_timeout, results, shots))
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


def report(results: dict, sessions: int, steps: int, wall: float) -> str:
    latencies = np.array([x for lat, _ in results.values() for x in lat])
    errors = [e for _, errs in results.values() for e in errs]
    lines = [f"### Load test: {sessions} sessions × {steps} Steps", "",
             "| steps completed | p50 (s) | p90 (s) | p99 (s) | max (s) | mean (s) | wall clock (s) |",
             "|---|---|---|---|---|---|---|"]
    if len(latencies):
        p50, p90, p99 = np.percentile(latencies, [50, 90, 99])
        lines.append(f"| {len(latencies)} / {sessions * steps} | {p50:.2f} | {p90:.2f} | {p99:.2f} "
                     f"| {latencies.max():.2f} | {latencies.mean():.2f} | {wall:.0f} |")
    else:
        lines.append(f"| 0 / {sessions * steps} | — | — | — | — | — | {wall:.0f} |")
    lines += ["", "Latency: from the click on Step until the page's counter shows the new iteration."]
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
    args = parser.parse_args(argv)
    if not 1 <= args.sessions <= 100 or not 1 <= args.steps <= 50:
        parser.error("--sessions must be 1..100 and --steps 1..50")
    if not Path(CHROMIUM).exists():
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
            server = serve_app(Path(tmp) / "server.log", {"IFO_LAB_FAST": "1", "IFO_LAB_RUNS": str(Path(tmp) / "runs")})
        with server as url:  # RuntimeError with the server's log if it does not start
            start = time.perf_counter()
            if args.screenshots:
                Path(args.screenshots).mkdir(parents=True, exist_ok=True)
            results = asyncio.run(run_sessions(url, args.sessions, args.steps, args.step_timeout, args.timeout,
                                               args.screenshots))
            print(report(results, args.sessions, args.steps, time.perf_counter() - start))
    return 0


if __name__ == "__main__":
    sys.exit(main())
