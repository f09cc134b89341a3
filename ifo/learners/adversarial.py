"""GAIL and GAIfO: one adversarial learner, two discriminator inputs (thesis Sec 3.3, 3.4).

    D(s, x): expert or agent?      GAIL:  x = a  (the expert's actions: a reference, like BC)
                                   GAIfO: x = s' (the expert's states only: IfO)
    π: stable-baselines3's PPO (the generator), rewarded by D instead of the environment

    each Step (one round, as the `imitation` library's adversarial trainer runs it):
        agent samples <- the transitions π made during the last round's PPO training
                         (the first round: a run of the untrained π)                   "collect"
        D <- `disc_updates` steps of  min_D -E_T_e[log D] - E_agent[log(1 - D)]         Eq 3.7
                                      (expert = 1, agent = 0)                           "discriminator"
        π <- PPO.learn(round_steps, reset_num_timesteps=False) on the environment
             with its reward replaced by r(s, x) = -log(1 - D(s, x)) (or log D - log(1 - D),
             log D: `reward`); its transitions are recorded for the next round          "generator"

The reward is replaced by a stable-baselines3 VecEnv wrapper (`learned_reward_env`) that sees every
step of every environment, the true next state of a finished episode included (SB3 keeps it in
info["terminal_observation"]). The environments are reseeded at the start of every round from the
run's "learner" episode stream, PPO's action sampling from the round's torch seed and its mini-batch
order from the round's numpy seed, so a round is the same whatever happened before it (undo, reload).
Everything that changes is state: PPO's policy and its Adam, D and its Adam, PPO's step counters and
the agent samples waiting for the next round's D.
"""
from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import torch

from ifo.components.discriminator import (DISCRIMINATOR_INPUTS, INPUT_LABELS, REWARD_LABELS, REWARDS, Discriminator,
                                          logits_of, reward_from_logits, train_discriminator)
from ifo.envs import EnvSpec
from ifo.learners.base import Context, Learner, LearnerConfig, Phase
from ifo.options import option

# Per environment: PPO's settings follow rl-baselines3-zoo's tuned ones for these tasks where they
# exist (CartPole: 8 envs x 32 steps, 20 epochs, GAE 0.8, gamma 0.98; LunarLander: 16 x 1024, 4 epochs
# of batch 64, GAE 0.98, gamma 0.999, entropy 0.01), with constant learning rates (a learner's round
# must not depend on how many rounds the run has). `round_steps` keeps a CartPole Step to about a
# second; 50 rounds make 100k steps there, 0.8M on LunarLander. On CartPole a discriminator trained 8
# steps a round grew confident enough to starve the reward and the policy collapsed after reaching 500
# (1 of 2 seeds); 2 steps a round kept 3 seeds of 3 at 500 (docs/CHOICES.md).
ENV_DEFAULTS: dict[str, dict] = {
    "cartpole": dict(n_envs=8, ppo_steps=32, ppo_batch_size=256, policy_epochs=20, gamma=0.98, gae_lambda=0.8,
                     ent_coef=0.0, lr=1e-3, round_steps=2048, reward="positive", disc_updates=2),
    "acrobot": dict(n_envs=16, ppo_steps=256, ppo_batch_size=256, policy_epochs=4, gamma=0.99, gae_lambda=0.94,
                    ent_coef=0.0, lr=1e-3, round_steps=8192, reward="logit"),
    "mountaincar": dict(n_envs=16, ppo_steps=256, ppo_batch_size=256, policy_epochs=4, gamma=0.99, gae_lambda=0.98,
                        ent_coef=0.0, lr=1e-3, round_steps=8192, reward="logit"),
    "lunarlander": dict(n_envs=16, ppo_steps=1024, ppo_batch_size=64, policy_epochs=4, gamma=0.999, gae_lambda=0.98,
                        ent_coef=0.01, lr=3e-4, round_steps=16384, reward="logit"),
}
COMMON_DEFAULTS = dict(n_envs=8, ppo_steps=256, ppo_batch_size=256, policy_epochs=10, gamma=0.99, gae_lambda=0.95,
                       ent_coef=0.0, lr=3e-4, round_steps=4096, reward="logit", disc_updates=8)


