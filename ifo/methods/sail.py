"""Self-Supervised Adversarial Imitation Learning (Ch. 9, Algorithm 9.1): IUPE's self-supervised loop
with a discriminator instead of a goal test, and a next-state generator that carries the
discriminator's judgement into the policy (ifo/learners/sail.py)."""
from ifo.methods import Method

SAIL = Method(
    name="sail", title="SAIL",
    summary="IUPE's loop where a discriminator, not a goal test, picks the runs the IDM learns from, and a "
            "next-state generator trains the policy.",
    learner="sail",
    preset={"labels": "idm", "single_pass": False, "sampling": "none", "attention": "gated", "explore_labels": True,
            "explore_rollouts": True},
)
