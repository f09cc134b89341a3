"""CRIL: Combined Reinforcement and Imitation Learning (thesis Ch. 8, Algorithm 8.1).

IUPE's loop (IDM, sampled labels, behavioural cloning, goal-aware sampling) interleaved with
DQN-style temporal-difference updates of the SAME policy network from its own experience:

    I_pre <- runs of the untrained policy; I_s <- I_pre; T_e <- expert state pairs (no actions)
    while π improves:
        M(a | s, s') <- TRAIN(M, I_s)                                    line 7  (Eq 5.1, clip ±1)
        Â <- M(T_e), sampled from its softmax                            line 8
        π <- BCLOSS(T_e, Â)                                              line 9  (Eq 5.2, clip ±1)
        ε <- π's exploration ratio on T_e (share of sampled actions that are not the MAP one)
        for e in 1..|E|: run π ε-greedily; I_pos <- (s, a, s'); replay memory <- (s, a, r, s', done)
                         π <- TDLOSS(replay)                              line 13 (Eq 8.1, clip ±0.5)
        I_s <- GOALSAMPLER(I_pre, I_pos) with I_pos's share at most        line 15
               lim sup I_pos = 1 - 1 / (1 + (n/e - 1)^-k)                                 (Eq 8.2)

The policy's outputs are its logits for behavioural cloning and its Q-values for the TD updates
(one network, as the thesis has it). The replay memory holds 10x the expert's average episode
length (Sec 8.2); IDM and policy have layer normalisation (Sec 8.2). The stop rule of Sec 8.2
(no change of the policy's actions on T_e between two iterations, or no significant decrease of
its loss) is available and off by default. Runs of the policy go in `td_rounds` batches, each
followed by its TD updates (see docs/CHOICES.md).
"""
from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ifo.components.exploration import choose, exploration_rate
from ifo.components.replay import ReplayMemory
from ifo.envs.rollout import Rollouts, run_episodes
from ifo.learners.base import Phase
from ifo.learners.bco import BCOConfig, BCOLearner, rollouts_record
from ifo.options import option


def share_limit(iteration: int, n: int, k: float = 2.0) -> float:
    """Eq 8.2: the upper limit of I_pos's share of I_s at iteration e (1-based); 1 from e = n on."""
    e = max(1, int(iteration))
    if e >= n:
        return 1.0
    return 1.0 - 1.0 / (1.0 + (n / e - 1.0) ** (-k))


@dataclass(frozen=True)
class CRILConfig(BCOConfig):
    """IUPE's switches and sizes, plus the reinforcement-learning part (Sec 8.2-8.3)."""

    gamma: float | None = option(0.99, "discount of the TD target (Eq 8.1)", low=0.0, high=1.0, advanced=True)
    td_lr: float | None = option(1e-4, "Adam's learning rate of the TD updates: small, so they refine the policy "
                                       "the imitation step trains rather than overwrite it", low=1e-8, high=10.0,
                                 advanced=True)
    scale_rewards: bool | None = option(True, "multiply rewards by (1 - gamma), so Q-values stay on the scale of "
                                              "the logits the imitation step trains in the same network",
                                        advanced=True)
    replay_multiple: int | None = option(10, "the replay memory holds this many times the expert's average "
                                             "episode length (Sec 8.2)", low=1, high=1000, advanced=True)
    td_updates: int | None = option(None, "TD mini-batch updates after each run of the policy", low=0,
                                    high=10_000, advanced=True, work=1)
    td_rounds: int | None = option(5, "the |E| runs go in this many batches, each followed by its TD updates",
                                   low=1, high=10_000, advanced=True)
    rl_clip: float | None = option(0.5, "gradient clipping of the TD updates, ±value (Sec 8.3)", low=1e-6,
                                   advanced=True)
    il_clip: float | None = option(1.0, "gradient clipping of the imitation steps, ±value (Sec 8.3)", low=1e-6,
                                   advanced=True)
    layer_norm: bool | None = option(True, "layer normalisation in the IDM and the policy (Sec 8.2)",
                                     advanced=True)
    share_k: float | None = option(2.0, "k of Eq 8.2: the slope of I_pos's share limit", low=0.01, high=100,
                                   advanced=True)
    share_n: int | None = option(None, "n of Eq 8.2: the iteration at which I_pos's share limit reaches 100% "
                                       "(default: the run's iterations)", low=1, advanced=True)
    stop_rule: bool | None = option(False, "stop when the policy's actions on T_e no longer change between two "
                                           "iterations, or its loss no longer decreases (Sec 8.2)",
                                    title="Stop rule (Sec 8.2)")

    def follows_iteration_count(self) -> bool:
        return self.share_n is None  # Eq 8.2's n defaults to the run's iterations

    def env_defaults(self, spec) -> dict:
        return {**super().env_defaults(spec), "td_updates": 8, "episodes_per_iteration": 20}

    def unused(self) -> set[str]:
        return super().unused() | {"explore_rollouts"}  # its runs are ε-greedy, ε from the imitation step


