"""Learners: one per method family (see ifo/learners/base.py for the seam they share).

    bco    the BCO loop with switches: BC, BCO, BCO(α), ABCO, IUPE (bco.py)
    cril   IUPE's loop with TD updates of the policy from its own experience (cril.py)

Every module of this package is read for Learner classes with a `key`; a method names its
learner by that key (ifo/methods/). A new family is a new file.
"""
import importlib
import pkgutil

from ifo.learners.base import Context, HiddenTruth, Learner, LearnerConfig, Phase, StepCancelled


def _discover() -> dict[str, type[Learner]]:
    found = {}
    for module in pkgutil.iter_modules(__path__):
        for value in vars(importlib.import_module(f"{__name__}.{module.name}")).values():
            if isinstance(value, type) and issubclass(value, Learner) and "key" in vars(value):
                found[value.key] = value
    return found


LEARNERS: dict[str, type[Learner]] = _discover()

__all__ = ["LEARNERS", "Context", "HiddenTruth", "Learner", "LearnerConfig", "Phase", "StepCancelled"]
