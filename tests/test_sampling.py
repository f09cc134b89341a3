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


EPISODES = np.array([0, 0, 0, 0, 1, 1, 2, 2, 2, 2])  # which run each transition of POS came from


def test_eq_5_3_averages_action_shares_per_run_not_per_transition():
    from ifo.components.sampling import run_action_distribution

    # run 0: actions 0,0,1,1 (shares .5/.5); run 1: actions 0,1 (.5/.5); a long run would weigh as much as a short
    q = run_action_distribution(np.array([0, 0, 0, 0, 0, 0, 1, 1]), np.array([0] * 6 + [1, 1]), 2)
    assert q.tolist() == [0.5, 0.5]  # pooled counts would say 6/8 for action 0


def test_abco_draws_p_times_N_from_successful_runs_and_the_rest_from_I_pre():
    # p = 0.05, N = 100: 5 from the successful runs following P(A|E;I_pos) = (1/2, 1/2, 0)
    # and 95 from I_pre following P(A|I_pre) = (.6, .3, .1) -> 57, 28.5, 9.5
    t, mix = build_training_set("abco", PRE, POS, SUCCESS, 0.05, 3, RNG(), pos_episodes=EPISODES)
    assert sum(mix.from_pos) == 5 and mix.from_pos[2] == 0
    assert sum(mix.from_pre) == 95 and mix.from_pre[0] == 57
    assert mix.from_pre[1] + mix.from_pre[2] == 38
    assert (t.states[t.actions == 2] < 1000).all()  # the failed run never enters I_s
    assert mix.as_record()["realised_share"] == pytest.approx(0.05)


def test_abco_shrinks_I_s_so_short_runs_still_make_a_share_p():
    # p = 0.5 but the successful runs hold 6 transitions: 6 from them and 6 from I_pre, not 6 and 50
    _, mix = build_training_set("abco", PRE, POS, SUCCESS, 0.5, 3, RNG(), pos_episodes=EPISODES)
    assert mix.from_pos == [3, 3, 0] and sum(mix.from_pre) == 6
    rec = mix.as_record()
    assert rec["target_share"] == 0.5 and rec["realised_share"] == 0.5 and rec["size"] == 12


@pytest.mark.parametrize("mode", ["abco", "iupe"])
@pytest.mark.parametrize("p", [0.1, 0.37, 0.5, 0.8, 0.95])
@pytest.mark.parametrize("run_length", [3, 40, 400])
def test_the_realised_share_is_p_for_short_and_long_runs(mode, p, run_length):
    n_actions, pre = 3, make(np.arange(3000) % 3)
    rng = np.random.default_rng(1)
    runs = 20
    actions = rng.integers(0, n_actions, runs * run_length)
    pos = make(actions, offset=10_000)
    episodes = np.repeat(np.arange(runs), run_length)
    success = episodes < int(round(p * runs))  # p of the runs met the goal
    _, mix = build_training_set(mode, pre, pos, success, p, n_actions, rng, pos_episodes=episodes)
    n_pos, n_pre = sum(mix.from_pos), sum(mix.from_pre)
    assert n_pos > 0
    assert abs(n_pos - p * (n_pos + n_pre)) <= n_actions  # within one transition per class
    assert mix.as_record()["target_share"] == pytest.approx(p)


@pytest.mark.parametrize("mode", ["abco", "iupe"])
def test_p_of_one_is_the_successful_runs_alone(mode):
    t, mix = build_training_set(mode, PRE, POS, np.ones(10, bool), 1.0, 3, RNG(), pos_episodes=EPISODES)
    assert sum(mix.from_pre) == 0 and sum(mix.from_pos) == len(t) > 0
    assert mix.as_record()["realised_share"] == 1.0


def test_whole_sampling_draws_from_every_run_failed_ones_too():
    t, mix = build_training_set("abco-whole", PRE, POS, SUCCESS, 0.5, 3, RNG(), pos_episodes=EPISODES)
    assert mix.from_pos[2] > 0  # the failed run's action
    assert abs(sum(mix.from_pos) - 0.5 * len(t)) <= 3


def test_iupe_keeps_all_successful_runs_and_fills_with_I_pre_by_the_loss_probability():
    t, mix = build_training_set("iupe", PRE, POS, SUCCESS, 0.25, 3, RNG(), pos_episodes=EPISODES)
    assert mix.from_pos == [3, 3, 0]  # every successful transition
    assert sum(mix.from_pre) == 18  # n_pre = n_pos (1 - p) / p = 6 * 3
    # per action (1 - q(a)) * P(a | I_pre) = (.5*.6, .5*.3, 1*.1) = (.3, .15, .1): 9.8, 4.9, 3.3
    assert mix.from_pre == [10, 5, 3]
    assert len(t) == 24


def test_iupe_gives_actions_rare_in_successful_runs_more_random_samples():
    from ifo.components.sampling import allocate

    pre = make(np.arange(900) % 3)  # balanced I_pre
    pos = make([0] * 8 + [1] * 2, offset=1000)  # the successful run mostly pushes 0
    _, mix = build_training_set("iupe", pre, pos, np.ones(10, bool), 0.5, 3, RNG(),
                                pos_episodes=np.zeros(10, int))
    # weights (1 - q) = (.2, .8, 1.0): action 2, never used by the runs, gets the most
    assert mix.from_pre == allocate(10, np.array([0.2, 0.8, 1.0])).tolist()
    assert mix.from_pre[2] > mix.from_pre[1] > mix.from_pre[0]


def test_a_share_cap_lowers_p():
    _, mix = build_training_set("iupe", PRE, POS, SUCCESS, 0.5, 3, RNG(), pos_episodes=EPISODES, share_cap=0.25)
    rec = mix.as_record()
    assert rec["target_share"] == 0.25 and rec["cap"] == 0.25 and rec["realised_share"] == pytest.approx(0.25)


def test_appending_bco_alpha_keeps_I_pre_and_grows_by_every_run():
    first, mix = build_training_set("append", PRE, POS, SUCCESS, 0.5, 3, RNG())
    assert len(first) == len(PRE) + len(POS) and mix.from_pre == PRE.counts(3).tolist()
    second, mix = build_training_set("append", PRE, POS, SUCCESS, 0.5, 3, RNG(), previous=first)
    assert len(second) == len(first) + len(POS)
    assert sum(mix.from_pos) == 2 * len(POS)


@pytest.mark.parametrize("mode", ["abco", "iupe"])
def test_no_successful_run_falls_back_to_I_pre(mode):
    t, mix = build_training_set(mode, PRE, POS, np.zeros(10, bool), 0.0, 3, RNG())
    assert len(t) == 100 and mix.from_pos == [0, 0, 0] and mix.as_record()["realised_share"] == 0


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


def test_bco_alpha_keeps_I_pre_when_the_runs_hold_nothing():
    empty = POS.subset(np.zeros(0, dtype=np.int64))  # a maze policy that only walked into walls
    t, mix = build_training_set("none", PRE, empty, np.zeros(0, bool), 0.0, 3, RNG())
    assert len(t) == len(PRE) and sum(mix.from_pre) == len(PRE)  # never an empty I_s for the IDM
