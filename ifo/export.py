"""Export: every figure of a run as SVG, PNG and PDF, and a "slide pack" ZIP.

Figures are rendered server-side by plotly's kaleido (v1), which drives a headless
Chromium. We never download a browser: `find_chromium` looks for one that is installed
(`BROWSER_PATH`, Debian's /usr/bin/chromium, then chromium or Chrome on PATH) and, when
there is none, `ExportUnavailable` says so; in the app the chart's own camera button
still downloads PNG/SVG from the viewer's browser.

One Chromium is started on first use and kept for the life of the process (starting it
takes a few seconds, each figure after that about a quarter of a second). It lives in its
own thread with its own event loop, so `figure_bytes` may be called from any thread
(Streamlit runs deferred downloads on worker threads) and never blocks forever: a browser
that does not start within `START_TIMEOUT` seconds gives `ExportUnavailable`.

    run_figures(records, config)                one list of figures, the app's and the CLI's
    figure_bytes(fig, "svg" | "png" | "pdf")    bytes of one figure
    metrics_csv(records)                        one row per iteration
    slide_pack(records, config)                 ZIP: figures/, metrics.csv, config.json, README.txt
    export_run(run_dir, out_dir)                the same files written to a folder

No streamlit here (see ifo/ui/export.py).
"""
from __future__ import annotations

import asyncio
import atexit
import csv
import io
import json
import logging
import math
import os
import shutil
import signal
import threading
import time
import zipfile
from pathlib import Path
from typing import Sequence

import plotly.graph_objects as go

FORMATS = ("svg", "png", "pdf")
MIME = {"svg": "image/svg+xml", "png": "image/png", "pdf": "application/pdf"}
PNG_SCALE = 2  # a 1600x900 slide figure becomes a 3200x1800 PNG
SLIDE_WIDTH, SLIDE_HEIGHT = 1600, 900
START_TIMEOUT = 60.0  # seconds for Chromium to start
RENDER_TIMEOUT = 60.0  # seconds for one figure

_log = logging.getLogger(__name__)
NO_CHROMIUM = ("No Chromium found: install Debian's chromium package (apt-get install chromium) or set "
               "BROWSER_PATH; the chart's camera button still downloads PNG/SVG from your browser")

# Names tried on PATH, then usual install locations (Linux, macOS, Windows), after BROWSER_PATH.
_PATH_NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable", "chrome",
               "microsoft-edge", "msedge", "brave-browser")
_TYPICAL_PATHS = (
    "/usr/bin/chromium", "/usr/bin/chromium-browser", "/usr/bin/google-chrome", "/usr/bin/google-chrome-stable",
    "/snap/bin/chromium",
    "/Applications/Google Chrome.app/Contents/MacOS/Google Chrome",
    "/Applications/Chromium.app/Contents/MacOS/Chromium",
    r"C:\Program Files\Google\Chrome\Application\chrome.exe",
    r"C:\Program Files (x86)\Google\Chrome\Application\chrome.exe",
    r"C:\Program Files (x86)\Microsoft\Edge\Application\msedge.exe",
)

class ExportError(RuntimeError):
    """A figure could not be rendered."""


class ExportUnavailable(ExportError):
    """No browser to render with (none installed, or it would not start)."""

    def __init__(self, message: str = NO_CHROMIUM):
        super().__init__(message)


# ----------------------------------------------------------------------------- the browser
def _is_exe(path: str | os.PathLike) -> bool:
    return os.path.isfile(path) and os.access(path, os.X_OK)


def find_chromium() -> str | None:
    """The browser kaleido will drive: `BROWSER_PATH` (if it names an executable file), then
    /usr/bin/chromium, chromium / Chrome / Edge on PATH, then usual install locations.
    None when there is none. Never downloads anything."""
    env = os.environ.get("BROWSER_PATH", "").strip()
    if env and _is_exe(env):
        return env
    if _is_exe("/usr/bin/chromium"):
        return "/usr/bin/chromium"
    for name in _PATH_NAMES:
        found = shutil.which(name)
        if found and _is_exe(found):
            return found
    for path in _TYPICAL_PATHS:
        if _is_exe(path):
            return path
    return None


