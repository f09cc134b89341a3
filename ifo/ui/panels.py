"""Drawing helpers: a chart panel with its caption, the iteration counter, the metrics row."""
from __future__ import annotations

import plotly.graph_objects as go
import streamlit as st

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
