"""A run's configuration: the shared settings of `Run` plus the learner's own configuration.

    RunConfig(env="cartpole", method="iupe")                       a sensible run: defaults everywhere
    RunConfig(env="cartpole", method="iupe", learner=BCOConfig(pre_size=300))
    RunConfig.from_dict({"env": "cartpole", "method": "iupe", "pre_size": 300})   the same, flat

Fields left None take the method's choice, then the environment's default. Every field is
declared once with `ifo.options.option` (help, bounds), so the command line's flags and the
app's widgets are generated from these classes and checked by the same rules.
"""
from __future__ import annotations

from dataclasses import dataclass, fields, replace

from ifo.envs import ENV_NAMES, get_env
from ifo.learners.base import LearnerConfig
from ifo.methods import get_method
from ifo.options import check_field, option, specs

# Per environment: iteration counts short enough for a class (the thesis ran 100), the number of
# demonstrations, and the maze's step limit for training runs (I_pre, I_pos; evaluation keeps 1,000).
ENV_DEFAULTS: dict[str, dict] = {
    "cartpole": dict(iterations=10, expert_episodes=10),
    "acrobot": dict(iterations=15, expert_episodes=10),
    "mountaincar": dict(iterations=20, expert_episodes=10),
    "lunarlander": dict(iterations=20, expert_episodes=20),
    "maze3": dict(iterations=15, expert_episodes=100, rollout_max_steps=36),
    "maze5": dict(iterations=15, expert_episodes=100, rollout_max_steps=100),
    "maze10": dict(iterations=20, expert_episodes=100, rollout_max_steps=400),
}
REGISTERED_ENV_DEFAULTS = dict(iterations=10)  # a researcher's own environment: every demonstration they bring
MAX_SEED = 2**32 - 1
CONFIG_SCHEMA = 2  # 1: one flat dict (before learners had their own configuration)


# maze-only evaluation settings, drawn only for mazes (obs_mode and the like are advanced settings)
MAZE_EVALUATION_FIELDS = ("maze_eval_layouts", "deadlock_guard")
# every setting only a maze reads: on another task they take their defaults, so they never make another run
MAZE_ONLY_FIELDS = MAZE_EVALUATION_FIELDS + ("obs_mode", "image_size", "rollout_max_steps", "attention_probes")


