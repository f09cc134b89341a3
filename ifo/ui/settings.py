"""Widgets -> RunConfig, generated from the configuration classes (ifo.options): one widget per
field, labelled, bounded and explained by the field's own declaration, so the app, the
command line and the checks never drift apart.

- The run's main fields (environment, method, seed, iterations, and the maze's options) come
  first; then the learner's switches (for the BCO family: attention, sampling, exploration),
  then "More settings" (sizes, learning rate, ...), where an empty box means "the method's or
  the environment's default".
- Each method keeps its own switches (their keys hold the method, `step.iupe.sampling`), which
  start at the method's preset: choosing a method writes no other widget. (A method's callback
  that wrote its switches was lost when the browser sent its next change before the page of the
  first arrived, on a busy server: IUPE ran with BCO(α)'s switches.) A *preset* sets a method and
  its switches at once: the thesis's methods and the ablation rows of Tables 5.2 and 6.2
  (taken from `ifo.reproduce.TABLES`, one source of truth).
- With `bind=True` every widget keeps its value in the page's URL (`bind="query-params"`, the
  key is the parameter's name), so a teacher can share a link that opens the same
  configuration; a value appears in the URL only when it differs from the default.

Set IFO_LAB_ENVS to a researcher's own environments, comma-separated `module:name`
(`ifo.envs.register_env`), to offer them beside IfO Lab's; they learn from demonstrations
uploaded on *Your runs*.

Set IFO_LAB_FAST=1 to shrink every run built through `fast_overrides()` (10 evaluation
episodes, 10 policy runs per iteration, 2,000 random transitions, 2 policy epochs), so a
Step takes a fraction of a second. The app's tests set it; a teacher never needs it.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field

import streamlit as st

from ifo.config import MAZE_EVALUATION_FIELDS, MAZE_ONLY_FIELDS, RunConfig, switch_specs, switches
from ifo.envs import ENVS, UnknownEnvironment, found_by_module, get_env
from ifo.methods import METHODS, get_method
from ifo.options import Spec, check_field, heavier_than_default, specs
from ifo.reproduce import TABLES

log = logging.getLogger(__name__)

FAST_OVERRIDES = dict(eval_episodes=10, episodes_per_iteration=10, pre_size=2000, policy_epochs=2, round_steps=512)
MAIN_FIELDS = ("env", "method", "seed", "iterations")
MAZE_FIELDS = MAZE_EVALUATION_FIELDS  # shown for mazes only
# drawn with the maze's options, not in "More settings": which methods a maze can run depends on it
MAZE_UP_FRONT = ("obs_mode",)
NOT_WIDGETS = ("demos",)  # chosen on the runs page (uploads), not typed in
METHOD_FIELDS = ("labels", "single_pass")  # what makes BC or BCO: the method chooses them


def fast_overrides(method: str | None = None) -> dict:
    """The small-run settings when IFO_LAB_FAST is set to 1/true/yes, else nothing; with a method,
    only those its configuration has (GAIL has no I_pre)."""
    if os.environ.get("IFO_LAB_FAST", "").strip().lower() not in ("1", "true", "yes"):
        return {}
    if method is None:
        return dict(FAST_OVERRIDES)
    own = get_method(method).learner_class.Config.field_names() | {s.name for s in specs(RunConfig)}
    return {k: v for k, v in FAST_OVERRIDES.items() if k in own}


def app_envs() -> tuple[str, ...]:
    """The environments the pages offer: IfO Lab's own, then the researcher's: those IFO_LAB_ENVS names
    (comma-separated module:name; one that cannot be found is left out, and the log says why) and any
    other a saved run named (so it opens with its environment after the server restarts without it)."""
    for name in filter(None, (n.strip() for n in os.environ.get("IFO_LAB_ENVS", "").split(","))):
        try:
            get_env(name)
        except (UnknownEnvironment, ValueError) as e:  # a module missing, or registering nothing we can learn in
            _log_once(f"IFO_LAB_ENVS: {e}")
    return (*ENVS, *found_by_module())


_LOGGED: set[str] = set()  # said once per server, not on every rerun


def _log_once(message: str) -> None:
    if message not in _LOGGED:
        _LOGGED.add(message)
        log.warning(message)


def env_label(env: str) -> str:
    # stays the same whatever is on disk: a label that changes would reset the selectbox
    spec = get_env(env)
    return spec.thesis_name or spec.name


def method_label(method: str) -> str:
    return get_method(method).title


def default_iterations(env: str, method: str) -> int:
    """How many iterations a full run of this method on this environment has by default."""
    return RunConfig(env=env, method=method).resolved().iterations


def resolved_defaults(env: str, method: str) -> dict:
    """Every setting's value for a plain run of `method` on `env` (flat names)."""
    return RunConfig(env=env, method=method).resolved().flat()