@dataclass(frozen=True)
class AdversarialConfig(LearnerConfig):
    """The discriminator's inputs (GAIL or GAIfO), its training, its reward, and PPO's settings."""

    discriminator_input: str | None = option(None, "what the discriminator compares: state-action pairs (GAIL, "
                                                   "needs the expert's actions) or state transitions (GAIfO)",
                                             choices=DISCRIMINATOR_INPUTS, labels=INPUT_LABELS,
                                             title="Discriminator input")
    reward: str | None = option(None, "the generator's reward from D(s, x) = P(expert)", choices=REWARDS,
                                labels=REWARD_LABELS, advanced=True)
    round_steps: int | None = option(None, "environment steps PPO collects and learns from in one round (one "
                                           "Step); rounded up to whole PPO rollouts", low=1, high=10_000_000,
                                     advanced=True, work=1)
    disc_updates: int | None = option(None, "discriminator updates per round", low=0, high=100_000, advanced=True,
                                      work=1)
    disc_batch_size: int | None = option(256, "expert samples (and as many agent samples) per discriminator update",
                                         low=2, high=65_536, advanced=True)
    disc_lr: float | None = option(3e-4, "Adam's learning rate for the discriminator", low=1e-7, high=10.0,
                                   advanced=True)
    disc_hidden: tuple[int, ...] | None = option((64, 64), "hidden layer widths of the discriminator", advanced=True)
    n_envs: int | None = option(None, "environments PPO runs side by side", low=1, high=256, advanced=True)
    ppo_steps: int | None = option(None, "PPO's n_steps: steps per environment in one rollout", low=2,
                                   high=100_000, advanced=True)
    ppo_batch_size: int | None = option(None, "PPO's mini-batch size", low=2, high=1_000_000, advanced=True)
    policy_epochs: int | None = option(None, "PPO's n_epochs: passes over each rollout", low=1, high=1000,
                                       advanced=True, work=1)
    lr: float | None = option(None, "PPO's (constant) learning rate", low=1e-7, high=10.0, advanced=True)
    gamma: float | None = option(None, "PPO's discount", low=0.0, high=1.0, advanced=True)
    gae_lambda: float | None = option(None, "PPO's GAE λ", low=0.0, high=1.0, advanced=True)
    ent_coef: float | None = option(None, "PPO's entropy bonus", low=0.0, high=10.0, advanced=True)
    clip_range: float | None = option(0.2, "PPO's clipping of the probability ratio", low=1e-3, high=10.0,
                                      advanced=True)
    hidden: tuple[int, ...] | None = option((64, 64), "hidden layer widths of PPO's policy and value networks",
                                            advanced=True)

    def env_defaults(self, spec: EnvSpec) -> dict:
        return {**COMMON_DEFAULTS, **ENV_DEFAULTS.get(spec.settings_name, {})}


def learned_reward_env(venv, reward_fn):
    """`venv` (a stable-baselines3 VecEnv) with the environment's reward replaced by
    `reward_fn(s, a, s')`, and every transition recorded while its `recording` is a list.
    (Defined here, not at import, so importing the learners does not import stable-baselines3.)"""
    from stable_baselines3.common.vec_env import VecEnvWrapper

    class LearnedReward(VecEnvWrapper):
        def __init__(self):
            super().__init__(venv)
            self.recording: list | None = None
            self._obs = self._actions = None

        def reset(self):
            self._obs = self.venv.reset()
            return self._obs

        def step_async(self, actions):
            self._actions = np.asarray(actions).reshape(self.num_envs)
            self.venv.step_async(actions)

        def step_wait(self):
            obs, _true_reward, dones, infos = self.venv.step_wait()
            next_obs = np.array(obs, copy=True)
            for i in np.flatnonzero(dones):  # the episode ended and SB3 already reset it: the true s'
                next_obs[i] = infos[i]["terminal_observation"]
            if self.recording is not None:
                self.recording.append((np.array(self._obs, copy=True), self._actions.copy(), next_obs))
            rewards = reward_fn(self._obs, self._actions, next_obs)
            self._obs = obs
            return obs, np.asarray(rewards, dtype=np.float32), dones, infos

    return LearnedReward()


