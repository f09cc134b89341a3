"""I_s construction (Eqs 5.3-5.5, Sec 6.1) on hand-made data, with exact counts."""
import numpy as np
import pytest

from ifo.components.exploration import choose, exploration_rate
from ifo.components.sampling import allocate, build_training_set
from ifo.data.transitions import Transitions


def make(actions, offset=0.0):
    actions = np.asarray(actions)
    s = np.arange(len(actions), dtype=np.float32)[:, None] + offset
    return Transitions(s, actions, s + 1)


PRE = make([0] * 60 + [1] * 30 + [2] * 10)  # |I_pre| = 100, P(A|I_pre) = .6/.3/.1
# two successful runs (actions 0,0,1,1 and 0,1) and one failed run (2,2,2,2)
POS = make([0, 0, 1, 1, 0, 1, 2, 2, 2, 2], offset=1000)
SUCCESS = np.array([True] * 6 + [False] * 4)
RNG = lambda: np.random.default_rng(0)  # noqa: E731


def test_allocate_follows_the_distribution_and_sums_exactly():
    assert allocate(10, np.array([6, 3, 1])).tolist() == [6, 3, 1]
    counts = allocate(7, np.array([1, 1, 1]))
    assert counts.sum() == 7 and counts.max() - counts.min() <= 1
    assert allocate(0, np.array([1, 2])).tolist() == [0, 0]


def test_bco_alpha_trains_on_every_policy_run():
    t, mix = build_training_set("none", PRE, POS, SUCCESS, 2 / 3, 3, RNG())
    assert len(t) == 10 and mix.from_pre == [0, 0, 0] and mix.from_pos == [3, 3, 4]


def test_bco_alpha_keeps_a_budget_of_N_transitions_when_runs_are_long():
    long_runs = make(np.arange(250) % 3, offset=1000)
    t, mix = build_training_set("none", PRE, long_runs, np.ones(250, bool), 1.0, 3, RNG())
    assert len(t) == 100 and sum(mix.from_pos) == 100 and (t.states >= 1000).all()


def test_abco_draws_p_times_N_from_successful_runs_and_the_rest_from_I_pre():
    # p = 0.05, N = 100: 5 from successful I_pos following P(A|E;I_pos) = (3/6, 3/6, 0)
    # and 95 from I_pre following P(A|I_pre) = (.6, .3, .1) -> 57, 28.5, 9.5
    t, mix = build_training_set("abco", PRE, POS, SUCCESS, 0.05, 3, RNG())
    assert sum(mix.from_pos) == 5 and mix.from_pos[2] == 0
    assert sum(mix.from_pre) == 95 and mix.from_pre[0] == 57
    assert mix.from_pre[1] + mix.from_pre[2] == 38
    assert (t.states[t.actions == 2] < 1000).all()  # the failed run never enters I_s


def test_abco_takes_what_exists_when_a_class_is_short():
    _, mix = build_training_set("abco", PRE, POS, SUCCESS, 0.5, 3, RNG())
    # p*N = 50 wanted from 6 successful transitions: all 6 are used, none duplicated
    assert mix.from_pos == [3, 3, 0] and sum(mix.from_pre) == 50


def test_whole_sampling_uses_every_run():
    _, mix = build_training_set("abco-whole", PRE, POS, SUCCESS, 0.5, 3, RNG())
    assert mix.from_pos == [3, 3, 4] and sum(mix.from_pre) == 50


def test_iupe_keeps_all_successful_runs_and_fills_with_I_pre_by_the_loss_share():
    t, mix = build_training_set("iupe", PRE, POS, SUCCESS, 0.25, 3, RNG())
    assert mix.from_pos == [3, 3, 0]
    # (1-p) * N = 75 following P(A|I_pre): 45, 22.5, 7.5 -> the tie on .5 goes to the first class
    assert mix.from_pre == [45, 23, 7]
    assert len(t) == 81


@pytest.mark.parametrize("mode", ["abco", "iupe"])
def test_no_successful_run_falls_back_to_I_pre(mode):
    t, mix = build_training_set(mode, PRE, POS, np.zeros(10, bool), 0.0, 3, RNG())
    assert len(t) == 100 and mix.from_pos == [0, 0, 0]


def test_unknown_mode_is_refused():
    with pytest.raises(ValueError, match="sampling must be one of"):
        build_training_set("everything", PRE, POS, SUCCESS, 0.5, 3, RNG())


def test_map_choice_and_sampled_choice():
    probs = np.array([[0.9, 0.1], [0.2, 0.8]] * 500)
    chosen, map_a = choose(probs, sample=False, rng=RNG())
    assert (chosen == map_a).all() and exploration_rate(chosen, map_a) == 0
    chosen, map_a = choose(probs, sample=True, rng=RNG())
    rate = exploration_rate(chosen, map_a)
    assert 0.1 < rate < 0.2  # (0.1 + 0.2) / 2 expected
    certain = np.array([[0.0, 1.0]] * 100)
    chosen, _ = choose(certain, sample=True, rng=RNG())
    assert (chosen == 1).all()
