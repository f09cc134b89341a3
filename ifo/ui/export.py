"""Download buttons for slide-ready figures (SVG, PNG, PDF) and a run's slide pack (ZIP).

Nothing is rendered while the page draws: each button holds a callable that Streamlit runs
only when someone clicks it (on a worker thread; `ifo.export` is thread-safe), so a page
with many charts pays nothing per rerun. Without a usable Chromium the helpers show one
`st.info` instead of the buttons; the chart's own camera button (set up by
`ifo.ui.panels.CHART_CONFIG`) still downloads SVG/PNG drawn by the viewer's browser.

    chart_downloads(fig, "aer", key="step.aer.dl")                        # slide theme on a copy
    chart_downloads(fig, "aer", key="step.aer.dl",
                    draw=functools.partial(figures.learning_curve, records, "aer"))  # redrawn with theme="slide"
    slide_pack_download(records, run.config.to_dict(), key="step.pack")
"""
from __future__ import annotations

import re
from typing import Callable, Sequence

import plotly.graph_objects as go
import streamlit as st

from ifo import export

LABELS = {"svg": "SVG", "png": "PNG", "pdf": "PDF"}
HELP = {
    "svg": "Vector drawing for slides: 16:9 (1600x900), large fonts. Drawn on the server.",
    "png": f"High-resolution picture: {export.PNG_SCALE * export.SLIDE_WIDTH}x"
           f"{export.PNG_SCALE * export.SLIDE_HEIGHT} px, 16:9, large fonts. Drawn on the server.",
    "pdf": "PDF page for slides or a report: 16:9, large fonts. Drawn on the server.",
}


def _file_stem(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-.") or "figure"


def export_note() -> bool:
    """Show one `st.info` when server-side export cannot work here; True when it can."""
    problem = export.export_problem()
    if problem is not None:
        st.info(f"{problem}.", icon=":material/info:")
        return False
    return True


def _slide_figure(fig: go.Figure, draw: Callable[..., go.Figure] | None) -> go.Figure:
    return draw(theme="slide") if draw is not None else export.slide_theme(fig)


def chart_downloads(fig: go.Figure, name: str, key: str, *, draw: Callable[..., go.Figure] | None = None,
                    formats: Sequence[str] = export.FORMATS, note: bool = True) -> None:
    """Three small download buttons (SVG, PNG, PDF) for one chart, in the slide theme.

    `draw`, when given, is called as `draw(theme="slide")` at click time to redraw the figure
    properly for slides (e.g. `functools.partial(figures.learning_curve, records, "aer")`);
    otherwise a copy of `fig` gets the slide theme. `key` must be unique on the page. Without
    Chromium: one `st.info` (or nothing with `note=False`, e.g. after a page-level `export_note()`).
    """
    if export.export_problem() is not None:
        if note:
            export_note()
        return
    stem = _file_stem(name)
    with st.container(horizontal=True, gap="small", key=f"{key}.row"):
        for fmt in formats:
            def data(fmt=fmt) -> bytes:  # runs only on click, on a Streamlit worker thread
                return export.figure_bytes(_slide_figure(fig, draw), fmt)

            st.download_button(LABELS[fmt], data=data, file_name=f"{stem}.{fmt}", mime=export.MIME[fmt],
                               key=f"{key}.{fmt}", help=HELP[fmt], on_click="ignore", type="tertiary",
                               icon=":material/download:")


def slide_pack_download(records: Sequence[dict], config: dict, key: str, *,
                        formats: Sequence[str] = export.FORMATS, run_dir: str | None = None,
                        label: str = "Slide pack (ZIP)") -> None:
    """One download button for the run's slide pack: every figure of `export.run_figures` as
    SVG, PNG and PDF, metrics.csv, config.json and a README (built on click: a few seconds).
    Without Chromium: an `st.info`, and the same ZIP without figures (metrics, configuration)."""
    records, config = list(records), dict(config)
    stem = _file_stem(f"{config.get('env', 'run')}-{config.get('method', '')}-s{config.get('seed', 0)}-slides")
    problem = export.export_problem()
    if problem is not None:
        st.info(f"{problem}. The download below holds the metrics and the configuration only.",
                icon=":material/info:")
        formats = ()
        label = "Metrics and configuration (ZIP)"

    def data() -> bytes:
        return export.slide_pack(records, config, formats, run_dir=run_dir)

    st.download_button(label, data=data, file_name=f"{stem}.zip", mime="application/zip", key=key,
                       on_click="ignore", icon=":material/folder_zip:", disabled=not records,
                       help="Every chart of this run (16:9, large fonts) as "
                            f"{', '.join(LABELS[f] for f in formats) or 'no figures'}, "
                            "plus metrics.csv (one row per iteration) and config.json.")


__all__ = ["chart_downloads", "slide_pack_download", "export_note"]