# --------------------------------------------------------------------------- presets
@dataclass(frozen=True)
class Preset:
    label: str
    method: str
    switches: dict  # the learner's switches
    source: str = ""  # "Table 6.2" for an ablation row
    thesis: dict = field(default_factory=dict)  # env -> the thesis's numbers for that row, in words


def _presets() -> dict[str, Preset]:
    out = {m: Preset(get_method(m).title, m, switches(RunConfig(method=m).resolved()))
           for m, method in METHODS.items() if not method.sees_expert_actions}
    for table_id in ("5.2", "6.2"):
        table = TABLES[table_id]
        for row in table.rows:
            numbers = {env: f"P = {p:.3f}, AER = {aer:.3f}" for env, (p, aer) in table.thesis.get(row.label, {}).items()}
            cfg = RunConfig.from_dict({"method": row.method, **row.overrides}).resolved()
            out[f"t{table_id}:{row.label}"] = Preset(f"Table {table_id}: {row.label}", row.method, switches(cfg),
                                                     f"Table {table_id}", numbers)
    return out


PRESETS: dict[str, Preset] = _presets()


def matching_presets(method: str, values: dict) -> list[Preset]:
    """The presets these settings are (the same learner family and single-pass-ness, the same switches)."""
    m = get_method(method)
    return [p for p in PRESETS.values()
            if p.switches == {k: values.get(k) for k in p.switches}
            and get_method(p.method).learner == m.learner and get_method(p.method).fixed_iterations == m.fixed_iterations]


# --------------------------------------------------------------------------- the choice
@dataclass(frozen=True)
class Choice:
    """What the settings widgets say, before it becomes a RunConfig: flat settings by name (a
    learner setting left None takes the method's preset or the environment's default)."""

    values: dict

    @property
    def env(self) -> str:
        return self.values["env"]

    @property
    def method(self) -> str:
        return self.values["method"]

    def config(self) -> RunConfig:
        """The resolved configuration; raises ValueError with a plain message if a value is impossible."""
        return RunConfig.from_dict({**fast_overrides(self.method), **self.values}).resolved()  # small-run defaults

    @classmethod
    def from_config(cls, config: RunConfig) -> "Choice":
        values = config.flat()
        values.pop("learner", None)
        return cls(values)


def _k(key: str, name: str) -> str:
    return f"{key}.{name}"


def iterations_key(key: str, env: str, method: str) -> str:
    return f"{key}.iterations.{env}.{method}"


def switch_key(key: str, method: str, name: str) -> str:
    return f"{key}.{method}.{name}"


def _switch_names(method: str) -> set[str]:
    return {s.name for s in switch_specs(get_method(method).learner_class.Config)}


def _widget_key(key: str, name: str, env: str, method: str) -> str:
    if name == "iterations":
        return iterations_key(key, env, method)
    return switch_key(key, method, name) if name in _switch_names(method) else _k(key, name)


def set_widgets(key: str, choice: Choice) -> None:
    """Put a choice into the widgets' session state (before they are drawn: a loaded run)."""
    ss, env, method = st.session_state, choice.env, choice.method
    defaults = Choice({"env": env, "method": method}).config().flat()  # what an empty box gives (small runs too)
    advanced = {s.name for s in _all_specs(method) if s.advanced}
    for name, value in choice.values.items():
        if name in NOT_WIDGETS + METHOD_FIELDS or name == "learner":
            continue
        if name == "iterations" and get_method(method).fixed_iterations is not None:
            continue
        if name in advanced:  # empty box = the default; only differences are written
            value = None if value == defaults.get(name) else value
        ss[_widget_key(key, name, env, method)] = _widget_value(name, value)


def _widget_value(name: str, value):
    if name == "hidden":  # the one text box: empty is its default
        return ",".join(map(str, value)) if value else ""
    return ",".join(map(str, value)) if isinstance(value, tuple) else value


def _all_specs(method: str) -> tuple[Spec, ...]:
    return specs(RunConfig) + specs(get_method(method).learner_class.Config)


