"""Widgets -> RunConfig: the environment, method, seed, iterations and ablation switches.

The switches (attention, sampling mode, exploration of labels and of rollouts, AER with
sampled or MAP actions) are plain RunConfig fields. Choosing a method sets them to the
method's components; a *preset* sets a method and its switches at once: the thesis's
methods (BCO, BCO(α), ABCO, IUPE) and the ablation rows of Tables 5.2 and 6.2, taken
from `ifo.reproduce.TABLES` (one source of truth).

With `bind=True` every widget keeps its value in the page's URL (`bind="query-params"`,
the key is the parameter's name), so a teacher can share a link that opens the same
configuration. A switch appears in the URL only when it differs from the method's choice.

Set IFO_LAB_FAST=1 to shrink every run built through `fast_overrides()` (10 evaluation
episodes, 10 policy runs per iteration, 2,000 random transitions, 2 policy epochs), so a
Step takes a fraction of a second. The app's tests set it; a teacher never needs it.
"""
from __future__ import annotations

import os
from dataclasses import asdict, dataclass

import streamlit as st

from ifo.config import RunConfig
from ifo.envs import ENVS, get_env
from ifo.methods import METHODS, get_method
from ifo.reproduce import TABLES

FAST_OVERRIDES = dict(eval_episodes=10, episodes_per_iteration=10, pre_size=2000, policy_epochs=2)
SWITCHES = ("attention", "sampling", "explore_labels", "explore_rollouts")
ATTENTION_LABELS = {"none": "off", "gated": "on (gated, as in the thesis)", "features": "over state variables"}
SAMPLING_LABELS = {"none": "none: I_s = I_pos (BCO(α))", "abco": "ABCO, partial (Eqs 5.3–5.5)",
                   "abco-whole": "ABCO, whole (Table 5.2)", "iupe": "IUPE (Sec 6.1)"}
EVAL_LABELS = {False: "MAP actions (the most likely)", True: "actions sampled from π"}
MAZE_EVAL_LABELS = {"held-out": "100 layouts it never saw", "demonstration": "the demonstrations' layouts (thesis)"}


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


# --------------------------------------------------------------------------- presets
@dataclass(frozen=True)
class Preset:
    label: str
    method: str
    switches: dict  # the four SWITCHES
    source: str = ""  # "Table 6.2" for an ablation row
    thesis: str = ""  # the thesis's numbers for that row, in words


def _components(method: str, overrides: dict | None = None) -> dict:
    comp = get_method(method).components
    return {k: (overrides or {}).get(k, comp.get(k)) for k in SWITCHES}


def _presets() -> dict[str, Preset]:
    out = {m: Preset(get_method(m).title, m, _components(m)) for m in ("bco", "bco-alpha", "abco", "iupe")}
    for table_id in ("5.2", "6.2"):
        table = TABLES[table_id]
        for row in table.rows:
            numbers = []
            for env, (p, aer) in table.thesis.get(row.label, {}).items():
                numbers.append(f"{env_label(env)}: P = {p:.3f}, AER = {aer:.3f}")
            out[f"t{table_id}:{row.label}"] = Preset(f"Table {table_id}: {row.label}", row.method,
                                                     _components(row.method, row.overrides), f"Table {table_id}",
                                                     "; ".join(numbers))
    return out


PRESETS: dict[str, Preset] = _presets()


def matching_presets(method: str, switches: dict) -> list[Preset]:
    """The presets these settings are (same iterative-ness, same switches)."""
    iterative = get_method(method).iterative
    return [p for p in PRESETS.values()
            if p.switches == {k: switches.get(k) for k in SWITCHES} and get_method(p.method).iterative == iterative
            and get_method(p.method).uses_idm == get_method(method).uses_idm]


# --------------------------------------------------------------------------- the choice
@dataclass(frozen=True)
class Choice:
    """What the settings widgets say, before it becomes a RunConfig. Switches left None take
    the method's components."""

    env: str
    method: str
    seed: int
    iterations: int
    attention: str | None = None
    sampling: str | None = None
    explore_labels: bool | None = None
    explore_rollouts: bool | None = None
    eval_explore: bool = False
    maze_eval_layouts: str = "held-out"  # maze only
    deadlock_guard: bool = False  # maze only

    def config(self) -> RunConfig:
        """The resolved configuration; raises ValueError with a plain message if a value is impossible."""
        return RunConfig(**asdict(self), **fast_overrides()).resolved()

    @classmethod
    def from_config(cls, config: RunConfig) -> "Choice":
        return cls(config.env, config.method, config.seed, config.iterations,
                   **{k: getattr(config, k) for k in (*SWITCHES, "eval_explore", *MAZE_FIELDS)})


MAZE_FIELDS = ("maze_eval_layouts", "deadlock_guard")


def _k(key: str, name: str) -> str:
    return f"{key}.{name}"