def unavailable_message() -> str:
    """The message of `ExportUnavailable` for this machine (mentions a BROWSER_PATH that is wrong)."""
    env = os.environ.get("BROWSER_PATH", "").strip()
    if env and not _is_exe(env):
        return f"{NO_CHROMIUM} (BROWSER_PATH={env!r} is not an executable file)"
    return NO_CHROMIUM


class _Renderer:
    """One kaleido (one Chromium) on a private event loop in a daemon thread."""

    def __init__(self, browser: str):
        import kaleido

        quiet = logging.getLogger("choreographer.browser_async")  # "Wait expired..." after a failed start
        if quiet.level == logging.NOTSET:
            quiet.setLevel(logging.ERROR)
        self.browser = browser
        self.loop = asyncio.new_event_loop()
        # a start that timed out leaves a task whose error nobody reads: log it, don't print it
        self.loop.set_exception_handler(lambda loop, context: _log.debug("kaleido: %s", context.get("message")))
        self.thread = threading.Thread(target=self.loop.run_forever, name="ifo-export-kaleido", daemon=True)
        self.thread.start()
        try:
            # path= goes through kaleido.Kaleido -> choreographer.Browser -> Chromium(path=...): exactly this
            # binary, whatever BROWSER_PATH says. mathjax=False: no CDN fetch, fully offline.
            self._call(self._start(kaleido), START_TIMEOUT)
        except BaseException:
            self._kill_process()  # a half-started browser: no waiting for it to close politely
            if hasattr(self, "kaleido"):
                self.close(timeout=5)
            else:
                self._stop_loop()
            raise

    def _kill_process(self) -> None:
        proc = getattr(getattr(self, "kaleido", None), "subprocess", None)
        if proc is None or proc.poll() is not None:
            return
        try:
            if hasattr(os, "killpg"):
                os.killpg(proc.pid, signal.SIGKILL)  # choreographer starts it in its own process group
            else:
                proc.kill()
        except (ProcessLookupError, PermissionError):
            proc.kill()
        try:
            proc.wait(5)
        except Exception:  # noqa: BLE001
            pass

    async def _start(self, kaleido) -> None:  # built on the loop that will use it
        self.kaleido = kaleido.Kaleido(path=self.browser, mathjax=False, n=1)
        await self.kaleido.open()

    def _call(self, coroutine, timeout: float):
        future = asyncio.run_coroutine_threadsafe(coroutine, self.loop)
        try:
            return future.result(timeout)
        except TimeoutError:
            future.cancel()
            raise

    def alive(self) -> bool:
        proc = getattr(self.kaleido, "subprocess", None)
        return self.thread.is_alive() and proc is not None and proc.poll() is None

    def render(self, fig: go.Figure, opts: dict) -> bytes:
        return self._call(self.kaleido.calc_fig(fig, opts), RENDER_TIMEOUT)

    def _stop_loop(self) -> None:
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)

    def close(self, timeout: float = 10) -> None:
        try:
            self._call(self.kaleido.close(), timeout)
        except BaseException:  # noqa: BLE001 - best effort: the browser may be gone already
            self._kill_process()
        self._stop_loop()


_lock = threading.Lock()
_renderer: _Renderer | None = None
_start_error: str | None = None  # why the last start failed (shown by the app instead of crashing)
_start_failed_browser: str | None = None


def _get_renderer() -> _Renderer:
    global _renderer, _start_error, _start_failed_browser
    with _lock:
        browser = find_chromium()
        if browser is None:
            raise ExportUnavailable(unavailable_message())
        if _renderer is not None and _renderer.browser == browser and _renderer.alive():
            return _renderer
        if _start_error is not None and _start_failed_browser == browser:
            raise ExportUnavailable(_start_error)  # no second wait on a browser that would not start
        if _renderer is not None:  # another browser asked for, or this one died: start afresh
            _renderer.close()
            _renderer = None
        try:
            _renderer = _Renderer(browser)
        except Exception as exc:  # a browser that will not start
            if isinstance(exc, TimeoutError):
                reason = f"no answer within {START_TIMEOUT:.0f} s"
            else:  # choreographer's first line says what happened; the rest suggests downloading a browser
                reason = str(exc.args[0] if exc.args else type(exc).__name__).strip()
            _start_error = (f"Chromium at {browser} would not start ({reason}); static exports are off. "
                            "The chart's camera button still downloads PNG/SVG from your browser")
            _start_failed_browser = browser
            raise ExportUnavailable(_start_error) from exc
        _start_error = _start_failed_browser = None
        return _renderer


