"""Behavioural Cloning (Sec 2.2.1): the supervised reference. It is the one method that
learns from the expert's actions: pi_phi is fit to (s_e, a_e) by maximum likelihood."""
from ifo.methods import Method

BC = Method(
    name="bc", title="BC",
    summary="Supervised reference: the policy learns from the expert's true actions.",
    learner="bco", sees_expert_actions=True,
    preset={"labels": "expert", "single_pass": False, "sampling": "none", "attention": "none",
            "explore_labels": False, "explore_rollouts": False},
)