def _apply_preset(key: str) -> None:
    name = st.session_state.get(_k(key, "preset"))
    if name in PRESETS:
        preset = PRESETS[name]
        st.session_state[_k(key, "method")] = preset.method
        for switch, value in preset.switches.items():
            st.session_state[switch_key(key, preset.method, switch)] = value
    st.session_state[_k(key, "preset")] = None  # the selectbox only applies; the caption says what matches


def link_by_name(widget_key: str, choices, label) -> None:
    """A link may name a choice as the configuration does (`?step.env=maze3`), not by the label the bound
    widget writes (`Maze 3x3`), which Streamlit would drop (opening the default). Called before the
    widget is drawn: it starts with the named choice."""
    value = st.query_params.get(widget_key)
    if value is None or widget_key in st.session_state:
        return
    by_name = {str(c): c for c in choices if c is not None}
    if value in by_name and value not in {str(label(c)) for c in by_name.values()}:
        st.session_state[widget_key] = by_name[value]


def link_by_old_name(widget_key: str, old_key: str, s: Spec) -> None:
    """A link made before each method kept its own switches names a switch without the method
    (`?step.explore_rollouts=false`): the switch starts with the link's value, and the URL takes the new name."""
    value = st.query_params.get(old_key)
    if value is None:
        return
    del st.query_params[old_key]
    parsed = url_value(s, value)
    if parsed is not None and widget_key not in st.session_state:
        st.session_state[widget_key] = parsed
        st.query_params[widget_key] = value  # the text the widget writes: a reload keeps the switch


def url_value(s: Spec, text: str):
    """A URL parameter's text as the field's value (a label, a bool, a number), or None if it is none of them."""
    by_label = {str(label): value for value, label in s.labels.items()}
    if text in by_label:
        return by_label[text]
    try:
        value = {bool: lambda t: str(t).lower() in ("true", "1"), int: int, float: float}.get(s.kind, str)(text)
        check_field(s, value)
        return value
    except (ValueError, TypeError):
        return None


def _widget(s: Spec, key: str, default, bind: dict, disabled: bool = False, optional: bool = False):
    """One widget for one field, as its declaration says (labels, bounds, help)."""
    if bind and s.choices and s.labels:
        link_by_name(key, s.choices, lambda v: s.labels.get(v, v))
    return _draw_widget(s, key, default, bind, disabled, optional)


def _draw_widget(s: Spec, key: str, default, bind: dict, disabled: bool, optional: bool):
    help_text = s.help[0].upper() + s.help[1:] + "." if s.help else None
    if optional and (s.choices is not None or s.kind is bool):  # None: the default, shown as such
        choices = [None] + (list(s.choices) if s.choices is not None else [False, True])
        name = lambda v: str(s.labels.get(v, v))  # noqa: E731
        return st.selectbox(s.label, choices, key=key, help=help_text, disabled=disabled, **bind,
                            format_func=lambda v: f"default ({name(default)})" if v is None else name(v))
    if s.choices is not None or (s.kind is bool and s.labels):
        choices = list(s.choices) if s.choices is not None else [False, True]
        fmt = (lambda v: str(s.labels.get(v, v))) if s.labels else str
        index = choices.index(default) if default in choices else 0
        if s.widget == "radio":
            return st.radio(s.label, choices, index=index, format_func=fmt, key=key, help=help_text,
                            disabled=disabled, **bind)
        return st.selectbox(s.label, choices, index=index, format_func=fmt, key=key, help=help_text,
                            disabled=disabled, **bind)
    if s.kind is bool:
        return st.toggle(s.label, value=bool(default), key=key, help=help_text, disabled=disabled, **bind)
    if s.kind in (int, float):
        step = 1 if s.kind is int else None
        # Streamlit refuses bounds of mixed types (CRIL's share_k is a float bounded by the int 100)
        low = None if s.low is None else s.kind(s.low)
        high = None if s.high is None else s.kind(s.high)
        if optional:  # empty: the default (shown as the placeholder)
            value = st.number_input(s.label, min_value=low, max_value=high, value=None, step=step, key=key,
                                    help=help_text, disabled=disabled, placeholder=f"default: {default:g}"
                                    if default is not None else "default", format="%g" if s.kind is float else None,
                                    **bind)
            return value
        return st.number_input(s.label, min_value=low, max_value=high, value=None if default is None else
                               s.kind(default), step=step, key=key,
                               help=help_text, disabled=disabled, **bind)
    if s.kind is tuple:
        text = st.text_input(s.label, value="", key=key, help=help_text, disabled=disabled,
                             placeholder=f"default: {','.join(map(str, default or ()))}", **bind) or ""
        try:
            return tuple(int(v) for v in text.split(",") if v.strip()) or None
        except ValueError:
            raise ValueError(f"{s.name} must be whole numbers separated by commas, got {text!r}") from None
    return st.text_input(s.label, value=default or "", key=key, help=help_text, disabled=disabled, **bind) or None


