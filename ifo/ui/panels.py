"""Drawing helpers: a chart panel with its caption, the iteration counter, the metrics row,
and the drawing of the registry's panels (`ifo.ui.registry`), the rollout video among them."""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from typing import Any, Callable

import plotly.graph_objects as go
import streamlit as st

from ifo.ui.export import chart_downloads, export_note, slide_pack_download
from ifo.figure_registry import EnvView
from ifo.runtime import BoundedCache

# The chart's camera button downloads an SVG drawn by the browser: slides, no server work.
CHART_CONFIG = {"toImageButtonOptions": {"format": "svg"}, "displaylogo": False}


def chart(fig: go.Figure, key: str, caption: str) -> None:
    """One panel: the figure (stable key, so it is redrawn in place) and one plain sentence."""
    st.plotly_chart(fig, key=key, config=CHART_CONFIG)
    st.caption(caption)


def grid(panels: list[tuple[go.Figure, str, str]], columns: int = 2) -> None:
    """Panels (figure, key, caption) laid out `columns` to a row."""
    for start in range(0, len(panels), columns):
        for col, panel in zip(st.columns(columns), panels[start:start + columns]):
            with col:
                chart(*panel)


def counter(iteration: int, total: int) -> None:
    st.markdown(f"#### Iteration {iteration} of {total}")


def _fmt(value, pattern: str) -> str:
    return "n/a" if value is None else pattern.format(value)


def _delta(records: list[dict], get, pattern: str) -> str | None:
    if len(records) < 2 or get(records[-1]) is None or get(records[-2]) is None:
        return None
    text = pattern.format(get(records[-1]) - get(records[-2]))
    return text if any(c in "123456789" for c in text) else None  # no arrow for "no change"


def metrics_row(records: list[dict]) -> None:
    """AER, Performance, goal rate and seconds of the last iteration, with the change since the one before."""
    if not records:
        return
    last = records[-1]
    ev = last["evaluation"]
    aer = lambda r: r["evaluation"]["aer"]  # noqa: E731
    perf = lambda r: r["evaluation"].get("performance")  # noqa: E731
    goal = lambda r: r["evaluation"].get("goal_rate")  # noqa: E731
    cols = st.columns(4)
    cols[0].metric("AER", _fmt(ev["aer"], "{:.1f}"), _delta(records, aer, "{:+.1f}"),
                   help="Average episodic reward of the learner's evaluation episodes (Eq 4.1).")
    cols[1].metric("Performance P", _fmt(ev.get("performance"), "{:.2f}"), _delta(records, perf, "{:+.2f}"),
                   help="0 = a random policy, 1 = the expert (Eq 4.2).")
    cols[2].metric("Goal rate", _fmt(ev.get("goal_rate"), "{:.0%}"), _delta(records, goal, "{:+.0%}"),
                   help="Share of evaluation episodes that reached the goal.")
    cols[3].metric("Seconds per iteration", _fmt(last["seconds"].get("total"), "{:.1f}"), delta_color="off",
                   help="Time the last iteration took to train and evaluate.")


# --------------------------------------------------------------------------- the registry's panels
@dataclass
class PanelContext:
    """What a panel may use: the slot and its run (None when watching a shared run), the records, the
    iteration the slider shows (1-based), and the run's configuration as a dict."""

    slot: Any
    run: Any
    records: list
    iteration: int | None
    config: dict | None = None
    _records_key: str | None = None

    @property
    def config_dict(self) -> dict:
        return self.config if self.config is not None else self.run.config.to_dict()

    @property
    def records_key(self) -> str:
        """A hash of the records' content (what a figure is a function of), computed once per page run."""
        if self._records_key is None:
            self._records_key = content_key(self.records)
        return self._records_key


# Figures are pure functions of (records, environment, iteration shown), and building one in plotly
# costs ~50 ms, ten times what sending it does. A class following one lesson draws the same figures
# (its students take the teacher's iterations from the cache), and every rerun of a page (a scrub back
# and forth, a Play's ticks) draws them again: so each is built once per server process and shared.
# Streamlit and the downloads only read a figure (to_dict, a copy for the slide theme).
_figures = BoundedCache(256)  # figures, by what each is a pure function of


def shared(key: tuple, build: Callable[[], go.Figure | None]) -> go.Figure | None:
    """`build()`, once per `key` (what the figure is a pure function of) across every session of this server."""
    return _figures.get_or_build(key, lambda: for_screen(build()))


def for_screen(fig: go.Figure | None) -> go.Figure | None:
    """The figure without plotly's template: Streamlit's theme replaces it on screen (the page looks the
    same), and Streamlit copies and sends each figure for every session that shows it, the template being
    most of a small figure (scripts/page_bytes.py). Slides get their own (ifo.export.slide_theme)."""
    if fig is not None:
        fig.layout.template = "none"
    return fig


def shared_figure(panel, ctx: PanelContext) -> go.Figure | None:
    """`panel.draw(records, env, iteration)`, built once per content across every session of this server."""
    env = EnvView.of(ctx.config_dict)
    return shared((panel.key, ctx.records_key, env, ctx.iteration), lambda: panel.draw(ctx.records, env, ctx.iteration))


def content_key(data) -> str:
    """A hash of JSON-able data's content (records, a record): the key of the figures drawn from it."""
    return hashlib.blake2b(json.dumps(data, sort_keys=True, default=str).encode(), digest_size=16).hexdigest()


def panel_caption(panel) -> None:
    st.caption(f"{panel.explanation} *{panel.thesis_figure}.*")


