"""Generative Adversarial Imitation Learning (Ho & Ermon 2016; thesis Sec 3.3): a reference that,
like BC, learns from the expert's actions.

    D(s, a) <- expert (s, a) pairs against the agent's             (Eq 3.7)
    π       <- PPO on the reward -log(1 - D(s, a))                 (TRPO in the original)

One Step is one round: discriminator updates on the agent's latest samples, then PPO learns
from the environment with D's reward (ifo/learners/adversarial.py).
"""
from ifo.methods import Method

GAIL = Method(
    name="gail", title="GAIL",
    summary="Adversarial reference: a discriminator tells the expert's (s, a) from the agent's; PPO learns from "
            "its reward.",
    learner="adversarial", sees_expert_actions=True,
    preset={"discriminator_input": "state-action"},
    run_defaults={"iterations": 50},
)
