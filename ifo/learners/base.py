"""The seam every method plugs into: a learner, the context `Run` builds for it, and its phases.

    Run                          builds the shared context once, steps the learner, evaluates, saves
     └─ Context                  environment pool, T_e (states only), hidden truth, seeds, phase timer
     └─ Learner(context, config) one method family: its configuration, its phases, and
          step(iteration, rng) -> {section: ...}   one press of Step (only its own record sections)
          act(obs, sample, rng) -> (actions, MAP)  the policy, batched, for evaluation and video
          state() / load_state()                   everything that changes, as arrays (checkpoints, undo)

The expert's true actions never reach an IfO learner's data: `Context.expert` holds states
only, and `HiddenTruth` turns the hidden actions into diagnostic numbers for people (accuracy,
confusion) without ever handing the array to the learner. `Context.expert_actions` is set only
for the reference methods that are defined to see them (BC, GAIL).
"""
from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass, field, fields, replace
from typing import Callable, ClassVar, Iterator

import numpy as np
import torch

from ifo.data.demos import ExpertTransitions
from ifo.data.transitions import Transitions, collect_random_transitions, random_transitions_once
from ifo.envs import EnvSpec
from ifo.envs.rollout import EnvPool
from ifo.io import load_module_arrays, load_optimizer_arrays, module_arrays, optimizer_arrays
from ifo.options import check_field, specs
from ifo.seeds import Seeds


@dataclass(frozen=True)
class Phase:
    """One part of a learner's round, as a person watching the progress bar reads it."""

    name: str
    doing: str  # "training the inverse dynamics model (IDM) on I_s"
    box: str  # the box of the loop diagram that lights up meanwhile


class StepCancelled(Exception):
    """Raised between phases when someone cancelled the iteration; the run is rolled back."""


# ----------------------------------------------------------------------------- configuration
@dataclass(frozen=True)
class LearnerConfig:
    """Base of every learner's configuration. Fields left None take the method's preset, then the
    environment's default (`env_defaults`), then the field's own default."""

    def env_defaults(self, spec: EnvSpec) -> dict:
        return {}

    def fixed_iterations(self) -> int | None:
        """A learner that is a single pass says 1; iterative ones say None."""
        return None

    def unused(self) -> set[str]:
        """Fields these settings make irrelevant (greyed out in the app)."""
        return set()

    def follows_iteration_count(self) -> bool:
        """Whether the run's iteration count changes what each iteration does. Then a shorter training is not
        the start of a longer one (`bench recheck` trains such a row's whole count)."""
        return False

    def resolved(self, preset: dict, spec: EnvSpec) -> "LearnerConfig":
        values = {}
        env = self.env_defaults(spec)
        for f in fields(self):
            v = getattr(self, f.name)
            for source in (preset, env):
                if v is None:
                    v = source.get(f.name)
            values[f.name] = tuple(v) if isinstance(v, list) else v
        out = replace(self, **values)
        out.check()
        return out

    def check(self) -> None:
        for s in specs(type(self)):
            check_field(s, getattr(self, s.name))

    def to_dict(self) -> dict:
        return {f.name: (list(v) if isinstance(v := getattr(self, f.name), tuple) else v) for f in fields(self)}

    @classmethod
    def field_names(cls) -> set[str]:
        return {f.name for f in fields(cls)}

    @classmethod
    def branchable(cls) -> set[str]:
        """Settings a run may change in the middle and go on from where it is (a branch): those that
        change neither the networks nor the data collected so far."""
        return set()


