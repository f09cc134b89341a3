"""Combined Reinforcement and Imitation Learning (Ch. 8, Algorithm 8.1): IUPE's loop, with the
policy also learning from its own rewards by temporal-difference updates (ifo/learners/cril.py)."""
from ifo.methods import Method

CRIL = Method(
    name="cril", title="CRIL",
    summary="IUPE's loop plus TD updates of the policy from its own experience, ε from its exploration ratio.",
    learner="cril",
    preset={"labels": "idm", "single_pass": False, "sampling": "iupe", "attention": "gated", "explore_labels": True,
            "explore_rollouts": False},
)
