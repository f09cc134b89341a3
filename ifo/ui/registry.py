"""The step page's panels: the library's figures (`ifo.figure_registry`, chosen by the sections
the records have, as the export chooses them) plus the panels that are not a figure (the
rollout video). A lesson hides any of them by key (`?hide=idm,rollout`).

A panel is a chart with a short plain-language explanation and the thesis figure it
corresponds to; `draw(records, env, iteration, theme)` gives the figure (iteration = the one
the slider scrubs to), or `render(ctx)` draws into the current Streamlit container.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

from ifo.figure_registry import FIGURES, EnvView, FigureView


@dataclass(frozen=True)
class Panel:
    key: str
    title: str
    thesis_figure: str
    explanation: str
    draw: Callable | None = None  # (records, env, iteration) -> figure
    render: Callable[[Any], None] | None = None  # custom drawing (gets a PanelContext) instead of `draw`
    wide: bool = False
    applies: Callable[[list], bool] = lambda records: True

    @classmethod
    def of(cls, view: FigureView) -> "Panel":
        return cls(view.key, view.title, view.source, view.explanation,
                   draw=lambda records, env, it: view.draw(records, env, it, "screen"), wide=view.wide,
                   applies=view.applies)


def _rollout_render(ctx) -> None:  # imported lazily: the video panel needs streamlit
    from ifo.ui.panels import rollout_panel

    rollout_panel(ctx)


PANELS: list[Panel] = [Panel.of(v) for v in FIGURES if v.page] + [
    Panel("rollout", "A rollout of the policy", "Thesis Figs 4.1–4.5 (the environments), Fig 5.1",
          "The learner playing one episode beside the expert playing the same episode: what the numbers above "
          "look like.", render=_rollout_render, wide=True),
]


def panel_keys() -> list[str]:
    return [p.key for p in PANELS]


def active_panels(records: list, hidden: set[str] = frozenset()) -> list[Panel]:
    """The panels these records show, in order, minus the hidden ones (none before the first iteration)."""
    if not records:
        return []
    return [p for p in PANELS if p.key not in hidden and p.applies(records)]


def env_view(run) -> EnvView:
    return EnvView.of(run.config.to_dict())