# ----------------------------------------------------------------------------- the hidden truth
class HiddenTruth:
    """The expert's true actions, aligned with T_e: shown to people as diagnostics, never trained on.

    Every method returns numbers for a record (or nothing when the demonstrations have no
    actions); the array itself is never handed out.
    """

    def __init__(self, actions: np.ndarray | None, n_actions: int):
        self._actions = None if actions is None else np.asarray(actions, dtype=np.int64)
        self.n_actions = n_actions

    @property
    def available(self) -> bool:
        return self._actions is not None

    def idm_report(self, map_labels: np.ndarray, probs: np.ndarray) -> dict:
        """How the IDM's MAP labels on T_e compare with what the expert really did."""
        if self._actions is None:
            return {}
        a, n = self._actions, self.n_actions
        true_p = probs[np.arange(len(a)), a] if len(a) else np.zeros(0)
        return {"true_counts": np.bincount(a, minlength=n).tolist(),
                "expert_accuracy": float(np.mean(map_labels == a)),
                "confusion": np.bincount(a * n + map_labels, minlength=n * n).reshape(n, -1).tolist(),
                "true_action_probability_histogram": histogram(true_p)}

    def accuracy(self, chosen: np.ndarray) -> dict:
        """{"accuracy": share of `chosen` (labels or actions, one row per pass) equal to the truth}."""
        if self._actions is None:
            return {}
        return {"accuracy": float(np.mean(np.asarray(chosen) == self._actions))}

    def counts(self) -> list[int] | None:
        return None if self._actions is None else np.bincount(self._actions, minlength=self.n_actions).tolist()

    def image_distances(self, pre, pos_states: np.ndarray, pos_actions: np.ndarray, expert_states: np.ndarray) -> dict:
        """Fig 5.3's per-action mean-image distances (they group the expert's frames by true action)."""
        from ifo.probes import action_mean_image_distances

        if self._actions is None:
            return {}
        return {"mean_image_distance": action_mean_image_distances(
            pre.states, pre.actions, pos_states, pos_actions, expert_states, self._actions, self.n_actions)}


def histogram(p: np.ndarray, bins: int = 10) -> list[int]:
    """Counts of probabilities in `bins` equal bins over [0, 1] (1.0 falls in the last)."""
    return np.bincount(np.minimum((np.asarray(p) * bins).astype(np.int64), bins - 1), minlength=bins).tolist()


# ----------------------------------------------------------------------------- the context
@dataclass
class Context:
    """What `Run` builds once and every learner shares."""

    spec: EnvSpec
    config: object  # the resolved RunConfig (shared settings; the learner's own are config.learner)
    pool: EnvPool  # environments for the learner's own runs (I_pre, I_pos, RL); evaluation has its own
    expert: ExpertTransitions  # T_e: the expert's state pairs, no actions
    truth: HiddenTruth  # the hidden actions, as diagnostics only
    seeds: Seeds
    expert_actions: np.ndarray | None = None  # only for methods defined to see them (BC, GAIL)
    expert_returns: np.ndarray | None = None  # the demonstrations' episode returns
    on_phase: Callable[[str], None] | None = None  # Run's progress and cancel check
    seconds: dict = field(default_factory=dict)  # time per phase of the iteration in progress

    @property
    def n_actions(self) -> int:
        return self.spec.n_actions

    @property
    def obs_shape(self) -> tuple[int, ...]:
        return tuple(self.expert.states.shape[1:])

    def require_vector_states(self, method: str, why: str = "") -> None:
        """ValueError in plain words when a method that reads state vectors gets images (the maze)."""
        if len(self.obs_shape) != 1:
            from ifo.config import RunConfig
            from ifo.options import specs

            [setting] = [s for s in specs(RunConfig) if s.name == "obs_mode"]
            raise ValueError(f"{method} learns from vector states{why}; on a maze choose its vector observations "
                             f"(the setting \"{setting.label}\": vector; {setting.flag} vector)")

    def random_transitions(self, size: int, per_action_cap: int,
                           rng: np.random.Generator) -> tuple[Transitions, int]:
        """I_pre: random-policy transitions from the learner's environments, class-balanced, and the
        environment steps they took (`collect_random_transitions`; moves into the maze's walls dropped).
        Collected once per process for the same environments, seed, sizes and `rng` state."""
        key = {"env": self.spec.name, "pool": self.pool.env_kwargs, "batched": self.pool.batched,
               "seed": self.seeds.seed, "size": size, "cap": per_action_cap}
        return random_transitions_once(key, rng, lambda: collect_random_transitions(
            self.pool, self.n_actions, size, per_action_cap, rng,
            seeds=lambda batch, n: self.seeds.episodes("pre", n, batch), drop_unchanged=self.spec.is_maze))

    @contextmanager
    def phase(self, name: str) -> Iterator[None]:
        """Time a phase of the iteration and tell `Run` it started (progress bar, cancel check)."""
        if self.on_phase is not None:
            self.on_phase(name)
        start = time.perf_counter()
        yield
        self.seconds[name] = self.seconds.get(name, 0.0) + time.perf_counter() - start


