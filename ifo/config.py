"""A run's configuration: every ablation switch is a plain field.

Fields left as None take the method's default (its components) and then the
environment's default (sizes and learning rates that suit it), so
`RunConfig(env="cartpole", method="iupe")` is a sensible run.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace

from ifo.components.sampling import SAMPLING_MODES
from ifo.envs import get_env
from ifo.methods import get_method
from ifo.nets import ATTENTION_KINDS

# Sizes per environment. I_pre sizes follow the authors' code (|A| x 5,000 capped per
# class; CartPole 10k, Acrobot/MountainCar 15k); iteration counts are kept short
# enough for a class, the thesis ran 100.
ENV_DEFAULTS: dict[str, dict] = {
    "cartpole": dict(pre_size=10_000, iterations=10, expert_episodes=10, episodes_per_iteration=50, lr=3e-3),
    "acrobot": dict(pre_size=15_000, iterations=15, expert_episodes=10, episodes_per_iteration=50, lr=3e-3),
    "mountaincar": dict(pre_size=15_000, iterations=20, expert_episodes=10, episodes_per_iteration=50, lr=3e-3),
    "lunarlander": dict(pre_size=20_000, iterations=20, expert_episodes=20, episodes_per_iteration=50, lr=1e-3),
    # mazes: images through a CNN cost ~100x a vector MLP, so fewer gradient steps per
    # iteration, and training runs stop after 4 x cells steps (evaluation keeps 1,000)
    "maze3": dict(pre_size=4_000, iterations=15, expert_episodes=100, episodes_per_iteration=50, lr=1e-3,
                  idm_epochs=1, policy_epochs=5, rollout_max_steps=36),
    "maze5": dict(pre_size=6_000, iterations=15, expert_episodes=100, episodes_per_iteration=50, lr=1e-3,
                  idm_epochs=1, policy_epochs=5, rollout_max_steps=100),
    "maze10": dict(pre_size=10_000, iterations=20, expert_episodes=100, episodes_per_iteration=50, lr=1e-3,
                   idm_epochs=1, policy_epochs=5, rollout_max_steps=400),
}
COMMON_DEFAULTS = dict(idm_epochs=2, policy_epochs=10)


@dataclass(frozen=True)
class RunConfig:
    env: str = "cartpole"
    method: str = "bco-alpha"
    seed: int = 0
    iterations: int | None = None  # alpha: how many presses of Step make a full run
    expert_episodes: int | None = None  # how many demonstration episodes T_e holds
    pre_size: int | None = None  # |I_pre| before the 70/30 split
    pre_per_action_cap: int = 5_000
    episodes_per_iteration: int | None = None  # |E|
    eval_episodes: int = 100
    idm_epochs: int | None = None
    policy_epochs: int | None = None
    batch_size: int = 128
    lr: float | None = None
    hidden: tuple[int, ...] = (32, 32)
    # components (None: the method's choice)
    attention: str | None = None
    sampling: str | None = None
    explore_labels: bool | None = None
    explore_rollouts: bool | None = None
    eval_explore: bool = False  # measure AER with sampled (True) or MAP (False) actions
    # data
    demos: str | None = None  # a user's .npz demonstrations instead of the shipped ones
    obs_mode: str = "image"  # maze only: "image" or "vector"
    image_size: int = 32  # maze only
    rollout_max_steps: int | None = None  # maze: step limit of training runs (I_pre, I_pos)
    deadlock_guard: bool = False  # maze evaluation: end on the 4th visit to a cell with return -1
    # maze evaluation layouts: "held-out" (never seen in demonstrations), or "demonstration":
    # the layouts the demonstrations came from, as the thesis authors evaluated
    maze_eval_layouts: str = "held-out"
    attention_probes: bool = True  # maze images: Grad-CAM maps and mean-image distances each iteration

    def resolved(self) -> "RunConfig":
        """A copy with every None filled in, after checking every value."""
        spec = get_env(self.env)
        method = get_method(self.method)
        env_defaults = ENV_DEFAULTS[spec.name]
        values = {}
        for f in fields(self):
            v = getattr(self, f.name)
            if v is None and f.name in method.components:
                v = method.components[f.name]
            if v is None and f.name in env_defaults:
                v = env_defaults[f.name]
            if v is None and f.name in COMMON_DEFAULTS:
                v = COMMON_DEFAULTS[f.name]
            values[f.name] = v
        values["env"], values["method"] = spec.name, method.name
        values["hidden"] = tuple(int(h) for h in values["hidden"])
        if not method.iterative:
            values["iterations"] = 1
        cfg = replace(self, **values)
        cfg.validate()
        return cfg

    def validate(self) -> None:
        positive = ["iterations", "expert_episodes", "pre_size", "episodes_per_iteration", "eval_episodes",
                    "idm_epochs", "policy_epochs", "batch_size", "pre_per_action_cap", "image_size", "rollout_max_steps"]
        for name in positive:
            v = getattr(self, name)
            if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < 1):
                raise ValueError(f"{name} must be a whole number >= 1, got {v!r}")
        if self.lr is not None and not (0 < self.lr < 10):
            raise ValueError(f"lr must be between 0 and 10, got {self.lr!r}")
        if self.attention is not None and self.attention not in ATTENTION_KINDS:
            raise ValueError(f"attention must be one of {ATTENTION_KINDS}, got {self.attention!r}")
        if self.sampling is not None and self.sampling not in SAMPLING_MODES:
            raise ValueError(f"sampling must be one of {SAMPLING_MODES}, got {self.sampling!r}")
        if self.obs_mode not in ("image", "vector"):
            raise ValueError(f"obs_mode must be 'image' or 'vector', got {self.obs_mode!r}")
        if self.maze_eval_layouts not in ("held-out", "demonstration"):
            raise ValueError(f"maze_eval_layouts must be 'held-out' or 'demonstration', got {self.maze_eval_layouts!r}")
        if not 16 <= self.image_size <= 256:
            raise ValueError(f"image_size must be between 16 and 256, got {self.image_size}")
        if any(h < 1 for h in self.hidden) or not self.hidden:
            raise ValueError(f"hidden must list positive layer widths, got {self.hidden!r}")
        if self.iterations is not None and self.iterations > 10_000:
            raise ValueError(f"iterations must be at most 10000, got {self.iterations}")

    def to_dict(self) -> dict:
        d = asdict(self)
        d["hidden"] = list(self.hidden)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "RunConfig":
        known = {f.name for f in fields(cls)}
        unknown = set(d) - known
        if unknown:
            raise ValueError(f"unknown configuration field(s): {', '.join(sorted(unknown))}")
        d = dict(d)
        if "hidden" in d:
            d["hidden"] = tuple(d["hidden"])
        return cls(**d)