def export_problem() -> str | None:
    """Why exports cannot work here, or None when they should: cheap (no browser started),
    for the app to decide between download buttons and a note."""
    browser = find_chromium()
    if browser is None:
        return unavailable_message()
    if _start_error is not None and _start_failed_browser == browser:
        return _start_error
    return None


def shutdown() -> None:
    """Close the browser and forget a failed start (the next export starts one again)."""
    global _renderer, _start_error, _start_failed_browser
    with _lock:
        _start_error = _start_failed_browser = None
        if _renderer is not None:
            _renderer.close()
            _renderer = None


atexit.register(shutdown)


def figure_bytes(fig: go.Figure, fmt: str, scale: float | None = None) -> bytes:
    """The figure as SVG, PNG or PDF bytes, at the figure's own width and height (the slide
    theme sets 1600x900). PNG is drawn at `PNG_SCALE` (2) times that unless `scale` says
    otherwise. Raises ExportUnavailable without a usable Chromium."""
    fmt = fmt.lower().lstrip(".")
    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {', '.join(FORMATS)}, got {fmt!r}")
    opts = {"format": fmt, "scale": scale if scale is not None else (PNG_SCALE if fmt == "png" else 1)}
    renderer = _get_renderer()
    try:
        return renderer.render(fig, opts)
    except TimeoutError as exc:
        shutdown()  # a hung browser: start a fresh one next time
        raise ExportError(f"rendering the figure as {fmt} took over {RENDER_TIMEOUT:.0f} s") from exc
    except Exception as exc:
        if not renderer.alive():
            shutdown()  # the browser died: the next export starts a new one
        raise ExportError(f"rendering the figure as {fmt} failed: {exc}") from exc


# ----------------------------------------------------------------------------- figures of a run
def slide_theme(fig: go.Figure) -> go.Figure:
    """A copy of a screen-themed figure with the slide theme of `ifo.figures` (16:9 1600x900,
    large fonts). Redrawing with `theme="slide"` is better when you can; this is for figures
    you only have drawn."""
    out = go.Figure(fig)
    out.update_layout(width=SLIDE_WIDTH, height=SLIDE_HEIGHT, font=dict(size=22), title_font_size=30, template="plotly_white",
                      legend=dict(orientation="h", y=-0.2), margin=dict(t=60))
    return out


def run_figures(records: Sequence[dict], config: dict, theme: str = "slide") -> dict[str, go.Figure]:
    """Every figure these records can show, by name, in slide order: the figure registry's choice
    (`ifo.figure_registry`), the one the app's panels make too. `config` is the run's configuration
    (names of actions and state variables, maze sizes). Empty records give no figures."""
    from ifo.figure_registry import EnvView, views_for

    env = EnvView.of(config)
    return {view.key: view.draw(records, env, None, theme) for view in views_for(records)}


# ----------------------------------------------------------------------------- metrics and the pack
def _scalars(section: dict, prefix: str) -> dict:
    return {f"{prefix}.{k}": v for k, v in section.items() if isinstance(v, (int, float, bool)) or v is None}


def metric_columns(records: Sequence[dict]) -> list[str]:
    """iteration, then every scalar of every section these records have (section.field), in the
    sections' order: the columns follow the method, whichever it is."""
    from ifo.records import SECTIONS

    columns: dict[str, None] = {"iteration": None}
    for section in SECTIONS:
        for r in records:
            if isinstance(r.get(section), dict):
                columns.update(dict.fromkeys(_scalars(r[section], section)))
    return list(columns)


def _cell(v) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return ""
    if isinstance(v, float):
        return format(v, ".6g")
    return str(v)