# ----------------------------------------------------------------------------- the learner
class Learner:
    """Base of the method families. A subclass sets `Config`, `phases` and `diagram`, builds its
    models in `__init__`, and lists what changes in `modules`, `optimizers` and `data_state()`."""

    key: ClassVar[str]  # the name methods use for this family ("bco", "cril", ...)
    Config: ClassVar[type[LearnerConfig]]
    phases: ClassVar[tuple[Phase, ...]]
    diagram: ClassVar[str] = "bco"  # the layout of its loop diagram (ifo/ui/diagram.py LAYOUTS)

    def __init__(self, ctx: Context, config: LearnerConfig):
        self.ctx, self.config = ctx, config
        self.modules: dict[str, torch.nn.Module] = {}
        self.optimizers: dict[str, torch.optim.Optimizer] = {}
        self.dropout_masks = torch.Generator()  # ifo.nets.RunDropout's masks while this learner's step runs

    # -- the round
    def step(self, iteration: int, rng: np.random.Generator) -> dict:
        raise NotImplementedError

    def probabilities(self, obs: np.ndarray) -> np.ndarray:
        """The policy's action probabilities for a batch of observations (n, |A|)."""
        raise NotImplementedError

    def act(self, obs: np.ndarray, sample: bool, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """Actions for a batch of observations (sampled from the policy or MAP) and the MAP actions."""
        from ifo.components.exploration import choose

        return choose(self.probabilities(obs), sample, rng)

    @property
    def policy(self) -> torch.nn.Module:
        """The network that acts (Grad-CAM and probes look at it)."""
        return self.modules["policy"]

    @property
    def draws_global_rng(self) -> bool:
        """Whether a step draws from torch's or numpy's process-wide generators (then it seeds them and
        the run holds ifo.seeds.GLOBAL_RNG while it trains). Families that need them only for dropout say
        so more precisely; the default is the safe answer."""
        return True

    def seed_global_rng(self, rng: np.random.Generator) -> None:
        """Seed torch's process-wide generator from the iteration's stream, if this learner draws from it
        (the stream moves on either way: the same numbers whichever the answer). A learner that does not
        must not touch it: another thread's training may be drawing from it."""
        seed = int(rng.integers(2**31))
        self.dropout_masks.manual_seed(seed)  # the masks torch.manual_seed(seed) gave them when they drew from it
        if self.draws_global_rng:
            torch.manual_seed(seed)

    def active_phases(self) -> list[str]:
        """The phases one iteration goes through with these settings, in order."""
        return [p.name for p in self.phases]

    def finished(self) -> bool:
        """True when the learner's own stop rule says further iterations would not help."""
        return False

    def sizes(self) -> dict:
        """Sizes of the data flowing round, for the loop diagram (|I_pre|, |T_e|, ...)."""
        return {"expert_size": len(self.ctx.expert)}

    # -- everything that changes, as arrays (checkpoints; undoing a failed iteration)
    def data_state(self) -> dict[str, np.ndarray]:
        return {}

    def load_data_state(self, arrays: dict[str, np.ndarray]) -> None:
        pass

    def state(self) -> tuple[dict[str, np.ndarray], dict]:
        arrays, meta = {}, {"optimizers": {}}
        for name, module in self.modules.items():
            arrays.update(module_arrays(name, module))
        for name, opt in self.optimizers.items():
            opt_arrays, meta["optimizers"][name] = optimizer_arrays(f"opt.{name}", opt)
            arrays.update(opt_arrays)
        arrays.update(self.data_state())
        return arrays, meta

    def load_state(self, arrays: dict[str, np.ndarray], meta: dict) -> None:
        for name, module in self.modules.items():
            load_module_arrays(name, module, arrays)
        for name, opt in self.optimizers.items():
            # checkpoints before schema 2 kept each optimizer's groups under "<name>_optimizer"
            groups = meta["optimizers"][name] if "optimizers" in meta else meta[f"{name}_optimizer"]
            load_optimizer_arrays(f"opt.{name}", opt, arrays, groups)
        self.load_data_state(arrays)
