"""The BCO family: one loop with switches. BC, BCO, BCO(α), ABCO and IUPE are its presets
(ifo/methods/), and every ablation row of the thesis's Tables 5.2 and 6.2 is a configuration.

    I_pre <- random-policy transitions (s, a, s'), split 70/30          # self-supervision
    T_e   <- the expert's state pairs (s, s')                           # NO actions
    I_s   <- I_pre
    each step (one iteration):
        M(a | s, s')  trained on I_s                                     # Eq 5.1
        â <- label(M, T_e)       MAP, or sampled afresh per pass (explore_labels, Sec 6.2)
        π(a | s)      trained on (s_e, â)                                # Eq 5.2
        I_pos, v_e <- run π |E| times, MAP or sampled (explore_rollouts); v_e = goal reached
        I_s <- sample(I_pre, I_pos, v_e)   none | abco | abco-whole | iupe  (Eqs 5.3-5.5, Sec 6.1)

BC (labels="expert") clones the expert's true actions instead of â: the supervised reference.
BCO (single_pass) stops after the first pass: no runs of π, I_s stays I_pre.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ifo.components.exploration import choose, exploration_rate, label_passes
from ifo.components.learning import fit, make_optimizer, predict_proba
from ifo.components.sampling import SAMPLING_MODES, build_training_set
from ifo.data.transitions import Transitions, stratified_split
from ifo.envs import EnvSpec
from ifo.envs.rollout import Rollouts, run_episodes
from ifo.learners.base import Context, Learner, LearnerConfig, Phase, histogram
from ifo.nets import ATTENTION_KINDS, InverseDynamics, Policy, feature_attention_map, gate_report, uses_dropout
from ifo.options import option
from ifo.probes import grad_cam_probe_record

# Sizes per environment. I_pre follows the authors' code (|A| x 5,000 capped per class;
# CartPole 10k, Acrobot/MountainCar 15k); mazes: images through a CNN cost ~100x a vector MLP,
# so fewer gradient steps per iteration.
ENV_DEFAULTS: dict[str, dict] = {
    "cartpole": dict(pre_size=10_000, episodes_per_iteration=50, lr=3e-3),
    "acrobot": dict(pre_size=15_000, episodes_per_iteration=50, lr=3e-3),
    "mountaincar": dict(pre_size=15_000, episodes_per_iteration=50, lr=3e-3),
    "lunarlander": dict(pre_size=20_000, episodes_per_iteration=50, lr=1e-3),
    "maze3": dict(pre_size=4_000, episodes_per_iteration=50, lr=1e-3, idm_epochs=1, policy_epochs=5),
    "maze5": dict(pre_size=6_000, episodes_per_iteration=50, lr=1e-3, idm_epochs=1, policy_epochs=5),
    "maze10": dict(pre_size=10_000, episodes_per_iteration=50, lr=1e-3, idm_epochs=1, policy_epochs=5),
}
COMMON_DEFAULTS = dict(idm_epochs=2, policy_epochs=10, pre_size=10_000, episodes_per_iteration=50, lr=1e-3)
ATTENTION_LABELS = {"none": "off", "gated": "on (gated, as in the thesis)", "features": "over state variables"}
SAMPLING_LABELS = {"none": "none: I_s = I_pos (BCO(α), as the thesis)",
                   "append": "append: I_pre + every run so far (BCO(α), Torabi et al.)",
                   "abco": "ABCO, partial (Eqs 5.3–5.5)", "abco-whole": "ABCO, whole (Table 5.2)",
                   "iupe": "IUPE (Sec 6.1)"}


@dataclass(frozen=True)
class BCOConfig(LearnerConfig):
    """The BCO loop's switches and sizes (None: the method's preset, then the environment's default)."""

    attention: str | None = option(None, "an attention module in the IDM and the policy (ABCO, IUPE; Sec 5.3); "
                                         "'over state variables' learns which variables matter and can be drawn",
                                   choices=ATTENTION_KINDS, labels=ATTENTION_LABELS, title="Attention")
    sampling: str | None = option(None, "what the IDM trains on next: the policy's own runs (I_pos), mixed with "
                                        "the random transitions (I_pre) by how often the runs reached the goal",
                                  choices=SAMPLING_MODES, labels=SAMPLING_LABELS, title="Sampling of I_s")
    explore_labels: bool | None = option(None, "label the expert's pairs with actions sampled from the IDM's "
                                               "softmax instead of the most likely one (IUPE, Sec 6.2)",
                                         title="Explore: sample the labels")
    explore_rollouts: bool | None = option(None, "run the policy with actions sampled from its softmax while it "
                                                 "collects its own experience (IUPE)",
                                           title="Explore: sample the policy's actions")
    labels: str | None = option(None, "where the policy's labels come from: the IDM (IfO) or the expert's true "
                                      "actions (BC, the supervised reference)", choices=("idm", "expert"),
                                advanced=True)
    single_pass: bool | None = option(None, "one pass and stop, as BCO does: no runs of the policy, I_s = I_pre",
                                      advanced=True)
    pre_size: int | None = option(None, "|I_pre|: random-policy transitions before the 70/30 split", low=10,
                                  high=2_000_000, advanced=True, work=1, title="|I_pre|")
    pre_per_action_cap: int | None = option(5_000, "at most this many random transitions per action in I_pre",
                                            low=1, advanced=True)
    episodes_per_iteration: int | None = option(None, "|E|: runs of the policy per iteration, which make I_pos",
                                                low=1, high=10_000, advanced=True, work=1, title="|E|")
    idm_epochs: int | None = option(None, "passes of the IDM over I_s per iteration", low=1, high=1000,
                                    advanced=True, work=1)
    policy_epochs: int | None = option(None, "passes of the policy over T_e per iteration", low=1, high=1000,
                                       advanced=True, work=1)
    batch_size: int | None = option(128, "mini-batch size of both models", low=2, high=65_536, advanced=True)
    lr: float | None = option(None, "Adam's learning rate for both models", low=1e-7, high=10.0, advanced=True)
    hidden: tuple[int, ...] | None = option((32, 32), "hidden layer widths of the vector networks",
                                            advanced=True)

    def env_defaults(self, spec: EnvSpec) -> dict:
        return {**COMMON_DEFAULTS, **ENV_DEFAULTS.get(spec.settings_name, {})}

    def fixed_iterations(self) -> int | None:
        return 1 if self.single_pass else None

    @classmethod
    def branchable(cls) -> set[str]:
        # attention and hidden change the networks, the sizes change I_pre: those start a new run
        return {"sampling", "explore_labels", "explore_rollouts", "episodes_per_iteration", "idm_epochs",
                "policy_epochs"}

    def unused(self) -> set[str]:
        out = set()
        if self.labels == "expert":
            out |= {"explore_labels", "idm_epochs", "pre_size", "pre_per_action_cap"}
        if self.labels == "expert" or self.single_pass:
            out |= {"sampling", "explore_rollouts", "episodes_per_iteration"}
        return out

    def check(self) -> None:
        super().check()
        if self.pre_size is not None and self.pre_per_action_cap is not None and self.pre_size < 10:
            raise ValueError(f"pre_size must be at least 10, got {self.pre_size}")


