"""The run: builds the shared context once, then steps a learner iteration by iteration.

    run = Run(RunConfig(env="cartpole", method="iupe"))
    record = run.step()      # one learner round + evaluation: plain numbers and lists
    run.save("runs/demo")    # atomic; run = Run.load("runs/demo") continues exactly

`Run` knows nothing about any method: the learner (ifo/learners/) does its round and
returns its own record sections; `Run` adds the evaluation (AER Eq 4.1, Performance Eq 4.2,
trajectory fidelity), the timings and the iteration number. An iteration is all or nothing:
if it fails or is cancelled, the learner is put back exactly as it was before the Step.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager, nullcontext
from dataclasses import replace
from pathlib import Path
from typing import Callable, Iterator

import numpy as np
import torch

from ifo import records as record_schema
from ifo.config import RunConfig
from ifo.data.demos import Demonstrations, load_demonstrations
from ifo.data.shipped import load_shipped_demonstrations
from ifo.envs import get_env
from ifo.envs.rollout import EnvPool, Rollouts, run_episodes
from ifo.io import load_module_arrays, module_arrays
from ifo.iteration_cache import Entry, IterationCache, lineage_next, lineage_start, wait_or_compute
from ifo.learners.base import Context, HiddenTruth, StepCancelled
from ifo.methods import get_method
from ifo.nets import dropout_masks_from
from ifo.metrics import aer, performance, trajectory_fidelity
from ifo.probes import policy_map_record
from ifo.runtime import limit_threads
from ifo.seeds import GLOBAL_RNG, Seeds, evaluation_seeds

Progress = Callable[[str, int], None]  # (phase name, iteration) -> None
DEMONSTRATION_LAYOUTS = 100  # the shipped maze demonstrations come from the training pool's first 100 layouts
EVALUATE = "evaluate"
REMOTE = "remote"  # the progress phase of an iteration that trains on a Ray worker (ifo.remote)
HISTORY = "history"  # checkpoint arrays "history.<iteration>.<weight>": the policy after each iteration


class RunFinished(RuntimeError):
    pass


class Run:
    def __init__(self, config: RunConfig, demos: Demonstrations | None = None, progress: Progress | None = None,
                 cache: IterationCache | None = None, trainer=None):
        limit_threads()  # one torch thread unless IFO_TORCH_THREADS says otherwise (see ifo.runtime)
        self.config = cfg = config.resolved()
        self.spec = spec = get_env(cfg.env)
        self.method = get_method(cfg.method)
        self.progress = progress
        self._cancel = threading.Event()
        seeds = Seeds(cfg.seed)
        self.pool, self.eval_pool = self._pools()

        # T_e: expert state pairs. The true actions stay in HiddenTruth (diagnostics) unless the
        # method is one that is defined to learn from them (BC, GAIL).
        if demos is None:
            demos = (load_demonstrations(cfg.demos, spec, self._obs_shape(),
                                         require_actions=self.method.sees_expert_actions)
                     if cfg.demos else load_shipped_demonstrations(spec, cfg.obs_mode, cfg.image_size,
                                                                   cfg.expert_episodes))
        if cfg.expert_episodes is None:  # a registered environment: all the demonstrations brought
            self.config = cfg = replace(cfg, expert_episodes=demos.n_episodes)
        if demos.n_episodes < cfg.expert_episodes:
            if config.expert_episodes is not None:  # asked for explicitly: say it cannot be had
                raise ValueError(f"expert_episodes is {config.expert_episodes}, but the demonstrations hold only "
                                 f"{demos.n_episodes} episode(s)")
            self.config = cfg = replace(cfg, expert_episodes=demos.n_episodes)  # record what is used
        self.demos = demos.first_episodes(cfg.expert_episodes)
        self.references = self._references()
        self.ctx = Context(spec, cfg, self.pool, self.demos.transitions,
                           HiddenTruth(self.demos.hidden_actions, spec.n_actions), seeds,
                           expert_actions=self.demos.hidden_actions if self.method.sees_expert_actions else None,
                           expert_returns=self.demos.episode_returns, on_phase=self._on_phase)
        with GLOBAL_RNG:  # another session's training must not draw from the generator in between
            torch.manual_seed(seeds.torch_seed("init"))  # the networks' initial weights
            self.learner = self.method.learner_class(self.ctx, cfg.learner)
        self.records: list[dict] = []
        self.last_evaluation: Rollouts | None = None
        self.parent: str | None = None  # the checkpoint this run was loaded from or last saved as
        self.policy_history: dict[int, dict[str, np.ndarray]] = {}  # iteration -> the policy's weights then
        # shared iterations (ifo.iteration_cache): the key of this run's state; None: nothing shared
        # (a user's own demonstrations are not part of the key, so such runs never share)
        self.cache = cache
        self.lineage: str | None = None if cfg.demos or spec.registered else lineage_start(self._identity())
        self.last_step_cached = False
        # where iterations train: None here; an ifo.remote.RemoteTrainer sends them to Ray workers
        # (never a run on a user's own demonstrations: lineage None, the file stays here)
        self.trainer = trainer

    # ------------------------------------------------------------------ the shared context
    def _pools(self) -> tuple[EnvPool, EnvPool]:
        """Environments for the learner's own runs, and for evaluation.

        Maze worlds. Held-out: the learner's runs (I_pre, I_pos) on the training layouts, evaluation
        on layouts never seen. Demonstration (the thesis authors' world): the demonstrations'
        layouts are the only ones, for I_pre, training runs and evaluation alike."""
        cfg, spec = self.config, self.spec
        if not spec.is_maze:
            return EnvPool(spec), EnvPool(spec)
        maze = {"obs_mode": cfg.obs_mode, "image_size": cfg.image_size}
        if cfg.maze_eval_layouts == "demonstration":
            maze["n_layouts"] = DEMONSTRATION_LAYOUTS
        eval_split = "eval" if cfg.maze_eval_layouts == "held-out" else "train"
        return (EnvPool(spec, **maze, split="train", max_steps=cfg.rollout_max_steps),
                EnvPool(spec, **maze, split=eval_split, deadlock_guard=cfg.deadlock_guard))

    def _obs_shape(self) -> tuple[int, ...]:
        return tuple(self.pool.envs(1)[0].observation_space.shape)

    def _references(self) -> dict:
        """Random and expert returns that Performance normalises by (per eval episode for the maze)."""
        refs = self.spec.references()
        n = self.config.eval_episodes
        key = "per_layout" if self.config.maze_eval_layouts == "held-out" else "per_layout_demonstration"
        if self.spec.is_maze and key in refs:
            layouts = refs[key]
            idx = np.arange(n) % len(layouts["expert"])
            return {"random": np.asarray(layouts["random"])[idx], "expert": np.asarray(layouts["expert"])[idx],
                    "random_aer": refs.get("random_aer"), "expert_aer": refs.get("expert_aer")}
        expert = refs.get("expert_aer")
        if self.config.demos or expert is None:  # a user's demonstrator (no expert ships): what it achieved
            expert = float(np.mean(self.demos.episode_returns))
        return {"random": refs.get("random_aer"), "expert": expert,
                "random_aer": refs.get("random_aer"), "expert_aer": expert}

    def _reference_policy(self):
        """The shipped expert network (a stable-baselines3 DQN on MountainCar): pi* of Table 8.1."""
        if not hasattr(self, "_reference"):
            from ifo.experts import load_expert

            try:
                self._reference = load_expert(self.spec)
            except FileNotFoundError:
                self._reference = None
        return self._reference

    # ------------------------------------------------------------------ what people see of it
    @property
    def expert(self):
        """T_e: the expert's state pairs."""
        return self.ctx.expert

    @property
    def policy(self) -> torch.nn.Module:
        return self.learner.policy

    def phases(self) -> list[str]:
        """The phases one iteration of this run goes through, in order (for progress displays)."""
        return self.learner.active_phases() + [EVALUATE]

    def phase_text(self, name: str) -> str:
        """What a phase does, in plain words."""
        for p in self.learner.phases:
            if p.name == name:
                return p.doing
        if name == REMOTE:
            return "training the whole iteration on a Ray worker"
        return "measuring the policy: AER and Performance" if name == EVALUATE else name

    @property
    def iteration(self) -> int:
        return len(self.records)

    @property
    def finished(self) -> bool:
        return self.iteration >= self.config.iterations or self.learner.finished()

    def set_iterations(self, n: int) -> None:
        """Change how many iterations the full run has (never below the ones already done)."""
        if not isinstance(n, int) or n < max(1, self.iteration):
            raise ValueError(f"iterations must be a whole number >= {max(1, self.iteration)}, got {n!r}")
        fixed = self.config.learner.fixed_iterations()
        if fixed is not None and n != fixed:
            raise ValueError(f"{self.method.title} is a single pass: it has exactly {fixed} iteration")
        self.config = replace(self.config, iterations=n)

    # ------------------------------------------------------------------ the loop
    def cancel(self) -> None:
        """Ask the iteration in progress (in another thread) to stop at its next phase; it is undone."""
        self._cancel.set()

    def _on_phase(self, name: str) -> None:
        if self._cancel.is_set():
            raise StepCancelled("the iteration was cancelled")
        if self.progress is not None:
            self.progress(name, self.iteration + 1)

    def _identity(self) -> dict:
        """What makes one iteration of this run what it is: every setting but the number of iterations."""
        return {**self.config.to_dict(), "iterations": None}

    def step(self) -> dict:
        """Run one iteration and return its record. All or nothing: on any error (or a cancel) the
        learner and the run are left exactly as they were, so a retry gives the same numbers. With a
        cache, an iteration another session already computed (same lineage) is loaded, not trained."""
        if self.finished:
            raise RunFinished(f"the run has done all {self.config.iterations} iterations")
        self.last_step_cached = False
        if self.lineage is None:  # a user's own demonstrations: never shared, never sent away
            return self._train_step()
        key = self.next_key()
        remote = self.trainer is not None
        if self.cache is None and not remote:  # nothing to share: no entry to build
            record = self._train_step()
            self.lineage = key  # a run saved now and opened with a cache must not take another's past
            return record
        compute = self._trained_remotely if remote else self._trained_here
        if self.cache is None:
            entry, computed = compute(), True
        else:
            entry, computed = wait_or_compute(self.cache, key, compute)
        if remote or not computed:  # a worker's iteration, or another session's: take its result
            self._take(entry)
            self.last_step_cached = not computed
        self.lineage = key
        return self.records[-1]

    def next_key(self) -> str:
        """The iteration cache's key of the state after the next iteration (ifo.iteration_cache)."""
        return lineage_next(self.lineage, self._identity(), self.iteration + 1)

    def _trained_here(self) -> Entry:
        return self._entry(self._train_step())

    def train_from(self, iteration: int, arrays: dict, meta: dict) -> Entry:
        """Iteration `iteration + 1` trained from the learner state (arrays, meta) it had after `iteration`,
        as a cache entry: what a Ray worker does for another process's run (ifo.remote). An iteration needs
        only that state and its number (its random stream); this run's own past records are dropped."""
        self.learner.load_state(arrays, meta)
        self.records = [{}] * iteration
        self.policy_history = {}
        return self._trained_here()

    def _trained_remotely(self) -> Entry:
        """The next iteration from the trainer's worker; this run is not changed (the caller takes it)."""
        self._cancel.clear()
        self._on_phase(REMOTE)
        return self.trainer.train(self)

    @property
    def cancel_requested(self) -> bool:
        return self._cancel.is_set()

    def step_if_cached(self) -> dict | None:
        """The next iteration if another session already computed it (no waiting, no training), else None."""
        if self.cache is None or self.lineage is None or self.finished:
            return None
        key = self.next_key()
        entry = self.cache.get(key)
        if entry is None:
            return None
        self._take(entry)
        self.lineage = key
        return self.records[-1]

    def _take(self, entry: Entry) -> None:
        self.learner.load_state({k[len("learner."):]: v for k, v in entry.arrays.items() if k.startswith("learner.")},
                                entry.meta)
        self.records.append(entry.record)
        self.policy_history[self.iteration] = {k: v for k, v in entry.arrays.items() if k.startswith(HISTORY)}
        self.last_step_cached = True

    def _entry(self, record: dict):
        arrays, meta = self.learner.state()
        return Entry({**{f"learner.{k}": v for k, v in arrays.items()}, **self.policy_history[self.iteration]},
                     meta, record)

    def _train_step(self) -> dict:
        i = self.iteration
        self._cancel.clear()
        rng = self.ctx.seeds.rng("iteration", i)
        before = self.learner.state(), dict(self.learner.__dict__), self.last_evaluation
        self.ctx.seconds = seconds = {}
        try:
            with GLOBAL_RNG if self.learner.draws_global_rng else nullcontext(), \
                    dropout_masks_from(self.learner.dropout_masks):
                sections = self.learner.step(i, rng)
            with self.ctx.phase(EVALUATE):
                evaluation = self.evaluate(self.config.eval_explore, rng)
                if self.spec.policy_map_axes:  # Figs 8.2, 8.3: the policy over the state space, for every method
                    sections["policy_map"] = policy_map_record(self.learner.probabilities, self.spec.policy_map_axes,
                                                               self._reference_policy())
        except BaseException:
            (arrays, meta), attributes, self.last_evaluation = before
            self.learner.load_state(arrays, meta)  # what it changed in place (weights, optimisers)
            self.learner.__dict__.update(attributes)  # what it reassigned (I_s, its last runs, ...)
            raise
        finally:
            self._cancel.clear()
        seconds["total"] = sum(seconds.values())
        record = record_schema.check({"iteration": i + 1, "schema": record_schema.SCHEMA, **sections,
                                      "evaluation": evaluation, "seconds": seconds})
        self.records.append(record)
        self.policy_history[i + 1] = module_arrays(HISTORY, self.learner.policy)  # to replay any iteration later
        return record

    @contextmanager
    def policy_at(self, iteration: int) -> Iterator[None]:
        """The policy as it was after `iteration` while the block runs (a video of a past iteration);
        then the current one again. Never while the run trains (the caller holds its lock)."""
        if iteration not in self.policy_history:
            raise KeyError(f"no policy kept for iteration {iteration}")
        now = module_arrays(HISTORY, self.learner.policy)
        load_module_arrays(HISTORY, self.learner.policy, self.policy_history[iteration])
        try:
            yield
        finally:
            load_module_arrays(HISTORY, self.learner.policy, now)

    def branch(self, **changes) -> "Run":
        """A new run that continues this one from its current iteration with some settings changed (a
        switch such as sampling or exploration): the same I_pre, the same models and records so far.
        Only the learner's `branchable` settings (and the run's iterations and eval_explore) may change."""
        allowed = self.learner.Config.branchable() | {"iterations", "eval_explore"}
        refused = set(changes) - allowed
        if refused:
            raise ValueError(f"{', '.join(sorted(refused))} change the networks or the data: start a new run instead")
        branch = Run(self.config.with_values(**changes), demos=self.demos)
        arrays, meta = self.learner.state()
        branch.learner.load_state(arrays, meta)
        branch.records = [dict(r) for r in self.records]
        branch.policy_history = dict(self.policy_history)
        branch.lineage, branch.cache = self.lineage, self.cache  # the same past; its next steps differ
        branch.trainer = self.trainer
        return branch

    def evaluate(self, explore: bool = False, rng: np.random.Generator | None = None) -> dict:
        """AER, Performance and fidelity of the current policy on the evaluation episodes,
        with MAP actions or with actions sampled from its softmax (`explore`)."""
        cfg = self.config
        rng = rng if rng is not None else self.ctx.seeds.rng("evaluation", self.iteration)
        ro = run_episodes(self.eval_pool, lambda obs: self.learner.act(obs, explore, rng),
                          evaluation_seeds(cfg.eval_episodes, self.spec.is_maze),
                          skip_cycles=self.spec.deterministic and not explore and not cfg.deadlock_guard)
        self.last_evaluation = ro
        returns = ro.returns
        refs = self.references
        perf = None
        if refs.get("random") is not None and refs.get("expert") is not None:
            perf = performance(returns, refs["random"], refs["expert"])
        return {
            "aer": aer(returns), "aer_std": float(returns.std()), "performance": perf,
            "returns": returns.tolist(), "goal_rate": float(ro.goals.mean()),
            "mean_length": float(ro.lengths.mean()), "sampled_actions": bool(explore),
            "fidelity": trajectory_fidelity(ro.states, self.expert.states, seed=cfg.seed),
            "random_reference": refs.get("random_aer"), "expert_reference": refs.get("expert_aer"),
        }

    def run(self, iterations: int | None = None) -> list[dict]:
        n = self.config.iterations - self.iteration if iterations is None else iterations
        for _ in range(n):
            if self.finished:
                break
            self.step()
        return self.records

    def act(self, obs: np.ndarray, sample: bool = False, rng: np.random.Generator | None = None):
        """Actions for a batch of observations (video, people playing with the policy)."""
        return self.learner.act(obs, sample, rng or np.random.default_rng(0))[0]

    # ------------------------------------------------------------------ saving
    def save(self, directory: str | Path, overwrite: bool = False) -> Path:
        """Save configuration, records and the learner's state as a new checkpoint of `directory`
        (atomic, locked; see ifo.checkpoint). Refuses when another session saved this run folder
        since this run last saw it (`checkpoint.RunChanged`), unless `overwrite`."""
        from ifo import checkpoint

        arrays, meta = self.learner.state()
        for it, weights in self.policy_history.items():
            arrays.update({f"{HISTORY}.{it}.{k[len(HISTORY) + 1:]}": v for k, v in weights.items()})
        meta = {**meta, "iteration": self.iteration, "schema": record_schema.SCHEMA, "lineage": self.lineage}
        self.parent = checkpoint.save(directory, config=self.config.to_dict(), records=self.records, arrays=arrays,
                                      meta=meta, parent=self.parent, overwrite=overwrite,
                                      demos_source=Path(self.config.demos) if self.config.demos else None)
        return Path(directory)

    @classmethod
    def load(cls, directory: str | Path, progress: Progress | None = None,
             cache: IterationCache | None = None, trainer=None) -> "Run":
        from ifo import checkpoint

        directory = Path(directory)
        ckpt = checkpoint.load(directory)
        cfg = RunConfig.from_dict(ckpt.config)
        if cfg.demos:
            cfg = replace(cfg, demos=str(directory / checkpoint.DEMOS_FILE))
        run = cls(cfg, progress=progress, cache=cache, trainer=trainer)
        run.learner.load_state(ckpt.arrays, ckpt.meta)
        run.lineage = ckpt.meta.get("lineage") if not cfg.demos else None  # (runs saved before it: no sharing)
        run.records = [record_schema.upgrade(r) for r in ckpt.records]
        for key, value in ckpt.arrays.items():  # saved runs before the history kept only the latest policy
            if key.startswith(HISTORY + "."):
                it, name = key[len(HISTORY) + 1:].split(".", 1)
                run.policy_history.setdefault(int(it), {})[f"{HISTORY}.{name}"] = value
        run.parent = ckpt.name
        return run
