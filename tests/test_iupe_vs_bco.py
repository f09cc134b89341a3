"""A short IUPE run on CartPole beats BCO(α) from the same seed (issue 3).

With a small I_pre (300 random transitions) the first IDM is weak and the first policy's runs
hold mostly one action. BCO(α) retrains its IDM on those runs alone and, from seed 5, collapses:
it gives every expert pair the same action ("vanishing actions", thesis Sec 6.1) and the pole
falls within ~10 steps. IUPE keeps only the successful runs and fills I_s from I_pre, so it
recovers. `python -m ifo bench vanishing` prints the same comparison over ten seeds
(docs/reproduction/vanishing-actions-cartpole.md: BCO(α) solves 4/10, IUPE 9/10).
"""
from ifo.bench import VANISHING, vanishing_actions_case

SEED = 5


def test_short_iupe_run_beats_bco_alpha_from_the_same_seed():
    bco = vanishing_actions_case("bco-alpha", SEED)
    iupe = vanishing_actions_case("iupe", SEED)
    assert len(iupe["aer_curve"]) == VANISHING["iterations"] == len(bco["aer_curve"])

    assert iupe["aer"] >= 475, iupe  # CartPole solved (500 is the cap)
    assert bco["aer"] < 100, bco
    # why: BCO(α)'s IDM labels (nearly) every expert pair with one action; IUPE's stays balanced
    assert bco["largest_label_share"] >= 0.95
    assert iupe["largest_label_share"] <= 0.7