@contextmanager
def numpy_global_seed(seed: int):
    """stable-baselines3 shuffles PPO's mini-batches with numpy's global generator: seed it for the
    round, and give the process its previous state back afterwards."""
    saved = np.random.get_state()
    np.random.seed(seed)
    try:
        yield
    finally:
        np.random.set_state(saved)


class AdversarialLearner(Learner):
    key = "adversarial"
    diagram = "adversarial"
    Config = AdversarialConfig
    phases = (
        Phase("collect", "running the untrained policy for the discriminator's first agent samples", "rollout"),
        Phase("discriminator", "training the discriminator: expert samples against the agent's", "discriminator"),
        Phase("generator", "training the policy with PPO on the discriminator's reward", "policy"),
    )

    def __init__(self, ctx: Context, config: AdversarialConfig):
        super().__init__(ctx, config)
        from stable_baselines3 import PPO
        from stable_baselines3.common.logger import Logger
        from stable_baselines3.common.vec_env import DummyVecEnv

        cfg = config
        ctx.require_vector_states("GAIL" if cfg.discriminator_input == "state-action" else "GAIfO")
        if cfg.discriminator_input == "state-action" and ctx.expert_actions is None:
            raise ValueError("a (s, a) discriminator (GAIL) learns from the expert's actions, and this run has "
                             "none: GAIL needs demonstrations with actions, GAIfO does not")
        # T_e for the discriminator: (s, a) for GAIL, (s, s') for GAIfO
        self.expert_inputs = (ctx.expert.states, ctx.expert_actions if cfg.discriminator_input == "state-action"
                              else ctx.expert.next_states)
        self.discriminator = Discriminator(ctx.obs_shape[0], ctx.n_actions, cfg.discriminator_input, cfg.disc_hidden)
        self.discriminator.fit_input_scaling(*map(torch.as_tensor, self.expert_inputs))

        # the generator: PPO on copies of the environment whose reward is D's
        spec, kwargs = ctx.spec, dict(ctx.pool.env_kwargs)
        venv = DummyVecEnv([lambda: spec.make(**kwargs) for _ in range(cfg.n_envs)])
        self.venv = learned_reward_env(venv, self.learned_reward)
        self.model = PPO("MlpPolicy", self.venv, learning_rate=cfg.lr, n_steps=cfg.ppo_steps,
                         batch_size=cfg.ppo_batch_size, n_epochs=cfg.policy_epochs, gamma=cfg.gamma,
                         gae_lambda=cfg.gae_lambda, clip_range=cfg.clip_range, ent_coef=cfg.ent_coef,
                         policy_kwargs=dict(net_arch=list(cfg.hidden)), device="cpu", verbose=0,
                         seed=int(ctx.seeds.rng("learner").integers(2**31)))
        self.model.set_logger(Logger(folder=None, output_formats=[]))  # keeps PPO's last statistics, prints nothing
        self.rollout_size = cfg.n_envs * cfg.ppo_steps
        self.rollouts_per_round = max(1, math.ceil(cfg.round_steps / self.rollout_size))

        self.modules["policy"] = self.model.policy
        self.modules["discriminator"] = self.discriminator
        self.optimizers["policy"] = self.model.policy.optimizer
        self.optimizers["discriminator"] = torch.optim.Adam(self.discriminator.parameters(), lr=cfg.disc_lr)
        self.agent_states = self.agent_inputs = None  # the agent samples the next round's D trains on
        self.environment_steps = 0

    # ------------------------------------------------------------------ the policy
    def probabilities(self, obs: np.ndarray) -> np.ndarray:
        policy = self.model.policy
        with torch.no_grad():
            dist = policy.get_distribution(policy.obs_to_tensor(np.asarray(obs))[0])
            return dist.distribution.probs.numpy().astype(np.float64)

    def reward_of(self, s: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The generator's reward for samples (s, x): x the action (GAIL) or the next state (GAIfO)."""
        logits = torch.as_tensor(logits_of(self.discriminator, s, x))
        return reward_from_logits(logits, self.config.reward).numpy()

    def learned_reward(self, s: np.ndarray, a: np.ndarray, s2: np.ndarray) -> np.ndarray:
        return self.reward_of(s, a if self.config.discriminator_input == "state-action" else s2)

    def active_phases(self) -> list[str]:
        return (["collect"] if self.agent_states is None else []) + ["discriminator", "generator"]

    # ------------------------------------------------------------------ one round
    def step(self, iteration: int, rng: np.random.Generator) -> dict:
        ctx, cfg = self.ctx, self.config
        self.seed_global_rng(rng)  # PPO samples its actions with torch's global generator
        collect_seed, learn_seed = (int(s) for s in ctx.seeds.episodes("learner", 2, iteration))  # environments
        with numpy_global_seed(int(rng.integers(2**31))):
            if self.agent_states is None:
                with ctx.phase("collect"):
                    self._collect(collect_seed)
            with ctx.phase("discriminator"):
                fit = train_discriminator(self.discriminator, self.optimizers["discriminator"], self.expert_inputs,
                                          (self.agent_states, self.agent_inputs), cfg.disc_updates,
                                          cfg.disc_batch_size, rng)
                mean_reward = float(self.reward_of(self.agent_states, self.agent_inputs).mean())
            with ctx.phase("generator"):
                steps = self._learn(learn_seed)
        stats = self.model.logger.name_to_value
        record = {
            "discriminator": {"loss": fit.loss, "accuracy_expert": fit.accuracy_expert,
                              "accuracy_agent": fit.accuracy_agent, "mean_reward": mean_reward},
            "generator": {"loss": float(stats["train/policy_gradient_loss"]),
                          "value_loss": float(stats["train/value_loss"]),
                          "entropy": -float(stats["train/entropy_loss"]), "environment_steps": steps},
            "samples": {"environment_steps": self.environment_steps, "expert_samples": len(ctx.expert)},
        }
        if ctx.truth.available:  # a diagnostic for people: does π choose what the expert chose on T_e?
            record["policy"] = {"expert_accuracy": ctx.truth.accuracy(
                self.probabilities(ctx.expert.states).argmax(-1))["accuracy"]}
        return record

    @contextmanager
    def _recorded(self, seed: int):
        """Reset every environment from `seed` on its next reset, and keep the transitions made meanwhile
        as the agent samples of the next discriminator training."""
        self.venv.seed(seed)
        self.venv.recording = recording = []
        try:
            yield
        finally:
            self.venv.recording = None
        s, a, s2 = (np.concatenate(part) for part in zip(*recording))
        self.agent_states = s
        self.agent_inputs = a if self.config.discriminator_input == "state-action" else s2

    def _collect(self, seed: int) -> None:
        """The first agent samples: one PPO-sized rollout of the untrained policy (no learning)."""
        with self._recorded(seed):
            obs = self.venv.reset()
            for _ in range(self.config.ppo_steps):
                actions, _ = self.model.predict(obs, deterministic=False)
                obs, _, _, _ = self.venv.step(actions)
        self.environment_steps += self.rollout_size

    def _learn(self, seed: int) -> int:
        """PPO on D's reward from freshly reset environments; its transitions become the next agent samples."""
        steps = self.rollouts_per_round * self.rollout_size
        with self._recorded(seed):
            self.model._last_obs = None  # makes learn() reset the environments (with the seeds just set)
            self.model.learn(steps, reset_num_timesteps=False, log_interval=None)
        self.environment_steps += steps
        return steps

    # ------------------------------------------------------------------ state
    def data_state(self) -> dict[str, np.ndarray]:
        out = {"counters.environment_steps": np.array(self.environment_steps),
               "ppo.num_timesteps": np.array(self.model.num_timesteps),
               "ppo.n_updates": np.array(self.model._n_updates)}
        if self.agent_states is not None:
            out["agent.states"] = self.agent_states.copy()
            out["agent.inputs"] = self.agent_inputs.copy()
        return out

    def load_data_state(self, arrays: dict[str, np.ndarray]) -> None:
        self.environment_steps = int(arrays["counters.environment_steps"])
        self.model.num_timesteps = int(arrays["ppo.num_timesteps"])
        self.model._n_updates = int(arrays["ppo.n_updates"])
        if "agent.states" in arrays:
            self.agent_states, self.agent_inputs = np.array(arrays["agent.states"]), np.array(arrays["agent.inputs"])
        else:
            self.agent_states = self.agent_inputs = None