def draw_panels(panels, ctx: PanelContext, columns: int = 2) -> None:
    """Lay the registry's panels out `columns` to a row (wide ones take a row), each with its caption."""
    row: list = []
    downloads = False

    def flush():
        if row:
            for col, p in zip(st.columns(columns), row):
                with col:
                    _one(p, ctx, downloads)
            row.clear()

    if ctx.records and export_note():  # once per page: says so when no Chromium can render the downloads
        # Off by default: three buttons under every chart are 27 widgets that each Step of each student
        # in a class would register again; the slide pack below holds every chart either way.
        downloads = st.toggle("Slide downloads under each chart (SVG, PNG, PDF)", key="export.per_chart",
                              help="Slide-ready files of one chart (16:9, large fonts), drawn on the server. "
                                   "The slide pack at the bottom of the page holds every chart.")
    for p in panels:
        if p.wide:
            flush()
            _one(p, ctx, downloads)
        else:
            row.append(p)
            if len(row) == columns:
                flush()
    flush()
    if ctx.records:
        slide_pack_download(ctx.records, ctx.config_dict, key="export.pack")


def _one(panel, ctx: PanelContext, downloads: bool = False) -> None:
    if panel.render is not None:
        st.markdown(f"##### {panel.title}")
        panel.render(ctx)
        panel_caption(panel)
        return
    fig = shared_figure(panel, ctx)
    if fig is None:
        return
    st.plotly_chart(fig, key=f"panel.{panel.key}", config=CHART_CONFIG)
    panel_caption(panel)
    if ctx.records and downloads:  # slide-ready SVG/PNG/PDF, rendered server-side only when clicked
        chart_downloads(fig, panel.key, key=f"export.{panel.key}", note=False)


def show_records(records: list[dict], total: int, hide: set[str], sizes: dict, areas: tuple,
                 context: Callable[[int | None], PanelContext], key: str = "step", layout: str = "bco") -> int | None:
    """The iteration counter, the scrub slider, the loop diagram at the iteration shown, the metrics
    row and the registry's panels: what the step page and a watched (shared) run both draw.
    `areas` are (counter, slider, diagram) placeholders; `context(shown)` makes the panels' context.
    Returns the iteration the slider shows (None: the latest)."""
    from ifo.ui.diagram import loop_diagram
    from ifo.ui.registry import active_panels

    count_area, scrub_area, diagram_area = areas
    with count_area:
        counter(len(records), total)
    shown = None
    if len(records) >= 2:
        shown = scrub_area.slider("Show iteration", 1, len(records), len(records), key=f"{key}.view",
                                  help="Scrub back through past iterations: every chart and the diagram "
                                       "show the iteration you pick. The latest is the default.")
    record = next((r for r in records if r["iteration"] == shown), records[-1] if records else None)
    ctx = context(shown)
    if "diagram" not in hide:  # a pure function of the records and the iteration shown, like the panels
        diagram = shared(("diagram", ctx.records_key, shown, tuple(sorted(sizes.items())), layout),
                         lambda: loop_diagram(record, None, **sizes, layout=layout))
        diagram_area.plotly_chart(diagram, key=f"{key}.diagram", config=CHART_CONFIG)
        st.caption("The method's loop: the box being trained lights up; the numbers are those of the iteration "
                   "shown. *Thesis Algorithms 5.1 (ABCO), 6.1 (IUPE), 8.1 (CRIL), 9.1 (SAIL); Sec 3.2-3.4 "
                   "(ILPO, GAIL, GAIfO).*")
    if not records:
        return None
    if "metrics" not in hide:
        metrics_row([r for r in records if shown is None or r["iteration"] <= shown])
    draw_panels(active_panels(records, hide), ctx)
    return shown


def rollout_panel(ctx: PanelContext) -> None:
    """The learner's rollout beside the expert's (same episode), rendered on demand and cached
    per (run, iteration) in the slot: rendering and encoding take a few seconds."""
    slot, run = ctx.slot, ctx.run
    if run is None and ctx.records:
        st.info("Make your own copy of this run (button above) to watch its policy play.")
        return
    if run is None or not ctx.records:
        st.info("Train an iteration first: then you can watch the policy play.")
        return
    latest = run.iteration
    shown = ctx.iteration or latest  # the iteration the slider shows: its policy plays
    kept = shown in run.policy_history or shown == latest
    if st.button(f"Show a rollout of the policy after iteration {shown}", key="rollout", icon=":material/movie:",
                 disabled=shown in slot.videos or not kept,
                 help=None if kept else "This saved run kept only its latest policy (saved before the app kept "
                                        "every iteration's): scrub to the latest iteration."):
        with st.spinner("Playing one episode and encoding the video..."):
            try:
                slot.render_videos(iteration=shown)
            except Exception as e:  # a missing expert, no ffmpeg, ...
                st.error(f"Could not make the video: {e}")
    have = sorted(slot.videos)
    if not have:
        return
    at = shown if shown in slot.videos else have[-1]
    if at != shown:
        st.caption(f"No rollout was recorded at iteration {shown}; showing iteration {at}.")
    learner, expert = slot.videos[at], slot.expert_video()
    left, right = st.columns(2)
    with left:
        st.markdown(f"**Learner after iteration {at}**: return {learner[1]:.2f} in {learner[2]} steps")
        st.video(learner[0], autoplay=True, muted=True, loop=True)
    with right:
        if expert is None:
            st.caption("No expert video: this environment has no shipped expert.")
        elif expert[0] == learner[0]:  # frame for frame the same film (and one video element per content)
            st.markdown(f"**Expert, same episode**: return {expert[1]:.2f} in {expert[2]} steps")
            st.success("The learner played this episode exactly as the expert did.")
        else:
            st.markdown(f"**Expert, same episode**: return {expert[1]:.2f} in {expert[2]} steps")
            st.video(expert[0], autoplay=True, muted=True, loop=True)