@dataclass(frozen=True)
class RunConfig:
    env: str = option("cartpole", f"the task the expert demonstrated: one of {', '.join(ENV_NAMES)}, a "
                                  "gymnasium id, or your own as module:name (ifo.envs.register_env)",
                      title="Environment")
    method: str = option("bco-alpha", "the method (see `ifo.methods`)", title="Method")
    seed: int = option(0, "same seed, same numbers", low=0, high=MAX_SEED, title="Seed")
    iterations: int | None = option(None, "α: how many presses of Step make a full run", low=1, high=10_000,
                                    title="Iterations in the run")
    expert_episodes: int | None = option(None, "how many demonstration episodes T_e holds", low=1, high=100_000,
                                         advanced=True, work=1)
    expert_level: int = option(1, "which expert demonstrated (thesis Table 7.1): 1 the best .. 5 the worst; "
                                  "Performance is then measured against that expert's AER (control tasks only)",
                               low=1, high=5, advanced=True, title="Expert level")
    eval_episodes: int = option(100, "evaluation episodes per iteration (held-out seeds or maze layouts)", low=1,
                                high=10_000, advanced=True, work=1)
    eval_explore: bool = option(False, "measure AER with actions sampled from the policy's softmax instead of "
                                       "the MAP action (the thesis measured IUPE so)", title="Measure AER with",
                                widget="radio",
                                labels={False: "MAP actions (the most likely)", True: "actions sampled from π"})
    demos: str | None = option(None, "your own demonstrations (.npz: obs, rewards, episode_starts[, actions])",
                               advanced=True)
    obs_mode: str = option("image", "maze observations: images, or a vector of the agent's cell and the walls",
                           choices=("image", "vector"), advanced=True, title="Maze observations")
    image_size: int = option(32, "maze image side in pixels", low=16, high=256, advanced=True, work=2)
    rollout_max_steps: int | None = option(None, "maze: step limit of the learner's own runs (I_pre, I_pos)",
                                           low=1, high=100_000, advanced=True, work=1)
    deadlock_guard: bool = option(True, "maze evaluation ends an episode on the 4th visit to a cell with "
                                        "return -1 (the thesis's evaluation); off, a lost agent wanders to the "
                                        "1,000-step limit", title="Deadlock guard")
    maze_eval_layouts: str = option("held-out", "maze: evaluate on held-out layouts, or live in the "
                                                "demonstrations' layouts (the thesis authors' protocol)",
                                    choices=("held-out", "demonstration"), title="Evaluate on", widget="radio",
                                    labels={"held-out": "100 layouts it never saw",
                                            "demonstration": "the demonstrations' layouts (thesis)"})
    attention_probes: bool = option(True, "maze images: Grad-CAM maps and mean-image distances each iteration",
                                    advanced=True)
    learner: LearnerConfig | None = None  # the method family's own settings (None: all its defaults)

    # ------------------------------------------------------------------ resolving
    @property
    def learner_config_class(self) -> type[LearnerConfig]:
        return get_method(self.method).learner_class.Config

    def resolved(self) -> "RunConfig":
        """A copy with every None filled in, after checking every value (ValueError in plain words)."""
        spec = get_env(self.env)
        method = get_method(self.method)
        cls = method.learner_class.Config
        learner = self.learner if self.learner is not None else cls()
        if not isinstance(learner, cls):
            raise ValueError(f"{method.title} takes a {cls.__name__}, not a {type(learner).__name__}")
        learner = learner.resolved(method.preset, spec)
        values = {}
        for s in specs(RunConfig):
            v = getattr(self, s.name)
            for source in (method.run_defaults, ENV_DEFAULTS.get(spec.settings_name, REGISTERED_ENV_DEFAULTS)):
                if v is None:
                    v = source.get(s.name)
            values[s.name] = v
        values["env"], values["method"] = spec.name, method.name
        if not spec.is_maze:  # settings that only a maze reads take their defaults: they do not make another run
            values.update({name: getattr(RunConfig, name) for name in MAZE_ONLY_FIELDS})
        if learner.fixed_iterations() is not None:
            values["iterations"] = learner.fixed_iterations()
        cfg = replace(self, **values, learner=learner)
        cfg.check()
        return cfg

    def check(self) -> None:
        for s in specs(RunConfig):
            check_field(s, getattr(self, s.name))
        if self.learner is not None:
            self.learner.check()

    # ------------------------------------------------------------------ flat views (CLI, widgets, files)
    def flat(self) -> dict:
        """Every setting in one dict: the run's and the learner's (names never collide)."""
        out = {s.name: getattr(self, s.name) for s in specs(RunConfig)}
        if self.learner is not None:
            out.update({f.name: getattr(self.learner, f.name) for f in fields(self.learner)})
        return out

    def with_values(self, **values) -> "RunConfig":
        """A copy with some settings changed, run's and learner's alike (flat names)."""
        return RunConfig.from_dict({**self.flat(), **values})

    def to_dict(self) -> dict:
        d = {s.name: getattr(self, s.name) for s in specs(RunConfig)}
        d["learner"] = None if self.learner is None else self.learner.to_dict()
        d["schema"] = CONFIG_SCHEMA
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "RunConfig":
        """From `to_dict()`'s form, or from one flat dict of settings (the learner's among them)."""
        d = dict(d)
        d.pop("schema", None)
        nested = d.pop("learner", None) or {}
        if not isinstance(nested, dict):
            raise ValueError(f"'learner' must be a dict of settings, got {type(nested).__name__}")
        run_names = {s.name for s in specs(cls)}
        method = get_method(str(d.get("method", cls.method)))
        learner_cls = method.learner_class.Config
        flat_learner = {k: d.pop(k) for k in list(d) if k not in run_names and k in learner_cls.field_names()}
        unknown = set(d) - run_names
        unknown |= set(nested) - learner_cls.field_names()
        if unknown:
            raise ValueError(f"unknown configuration field(s): {', '.join(sorted(unknown))}")
        values = {**nested, **flat_learner}
        if isinstance(values.get("hidden"), list):
            values["hidden"] = tuple(values["hidden"])
        return cls(**d, learner=learner_cls(**values))


# ----------------------------------------------------------------------------- names people read
def switch_specs(learner_config_class) -> list:
    """A learner configuration's switches (its settings that are not sizes): what makes one method another."""
    return [s for s in specs(learner_config_class) if not s.advanced]


def switches(config: RunConfig) -> dict:
    """The learner's switches and their values."""
    learner = config.learner if config.learner is not None else config.learner_config_class()
    return {s.name: getattr(learner, s.name) for s in switch_specs(type(learner))}


def configuration_label(config: RunConfig) -> str:
    """A configuration's name: its method's title when the switches are the method's; another method's
    title when they are that method's (BCO(α) with ABCO's switches is ABCO); else the method with what
    differs spelled out ("BCO(α) + sampling iupe + explore labels")."""
    from ifo.methods import METHODS

    cfg = config.resolved()
    mine, method = switches(cfg), get_method(cfg.method)
    same_family = [m for m in METHODS.values() if m.learner == method.learner and
                   m.fixed_iterations == method.fixed_iterations and m.sees_expert_actions == method.sees_expert_actions]
    for m in [method] + same_family:
        if switches(replace(cfg, method=m.name, learner=None).resolved()) == mine:
            return m.title
    preset = switches(replace(cfg, learner=None).resolved())
    changed = []
    for s in specs(type(cfg.learner)):
        if s.name in mine and mine[s.name] != preset[s.name]:
            value, name = mine[s.name], s.name.replace("_", " ")
            changed.append(f"{'' if value else 'no '}{name}" if isinstance(value, bool) else f"{name} {value}")
    return f"{method.title} + " + " + ".join(changed)
