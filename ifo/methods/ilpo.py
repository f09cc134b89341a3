"""Imitating Latent Policies from Observation (Edwards et al. 2019; thesis Sec 3.2).

    G(E(s), z) -> s' for each latent action z, only the closest trained per expert pair   (Eq 3.3)
    π_ω(z | s) so that the expected next state matches the expert's                      (Eq 3.4)
    a few environment steps: z_t = the closest latent action (Eq 3.5), π_ξ(a | z, s) <- a_t
    act with π(a | s) = Σ_z π_ω(z | s) π_ξ(a | z, s)

Vector states only (ifo/learners/ilpo.py).
"""
from ifo.methods import Method

ILPO = Method(
    name="ilpo", title="ILPO",
    summary="Latent actions from the expert's states alone (a forward model per latent action), then a few "
            "environment steps to learn which real action each one is.",
    learner="ilpo",
)
