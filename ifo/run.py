"""The run: one object that steps a method through the BCO loop, iteration by iteration.

    I_pre <- random-policy transitions (s, a, s')               # self-supervision
    T_e   <- expert state pairs (s, s')                         # NO actions
    I_s   <- I_pre
    repeat (one iteration = one `step()`):
        M(a | s, s')  trained on I_s                           # Eq 5.1
        a_hat <- label(M, T_e)        MAP, or sampled (exploration, Sec 6.2; a fresh draw per epoch)
        pi(a | s)     trained on (s_e, a_hat)                  # Eq 5.2
        I_pos, v_e <- run pi |E| times, MAP or sampled; v_e = goal reached
        I_s <- sample(I_pre, I_pos, v_e)      none | abco | abco-whole | iupe  (Eqs 5.3-5.5, Sec 6.1)
        evaluate pi: AER (Eq 4.1), Performance (Eq 4.2), fidelity

`step()` returns the iteration's record: plain numbers and lists, no figures.
"""
from __future__ import annotations

import shutil
import time
import uuid
from contextlib import contextmanager
from dataclasses import replace
from pathlib import Path
from typing import Callable

import numpy as np
import torch

from ifo.components.exploration import choose, exploration_rate, label_passes
from ifo.components.learning import fit, make_optimizer, predict_proba
from ifo.components.sampling import build_training_set
from ifo.config import RunConfig
from ifo.data.demos import Demonstrations, load_demonstrations
from ifo.data.shipped import load_shipped_demonstrations
from ifo.data.transitions import PreDemonstrations, Transitions, collect_random_transitions, stratified_split
from ifo.envs import get_env
from ifo.envs.rollout import EnvPool, Rollouts, run_episodes
from ifo.io import (atomic_write_json, atomic_write_text, load_module_arrays, load_optimizer_arrays,
                    module_arrays, npz_bytes, optimizer_arrays, atomic_write_bytes)
from ifo.methods import get_method
from ifo.metrics import aer, performance, trajectory_fidelity
from ifo.nets import InverseDynamics, Policy, feature_attention_map
from ifo.probes import action_mean_image_distances, grad_cam_probe_record

Progress = Callable[[str, int], None]  # (phase name, iteration) -> None
EVAL_SEED_BASE = 1_000_000_000  # evaluation episodes: the same seeds (or maze layouts) for every run
DEMONSTRATION_LAYOUTS = 100  # the shipped maze demonstrations come from the training pool's first 100 layouts
PHASES = ("idm", "label", "policy", "attention", "rollout", "sampling", "evaluate")


class RunFinished(RuntimeError):
    pass


def _act_with(model: torch.nn.Module, sample: bool, rng: np.random.Generator):
    """A batched acting function for the rollout engine: softmax of the policy, sampled or MAP."""

    def act(obs: np.ndarray):
        probs = predict_proba(model, model, [obs])
        return choose(probs, sample, rng)

    return act