def run_settings(key: str = "run", where=None, bind: bool = False, switches_shown: bool = True) -> Choice:
    """Draw the run's settings (in the sidebar by default): environment, method, seed, iterations, the
    maze's options, then (with `switches_shown`) presets, the learner's switches and "More settings".
    `bind` keeps them in the URL. A value a widget cannot hold raises ValueError (shown by the page)."""
    where = st.sidebar if where is None else where
    b = {"bind": "query-params"} if bind else {}
    run_specs = {s.name: s for s in specs(RunConfig)}
    if bind:
        link_by_name(_k(key, "env"), app_envs(), env_label)
        link_by_name(_k(key, "method"), METHODS, method_label)
    with where:
        st.subheader("Run settings")
        env = st.selectbox("Environment", app_envs(), format_func=env_label, key=_k(key, "env"), **b,
                           help="The task the expert demonstrated. Only its states are given to the learner.")
        method = st.selectbox("Method", list(METHODS), format_func=method_label, key=_k(key, "method"),
                              index=list(METHODS).index("bco-alpha"), **b)
        st.caption(METHODS[method].summary)
        defaults = resolved_defaults(env, method)
        values = {"env": env, "method": method}
        values["seed"] = int(_widget(run_specs["seed"], _k(key, "seed"), 0, b))
        fixed = get_method(method).fixed_iterations
        if fixed is None:
            # the key holds env and method, so each pair starts from its own default
            values["iterations"] = int(_widget(run_specs["iterations"], iterations_key(key, env, method),
                                               defaults["iterations"], b))
        else:
            st.number_input("Iterations in the run", value=fixed, disabled=True, key=iterations_key(key, env, method),
                            help=f"{METHODS[method].title} is a single pass.")
            values["iterations"] = fixed
        if get_env(env).is_maze:
            values.update(_maze_widgets(key, run_specs, defaults, b))
        if not switches_shown:
            st.caption("Changing the environment, method or seed starts a new run.")
            return Choice(values)
        values.update(_switch_widgets(key, method, defaults, run_specs, b))
        values.update(_more_settings(key, env, method, defaults, b))
        st.caption("Changing the environment, method, seed or a switch starts a new run.")
    return Choice(values)


def _maze_widgets(key: str, run_specs: dict, defaults: dict, b: dict) -> dict:
    """What the learner sees of a maze (images, or the vector that SAIL, GAIL, GAIfO and ILPO need), and
    where a maze policy is judged: a generalisation test, or the thesis authors' protocol."""
    # an advanced setting like those of "More settings": empty is the default, a run saves only differences
    up_front = {name: _widget(run_specs[name], _k(key, name), defaults.get(name), b, optional=True)
                for name in MAZE_UP_FRONT}
    layouts = _widget(run_specs["maze_eval_layouts"], _k(key, "maze_eval_layouts"), "held-out", b)
    if layouts == "held-out":
        st.caption("A test of generalisation: from 100 demonstrations a policy mostly learns its mazes, so "
                   "even BC (which sees the true actions) scores low here (5×5: P ≈ 0.26). The thesis's "
                   "numbers come from the demonstrations' layouts.")
    guard = _widget(run_specs["deadlock_guard"], _k(key, "deadlock_guard"), run_specs["deadlock_guard"].default, b)
    return {**{name: v for name, v in up_front.items() if v is not None},
            "maze_eval_layouts": layouts, "deadlock_guard": bool(guard)}