def attention_report(model: torch.nn.Module, *inputs: np.ndarray) -> dict:
    """What the model's attention did in its last pass (attention="features": weight per variable) or
    does on these inputs (attention="gated": gamma and effect per block); {} without attention."""
    out = {}
    att = feature_attention_map(model)
    if att is not None:
        out["attention"] = att.tolist()
    if not getattr(model, "is_image", True):
        gates = gate_report(model, *inputs)
        if gates is not None:
            out["gates"] = gates
    return out


def acting(model: torch.nn.Module, sample: bool, rng: np.random.Generator):
    """A batched acting function for the rollout engine: the model's softmax, sampled or MAP."""

    def act(obs: np.ndarray):
        return choose(predict_proba(model, model, [obs]), sample, rng)

    return act


class BCOLearner(Learner):
    key = "bco"
    Config = BCOConfig
    phases = (
        Phase("idm", "training the inverse dynamics model (IDM) on I_s", "idm"),
        Phase("label", "labelling the expert's state pairs with the IDM", "label"),
        Phase("policy", "training the policy on those labels", "policy"),
        Phase("attention", "drawing where the policy looks (Grad-CAM)", "policy"),
        Phase("rollout", "running the policy to collect its own experience (I_pos)", "rollout"),
        Phase("sampling", "choosing what the IDM learns from next (I_s)", "sampling"),
        Phase("diagnostics", "comparing the policy's runs with the expert's images (Fig 5.3)", "rollout"),
    )

    def __init__(self, ctx: Context, config: BCOConfig):
        super().__init__(ctx, config)
        cfg, run_cfg = config, ctx.config
        obs_shape, n_actions = ctx.obs_shape, ctx.n_actions
        self.uses_idm = cfg.labels == "idm"
        if not self.uses_idm and ctx.expert_actions is None:
            raise ValueError("BC learns from the expert's actions, and these demonstrations have none")
        # I_pre: random-policy transitions, split 70/30 for the IDM's training and validation.
        rng = ctx.seeds.rng("pre")
        self.pre = self.train_set = self.idm = None  # train_set is I_s
        self.environment_steps = 0  # what the learner has taken from the environment so far (Table 8.3)
        self.il_clip = None  # gradient clipping of the imitation steps (CRIL: 1)
        if self.uses_idm:
            everything, steps = ctx.random_transitions(cfg.pre_size, cfg.pre_per_action_cap, rng)
            self.environment_steps += steps
            self.pre = stratified_split(everything, n_actions, 0.3, rng)
            self.train_set = self.pre.train
            self.idm = InverseDynamics(obs_shape, n_actions, cfg.hidden, cfg.attention, **self.network_options("idm"))
            self.idm.fit_input_scaling(*map(torch.as_tensor, (self.pre.train.states, self.pre.train.next_states)))
            self.modules["idm"] = self.idm
            self.optimizers["idm"] = make_optimizer(self.idm, cfg.lr)
        policy = Policy(obs_shape, n_actions, cfg.hidden, cfg.attention, **self.network_options("policy"))
        policy.fit_input_scaling(torch.as_tensor(ctx.expert.states))
        self.modules["policy"] = policy
        self.optimizers["policy"] = make_optimizer(policy, cfg.lr)
        self.probes = ctx.spec.is_maze and policy.is_image and run_cfg.attention_probes
        self.runs_policy = self.uses_idm and not cfg.single_pass
        self.last_rollouts = None

    def network_options(self, role: str) -> dict:
        """Extra options of the "idm" and the "policy" networks (CRIL and SAIL add layer normalisation)."""
        return {}

    def active_phases(self) -> list[str]:
        names = ["idm", "label"] if self.uses_idm else []
        names.append("policy")
        if self.probes:
            names.append("attention")
        if self.runs_policy:
            names += ["rollout", "sampling"]
            if self.probes and self.ctx.truth.available:
                names.append("diagnostics")
        return names

    def sizes(self) -> dict:
        return {**super().sizes(), "pre_size": len(self.pre.train) if self.pre is not None else None}

    def probabilities(self, obs):
        return predict_proba(self.policy, self.policy, [obs])

    @property
    def draws_global_rng(self) -> bool:
        return any(uses_dropout(m) for m in self.modules.values())  # the image heads' (and SAIL's D's) dropout

    # ------------------------------------------------------------------ one iteration
    def step(self, iteration: int, rng: np.random.Generator) -> dict:
        gen = self.ctx.seeds.torch_generator(rng)  # mini-batch order
        self.seed_global_rng(rng)  # dropout in the image heads
        record = self.imitate(rng, gen)  # Eqs 5.1-5.2
        if self.runs_policy:
            runs = self.run_policy(iteration, rng, record)  # I_pos, v_e
            self.resample(runs, rng, record)  # I_s for the next iteration
        record["samples"] = {"environment_steps": self.environment_steps, "expert_samples": len(self.ctx.expert)}
        return record

    def imitate(self, rng: np.random.Generator, gen: torch.Generator) -> dict:
        """M(a | s, s') trained on I_s (Eq 5.1), â = its labels for T_e, π trained on (s_e, â) (Eq 5.2)."""
        record, targets, labels = self.train_idm_and_label(rng, gen)
        self.clone(record, targets, labels, gen)
        return record

    def train_idm_and_label(self, rng: np.random.Generator, gen: torch.Generator) -> tuple[dict, np.ndarray, np.ndarray]:
        """Eq 5.1 on I_s, then â for T_e (one row of labels per pass of the policy, sampled afresh when
        exploring). Returns the record's idm and labels sections, the labels per pass, and the first pass's
        labels. BC: the expert's true actions instead (the supervised reference)."""
        ctx, cfg, n_actions = self.ctx, self.config, self.ctx.n_actions
        t_e, truth = ctx.expert, ctx.truth
        record: dict = {}
        if self.uses_idm:
            with ctx.phase("idm"):  # Eq 5.1 on I_s
                i_s = self.train_set
                idm_fit = fit(self.idm, self.idm, self.optimizers["idm"], [i_s.states, i_s.next_states], i_s.actions,
                              cfg.idm_epochs, cfg.batch_size, gen, clip_value=self.il_clip)
                val = self.pre.validation
                val_probs = predict_proba(self.idm, self.idm, [val.states, val.next_states])
            with ctx.phase("label"):  # â for the expert's pairs
                probs = predict_proba(self.idm, self.idm, [t_e.states, t_e.next_states])
                targets, map_labels = label_passes(probs, cfg.explore_labels, cfg.policy_epochs, rng)
                labels = targets[0]  # the first pass's labels stand for the iteration in the record
            record["idm"] = {
                "loss": idm_fit.loss, "train_accuracy": idm_fit.accuracy,
                "val_accuracy": float(np.mean(val_probs.argmax(-1) == val.actions)) if len(val) else None,
                "train_size": len(i_s),
                "prediction_counts": np.bincount(map_labels, minlength=n_actions).tolist(),
                "mean_probabilities": probs.mean(0).tolist(),
                "confidence_histogram": histogram(probs.max(-1)),
            }
            record["labels"] = {"counts": np.bincount(labels, minlength=n_actions).tolist(),
                                "sampled": bool(cfg.explore_labels),
                                "exploration_rate": exploration_rate(targets, np.broadcast_to(map_labels, targets.shape))}
            record["idm"].update(truth.idm_report(map_labels, probs))
            record["labels"].update(truth.accuracy(targets))
            record["idm"].update(attention_report(self.idm, t_e.states, t_e.next_states))
        else:
            labels = targets = ctx.expert_actions  # BC: the supervised reference learns from the true actions
        return record, targets, labels

    def clone(self, record: dict, targets: np.ndarray, labels: np.ndarray, gen: torch.Generator) -> None:
        """Eq 5.2: behavioural cloning of π on (s_e, â); the record's policy (and attention) sections."""
        ctx, cfg, t_e, truth, policy = self.ctx, self.config, self.ctx.expert, self.ctx.truth, self.policy
        with ctx.phase("policy"):  # Eq 5.2 on (s_e, â)
            pol_fit = fit(policy, policy, self.optimizers["policy"], [t_e.states], targets, cfg.policy_epochs,
                          cfg.batch_size, gen, clip_value=self.il_clip)
            pol_probs = predict_proba(policy, policy, [t_e.states])
        record["policy"] = {"loss": pol_fit.loss, "agreement": float(np.mean(pol_probs.argmax(-1) == labels))}
        if truth.available:
            record["policy"]["expert_accuracy"] = truth.accuracy(pol_probs.argmax(-1))["accuracy"]
        record["policy"].update(attention_report(policy, t_e.states))
        self.expert_probabilities = pol_probs  # the policy's softmax on T_e (CRIL's exploration ratio)
        if self.probes:
            with ctx.phase("attention"):  # Fig 6.1: Grad-CAM on fixed probe frames
                record["attention"] = {"grad_cam": grad_cam_probe_record(
                    policy, ctx.spec.kwargs["size"], ctx.config.image_size, loops=ctx.spec.kwargs.get("loops", 0.0))}

    def run_policy(self, iteration: int, rng: np.random.Generator, record: dict) -> Rollouts:
        """|E| runs of π, MAP or sampled: I_pos, and v_e (the goal-aware function) per run."""
        ctx, cfg = self.ctx, self.config
        with ctx.phase("rollout"):
            seeds = ctx.seeds.episodes("rollouts", cfg.episodes_per_iteration, iteration)
            ro = run_episodes(ctx.pool, acting(self.policy, cfg.explore_rollouts, rng), seeds,
                              skip_cycles=ctx.spec.deterministic and not cfg.explore_rollouts)
        self.last_rollouts = ro
        self.environment_steps += int(ro.lengths.sum())
        record["rollouts"] = rollouts_record(ro, sampled=bool(cfg.explore_rollouts))
        return ro

    def resample(self, ro: Rollouts, rng: np.random.Generator, record: dict, share_cap: float | None = None) -> None:
        """I_s for the next iteration from I_pre and the runs (Eqs 5.3-5.5, Sec 6.1)."""
        ctx, cfg, truth = self.ctx, self.config, self.ctx.truth
        with ctx.phase("sampling"):
            pos, successful = Transitions(ro.states, ro.actions, ro.next_states), ro.successful()
            episodes = ro.episode_index
            if ctx.spec.is_maze:  # as for I_pre: drop moves into walls (nothing to learn from)
                moved = pos.moved()
                pos, successful, episodes = pos.subset(np.flatnonzero(moved)), successful[moved], episodes[moved]
            self.train_set, mixture = build_training_set(
                cfg.sampling, self.pre.train, pos, successful, float(ro.goals.mean()), ctx.n_actions, rng,
                pos_episodes=episodes, share_cap=share_cap, previous=self.train_set)
        record["sampling"] = {"mode": cfg.sampling, **mixture.as_record()}
        if self.probes and truth.available:
            with ctx.phase("diagnostics"):  # Fig 5.3: diagnostics with the hidden truth
                record["attention"].update(truth.image_distances(self.pre.train, ro.states, ro.actions,
                                                                 ctx.expert.states))

    # ------------------------------------------------------------------ state
    def data_state(self) -> dict[str, np.ndarray]:
        out = {"counters.environment_steps": np.array(self.environment_steps)}
        return {**out, **self.train_set.arrays("train_set.")} if self.train_set is not None else out

    def load_data_state(self, arrays: dict[str, np.ndarray]) -> None:
        if self.uses_idm:
            self.train_set = Transitions.from_arrays(arrays, "train_set.")
        if "counters.environment_steps" in arrays:  # (checkpoints before schema 2 did not count)
            self.environment_steps = int(arrays["counters.environment_steps"])


def rollouts_record(ro: Rollouts, sampled: bool) -> dict:
    return {"returns": ro.returns.tolist(), "lengths": ro.lengths.tolist(), "goals": ro.goals.astype(int).tolist(),
            "win_probability": float(ro.goals.mean()), "sampled": sampled, "exploration_rate": ro.exploration_rate,
            "transitions": len(ro.actions)}
