"""SAIL: Self-Supervised Adversarial Imitation Learning (thesis Ch. 9, Algorithm 9.1).

IUPE's self-supervised loop, with the hand-written goal test replaced by a discriminator and a
generator that carries the discriminator's judgement into the policy:

    I_s <- random-policy transitions (I_pre)                            line 5
    T_e <- the teacher's state pairs (no actions); RB <- {} (the policy's trajectories)
    each iteration:
        M(a | s, s')  trained on I_s                                     line 7  (Eq 5.1)
        Â <- M(T_e), sampled from its softmax (exploration)              line 8
        π and G trained together on T_e (BEHAVIOURALCLONING)             line 9:
            cross-entropy(π(s_t), â_t)                                            (Eq 5.2)
          + |G(s_t, π(s_t)) - s_{t+1}|², flowing into π through its logits        (Eq 9.2)
          + λ · -log D(G(r', π(r'))) on windows r' of RB, into G and π            (Eq 9.1, min side)
        run π |E| times (actions sampled from its softmax) -> I_pos, RB   lines 10-11
        I_s <- I_s ∪ the runs D takes for the teacher's                   line 12 (D random at first,
                                                                          so sub-optimal runs get in)
        D trained on a few windows of T_e (teacher) and RB (student)      Eq 9.1, max side (Sec 9.1)

The models (Sec 9.2): M and π two hidden layers of 32 with the (gated) attention block after each,
M with layer normalisation; G two hidden layers of 2 x (|s| + 1), no attention, no normalisation;
D an LSTM of two layers of 32 with dropout 0.5. See ifo/components/sail_models.py, and the
choices where the thesis is silent in docs/CHOICES.md.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ifo.components.learning import as_tensor, make_optimizer, predict_proba
from ifo.components.sail_models import (Discriminator, EpisodeMemory, Generator, accept, masked_mean, pad,
                                        sample_windows, split_episodes, step_mask, teacher_probability,
                                        train_discriminator)
from ifo.data.transitions import Transitions
from ifo.envs import EnvSpec
from ifo.envs.rollout import Rollouts
from ifo.learners.base import Context, Phase
from ifo.learners.bco import BCOConfig, BCOLearner, attention_report
from ifo.options import option

# Sizes per environment. The IDM, labels and policy follow IUPE's defaults (ifo/learners/bco.py);
# LunarLander's episodes are long (up to 1,000 steps, Box2D stepped one environment at a time), so
# fewer runs and passes per iteration keep it near the others' seconds per iteration.
SAIL_ENV_DEFAULTS: dict[str, dict] = {
    "lunarlander": dict(policy_epochs=5, episodes_per_iteration=25, is_capacity=30_000),
}


@dataclass(frozen=True)
class SAILConfig(BCOConfig):
    """IUPE's IDM, labels and policy, plus SAIL's generator G and discriminator D (Sec 9.1-9.2)."""

    idm_layer_norm: bool | None = option(True, "layer normalisation in the IDM (Sec 9.2; the policy has none)",
                                     advanced=True)
    generator_into_policy: bool | None = option(
        True, "G's error on the teacher's next states also trains the policy through its logits (Sec 9.1.2); "
              "off: the logits are detached, as in the authors' published code",
        title="G's error trains the policy")
    adversarial_weight: float | None = option(
        None, "λ: weight of D's judgement of G's predicted next states (Eq 9.1) in the policy's and G's loss; "
              "0 turns the adversarial term off", low=0.0, high=100.0, title="Adversarial weight λ")
    adversarial_steps: int | None = option(None, "behavioural-cloning mini-batches per iteration that also carry "
                                                 "the adversarial term (spread evenly)", low=0, high=100_000,
                                           advanced=True, work=1)
    generator_weight: float | None = option(1.0, "weight of G's error (Eq 9.2) in the joint loss", low=0.0,
                                            high=100.0, advanced=True)
    discriminator_updates: int | None = option(None, "Adam steps of D per iteration", low=0, high=100_000,
                                               advanced=True, work=1)
    discriminator_batch: int | None = option(16, "windows of the teacher's and of the policy's trajectories per "
                                                 "step of D (each)", low=1, high=4096, advanced=True)
    window: int | None = option(32, "length of the windows of states D reads (longer trajectories are cut)",
                                low=2, high=10_000, advanced=True)
    discriminator_lr: float | None = option(1e-3, "Adam's learning rate for D", low=1e-7, high=10.0, advanced=True)
    accept_threshold: float | None = option(0.5, "a run enters I_s when D's mean probability that it is the "
                                                 "teacher's is at least this (line 12)", low=0.0, high=1.0,
                                            advanced=True)
    replay_episodes: int | None = option(100, "RB holds the policy's trajectories up to this many times the "
                                              "teacher's average episode length in states", low=1,
                                         high=100_000, advanced=True)
    is_capacity: int | None = option(None, "|I_s| at most: the oldest accepted runs leave first, I_pre stays",
                                     low=10, high=10_000_000, advanced=True, title="|I_s| at most")

    def env_defaults(self, spec: EnvSpec) -> dict:
        return {**super().env_defaults(spec), "adversarial_weight": 0.1, "adversarial_steps": 50,
                "discriminator_updates": 30, "is_capacity": 40_000, **SAIL_ENV_DEFAULTS.get(spec.settings_name, {})}

    def unused(self) -> set[str]:
        out = super().unused() | {"sampling", "labels", "single_pass"}  # D decides what joins I_s
        if not self.adversarial_weight:
            out.add("adversarial_steps")
        return out

    def check(self) -> None:
        super().check()
        if self.labels == "expert":
            raise ValueError("SAIL labels the teacher's states with its own IDM: labels must be 'idm'")
        if self.single_pass:
            raise ValueError("SAIL is iterative: single_pass must be false")


class SAILLearner(BCOLearner):
    key = "sail"
    Config = SAILConfig
    phases = (
        Phase("idm", "training the inverse dynamics model (IDM) on I_s", "idm"),
        Phase("label", "labelling the teacher's state pairs with actions sampled from the IDM", "label"),
        Phase("policy", "training the policy and the next-state generator G together on the teacher's states "
                        "(labels, G's error and the discriminator's judgement)", "policy"),
        Phase("rollout", "running the policy to collect its own trajectories", "rollout"),
        Phase("sampling", "adding to I_s the runs the discriminator takes for the teacher's", "sampling"),
        Phase("discriminator", "training the discriminator on teacher and student sequences", "sampling"),
    )

    def __init__(self, ctx: Context, config: SAILConfig):
        ctx.require_vector_states("SAIL", " (thesis Ch. 9)")
        super().__init__(ctx, config)  # lines 1-5: I_pre, I_s = I_pre, the IDM and the policy
        cfg, obs_shape, n_actions, t_e = config, ctx.obs_shape, ctx.n_actions, ctx.expert
        self.accepted = self.pre.train.subset(np.zeros(0, dtype=np.int64))  # the accepted runs: none yet
        s, s2 = torch.as_tensor(t_e.states, dtype=torch.float32), torch.as_tensor(t_e.next_states, dtype=torch.float32)
        self.generator = Generator(obs_shape[0], n_actions)
        self.generator.fit_scaling(s, s2)
        self.discriminator = Discriminator(obs_shape[0])
        self.discriminator.fit_input_scaling(s)
        self.modules.update(generator=self.generator, discriminator=self.discriminator)
        self.optimizers.update(generator=make_optimizer(self.generator, cfg.lr),
                               discriminator=make_optimizer(self.discriminator, cfg.discriminator_lr))
        # the teacher's trajectories as state sequences (D's "teacher" side), and RB (its "student" side)
        self.teacher = split_episodes(t_e.states, t_e.next_states, t_e.episode_index)
        mean_length = float(np.mean([len(q) for q in self.teacher])) if self.teacher else 1.0
        self.replay = EpisodeMemory(int(cfg.replay_episodes * max(1.0, mean_length)))

    def network_options(self, role: str) -> dict:
        return {"layer_norm": bool(self.config.idm_layer_norm)} if role == "idm" else {}  # Sec 9.2: the IDM's

    def active_phases(self) -> list[str]:
        return [p.name for p in self.phases]

    # ------------------------------------------------------------------ one iteration
    def step(self, iteration: int, rng: np.random.Generator) -> dict:
        gen = self.ctx.seeds.torch_generator(rng)  # mini-batch order
        self.seed_global_rng(rng)  # D's dropout
        record, targets, _ = self.train_idm_and_label(rng, gen)  # lines 7-8 (the BCO loop's)
        self.behavioural_cloning(targets, rng, gen, record)  # line 9
        runs = self.run_policy(iteration, rng, record)  # lines 10-11
        sequences = split_episodes(runs.states, runs.next_states, runs.episode_index)
        self.let_in(runs, sequences, record)  # line 12, with D as it stands (random at first)
        self.train_discriminator(sequences, rng, record)  # Eq 9.1, D's side
        record["samples"] = {"environment_steps": self.environment_steps, "expert_samples": len(self.ctx.expert)}
        return record

    def behavioural_cloning(self, targets: np.ndarray, rng: np.random.Generator, gen: torch.Generator,
                            record: dict) -> None:
        """Line 9: π and G trained together on T_e, one pass per row of `targets` (labels drawn afresh)."""
        ctx, cfg, t_e, truth = self.ctx, self.config, self.ctx.expert, self.ctx.truth
        policy, g = self.policy, self.generator
        with ctx.phase("policy"):
            s, s2 = as_tensor(t_e.states), as_tensor(t_e.next_states)
            y = torch.as_tensor(targets, dtype=torch.long)
            n, bs = len(s), cfg.batch_size
            batches = [(p, start) for p in range(len(y)) for start in range(0, n, bs) if min(bs, n - start) >= 2]
            adversarial = cfg.adversarial_weight > 0 and cfg.adversarial_steps > 0 and len(self.replay.sequences) > 0
            carry = set()
            if adversarial and batches:
                spread = np.linspace(0, len(batches) - 1, min(cfg.adversarial_steps, len(batches)))
                carry = set(spread.round().astype(int).tolist())
            policy.train()
            g.train()
            bc_sum = g_sum = count = 0.0
            adv_losses = []
            orders = [torch.randperm(n, generator=gen) for _ in range(len(y))]
            for k, (p, start) in enumerate(batches):
                idx = orders[p][start:start + bs]
                logits = policy(s[idx])
                bc = F.cross_entropy(logits, y[p, idx])
                g_loss, g_error = g.losses(s[idx], logits if cfg.generator_into_policy else logits.detach(), s2[idx])
                loss = bc + cfg.generator_weight * g_loss
                if k in carry:
                    adv = self._adversarial_loss(rng)
                    adv_losses.append(adv.item())
                    loss = loss + cfg.adversarial_weight * adv
                self.optimizers["policy"].zero_grad(set_to_none=True)
                self.optimizers["generator"].zero_grad(set_to_none=True)
                loss.backward()
                self.optimizers["policy"].step()
                self.optimizers["generator"].step()
                if p == len(y) - 1:  # the last pass stands for the iteration in the record
                    bc_sum += bc.item() * len(idx)
                    g_sum += g_error.item() * len(idx)
                    count += len(idx)
            pol_probs = predict_proba(policy, policy, [t_e.states])
        labels = targets[0]
        record["policy"] = {"loss": bc_sum / max(count, 1), "agreement": float(np.mean(pol_probs.argmax(-1) == labels))}
        if truth.available:
            record["policy"]["expert_accuracy"] = truth.accuracy(pol_probs.argmax(-1))["accuracy"]
        record["policy"].update(attention_report(policy, t_e.states))
        record["generator"] = {"loss": g_sum / max(count, 1)}
        self.last_adversarial_loss = float(np.mean(adv_losses)) if adv_losses else None  # -log D, for people
        self.expert_probabilities = pol_probs

    def _adversarial_loss(self, rng: np.random.Generator) -> torch.Tensor:
        """Eq 9.1, the policy's side: on windows r' of the policy's own trajectories, G's predicted next states
        G(s_t, π(s_t)) as a sequence, judged by D; -log D (the non-saturating form) for each real step."""
        cfg, d = self.config, self.discriminator
        windows = self.replay.sample(cfg.discriminator_batch, cfg.window + 1, rng)
        starts = [w[:-1] if len(w) > 1 else w for w in windows]  # s_t whose next states G predicts
        x, lengths = pad(starts)
        mask = step_mask(lengths, x.shape[1]).bool()
        flat = x[mask]
        predicted = torch.zeros_like(x)
        predicted[mask] = self.generator(flat, self.policy(flat))
        was = d.training
        d.eval()  # no dropout in the judge; its weights do not move here
        for q in d.parameters():
            q.requires_grad_(False)
        try:
            logits = d(predicted, lengths)
        finally:
            for q in d.parameters():
                q.requires_grad_(True)
            d.train(was)
        return masked_mean(F.softplus(-logits), mask.float())

    def let_in(self, runs: Rollouts, sequences: list[np.ndarray], record: dict) -> None:
        """Line 12: the runs D takes for the teacher's join I_s (no goal test); RB keeps every run."""
        ctx, cfg, n_actions = self.ctx, self.config, self.ctx.n_actions
        with ctx.phase("sampling"):
            taken = accept(self.discriminator, sequences, cfg.window, cfg.accept_threshold)
            pos = Transitions(runs.states, runs.actions, runs.next_states)
            new = pos.subset(np.flatnonzero(taken[runs.episode_index]))
            kept = Transitions.concat([self.accepted, new])
            room = max(0, cfg.is_capacity - len(self.pre.train))
            if len(kept) > room:  # the oldest accepted transitions leave first
                kept = kept.subset(np.arange(len(kept) - room, len(kept)))
            self.accepted = kept
            self.train_set = Transitions.concat([self.pre.train, self.accepted])
            self.replay.add(sequences)
        from_pre, from_pos = self.pre.train.counts(n_actions), self.accepted.counts(n_actions)
        size = int(from_pre.sum() + from_pos.sum())
        record["sampling"] = {"mode": "discriminator", "from_pre": from_pre.tolist(), "from_pos": from_pos.tolist(),
                              "size": size, "target_share": None,
                              "realised_share": float(from_pos.sum()) / size if size else None, "cap": None}
        record["discriminator"] = {"accepted_share": float(np.mean(taken)) if len(taken) else None}
        record["replay"] = {"size": len(self.replay), "capacity": self.replay.capacity}

    def train_discriminator(self, sequences: list[np.ndarray], rng: np.random.Generator, record: dict) -> None:
        """Eq 9.1, D's side: a few windows of T_e (teacher) against windows of RB (student), then D's accuracy
        on fresh windows of each (a sequence counts as called teacher when its mean probability is >= 0.5)."""
        ctx, cfg, d = self.ctx, self.config, self.discriminator
        with ctx.phase("discriminator"):
            loss = train_discriminator(d, self.optimizers["discriminator"], self.teacher, self.replay.sequences,
                                       cfg.discriminator_updates, cfg.discriminator_batch, cfg.window, rng)
            n = 4 * cfg.discriminator_batch
            p_teacher = teacher_probability(d, sample_windows(self.teacher, n, cfg.window, rng), cfg.window)
            p_student = teacher_probability(d, self.replay.sample(n, cfg.window, rng), cfg.window)
        record["discriminator"].update({
            "loss": loss if cfg.discriminator_updates else None,
            "accuracy_expert": float(np.mean(p_teacher >= 0.5)), "accuracy_agent": float(np.mean(p_student < 0.5))})

    # ------------------------------------------------------------------ state
    def data_state(self) -> dict[str, np.ndarray]:
        return {"counters.environment_steps": np.array(self.environment_steps),
                **{k: v.copy() for k, v in self.accepted.arrays("accepted.").items()},
                **self.replay.arrays("replay.")}

    def load_data_state(self, arrays: dict[str, np.ndarray]) -> None:
        self.environment_steps = int(arrays["counters.environment_steps"])
        self.accepted = Transitions.from_arrays({k: np.array(v) for k, v in arrays.items()}, "accepted.")
        self.train_set = Transitions.concat([self.pre.train, self.accepted])
        self.replay.load_arrays(arrays, "replay.")
