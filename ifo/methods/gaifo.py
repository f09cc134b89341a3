"""Generative Adversarial Imitation from Observation (Torabi et al. 2019; thesis Sec 3.4): GAIL
with a discriminator over state transitions, so the expert's actions are never needed.

    D(s, s') <- expert state pairs T_e against the agent's          (Eq 3.7 over transitions)
    π        <- PPO on the reward D gives the agent's transitions

One Step is one round: discriminator updates on the agent's latest samples, then PPO learns
from the environment with D's reward (ifo/learners/adversarial.py).
"""
from ifo.methods import Method

GAIFO = Method(
    name="gaifo", title="GAIfO",
    summary="A discriminator tells the expert's state transitions (s, s') from the agent's; PPO learns from its "
            "reward. No expert actions.",
    learner="adversarial",
    preset={"discriminator_input": "state-transition"},
    run_defaults={"iterations": 50},
)