def metrics_csv(records: Sequence[dict]) -> str:
    """One row per iteration, one column per scalar of the records' sections (`metric_columns`);
    empty cells where an iteration has no such number."""
    columns = metric_columns(records)
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(columns)
    for r in records:
        row = {"iteration": r["iteration"]}
        for section, value in r.items():
            if isinstance(value, dict):
                row.update(_scalars(value, section))
        w.writerow([_cell(row.get(c)) for c in columns])
    return buf.getvalue()


def _readme(records: Sequence[dict], config: dict, names: Sequence[str], formats: Sequence[str],
            run_dir: str | None) -> str:
    columns = metric_columns(records)
    ev = records[-1]["evaluation"] if records else {}
    perf = ev.get("performance")
    summary = (f"after {len(records)} iteration(s): AER {ev['aer']:.2f} ± {ev['aer_std']:.2f}, "
               f"Performance {'n/a' if perf is None else format(perf, '.3f')}, goal rate {ev['goal_rate']:.2f}"
               if records else "no iterations yet")
    fig_lines = "\n".join(f"  figures/{n}.{{{','.join(formats)}}}" for n in names) or "                (none in this pack)"
    where = run_dir or "RUN_FOLDER"
    return f"""IfO Lab slide pack
==================

Run: {config.get('method', '?')} on {config.get('env', '?')}, seed {config.get('seed', '?')}; {summary}.
Made {time.strftime('%Y-%m-%d %H:%M:%S')}.

Inside
  figures/      every chart of the run, 16:9 (1600x900) with large fonts:
                SVG (vector, for slides), PNG ({PNG_SCALE}x: {PNG_SCALE * SLIDE_WIDTH}x{PNG_SCALE * SLIDE_HEIGHT} px), PDF
{fig_lines}
  metrics.csv   one row per iteration, {len(columns)} columns (section.field: {', '.join(columns[:6])}, ...)
                (empty cell: the method has no such number, e.g. no IDM in BC)
  config.json   the run's full configuration (RunConfig.to_dict())

Redo these files from a saved run
  python -m ifo export {where} --out slides --formats {','.join(formats or FORMATS)} --zip

Redo the run itself (same settings, same seed)
  python -c "import json; from ifo.config import RunConfig; from ifo.run import Run; \\
run = Run(RunConfig.from_dict(json.load(open('config.json')))); run.run(); run.save('rerun')"
"""


def render_all(figs: dict[str, go.Figure], formats: Sequence[str] = FORMATS) -> dict[str, bytes]:
    """{"<name>.<fmt>": bytes} for every figure and format."""
    formats = _check_formats(formats)
    return {f"{name}.{fmt}": figure_bytes(fig, fmt) for name, fig in figs.items() for fmt in formats}


def _check_formats(formats: Sequence[str] | str) -> tuple[str, ...]:
    if isinstance(formats, str):
        formats = formats.split(",")
    out = tuple(dict.fromkeys(f.strip().lower().lstrip(".") for f in formats if f.strip()))
    bad = [f for f in out if f not in FORMATS]
    if bad or not out:
        raise ValueError(f"formats must be some of {', '.join(FORMATS)}, got {','.join(formats) or 'none'}")
    return out


def pack_files(records: Sequence[dict], config: dict, formats: Sequence[str] = FORMATS, *,
               run_dir: str | None = None) -> dict[str, bytes]:
    """The slide pack's files by relative path (figures/<name>.<fmt>, metrics.csv, config.json, README.txt).
    Empty `formats`: no figures (and no browser needed)."""
    formats = _check_formats(formats) if formats else ()
    figs = run_figures(records, config, "slide") if formats else {}
    files = {f"figures/{k}": v for k, v in render_all(figs, formats).items()} if formats else {}
    files["metrics.csv"] = metrics_csv(records).encode("utf-8")
    files["config.json"] = json.dumps(config, indent=1, sort_keys=True).encode("utf-8")
    files["README.txt"] = _readme(records, config, list(figs), formats, run_dir).encode("utf-8")
    return files


def slide_pack(records: Sequence[dict], config: dict,
               formats: Sequence[str] = FORMATS, *, run_dir: str | None = None) -> bytes:
    """One ZIP: figures/<name>.<fmt> for every figure of `run_figures`, metrics.csv, config.json, README.txt."""
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        for path, data in pack_files(records, config, formats, run_dir=run_dir).items():
            z.writestr(path, data)
    return buf.getvalue()


