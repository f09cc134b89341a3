"""Behavioural Cloning from Observation (Torabi et al. 2018; thesis Sec 3.1, 5.1.2).

BCO, one pass:
    I_pre <- random-policy transitions (s, a, s')
    M_theta <- argmax prod p_theta(a | s, s') over I_pre          (Eq 5.1)
    a_hat   <- MAP of M_theta on the expert pairs T_e
    pi_phi  <- argmax prod pi_phi(a_hat | s_e)                    (Eq 5.2)

BCO(alpha) repeats it alpha times, retraining the IDM only on the policy's own runs:
I_s = I_pos (sampling "none").
"""
from ifo.methods import Method

BCO = Method(
    name="bco", title="BCO",
    summary="One pass: IDM on random transitions, label the expert, clone the labels.",
    learner="bco",
    preset={"labels": "idm", "single_pass": True, "sampling": "none", "attention": "none", "explore_labels": False,
            "explore_rollouts": False},
)

BCO_ALPHA = Method(
    name="bco-alpha", title="BCO(α)",
    summary="Iterative BCO: after each pass the IDM is retrained on the policy's own runs (I_s = I_pos).",
    learner="bco",
    preset={"labels": "idm", "single_pass": False, "sampling": "none", "attention": "none", "explore_labels": False,
            "explore_rollouts": False},
)
