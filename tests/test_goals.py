"""The goal-aware functions (thesis Sec 5.2, 9.1.1) on hand-made and real episodes."""
import numpy as np
import pytest

from ifo.envs import ENVS, Episode, UnknownEnvironment, get_env
from ifo.envs.rollout import EnvPool, run_episodes


def ep(ret=0.0, length=1, terminated=False, truncated=False, obs=(0.0,) * 8, reward=0.0, info=None):
    return Episode(ret, length, terminated, truncated, np.asarray(obs), reward, info or {})


def test_cartpole_goal_is_surviving_195_steps():
    goal = get_env("cartpole").goal
    assert goal(ep(ret=195, length=195, terminated=True))
    assert goal(ep(ret=500, length=500, truncated=True))
    assert not goal(ep(ret=194, length=194, terminated=True))


@pytest.mark.parametrize("name", ["acrobot", "mountaincar"])
def test_reaching_the_terminal_is_the_goal_and_time_out_is_not(name):
    goal = get_env(name).goal
    assert goal(ep(terminated=True))
    assert not goal(ep(truncated=True))


def test_lunarlander_goal_is_landing_at_rest_inside_the_screen():
    goal = get_env("lunarlander").goal
    assert goal(ep(terminated=True, reward=100.0, obs=(0.1,) + (0.0,) * 7))
    assert not goal(ep(terminated=True, reward=-100.0))  # crash
    assert not goal(ep(terminated=True, reward=100.0, obs=(1.2,) + (0.0,) * 7))  # off screen
    assert not goal(ep(truncated=True, reward=0.5))  # still hovering at the time limit


def test_maze_goal_reads_the_final_step():
    goal = get_env("maze5").goal
    assert goal(ep(terminated=True, reward=1.0, info={"at_goal": True}))
    assert not goal(ep(terminated=True, reward=-1.0, info={"at_goal": False}))


def test_mountaincar_goal_on_real_episodes():
    """An energy-pumping controller reaches the flag; doing nothing never does."""
    pool = EnvPool(get_env("mountaincar"))

    def pump(obs):
        a = np.where(obs[:, 1] >= 0, 2, 0)
        return a, a

    def idle(obs):
        a = np.ones(len(obs), dtype=int)
        return a, a

    assert run_episodes(pool, pump, range(5), record=False).goals.all()
    assert not run_episodes(pool, idle, range(5), record=False).goals.any()


def test_environment_names_and_aliases():
    assert get_env("CartPole-v1").name == "cartpole"
    assert get_env("LunarLander-v3").name == "lunarlander"
    assert get_env(" Maze10 ").name == "maze10"
    for spec in ENVS.values():
        assert spec.n_actions == len(spec.action_names) >= 2
    with pytest.raises(UnknownEnvironment, match="unknown environment 'pong'"):
        get_env("pong")