# What the figures, metrics.csv and README read without a default: a record without one is refused
# with a clear message rather than a KeyError deep inside plotting.
RECORD_FIELDS = ("iteration", "evaluation", "seconds")
EVALUATION_FIELDS = ("aer", "aer_std", "goal_rate")


def check_records(records, where: str = "the run") -> None:
    """ValueError naming the first record that lacks a field the export needs."""
    if not isinstance(records, list):
        raise ValueError(f"{where}: the records are not a list")
    for k, r in enumerate(records, 1):
        missing = [f for f in RECORD_FIELDS if not isinstance(r, dict) or f not in r]
        if not missing and isinstance(r["evaluation"], dict):
            missing = [f"evaluation.{f}" for f in EVALUATION_FIELDS if f not in r["evaluation"]]
        elif not missing:
            missing = ["evaluation (not a mapping)"]
        if missing:
            raise ValueError(f"{where}: record {k} of {len(records)} lacks {', '.join(missing)}; "
                             "it was not saved by this version of IfO Lab, or it is damaged")


def load_run_files(run_dir: str | os.PathLike) -> tuple[list[dict], dict, tuple[str, ...]]:
    """(records, config dict, action names) of a saved run, read from its files (`ifo.checkpoint`):
    no environment is built and no data collected, so it is instant even for a big maze run.
    FileNotFoundError without a run there; ValueError (CheckpointError) saying what is wrong otherwise."""
    from ifo import checkpoint
    from ifo.config import RunConfig
    from ifo.envs import get_env

    d = Path(run_dir)
    if not d.is_dir():
        raise FileNotFoundError(f"{d} is not a folder")
    ckpt = checkpoint.load(d, with_arrays=False)  # NoRun is a FileNotFoundError, DamagedRun a ValueError
    config = ckpt.config
    if not isinstance(config.get("env"), str):
        raise ValueError(f"{d}: the saved configuration names no environment ('env')")
    RunConfig.from_dict(config)  # unknown fields -> ValueError
    check_records(ckpt.records, str(d))
    return ckpt.records, config, tuple(get_env(config["env"]).action_names)


def export_run(run_dir: str | os.PathLike, out_dir: str | os.PathLike, formats: Sequence[str] = FORMATS,
               *, as_zip: bool = False) -> list[Path]:
    """Write a saved run's slide pack to `out_dir` (figures/, metrics.csv, config.json, README.txt;
    each file atomically) or, with `as_zip`, one `<run name>-slides.zip` there. Returns the paths.
    ValueError (no traceback in the CLI) for a run without iterations, records that lack a field,
    or an `out_dir` that is or lies under a file."""
    from ifo.checkpoint import blocking_file
    from ifo.io import atomic_write_bytes

    records, config, names = load_run_files(run_dir)
    if not records:
        raise ValueError(f"{run_dir} has no iterations yet: nothing to draw")
    out = Path(out_dir)
    blocker = blocking_file(out)
    if blocker is not None:
        where = "is a file" if blocker == out.absolute() else f"lies under {blocker}, which is a file"
        raise ValueError(f"--out {out} {where}, not a folder")
    try:
        if as_zip:
            path = out / f"{Path(run_dir).resolve().name}-slides.zip"
            atomic_write_bytes(path, slide_pack(records, config, formats, run_dir=str(run_dir)))
            return [path]
        files = pack_files(records, config, formats, run_dir=str(run_dir))
    except KeyError as exc:  # a field check_records does not know the figures need
        raise ValueError(f"{run_dir}: the saved records lack {exc} (needed for the figures)") from exc
    written = []
    for rel, data in files.items():
        atomic_write_bytes(out / rel, data)
        written.append(out / rel)
    return written


__all__ = ["FORMATS", "MIME", "NO_CHROMIUM", "ExportError", "ExportUnavailable", "find_chromium", "export_problem",
           "figure_bytes", "slide_theme", "run_figures", "metrics_csv", "pack_files", "slide_pack", "load_run_files",
           "check_records", "export_run", "render_all", "shutdown"]
