"""Learners: one per method family (see ifo/learners/base.py for the seam they share).

    bco    the BCO loop with switches: BC, BCO, BCO(α), ABCO, IUPE (ifo/learners/bco.py)
    cril   IUPE's loop with TD updates of the policy from its own experience (ifo/learners/cril.py)
"""
from ifo.learners.base import Context, HiddenTruth, Learner, LearnerConfig, Phase, StepCancelled
from ifo.learners.bco import BCOConfig, BCOLearner
from ifo.learners.cril import CRILConfig, CRILLearner

LEARNERS: dict[str, type[Learner]] = {"bco": BCOLearner, "cril": CRILLearner}

__all__ = ["LEARNERS", "Context", "HiddenTruth", "Learner", "LearnerConfig", "Phase", "StepCancelled", "BCOConfig",
           "BCOLearner", "CRILConfig", "CRILLearner"]