def iterations_key(key: str, env: str, method: str) -> str:
    return f"{key}.iterations.{env}.{method}"


def set_widgets(key: str, choice: Choice) -> None:
    """Put a choice into the widgets' session state (before they are drawn: a loaded run)."""
    ss = st.session_state
    ss[_k(key, "env")], ss[_k(key, "method")], ss[_k(key, "seed")] = choice.env, choice.method, int(choice.seed)
    for name in SWITCHES:
        ss[_k(key, name)] = getattr(choice, name)
    ss[_k(key, "eval_explore")] = bool(choice.eval_explore)
    ss[_k(key, "maze_eval_layouts")], ss[_k(key, "deadlock_guard")] = choice.maze_eval_layouts, choice.deadlock_guard
    if get_method(choice.method).iterative:
        ss[iterations_key(key, choice.env, choice.method)] = int(choice.iterations)


def _apply_method(key: str) -> None:
    """The method selectbox changed: its switches follow its components."""
    method = st.session_state[_k(key, "method")]
    for name, value in _components(method).items():
        st.session_state[_k(key, name)] = value


def _apply_preset(key: str) -> None:
    name = st.session_state.get(_k(key, "preset"))
    if name in PRESETS:
        preset = PRESETS[name]
        st.session_state[_k(key, "method")] = preset.method
        for switch, value in preset.switches.items():
            st.session_state[_k(key, switch)] = value
    st.session_state[_k(key, "preset")] = None  # the selectbox only applies; the caption says what matches


def run_settings(key: str = "run", where=None, bind: bool = False, switches: bool = True) -> Choice:
    """Draw the environment / method / seed / iterations pickers (in the sidebar by default),
    then (with `switches`) the presets and ablation switches. `bind` keeps them in the URL."""
    where = st.sidebar if where is None else where
    b = {"bind": "query-params"} if bind else {}
    with where:
        st.subheader("Run settings")
        env = st.selectbox("Environment", list(ENVS), format_func=env_label, key=_k(key, "env"), **b,
                           help="The task the expert demonstrated. Only its states are given to the learner.")
        method = st.selectbox("Method", list(METHODS), format_func=method_label, key=_k(key, "method"),
                              index=list(METHODS).index("bco-alpha"), on_change=_apply_method, args=(key,), **b)
        st.caption(METHODS[method].summary)
        seed = int(st.number_input("Seed", min_value=0, max_value=1_000_000, value=0, step=1, key=_k(key, "seed"),
                                   help="Same seed, same numbers.", **b))
        default = default_iterations(env, method)
        if METHODS[method].iterative:
            # the key holds env and method, so each pair starts from its own default
            iterations = int(st.number_input("Iterations in the run", min_value=1, max_value=1000, value=default,
                                             step=1, key=iterations_key(key, env, method), **b,
                                             help="How many presses of Step make a full run (the thesis's α)."))
        else:
            st.number_input("Iterations in the run", value=1, disabled=True, key=iterations_key(key, env, method),
                            help=f"{METHODS[method].title} is a single pass.")
            iterations = 1
        maze = _maze_widgets(key, b) if get_env(env).is_maze else {}
        if not switches:
            st.caption("Changing the environment, method or seed starts a new run.")
            return Choice(env, method, seed, iterations, **maze)
        values = _switch_widgets(key, method, b)
        st.caption("Changing the environment, method, seed or a switch starts a new run.")
    return Choice(env, method, seed, iterations, **values, **maze)


def _maze_widgets(key: str, b: dict) -> dict:
    """Where a maze policy is judged: a generalisation test, or the thesis authors' protocol."""
    layouts = st.radio("Evaluate on", list(MAZE_EVAL_LABELS), format_func=MAZE_EVAL_LABELS.get,
                       key=_k(key, "maze_eval_layouts"), **b,
                       help="Held-out layouts test whether the policy learned to navigate. The thesis "
                            "evaluated on the layouts its 100 demonstrations came from, and its agent "
                            "lived in those layouts only: that choice reproduces it.")
    if layouts == "held-out":
        st.caption("A test of generalisation: from 100 demonstrations a policy mostly learns its mazes, so "
                   "even BC (which sees the true actions) scores low here (5×5: P ≈ 0.26). The thesis's "
                   "numbers come from the demonstrations' layouts.")
    guard = st.toggle("Deadlock guard", key=_k(key, "deadlock_guard"), **b,
                      help="End an evaluation episode on the 4th visit to a cell, with return −1 (the thesis's "
                           "evaluation). Without it a policy that loops wanders until the 1,000-step limit.")
    return {"maze_eval_layouts": layouts, "deadlock_guard": bool(guard)}