def _switch_widgets(key: str, method: str, defaults: dict, run_specs: dict, b: dict) -> dict:
    cls = get_method(method).learner_class.Config
    st.subheader("Components")
    st.selectbox("Preset", list(PRESETS), index=None, key=_k(key, "preset"), format_func=lambda p: PRESETS[p].label,
                 placeholder="Apply a thesis configuration...", on_change=_apply_preset, args=(key,),
                 help="Sets the method and its switches to a configuration of the thesis: its methods, "
                      "and the ablation rows of Tables 5.2 (ABCO) and 6.2 (IUPE).")
    unused = cls(**{s.name: defaults.get(s.name) for s in specs(cls)}).unused()
    values = {}
    for s in switch_specs(cls):
        widget_key = switch_key(key, method, s.name)
        if b:
            link_by_old_name(widget_key, _k(key, s.name), s)
        values[s.name] = _widget(s, widget_key, defaults[s.name], b, disabled=s.name in unused)
    values["eval_explore"] = bool(_widget(run_specs["eval_explore"], _k(key, "eval_explore"), False, b))
    matches = matching_presets(method, values)
    env = st.session_state.get(_k(key, "env"))
    if matches:
        st.caption("These are the thesis's " + " = ".join(f"**{p.label}**" for p in matches) + ".")
        for p in matches:
            if env in p.thesis:  # only numbers for this environment
                st.caption(f"{p.source} reports for this row on {env_label(env)}: {p.thesis[env]}.")
    else:
        st.caption("A custom combination of components.")
    return values


def _more_settings(key: str, env: str, method: str, defaults: dict, b: dict) -> dict:
    """Sizes and rates, in an expander: an empty box keeps the method's or the environment's default."""
    maze = get_env(env).is_maze
    chosen = [s for s in _all_specs(method) if s.advanced and s.name not in NOT_WIDGETS + METHOD_FIELDS + MAZE_UP_FRONT
              and (maze or s.name not in MAZE_ONLY_FIELDS)]
    values = {}
    with st.expander("More settings"):
        st.caption("Empty boxes keep the default shown in grey.")
        for s in chosen:
            value = _widget(s, _k(key, s.name), defaults.get(s.name), b, optional=True)
            if value is not None:
                values[s.name] = int(value) if s.kind is int else value
    heavy = heavier_than_default(chosen, values, defaults)
    if heavy:  # outside the expander: a collapsed one would hide it
        st.warning("Slower Steps ahead: " + "; ".join(
            f"{s.label} {value:g} against the default {default:g} (up to ×{factor:,.0f} the work of what it sizes)"
            for s, value, default, factor in heavy) + ". Making the run and each Step may take minutes; the page "
            "times each iteration after the first Step.")
    return values


def choice_without_widgets(key: str) -> Choice:
    """The settings when the lesson hides their widgets (`?hide=settings`): from the session's widget
    state, else from the URL (the same parameters the bound widgets write), else defaults."""
    ss, qp = st.session_state, st.query_params

    def raw(name: str, widget_key: str | None = None):
        k = widget_key or _k(key, name)
        if k in ss:
            return "state", ss[k]
        for url_key in (k, _k(key, name)):  # a switch's name before it held the method (link_by_old_name)
            if qp.get(url_key) is not None:
                return "url", qp.get(url_key)
        return None, None

    def pick(s: Spec, default, widget_key: str | None = None):
        where, v = raw(s.name, widget_key)
        if where == "state":
            return v
        value = url_value(s, v) if where == "url" else None
        return default if value is None else value

    run_specs = {s.name: s for s in specs(RunConfig)}
    envs = app_envs()
    env_spec = Spec("env", str, False, "cartpole", "", envs, None, None, {e: env_label(e) for e in envs}, False,
                    "", "")
    method_spec = Spec("method", str, False, "bco-alpha", "", tuple(METHODS), None, None,
                       {m: method_label(m) for m in METHODS}, False, "", "")
    env, method = pick(env_spec, "cartpole"), pick(method_spec, "bco-alpha")
    defaults = resolved_defaults(env, method)
    values = {"env": env, "method": method, "seed": pick(run_specs["seed"], 0)}
    if get_method(method).fixed_iterations is None:
        values["iterations"] = pick(run_specs["iterations"], defaults["iterations"], iterations_key(key, env, method))
    for s in _all_specs(method):
        if s.name in values or s.name in NOT_WIDGETS + METHOD_FIELDS or (s.name in MAZE_ONLY_FIELDS
                                                                         and not get_env(env).is_maze):
            continue
        value = pick(s, None if s.advanced else defaults.get(s.name), _widget_key(key, s.name, env, method))
        if isinstance(value, str) and s.kind is tuple:
            value = tuple(int(v) for v in value.split(",") if v.strip()) or None
        if value is not None:
            values[s.name] = value
    return Choice(values)
