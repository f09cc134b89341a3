"""Widgets -> RunConfig: the environment, method, seed and iteration pickers every page shares.

Set IFO_LAB_FAST=1 to shrink every run built through `fast_overrides()` (10 evaluation
episodes, 10 policy runs per iteration, 2,000 random transitions, 2 policy epochs), so a
Step takes a fraction of a second. The app's tests set it; a teacher never needs it.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import streamlit as st

from ifo.config import RunConfig
from ifo.envs import ENVS, get_env
from ifo.methods import METHODS, get_method

FAST_OVERRIDES = dict(eval_episodes=10, episodes_per_iteration=10, pre_size=2000, policy_epochs=2)


def fast_overrides() -> dict:
    """The small-run settings when IFO_LAB_FAST is set to 1/true/yes, else nothing."""
    return dict(FAST_OVERRIDES) if os.environ.get("IFO_LAB_FAST", "").strip().lower() in ("1", "true", "yes") else {}


def env_label(env: str) -> str:
    # stays the same whatever is on disk: a label that changes would reset the selectbox
    spec = get_env(env)
    return spec.thesis_name or spec.name


def method_label(method: str) -> str:
    return get_method(method).title


def default_iterations(env: str, method: str) -> int:
    """How many iterations a full run of this method on this environment has by default."""
    return RunConfig(env=env, method=method).resolved().iterations


@dataclass(frozen=True)
class Choice:
    """What the settings widgets say, before it becomes a RunConfig."""

    env: str
    method: str
    seed: int
    iterations: int

    def config(self) -> RunConfig:
        """The resolved configuration; raises ValueError with a plain message if a value is impossible."""
        return RunConfig(env=self.env, method=self.method, seed=self.seed, iterations=self.iterations,
                         **fast_overrides()).resolved()


def run_settings(key: str = "run", where=None) -> Choice:
    """Draw the environment / method / seed / iterations pickers (in the sidebar by default)."""
    where = st.sidebar if where is None else where
    with where:
        st.subheader("Run settings")
        env = st.selectbox("Environment", list(ENVS), format_func=env_label, key=f"{key}.env",
                           help="The task the expert demonstrated. Only its states are given to the learner.")
        method = st.selectbox("Method", list(METHODS), format_func=method_label, key=f"{key}.method",
                              index=list(METHODS).index("bco-alpha"))
        st.caption(METHODS[method].summary)
        seed = int(st.number_input("Seed", min_value=0, max_value=1_000_000, value=0, step=1, key=f"{key}.seed",
                                   help="Same seed, same numbers."))
        default = default_iterations(env, method)
        if METHODS[method].iterative:
            # the key holds env and method, so each pair starts from its own default
            iterations = int(st.number_input("Iterations in the run", min_value=1, max_value=1000, value=default,
                                             step=1, key=f"{key}.iterations.{env}.{method}",
                                             help="How many presses of Step make a full run (the thesis's α)."))
        else:
            st.number_input("Iterations in the run", value=1, disabled=True, key=f"{key}.iterations.{env}.{method}",
                            help=f"{METHODS[method].title} is a single pass.")
            iterations = 1
        st.caption("Changing the environment, method or seed starts a new run.")
    return Choice(env, method, seed, iterations)
