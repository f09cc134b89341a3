"""Which of the registry's charts each method shows after one Step on CartPole: the AppTest and the
browser journeys check the same list, by key and by the title a person reads."""
from ifo.figure_registry import FIGURES

METHOD_CHARTS = {"bc": ["accuracy"], "bco": ["idm"], "bco-alpha": ["idm"], "abco": ["idm", "sampling", "win"],
                 "iupe": ["idm", "exploration"], "cril": ["td", "replay"], "sail": ["idm", "discriminator", "replay"],
                 "gail": ["discriminator", "generator"], "gaifo": ["discriminator"], "ilpo": ["latent"]}

TITLES = {view.key: view.title for view in FIGURES}


def chart_titles(method: str) -> list[str]:
    """The titles of `method`'s own charts (each chart draws its registry title, tests/test_figures.py)."""
    return [TITLES[key] for key in METHOD_CHARTS[method]]
