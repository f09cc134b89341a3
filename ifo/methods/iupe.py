"""Imitating Unknown Policies via Exploration (Ch. 6, Algorithm 6.1).

ABCO's loop with IUPE's sampling (Sec 6.1: every successful run, completed with I_pre
in proportion to the failures) and exploration (Sec 6.2): the expert labels a_hat and
the rollout actions are sampled from the softmax of the IDM and the policy instead of
taking the MAP action, so exploration decays by itself as the models grow confident.
"""
from ifo.methods import Method

IUPE = Method(
    name="iupe", title="IUPE",
    summary="ABCO's loop with IUPE sampling and exploration: labels and actions sampled from the softmax.",
    learner="bco",
    preset={"labels": "idm", "single_pass": False, "sampling": "iupe", "attention": "gated", "explore_labels": True,
            "explore_rollouts": True},
)
