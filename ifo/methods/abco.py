"""Augmented BCO (Ch. 5, Algorithm 5.1): BCO(alpha) + self-attention + goal-aware sampling.

    I_s <- I_pre
    for i in 0..alpha:
        M_theta <- TRAINIDM(I_s)                                   (Eq 5.1, SA in the IDM)
        a_hat   <- MAP of M_theta on T_e
        pi_phi  <- behaviouralCloning(T_e, a_hat)                   (Eq 5.2, SA in the policy)
        run pi_phi |E| times -> I_pos, v_e = goal reached
        I_s <- SAMPLING(I_pre, I_pos, P(g|E), v_e)                  (Eqs 5.3-5.5)
"""
from ifo.methods import Method

ABCO = Method(
    name="abco", title="ABCO",
    summary="BCO(α) with self-attention and goal-aware sampling that mixes I_pre and successful runs.",
    learner="bco",
    preset={"labels": "idm", "single_pass": False, "sampling": "abco", "attention": "gated", "explore_labels": False,
            "explore_rollouts": False},
)
