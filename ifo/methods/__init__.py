"""Methods are presets of a learner: which learner family, and which of its switches are on.

The BCO family (BC, BCO, BCO(α), ABCO, IUPE) is one learner (ifo/learners/bco.py) with
switches, because those methods really are ablations of one loop; each method's file states
its algorithm in the thesis's terms and its preset. Adding a method means a file and a line
in METHODS; adding a method family means a learner in ifo/learners/ as well.
"""
from __future__ import annotations

from dataclasses import dataclass, field


@dataclass(frozen=True)
class Method:
    name: str
    title: str
    summary: str
    learner: str  # the family: a key of ifo.learners.LEARNERS
    preset: dict = field(default_factory=dict)  # values for the learner's configuration fields
    sees_expert_actions: bool = False  # True only for the references that learn from them (BC, GAIL)
    run_defaults: dict = field(default_factory=dict)  # RunConfig values this method prefers (e.g. iterations)

    @property
    def learner_class(self):
        from ifo.learners import LEARNERS

        return LEARNERS[self.learner]

    def config(self, **values):
        """This method's learner configuration with `values` set (the rest: its preset)."""
        return self.learner_class.Config(**values)

    @property
    def fixed_iterations(self) -> int | None:
        """1 for a single-pass method (BCO), None for iterative ones."""
        return self.learner_class.Config(**self.preset).fixed_iterations()


# Every module of this package is read for its Method objects (a new method is a new file), shown
# in the thesis's order; the thesis's methods not found are "planned".
ORDER = ("bc", "bco", "bco-alpha", "abco", "iupe", "cril", "sail", "gail", "gaifo", "ilpo")


def _discover() -> dict[str, Method]:
    import importlib
    import pkgutil

    found = {}
    for module in pkgutil.iter_modules(__path__):
        for value in vars(importlib.import_module(f"{__name__}.{module.name}")).values():
            if isinstance(value, Method):
                found[value.name] = value
    rank = {name: k for k, name in enumerate(ORDER)}
    return dict(sorted(found.items(), key=lambda item: (rank.get(item[0], len(ORDER)), item[0])))


METHODS: dict[str, Method] = _discover()
PLANNED = tuple(name for name in ORDER if name not in METHODS)  # the thesis's methods not built yet


class UnknownMethod(ValueError):
    pass


def get_method(name: str) -> Method:
    key = name.strip().lower().replace("_", "-").replace("(", "-").replace(")", "").replace("α", "alpha")
    key = {"bcoalpha": "bco-alpha", "bco-a": "bco-alpha"}.get(key, key)
    if key in METHODS:
        return METHODS[key]
    if key in PLANNED:
        raise UnknownMethod(f"method {name!r} is planned but not implemented yet; available: {', '.join(METHODS)}")
    raise UnknownMethod(f"unknown method {name!r}; available: {', '.join(METHODS)}")
