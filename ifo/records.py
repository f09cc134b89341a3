"""Iteration records: what one press of Step produced, as plain data (JSON numbers and lists).

A record is a dict of typed *sections*. Every learner writes only the sections it has;
`Run` adds `iteration`, `schema`, `evaluation` and `seconds`. Figures, panels, the export
and the CSV choose what to draw by the sections a record has (`ifo.figures.REGISTRY`),
never by the method's name.

The TypedDicts below are the contract (documentation and type hints; records stay plain
dicts so they save as JSON and load without any class). `total=False` marks the keys a
learner may leave out (diagnostics that need the hidden true actions, for instance).
SCHEMA is bumped whenever a section changes meaning; `upgrade()` reads older records.
"""
from __future__ import annotations

from typing import TypedDict

SCHEMA = 2  # 1: records before sections were typed (no "schema" key)


class IdmSection(TypedDict, total=False):
    """The inverse dynamics model M(a | s, s') after its training on I_s (Eq 5.1)."""
    loss: float
    train_accuracy: float
    val_accuracy: float | None  # on I_pre's held-out 30%
    train_size: int  # |I_s|
    prediction_counts: list[int]  # its MAP label for each expert pair, counted per action (Figs 5.2, 6.2a)
    mean_probabilities: list[float]  # its softmax averaged over T_e
    confidence_histogram: list[int]  # 10 bins over [0, 1]: the MAP action's probability on each expert pair
    # diagnostics from the hidden true actions (shown to people, never trained on)
    true_counts: list[int]
    expert_accuracy: float
    confusion: list[list[int]]  # rows: true action, columns: MAP label
    true_action_probability_histogram: list[int]  # 10 bins: the probability given to the true action
    attention: list[float]  # attention="features": mean weight per input variable
    gates: list[dict]  # attention="gated": per block {"block", "gamma", "effect"} (see nets.gate_report)


class LabelsSection(TypedDict, total=False):
    """The pseudo-labels â given to the expert's states (MAP or sampled, Sec 6.2)."""
    counts: list[int]
    sampled: bool
    exploration_rate: float  # share of labels that are not the MAP action (Fig 6.2b)
    accuracy: float  # against the hidden truth


class PolicySection(TypedDict, total=False):
    """The policy pi(a | s) after behavioural cloning on (s_e, â) (Eq 5.2)."""
    loss: float
    agreement: float  # its MAP action equals its label
    expert_accuracy: float  # against the hidden truth
    attention: list[float]
    gates: list[dict]


class RolloutsSection(TypedDict, total=False):
    """The |E| runs of the policy that make I_pos (Sec 5.2)."""
    returns: list[float]
    lengths: list[int]
    goals: list[int]  # v_e, the goal-aware function per run
    win_probability: float  # P(g | E), Eq 5.3
    exploration_rate: float  # share of rollout actions that were not the MAP action
    transitions: int


class SamplingSection(TypedDict, total=False):
    """I_s for the next iteration (Eqs 5.3-5.5, Sec 6.1): per action, how much came from where."""
    mode: str
    from_pre: list[int]
    from_pos: list[int]
    size: int
    target_share: float | None  # the share of I_s the text asks to come from I_pos (p, or capped p)
    realised_share: float | None  # the share that did
    cap: float | None  # CRIL's upper limit on I_pos's share (Eq 8.2)


class AttentionSection(TypedDict, total=False):
    """Image attention diagnostics (Figs 5.3, 6.1)."""
    grad_cam: dict
    mean_image_distance: dict


class TdSection(TypedDict, total=False):
    """CRIL's temporal-difference updates of the policy from its own experience (Ch. 8)."""
    loss: float
    epsilon: float  # of its epsilon-greedy runs: the exploration ratio of the imitation step
    q_min: float
    q_max: float
    updates: int
    stop_rule_met: bool


class ReplaySection(TypedDict, total=False):
    size: int
    capacity: int


class SamplesSection(TypedDict, total=False):
    """What the learner has consumed so far: the thesis's sample count (Table 8.3)."""
    environment_steps: int
    expert_samples: int


class DiscriminatorSection(TypedDict, total=False):
    """An adversarial learner's discriminator D (GAIL, GAIfO, SAIL)."""
    loss: float
    accuracy_expert: float  # share of expert samples D calls expert
    accuracy_agent: float  # share of agent samples D calls agent
    accepted_share: float | None  # SAIL: share of the policy's episodes D lets into I^s
    mean_reward: float | None  # GAIL/GAIfO: mean learned reward of the agent's samples


class GeneratorSection(TypedDict, total=False):
    loss: float  # SAIL's G (Eq 9.2) during behavioural cloning; PPO's loss for GAIL/GAIfO
    value_loss: float | None
    entropy: float | None
    environment_steps: int | None


class LatentSection(TypedDict, total=False):
    """ILPO's latent actions."""
    assignment_counts: list[int]  # how many expert pairs each latent action explains best
    forward_error: float
    remap: list[list[int]]  # latent x real action counts of the remapping


class PolicyMapSection(TypedDict, total=False):
    """The policy over a grid of two state variables (Figs 8.2, 8.3; Table 8.1)."""
    x_name: str
    y_name: str
    x: list[float]
    y: list[float]
    action: list[list[int]]  # rows: y index, columns: x index
    probability: list[list[float]]
    reference_action: list[list[int]] | None
    kl: float | None  # KL(reference || policy), mean over the grid
    onehot_kl: float | None  # the same with the reference's MAP action as a one-hot


class EvaluationSection(TypedDict, total=False):
    aer: float  # Eq 4.1
    aer_std: float
    performance: float | None  # Eq 4.2
    returns: list[float]
    goal_rate: float
    mean_length: float
    sampled_actions: bool
    fidelity: float
    random_reference: float | None
    expert_reference: float | None


SECTIONS: dict[str, type] = {
    "idm": IdmSection, "labels": LabelsSection, "policy": PolicySection, "rollouts": RolloutsSection,
    "sampling": SamplingSection, "attention": AttentionSection, "td": TdSection, "replay": ReplaySection,
    "samples": SamplesSection, "discriminator": DiscriminatorSection, "generator": GeneratorSection,
    "latent": LatentSection, "policy_map": PolicyMapSection, "evaluation": EvaluationSection,
    "seconds": dict,
}
HEADER = ("iteration", "schema")


def check(record: dict) -> dict:
    """A record whose keys are all known sections; ValueError names the unknown ones."""
    unknown = set(record) - set(SECTIONS) - set(HEADER)
    if unknown:
        raise ValueError(f"unknown record section(s): {', '.join(sorted(unknown))}")
    return record


def upgrade(record: dict) -> dict:
    """A record of any earlier schema in today's form (schema 1 had the same sections, unnamed)."""
    if "schema" not in record:
        record = {**record, "schema": SCHEMA}
    return record


def sections_of(records) -> set[str]:
    """Every section any of these records has."""
    return {key for r in records for key in r if key in SECTIONS}
