"""ILPO: Imitating Latent Policies from Observation (Edwards et al. 2019; thesis Sec 3.2).

The expert's states alone teach what can happen next; a few environment steps teach which real
action makes each of those things happen:

    T_e <- the expert's state pairs (s, s'), no actions; Z = {z_1 .. z_k} latent actions
    each step (one iteration):
        G(E(s), z) -> Δ̂_z, one predicted change of state per latent action          Sec 3.2.1
            L_min = min_z || Δ - G(E(s), z) ||²       only the closest z learns     (Eq 3.3)
        π_ω(z | s) latent policy, with G's predictions held fixed:
            ŝ' = s + Σ_z π_ω(z | s) Δ̂_z,   L_exp = || s' - ŝ' ||²                   (Eq 3.4)
        run the policy |E| times (actions sampled), plus I_pre's random (s, a, s') from the start
        z_t = argmin_z || s_{t+1} - (s_t + G(E(s_t), z)) ||                            (Eq 3.5)
        π_ξ(a | z, s) <- cross-entropy on (s_t, z_t) -> a_t: the action remapping      Sec 3.2.2
    acting: π(a | s) = Σ_z π_ω(z | s) π_ξ(a | z, s)

Changes of state are standardised by the expert's statistics, so every state variable counts in
the distances of Eqs 3.3-3.5. For vector states only: this ILPO refuses images (the thesis's ILPO
crops and encodes maze images; see docs/CHOICES.md), so mazes need obs_mode=vector.

Through the hidden truth people also see the inverse dynamics model ILPO implies (z* by Eq 3.5,
then the remapping): how often it names the expert's real action.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ifo.components.exploration import choose
from ifo.components.learning import fit, make_optimizer, predict_proba
from ifo.data.transitions import Transitions, stratified_split
from ifo.envs import EnvSpec
from ifo.envs.rollout import run_episodes
from ifo.learners.base import Context, Learner, LearnerConfig, Phase, histogram
from ifo.learners.bco import rollouts_record
from ifo.nets import MLP, Standardize
from ifo.options import option

ENV_DEFAULTS: dict[str, dict] = {
    "cartpole": dict(pre_size=1000),
    "lunarlander": dict(pre_size=4000),
}
COMMON_DEFAULTS = dict(pre_size=2000, episodes_per_iteration=10, policy_epochs=20, remap_epochs=5)


@dataclass(frozen=True)
class ILPOConfig(LearnerConfig):
    """The latent model's size and training, and the few environment steps of the remapping."""

    latent_actions: int | None = option(None, "|Z|: latent actions the forward model proposes (default: as many "
                                              "as real actions)", low=2, high=64, title="Latent actions |Z|",
                                        advanced=True)
    policy_epochs: int | None = option(None, "passes of the latent forward model and the latent policy over T_e "
                                             "per iteration", low=1, high=10_000, advanced=True, work=1)
    min_updates: int | None = option(200, "at least this many mini-batch updates of the latent model per "
                                          "iteration (one demonstration is only a few mini-batches)", low=0,
                                     high=100_000, advanced=True, work=1)
    pre_size: int | None = option(None, "|I_pre|: random-policy transitions the remapping starts from (30% kept "
                                        "to measure it)", low=10, high=2_000_000, advanced=True, work=1,
                                  title="|I_pre|")
    episodes_per_iteration: int | None = option(None, "|E|: runs of the policy per iteration whose (s, a, s') "
                                                      "refine the remapping", low=0, high=10_000, advanced=True, work=1,
                                                title="|E|")
    remap_epochs: int | None = option(None, "passes of the remapping π_ξ(a | z, s) over its data per iteration",
                                      low=1, high=1000, advanced=True, work=1)
    batch_size: int | None = option(128, "mini-batch size of every model", low=2, high=65_536, advanced=True)
    lr: float | None = option(1e-3, "Adam's learning rate for every model", low=1e-7, high=10.0, advanced=True)
    hidden: tuple[int, ...] | None = option((64, 64), "hidden layer widths of the networks", advanced=True)

    def env_defaults(self, spec: EnvSpec) -> dict:
        return {**COMMON_DEFAULTS, "latent_actions": spec.n_actions, **ENV_DEFAULTS.get(spec.settings_name, {})}