class Run:
    def __init__(self, config: RunConfig, demos: Demonstrations | None = None, progress: Progress | None = None):
        self.config = cfg = config.resolved()
        self.spec = get_env(cfg.env)
        self.method = get_method(cfg.method)
        self.progress = progress
        torch.manual_seed(cfg.seed)
        maze = {"obs_mode": cfg.obs_mode, "image_size": cfg.image_size} if self.spec.is_maze else None
        # Maze worlds. Held-out: training runs (I_pre, I_pos) on the training layouts, evaluation on
        # layouts never seen. Demonstration (the thesis authors' world): the demonstrations' layouts
        # are the only ones, for I_pre, training runs and evaluation alike.
        if maze and cfg.maze_eval_layouts == "demonstration":
            maze["n_layouts"] = DEMONSTRATION_LAYOUTS
        self.pool = EnvPool(self.spec, **maze, split="train", max_steps=cfg.rollout_max_steps) if maze else EnvPool(self.spec)
        eval_split = "eval" if cfg.maze_eval_layouts == "held-out" else "train"
        self.eval_pool = (EnvPool(self.spec, **maze, split=eval_split, deadlock_guard=cfg.deadlock_guard) if maze
                          else EnvPool(self.spec))

        # T_e: expert state pairs. The true actions stay inside `self.demos.hidden_actions`.
        if demos is None:
            demos = (load_demonstrations(cfg.demos, self.spec, self._obs_shape(), require_actions=not self.method.uses_idm)
                     if cfg.demos else load_shipped_demonstrations(self.spec, cfg.obs_mode, cfg.image_size, cfg.expert_episodes))
        if not self.method.uses_idm and demos.hidden_actions is None:
            raise ValueError("BC learns from the expert's actions, and these demonstrations have none")
        self.demos = demos.first_episodes(cfg.expert_episodes)
        self.expert = self.demos.transitions
        self.references = self._references()

        # I_pre: random-policy transitions, split 70/30 for the IDM's training and validation.
        rng = np.random.default_rng([cfg.seed, 0])
        self.pre: PreDemonstrations | None = None
        self.train_set: Transitions | None = None  # I_s
        obs_shape = self.expert.states.shape[1:]
        self.idm = self.idm_optimizer = None
        if self.method.uses_idm:
            everything = collect_random_transitions(self.pool, self.spec.n_actions, cfg.pre_size, cfg.pre_per_action_cap,
                                                    rng, seed_base=cfg.seed * 10_000_000, drop_unchanged=self.spec.is_maze)
            self.pre = stratified_split(everything, self.spec.n_actions, 0.3, rng)
            self.train_set = self.pre.train
            self.idm = InverseDynamics(obs_shape, self.spec.n_actions, cfg.hidden, cfg.attention)
            self.idm.fit_input_scaling(*map(torch.as_tensor, (self.pre.train.states, self.pre.train.next_states)))
            self.idm_optimizer = make_optimizer(self.idm, cfg.lr)
        self.policy = Policy(obs_shape, self.spec.n_actions, cfg.hidden, cfg.attention)
        self.policy.fit_input_scaling(torch.as_tensor(self.expert.states))
        self.policy_optimizer = make_optimizer(self.policy, cfg.lr)
        self.records: list[dict] = []
        self.last_rollouts: Rollouts | None = None
        self.last_evaluation: Rollouts | None = None

    # ------------------------------------------------------------------ helpers
    def _obs_shape(self) -> tuple[int, ...]:
        env = self.pool.envs(1)[0]
        return tuple(env.observation_space.shape)

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
        if self.config.demos:  # a user's demonstrator: normalise by what it achieved
            expert = float(np.mean(self.demos.episode_returns))
        return {"random": refs.get("random_aer"), "expert": expert,
                "random_aer": refs.get("random_aer"), "expert_aer": expert}

    @contextmanager
    def _phase(self, name: str, seconds: dict):
        if self.progress is not None:
            self.progress(name, len(self.records) + 1)
        start = time.perf_counter()
        yield
        seconds[name] = seconds.get(name, 0.0) + time.perf_counter() - start

    def _can_skip_cycles(self, sampled_actions: bool) -> bool:
        return self.spec.deterministic and not sampled_actions

    def phases(self) -> list[str]:
        """The phases one iteration of this run goes through, in order (for progress displays)."""
        cfg = self.config
        names = ["idm", "label"] if self.idm is not None else []
        names.append("policy")
        probes = self.spec.is_maze and self.policy.is_image and cfg.attention_probes
        if probes:
            names.append("attention")
        if self.idm is not None and self.method.iterative:
            names += ["rollout", "sampling"]
        return names + ["evaluate"]

    def set_iterations(self, n: int) -> None:
        """Change how many iterations the full run has (never below the ones already done)."""
        if not isinstance(n, int) or n < max(1, self.iteration):
            raise ValueError(f"iterations must be a whole number >= {max(1, self.iteration)}, got {n!r}")
        if not self.method.iterative and n != 1:
            raise ValueError(f"{self.method.title} is a single pass: it has exactly one iteration")
        self.config = replace(self.config, iterations=n)

    @property
    def iteration(self) -> int:
        return len(self.records)

    @property
    def finished(self) -> bool:
        return self.iteration >= self.config.iterations

    # ------------------------------------------------------------------ the loop
    def step(self) -> dict:
        """Run one iteration and return its record."""
        if self.finished:
            raise RunFinished(f"the run has done all {self.config.iterations} iterations")
        cfg, i, n_actions = self.config, self.iteration, self.spec.n_actions
        rng = np.random.default_rng([cfg.seed, 1, i])
        gen = torch.Generator().manual_seed(int(rng.integers(2**31)))
        torch.manual_seed(int(rng.integers(2**31)))  # dropout in the image heads
        seconds: dict[str, float] = {}
        record: dict = {"iteration": i + 1}
        t_e = self.expert
        hidden = self.demos.hidden_actions  # shown to people, never trained on (except BC)

        if self.idm is not None:
            with self._phase("idm", seconds):  # Eq 5.1 on I_s
                i_s = self.train_set
                idm_fit = fit(self.idm, self.idm, self.idm_optimizer, [i_s.states, i_s.next_states], i_s.actions,
                              cfg.idm_epochs, cfg.batch_size, gen)
                val = self.pre.validation
                val_probs = predict_proba(self.idm, self.idm, [val.states, val.next_states])
            with self._phase("label", seconds):  # a_hat for the expert's pairs
                probs = predict_proba(self.idm, self.idm, [t_e.states, t_e.next_states])
                targets, map_labels = label_passes(probs, cfg.explore_labels, cfg.policy_epochs, rng)
                labels = targets[0]  # the first pass's labels stand for the iteration in the record
            record["idm"] = {
                "loss": idm_fit.loss, "train_accuracy": idm_fit.accuracy,
                "val_accuracy": float(np.mean(val_probs.argmax(-1) == val.actions)) if len(val) else None,
                "train_size": len(i_s),
                "prediction_counts": np.bincount(map_labels, minlength=n_actions).tolist(),
                "mean_probabilities": probs.mean(0).tolist(),
            }
            record["labels"] = {"counts": np.bincount(labels, minlength=n_actions).tolist(),
                                "sampled": bool(cfg.explore_labels),
                                "exploration_rate": exploration_rate(targets, np.broadcast_to(map_labels, targets.shape))}
            if hidden is not None:
                record["idm"]["true_counts"] = np.bincount(hidden, minlength=n_actions).tolist()
                record["idm"]["expert_accuracy"] = float(np.mean(map_labels == hidden))
                record["labels"]["accuracy"] = float(np.mean(targets == hidden))
                record["idm"]["confusion"] = np.bincount(hidden * n_actions + map_labels,
                                                         minlength=n_actions ** 2).reshape(n_actions, -1).tolist()
            att = feature_attention_map(self.idm)
            if att is not None:
                record["idm"]["attention"] = att.tolist()
        else:
            labels = targets = hidden  # BC: the supervised reference learns from the true actions

        with self._phase("policy", seconds):  # Eq 5.2 on (s_e, a_hat)
            pol_fit = fit(self.policy, self.policy, self.policy_optimizer, [t_e.states], targets,
                          cfg.policy_epochs, cfg.batch_size, gen)
            pol_probs = predict_proba(self.policy, self.policy, [t_e.states])
        record["policy"] = {"loss": pol_fit.loss, "agreement": float(np.mean(pol_probs.argmax(-1) == labels))}
        if hidden is not None:
            record["policy"]["expert_accuracy"] = float(np.mean(pol_probs.argmax(-1) == hidden))
        att = feature_attention_map(self.policy)
        if att is not None:
            record["policy"]["attention"] = att.tolist()
        probe_images = self.spec.is_maze and self.policy.is_image and cfg.attention_probes
        if probe_images:
            with self._phase("attention", seconds):  # Fig 6.1: Grad-CAM on fixed probe frames
                record["attention"] = {"grad_cam": grad_cam_probe_record(
                    self.policy, self.spec.kwargs["size"], cfg.image_size)}

        if self.idm is not None and self.method.iterative:
            with self._phase("rollout", seconds):  # I_pos and v_e
                seeds = cfg.seed * 10_000_000 + 1_000_000 + i * cfg.episodes_per_iteration + np.arange(
                    cfg.episodes_per_iteration)
                ro = run_episodes(self.pool, _act_with(self.policy, cfg.explore_rollouts, rng), seeds,
                                  skip_cycles=self._can_skip_cycles(cfg.explore_rollouts))
                self.last_rollouts = ro
            win = float(ro.goals.mean())
            record["rollouts"] = {"returns": ro.returns.tolist(), "lengths": ro.lengths.tolist(),
                                  "goals": ro.goals.astype(int).tolist(), "win_probability": win,
                                  "exploration_rate": ro.exploration_rate, "transitions": len(ro.actions)}
            with self._phase("sampling", seconds):  # I_s for the next iteration
                pos, successful = Transitions(ro.states, ro.actions, ro.next_states), ro.successful()
                if self.spec.is_maze:  # as for I_pre: drop moves into walls (nothing to learn from)
                    moved = pos.moved()
                    pos, successful = pos.subset(np.flatnonzero(moved)), successful[moved]
                self.train_set, mixture = build_training_set(cfg.sampling, self.pre.train, pos, successful,
                                                             win, n_actions, rng)
            record["sampling"] = {"mode": cfg.sampling, **mixture.as_record()}
            if probe_images and hidden is not None:
                with self._phase("attention", seconds):  # Fig 5.3: diagnostics with the hidden truth
                    record["attention"]["mean_image_distance"] = action_mean_image_distances(
                        self.pre.train.states, self.pre.train.actions, ro.states, ro.actions,
                        t_e.states, hidden, n_actions)

        with self._phase("evaluate", seconds):
            record["evaluation"] = self.evaluate(cfg.eval_explore, rng)
        seconds["total"] = sum(seconds.values())
        record["seconds"] = seconds
        self.records.append(record)
        return record

    def evaluate(self, explore: bool = False, rng: np.random.Generator | None = None) -> dict:
        """AER, Performance and fidelity of the current policy on the evaluation episodes,
        with MAP actions or with actions sampled from its softmax (`explore`)."""
        cfg = self.config
        rng = rng if rng is not None else np.random.default_rng([cfg.seed, 2, self.iteration])
        seeds = EVAL_SEED_BASE + np.arange(cfg.eval_episodes) if not self.spec.is_maze else np.arange(cfg.eval_episodes)
        ro = run_episodes(self.eval_pool, _act_with(self.policy, explore, rng), seeds,
                          skip_cycles=self._can_skip_cycles(explore) and not cfg.deadlock_guard)
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
        return _act_with(self.policy, sample, rng or np.random.default_rng(0))(obs)[0]

    # ------------------------------------------------------------------ saving
    def save(self, directory: str | Path) -> Path:
        """Save configuration, records and weights. A crash mid-save leaves the previous save intact:
        the checkpoint is written to a new folder first, then the LATEST pointer is swapped atomically."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        name = f"ckpt-{self.iteration:05d}-{uuid.uuid4().hex[:8]}"  # never the name LATEST points to
        tmp = directory / f".{name}.partial"
        shutil.rmtree(tmp, ignore_errors=True)
        tmp.mkdir()
        arrays = module_arrays("policy", self.policy)
        opt_arrays, opt_meta = optimizer_arrays("opt.policy", self.policy_optimizer)
        arrays.update(opt_arrays)
        meta = {"iteration": self.iteration, "policy_optimizer": opt_meta}
        if self.idm is not None:
            arrays.update(module_arrays("idm", self.idm))
            idm_opt, meta["idm_optimizer"] = optimizer_arrays("opt.idm", self.idm_optimizer)
            arrays.update(idm_opt)
            arrays.update(self.train_set.arrays("train_set."))
        atomic_write_bytes(tmp / "state.npz", npz_bytes(arrays))
        atomic_write_json(tmp / "meta.json", meta)
        atomic_write_json(tmp / "records.json", self.records, compact=True)
        tmp.rename(directory / name)
        atomic_write_json(directory / "config.json", self.config.to_dict())
        if self.config.demos and not (directory / "demos.npz").exists():
            shutil.copyfile(self.config.demos, directory / "demos.npz")
        atomic_write_text(directory / "LATEST", name)
        for old in directory.glob("ckpt-*"):
            if old.name != name:
                shutil.rmtree(old, ignore_errors=True)
        return directory

    @classmethod
    def load(cls, directory: str | Path, progress: Progress | None = None) -> "Run":
        import json

        directory = Path(directory)
        if not (directory / "LATEST").exists():
            raise FileNotFoundError(f"{directory} holds no saved run (no LATEST file)")
        cfg = RunConfig.from_dict(json.loads((directory / "config.json").read_text()))
        if cfg.demos:
            cfg = RunConfig.from_dict({**cfg.to_dict(), "demos": str(directory / "demos.npz")})
        run = cls(cfg, progress=progress)
        ckpt = directory / (directory / "LATEST").read_text().strip()
        meta = json.loads((ckpt / "meta.json").read_text())
        with np.load(ckpt / "state.npz", allow_pickle=False) as data:
            arrays = {k: data[k] for k in data.files}
        load_module_arrays("policy", run.policy, arrays)
        load_optimizer_arrays("opt.policy", run.policy_optimizer, arrays, meta["policy_optimizer"])
        if run.idm is not None:
            load_module_arrays("idm", run.idm, arrays)
            load_optimizer_arrays("opt.idm", run.idm_optimizer, arrays, meta["idm_optimizer"])
            run.train_set = Transitions.from_arrays(arrays, "train_set.")
        run.records = json.loads((ckpt / "records.json").read_text())
        return run