class CRILLearner(BCOLearner):
    key = "cril"
    Config = CRILConfig
    phases = (
        Phase("idm", "training the inverse dynamics model (IDM) on I_s", "idm"),
        Phase("label", "labelling the expert's state pairs with the IDM", "label"),
        Phase("policy", "training the policy on those labels", "policy"),
        Phase("rollout", "running the policy ε-greedily (I_pos) and learning from its rewards (TD, Eq 8.1)",
              "rollout"),
        Phase("sampling", "choosing what the IDM learns from next (I_s, capped by Eq 8.2)", "sampling"),
    )

    def __init__(self, ctx, config: CRILConfig):
        super().__init__(ctx, config)
        self.il_clip = config.il_clip
        policy = self.policy
        self.optimizers["td"] = torch.optim.Adam(policy.parameters(), lr=config.td_lr, foreach=True)
        lengths = np.bincount(ctx.expert.episode_index)
        capacity = int(config.replay_multiple * max(1.0, float(lengths[lengths > 0].mean())))
        self.replay = ReplayMemory(capacity, ctx.obs_shape, ctx.expert.states.dtype)
        self.share_n = config.share_n or ctx.config.iterations
        self.previous_actions: np.ndarray | None = None
        self.previous_loss: float | None = None
        self.stop = False

    def network_options(self, role: str) -> dict:
        return {"layer_norm": bool(self.config.layer_norm)}

    def active_phases(self) -> list[str]:
        return ["idm", "label", "policy", "rollout", "sampling"]

    def finished(self) -> bool:
        return bool(self.config.stop_rule and self.stop)

    # ------------------------------------------------------------------ one iteration
    def step(self, iteration: int, rng: np.random.Generator) -> dict:
        gen = self.ctx.seeds.torch_generator(rng)
        self.seed_global_rng(rng)  # dropout in the image heads
        record = self.imitate(rng, gen)  # lines 7-9
        epsilon = self.exploration_ratio(rng)
        runs = self.run_policy_and_learn(iteration, epsilon, rng, gen, record)  # lines 10-14
        cap = share_limit(iteration + 1, self.share_n, self.config.share_k)
        self.resample(runs, rng, record, share_cap=cap)  # line 15, Eq 8.2
        record["samples"] = {"environment_steps": self.environment_steps, "expert_samples": len(self.ctx.expert)}
        record["td"]["stop_rule_met"] = self.check_stop_rule(record)
        return record

    def exploration_ratio(self, rng: np.random.Generator) -> float:
        """ε: on the expert's states, the share of actions sampled from π's softmax that are not its MAP
        action, measured right after the imitation step (Sec 8.2: no time-decay schedule)."""
        sampled, best = choose(self.expert_probabilities, True, rng)
        return exploration_rate(sampled, best)

    def run_policy_and_learn(self, iteration: int, epsilon: float, rng: np.random.Generator,
                             gen: torch.Generator, record: dict) -> Rollouts:
        ctx, cfg, policy = self.ctx, self.config, self.policy
        target = copy.deepcopy(policy).eval()  # DQN's target network, refreshed every iteration
        seeds = ctx.seeds.episodes("rollouts", cfg.episodes_per_iteration, iteration)
        parts, losses, q_range = [], [], [np.inf, -np.inf]
        with ctx.phase("rollout"):
            for batch in np.array_split(seeds, min(cfg.td_rounds, len(seeds))):
                ro = run_episodes(ctx.pool, self._epsilon_greedy(epsilon, rng), batch)
                parts.append(ro)
                self.environment_steps += int(ro.lengths.sum())
                scale = 1.0 - cfg.gamma if cfg.scale_rewards else 1.0
                self.replay.add(ro.states, ro.actions, ro.rewards * scale, ro.next_states, _terminal_flags(ro))
                for _ in range(cfg.td_updates * len(batch)):
                    loss, q_lo, q_hi = self._td_update(target, rng)
                    losses.append(loss)
                    q_range = [min(q_range[0], q_lo), max(q_range[1], q_hi)]
        ro = _concat(parts)
        self.last_rollouts = ro
        record["rollouts"] = rollouts_record(ro, sampled=False)
        record["td"] = {"loss": float(np.mean(losses)) if losses else None, "epsilon": epsilon,
                        "q_min": q_range[0] if losses else None, "q_max": q_range[1] if losses else None,
                        "updates": len(losses)}
        record["replay"] = {"size": len(self.replay), "capacity": self.replay.capacity}
        return ro

    def _epsilon_greedy(self, epsilon: float, rng: np.random.Generator):
        def act(obs):
            best = self.probabilities(obs).argmax(-1)
            random = rng.random(len(obs)) < epsilon
            return np.where(random, rng.integers(0, self.ctx.n_actions, len(obs)), best), best

        return act

    def _td_update(self, target: torch.nn.Module, rng: np.random.Generator) -> tuple[float, float, float]:
        """One DQN step on a mini-batch of the replay memory (Eq 8.1), gradients clipped to ±rl_clip."""
        cfg, policy = self.config, self.policy
        s, a, r, s2, done = (torch.as_tensor(x) for x in self.replay.sample(cfg.batch_size, rng))
        policy.train()
        q = policy(s)
        with torch.no_grad():
            best_next = target(s2).max(-1).values
            y = r + cfg.gamma * (1.0 - done) * best_next
        loss = F.smooth_l1_loss(q.gather(1, a[:, None]).squeeze(1), y)
        self.optimizers["td"].zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_value_(policy.parameters(), cfg.rl_clip)
        self.optimizers["td"].step()
        return loss.item(), float(q.detach().min()), float(q.detach().max())

    def check_stop_rule(self, record: dict) -> bool:
        """Sec 8.2: no change in the policy's actions on T_e since the last iteration, or no significant
        decrease of its imitation loss (less than 1% of it)."""
        actions = self.expert_probabilities.argmax(-1)
        loss = record["policy"]["loss"]
        same = self.previous_actions is not None and np.array_equal(actions, self.previous_actions)
        flat = self.previous_loss is not None and self.previous_loss - loss < 0.01 * abs(self.previous_loss)
        self.previous_actions, self.previous_loss = actions, loss
        self.stop = bool(same or flat)
        return self.stop

    # ------------------------------------------------------------------ state
    def data_state(self) -> dict[str, np.ndarray]:
        out = {**super().data_state(), **self.replay.arrays("replay.")}
        if self.previous_actions is not None:
            out["stop.previous_actions"] = self.previous_actions.copy()
            out["stop.previous_loss"] = np.array(self.previous_loss)
        out["stop.met"] = np.array(self.stop)
        return out

    def load_data_state(self, arrays: dict[str, np.ndarray]) -> None:
        super().load_data_state(arrays)
        self.replay.load_arrays(arrays, "replay.")
        if "stop.previous_actions" in arrays:
            self.previous_actions = np.array(arrays["stop.previous_actions"])
            self.previous_loss = float(arrays["stop.previous_loss"])
        self.stop = bool(arrays.get("stop.met", False))


def _terminal_flags(ro: Rollouts) -> np.ndarray:
    """Per transition: 1 where the episode ended by termination (no bootstrap), 0 elsewhere (a time
    limit is not a terminal state)."""
    done = np.zeros(len(ro.actions), dtype=np.float32)
    ends = np.cumsum(np.bincount(ro.episode_index, minlength=len(ro.episodes))) - 1
    for e, end in enumerate(ends):
        if ro.episodes[e].terminated and end >= 0:
            done[end] = 1.0
    return done


def _concat(parts: list[Rollouts]) -> Rollouts:
    """One Rollouts of several batches (episode numbers made distinct)."""
    if len(parts) == 1:
        return parts[0]
    offsets = np.cumsum([0] + [len(p.episodes) for p in parts[:-1]])
    cat = lambda name: np.concatenate([getattr(p, name) for p in parts])  # noqa: E731
    return Rollouts(cat("states"), cat("actions"), cat("next_states"),
                    np.concatenate([p.episode_index + o for p, o in zip(parts, offsets)]), cat("rewards"),
                    cat("took_non_map"), [e for p in parts for e in p.episodes], cat("goals"))