class LatentForward(nn.Module):
    """G(E(s), z) for every z at once: (batch, |Z|, state) predicted changes of state, in units of the
    expert's standardised changes."""

    def __init__(self, obs_dim: int, n_latent: int, hidden=(64, 64)):
        super().__init__()
        self.n_latent, self.obs_dim = n_latent, obs_dim
        self.net = MLP(obs_dim, n_latent * obs_dim, hidden)  # E and G in one network; its input standardised
        self.delta = Standardize(obs_dim)  # the expert's changes of state

    def fit_scaling(self, s: torch.Tensor, s2: torch.Tensor) -> None:
        self.net.standardize.fit(s)
        self.delta.fit(s2 - s)

    def target(self, s: torch.Tensor, s2: torch.Tensor) -> torch.Tensor:
        return self.delta(s2 - s)

    def forward(self, s: torch.Tensor) -> torch.Tensor:
        return self.net(s).view(len(s), self.n_latent, self.obs_dim)

    def errors(self, s: torch.Tensor, s2: torch.Tensor) -> torch.Tensor:
        """|| Δ - G(E(s), z) ||² per sample and latent action (batch, |Z|), standardised units."""
        return (self(s) - self.target(s, s2).unsqueeze(1)).pow(2).mean(-1)


class Remap(nn.Module):
    """π_ξ(a | z, s): which real action a latent action is, in this state."""

    def __init__(self, obs_dim: int, n_latent: int, n_actions: int, hidden=(64, 64)):
        super().__init__()
        self.n_latent = n_latent
        self.net = MLP(obs_dim + n_latent, n_actions, hidden)

    def fit_input_scaling(self, s: torch.Tensor) -> None:
        std = self.net.standardize
        std.fit(torch.cat([s, torch.zeros(len(s), self.n_latent)], -1))
        std.mean[-self.n_latent:], std.std[-self.n_latent:] = 0.0, 1.0  # the one-hot z stays as it is

    def forward(self, s: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([s.float(), F.one_hot(z.long(), self.n_latent).float()], -1))