def _switch_widgets(key: str, method: str, b: dict) -> dict:
    m = get_method(method)
    comp = _components(method)
    st.subheader("Components")
    st.selectbox("Preset", list(PRESETS), index=None, key=_k(key, "preset"), format_func=lambda p: PRESETS[p].label,
                 placeholder="Apply a thesis configuration...", on_change=_apply_preset, args=(key,),
                 help="Sets the method and its switches to a configuration of the thesis: its methods, "
                      "and the ablation rows of Tables 5.2 (ABCO) and 6.2 (IUPE).")
    no_idm, no_rollouts = not m.uses_idm, not (m.uses_idm and m.iterative)
    attention = st.selectbox("Attention", list(ATTENTION_LABELS), format_func=ATTENTION_LABELS.get,
                             index=list(ATTENTION_LABELS).index(comp["attention"]), key=_k(key, "attention"), **b,
                             help="An attention module in the IDM and the policy (ABCO, IUPE). 'Over state "
                                  "variables' learns which variables matter and can be drawn as a chart.")
    sampling = st.selectbox("Sampling of I_s", list(SAMPLING_LABELS), format_func=SAMPLING_LABELS.get,
                            index=list(SAMPLING_LABELS).index(comp["sampling"]), key=_k(key, "sampling"), **b,
                            disabled=no_rollouts,
                            help="What the IDM trains on next: the policy's own runs (I_pos), mixed with the "
                                 "random transitions (I_pre) by how often the runs reached the goal.")
    explore_labels = st.toggle("Explore: sample the labels", value=bool(comp["explore_labels"]),
                               key=_k(key, "explore_labels"), disabled=no_idm, **b,
                               help="Label the expert's pairs with actions sampled from the IDM's softmax "
                                    "instead of the most likely one (IUPE, Sec 6.2).")
    explore_rollouts = st.toggle("Explore: sample the policy's actions", value=bool(comp["explore_rollouts"]),
                                 key=_k(key, "explore_rollouts"), disabled=no_rollouts, **b,
                                 help="Run the policy with actions sampled from its softmax while it collects "
                                      "its own experience (IUPE).")
    eval_explore = st.radio("Measure AER with", list(EVAL_LABELS), format_func=EVAL_LABELS.get,
                            key=_k(key, "eval_explore"), horizontal=False, **b,
                            help="The thesis measured IUPE with sampled actions; MAP actions are deterministic.")
    values = dict(attention=attention, sampling=sampling, explore_labels=bool(explore_labels),
                  explore_rollouts=bool(explore_rollouts))
    matches = matching_presets(method, values)
    if matches:
        st.caption("These are the thesis's " + " = ".join(f"**{p.label}**" for p in matches) + ".")
        for p in matches:
            if p.thesis:
                st.caption(f"{p.source} reports for this row — {p.thesis}.")
    else:
        st.caption("A custom combination of components.")
    return {**values, "eval_explore": bool(eval_explore)}


def choice_without_widgets(key: str) -> Choice:
    """The settings when the lesson hides their widgets (`?hide=settings`): from the session's
    widget state, else from the URL (the same parameters the bound widgets write), else defaults."""
    ss, qp = st.session_state, st.query_params

    def raw(name):
        k = _k(key, name)
        return ("state", ss[k]) if k in ss else ("url", qp.get(k)) if qp.get(k) is not None else (None, None)

    def pick(name, labels: dict, default):
        where, v = raw(name)
        if where == "state":
            return v
        by_label = {str(label): value for value, label in labels.items()}
        return by_label.get(v, default) if where == "url" else default

    env = pick("env", {e: env_label(e) for e in ENVS}, next(iter(ENVS)))
    method = pick("method", {m: method_label(m) for m in METHODS}, "bco-alpha")
    where, seed = raw("seed")
    try:
        seed = int(seed) if where else 0
    except ValueError:
        seed = 0
    comp = _components(method)
    it_key = iterations_key(key, env, method)
    iterations = ss.get(it_key, qp.get(it_key)) if get_method(method).iterative else 1
    try:
        iterations = int(iterations) if iterations is not None else default_iterations(env, method)
    except ValueError:
        iterations = default_iterations(env, method)
    bools = {True: "true", False: "false"}
    return Choice(env, method, seed, iterations,
                  attention=pick("attention", ATTENTION_LABELS, comp["attention"]),
                  sampling=pick("sampling", SAMPLING_LABELS, comp["sampling"]),
                  explore_labels=bool(pick("explore_labels", bools, comp["explore_labels"])),
                  explore_rollouts=bool(pick("explore_rollouts", bools, comp["explore_rollouts"])),
                  eval_explore=bool(pick("eval_explore", EVAL_LABELS, False)),
                  **({"maze_eval_layouts": pick("maze_eval_layouts", MAZE_EVAL_LABELS, "held-out"),
                      "deadlock_guard": bool(pick("deadlock_guard", bools, False))} if get_env(env).is_maze else {}))