class ILPOLearner(Learner):
    key = "ilpo"
    diagram = "ilpo"
    Config = ILPOConfig
    phases = (
        Phase("latent", "training the latent forward model and the latent policy on T_e (Eqs 3.3-3.4)", "latent"),
        Phase("rollout", "running the policy to see which real action each latent action is", "rollout"),
        Phase("remap", "learning the remapping from latent to real actions (Eq 3.5)", "remap"),
    )

    def __init__(self, ctx: Context, config: ILPOConfig):
        super().__init__(ctx, config)
        cfg = config
        ctx.require_vector_states("this ILPO", " only (its forward model predicts the change of a state vector)")
        d, k, n = ctx.obs_shape[0], cfg.latent_actions, ctx.n_actions
        s, s2 = torch.as_tensor(ctx.expert.states), torch.as_tensor(ctx.expert.next_states)
        self.dynamics = LatentForward(d, k, cfg.hidden)
        self.dynamics.fit_scaling(s.float(), s2.float())
        self.latent_policy = MLP(d, k, cfg.hidden)
        self.latent_policy.standardize.fit(s.float())
        self.remap = Remap(d, k, n, cfg.hidden)
        self.remap.fit_input_scaling(s.float())
        self.modules.update(policy=self.latent_policy, dynamics=self.dynamics, remap=self.remap)
        self.optimizers.update(latent=torch.optim.Adam([*self.dynamics.parameters(),
                                                        *self.latent_policy.parameters()], lr=cfg.lr, foreach=True),
                               remap=make_optimizer(self.remap, cfg.lr))
        # I_pre: a few random-policy steps, the remapping's first data (70% to learn, 30% to measure)
        everything, self.environment_steps = ctx.random_transitions(cfg.pre_size, cfg.pre_size, ctx.seeds.rng("pre"))
        self.pre = stratified_split(everything, n, 0.3, ctx.seeds.rng("pre", 1))

    def sizes(self) -> dict:
        return {**super().sizes(), "pre_size": len(self.pre.train)}

    # ------------------------------------------------------------------ the policy
    @torch.inference_mode()
    def latent_probabilities(self, obs: np.ndarray) -> np.ndarray:
        return predict_proba(self.latent_policy, self.latent_policy, [obs])

    @torch.inference_mode()
    def remap_probabilities(self, obs: np.ndarray) -> np.ndarray:
        """π_ξ(a | z, s) for every z: (batch, |Z|, |A|)."""
        k = self.config.latent_actions
        s = torch.as_tensor(np.asarray(obs), dtype=torch.float32)
        self.remap.eval()
        logits = self.remap(s.repeat_interleave(k, 0), torch.arange(k).repeat(len(s)))
        return torch.softmax(logits, -1).view(len(s), k, -1).numpy()

    def probabilities(self, obs: np.ndarray) -> np.ndarray:
        """π(a | s) = Σ_z π_ω(z | s) π_ξ(a | z, s)."""
        if len(obs) == 0:
            return np.zeros((0, self.ctx.n_actions))
        return np.einsum("bz,bza->ba", self.latent_probabilities(obs), self.remap_probabilities(obs))

    @torch.inference_mode()
    def assign(self, s: np.ndarray, s2: np.ndarray, batch: int = 8192) -> tuple[np.ndarray, np.ndarray]:
        """Eq 3.5: the latent action whose predicted next state is closest, and that distance²."""
        self.dynamics.eval()
        zs, errs = [], []
        for i in range(0, len(s), batch):
            e = self.dynamics.errors(torch.as_tensor(s[i:i + batch]).float(), torch.as_tensor(s2[i:i + batch]).float())
            err, z = e.min(1)
            zs.append(z.numpy())
            errs.append(err.numpy())
        return (np.concatenate(zs), np.concatenate(errs)) if zs else (np.zeros(0, np.int64), np.zeros(0))

    def implied_idm(self, s: np.ndarray, s2: np.ndarray) -> np.ndarray:
        """The inverse dynamics ILPO implies: z* by Eq 3.5, then π_ξ(a | z*, s); (batch, |A|)."""
        z, _ = self.assign(s, s2)
        with torch.inference_mode():
            self.remap.eval()
            return torch.softmax(self.remap(torch.as_tensor(s).float(), torch.as_tensor(z)), -1).numpy()

    # ------------------------------------------------------------------ one iteration
    def step(self, iteration: int, rng: np.random.Generator) -> dict:
        gen = self.ctx.seeds.torch_generator(rng)
        self.seed_global_rng(rng)
        record: dict = {}
        with self.ctx.phase("latent"):
            record["latent"], record["policy"] = self.train_latent(gen)
        with self.ctx.phase("rollout"):
            runs = self.run_policy(iteration, rng, record)
        with self.ctx.phase("remap"):
            self.train_remap(runs, gen, record)
        record["samples"] = {"environment_steps": self.environment_steps, "expert_samples": len(self.ctx.expert)}
        return record

    def train_latent(self, gen: torch.Generator) -> tuple[dict, dict]:
        """G by L_min (Eq 3.3) and π_ω by L_exp (Eq 3.4, G's predictions held fixed), on T_e."""
        cfg, t_e = self.config, self.ctx.expert
        s, s2 = torch.as_tensor(t_e.states).float(), torch.as_tensor(t_e.next_states).float()
        n = len(s)
        batches_per_epoch = max(1, -(-n // cfg.batch_size))
        updates = max(cfg.policy_epochs * batches_per_epoch, cfg.min_updates)
        self.dynamics.train()
        self.latent_policy.train()
        opt = self.optimizers["latent"]
        order = torch.zeros(0, dtype=torch.long)
        sums = np.zeros(2)
        for u in range(updates):
            if len(order) < min(cfg.batch_size, n):
                order = torch.cat([order, torch.randperm(n, generator=gen)])
            idx, order = order[:cfg.batch_size], order[cfg.batch_size:]
            pred = self.dynamics(s[idx])  # (B, |Z|, d)
            target = self.dynamics.target(s[idx], s2[idx])  # (B, d)
            loss_min = (pred - target.unsqueeze(1)).pow(2).mean(-1).min(1).values.mean()
            weights = torch.softmax(self.latent_policy(s[idx]), -1)  # π_ω(z | s)
            expected = (weights.unsqueeze(-1) * pred.detach()).sum(1)  # ŝ' - s, in standardised units
            loss_exp = (expected - target).pow(2).mean()
            opt.zero_grad(set_to_none=True)
            (loss_min + loss_exp).backward()
            opt.step()
            sums += (loss_min.item(), loss_exp.item())
        z, err = self.assign(t_e.states, t_e.next_states)
        k = cfg.latent_actions
        latent = {"assignment_counts": np.bincount(z, minlength=k).tolist(), "forward_error": float(err.mean())}
        return latent, {"loss": float(sums[1] / max(updates, 1))}  # L_exp, mean over the updates

    def run_policy(self, iteration: int, rng: np.random.Generator, record: dict):
        """|E| runs of the policy, actions sampled from π(a | s): (s, a, s') for the remapping."""
        cfg, ctx = self.config, self.ctx
        if cfg.episodes_per_iteration == 0:
            return None
        seeds = ctx.seeds.episodes("rollouts", cfg.episodes_per_iteration, iteration)
        ro = run_episodes(ctx.pool, lambda obs: choose(self.probabilities(obs), True, rng), seeds)
        self.environment_steps += int(ro.lengths.sum())
        record["rollouts"] = rollouts_record(ro, sampled=True)
        return ro

    def train_remap(self, runs, gen: torch.Generator, record: dict) -> None:
        """π_ξ(a | z, s) on I_pre and the runs, z by Eq 3.5 (Sec 3.2.2); the record's remapping table,
        and the implied inverse dynamics measured on I_pre's held-out 30% and (hidden truth) on T_e."""
        cfg, ctx, k, n = self.config, self.ctx, self.config.latent_actions, self.ctx.n_actions
        data = self.pre.train
        if runs is not None and len(runs.actions):
            data = Transitions.concat([data, Transitions(runs.states, runs.actions, runs.next_states)])
        z, _ = self.assign(data.states, data.next_states)
        remap_fit = fit(lambda s, zz: self.remap(s, zz), self.remap, self.optimizers["remap"], [data.states, z],
                        data.actions, cfg.remap_epochs, cfg.batch_size, gen)
        record["latent"]["remap"] = np.bincount(z * n + data.actions, minlength=k * n).reshape(k, n).tolist()
        val = self.pre.validation
        val_probs = self.implied_idm(val.states, val.next_states) if len(val) else np.zeros((0, n))
        t_e = ctx.expert
        probs = self.implied_idm(t_e.states, t_e.next_states)
        labels = probs.argmax(-1)
        record["idm"] = {"loss": remap_fit.loss, "train_accuracy": remap_fit.accuracy,
                         "val_accuracy": float(np.mean(val_probs.argmax(-1) == val.actions)) if len(val) else None,
                         "train_size": len(data), "prediction_counts": np.bincount(labels, minlength=n).tolist(),
                         "mean_probabilities": probs.mean(0).tolist(),
                         "confidence_histogram": histogram(probs.max(-1)),
                         **ctx.truth.idm_report(labels, probs)}
        chosen = self.probabilities(t_e.states).argmax(-1)
        record["policy"]["agreement"] = float(np.mean(chosen == labels))  # π's choice = the implied label
        if ctx.truth.available:
            record["policy"]["expert_accuracy"] = ctx.truth.accuracy(chosen)["accuracy"]


    # ------------------------------------------------------------------ state
    def data_state(self) -> dict[str, np.ndarray]:
        return {"counters.environment_steps": np.array(self.environment_steps)}

    def load_data_state(self, arrays: dict[str, np.ndarray]) -> None:
        self.environment_steps = int(arrays["counters.environment_steps"])
