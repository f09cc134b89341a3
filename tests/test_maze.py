"""The maze must be a faithful Gym-Maze: perfect layouts, exact rewards, a correct expert."""
import os

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")

import itertools  # noqa: E402
from collections import deque  # noqa: E402

import numpy as np  # noqa: E402
import pytest  # noqa: E402
from gymnasium.utils.env_checker import check_env  # noqa: E402

from ifo.envs import get_env  # noqa: E402
from ifo.envs.maze import (  # noqa: E402
    ACTION_NAMES, E, N, S, W, MazeEnv, ShortestPathExpert, generate_layout, layout_pool, random_return,
    render_maze, shortest_path_actions,
)

SIZES = (3, 5, 10)
BITS = {"N": 1, "S": 2, "W": 4, "E": 8}


# Independent helpers, so the tests do not check the module against itself.

def move(layout, cell, action):
    r, c = cell
    bit, dr, dc = [(1, -1, 0), (2, 1, 0), (4, 0, -1), (8, 0, 1)][action]
    return (r + dr, c + dc) if layout[r, c] & bit else (r, c)


def bfs_distance(layout, start=(0, 0)):
    n = layout.shape[0]
    dist = {start: 0}
    queue = deque([start])
    while queue:
        cell = queue.popleft()
        for a in range(4):
            nxt = move(layout, cell, a)
            if nxt not in dist:
                dist[nxt] = dist[cell] + 1
                queue.append(nxt)
    return dist.get((n - 1, n - 1))


def assert_perfect_maze(layout):
    n = layout.shape[0]
    assert layout.shape == (n, n) and layout.dtype == np.uint8
    assert layout.max() <= 15
    assert not (layout[0] & BITS["N"]).any() and not (layout[-1] & BITS["S"]).any()
    assert not (layout[:, 0] & BITS["W"]).any() and not (layout[:, -1] & BITS["E"]).any()
    # a passage is open from both sides
    assert np.array_equal(layout[1:] & BITS["N"] > 0, layout[:-1] & BITS["S"] > 0)
    assert np.array_equal(layout[:, 1:] & BITS["W"] > 0, layout[:, :-1] & BITS["E"] > 0)
    passages = int((layout[:-1] & BITS["S"] > 0).sum() + (layout[:, :-1] & BITS["E"] > 0).sum())
    assert passages == n * n - 1  # a tree: connected with n*n - 1 edges
    seen, stack = {(0, 0)}, [(0, 0)]
    while stack:
        cell = stack.pop()
        for a in range(4):
            nxt = move(layout, cell, a)
            if nxt not in seen:
                seen.add(nxt)
                stack.append(nxt)
    assert len(seen) == n * n


def run(env, actions):
    rewards, infos, flags = [], [], []
    for a in actions:
        _, reward, terminated, truncated, info = env.step(a)
        rewards.append(reward)
        infos.append(info)
        flags.append((terminated, truncated))
    return rewards, infos, flags


def sequential_sum(values):
    total = 0.0
    for v in values:
        total += v
    return total


# Layouts and pools

@pytest.mark.parametrize("size", SIZES)
def test_every_pool_layout_is_a_perfect_maze(size):
    for layout in layout_pool(size, "train") + layout_pool(size, "eval"):
        assert_perfect_maze(layout)


def test_generation_is_deterministic_and_varies_with_the_seed():
    for size in SIZES:
        assert np.array_equal(generate_layout(size, 7), generate_layout(size, 7))
        assert_perfect_maze(generate_layout(size, 7))
    assert len({generate_layout(5, s).tobytes() for s in range(20)}) == 20
    assert len({generate_layout(3, s).tobytes() for s in range(20)}) > 5


@pytest.mark.parametrize("size", SIZES)
def test_pools_are_disjoint_distinct_and_deterministic(size):
    train, evaluation = layout_pool(size, "train"), layout_pool(size, "eval")
    train_keys, eval_keys = [l.tobytes() for l in train], [l.tobytes() for l in evaluation]
    assert len(set(train_keys)) == len(train_keys) and len(set(eval_keys)) == len(eval_keys)
    assert not set(train_keys) & set(eval_keys)
    if size == 3:  # depth-first backtracking makes few 3x3 mazes: both splits get a fair share
        assert len(evaluation) >= 40 and len(train) >= 40
    else:
        assert len(evaluation) == 100 and len(train) == 1000
    assert eval_keys[0] == generate_layout(size, 1_000_000).tobytes()
    assert train_keys[0] == generate_layout(size, 0).tobytes() or size == 3
    assert [l.tobytes() for l in layout_pool(size, "eval")] == eval_keys
    with pytest.raises(ValueError):
        layout_pool(size, "test")


# Shortest paths and the expert

@pytest.mark.parametrize("size", SIZES)
def test_expert_walks_the_shortest_path_on_every_eval_layout(size):
    env = MazeEnv(size=size, split="eval", obs_mode="vector")
    expert = ShortestPathExpert()
    for index, layout in enumerate(env.pool):
        path = shortest_path_actions(layout)
        assert len(path) == bfs_distance(layout)
        obs, info = env.reset(options={"layout_index": index})
        assert info["layout_index"] == index
        steps, done = 0, False
        while not done:
            obs, reward, terminated, truncated, info = env.step(expert.act(obs[None])[0])
            steps += 1
            done = terminated or truncated
        assert info["at_goal"] and terminated and steps == len(path)
        assert env.expert_return() == pytest.approx(1 - (len(path) - 1) * 0.1 / size**2)


def test_no_shorter_path_exists_in_3x3_by_brute_force():
    for layout in layout_pool(3, "train") + layout_pool(3, "eval"):
        path = shortest_path_actions(layout)
        cell = (0, 0)
        for a in path:
            cell = move(layout, cell, a)
        assert cell == (2, 2)
        shorter = len(path) - 1  # try every action sequence of that length: none may reach the goal
        sequences = np.array(list(itertools.product(range(4), repeat=shorter)))
        table = np.array([[3 * move(layout, divmod(i, 3), a)[0] + move(layout, divmod(i, 3), a)[1]
                           for a in range(4)] for i in range(9)])
        cells = np.zeros(len(sequences), dtype=int)
        for t in range(shorter):
            cells = table[cells, sequences[:, t]]
            assert not (cells == 8).any()


def test_shortest_path_between_given_cells():
    layout = layout_pool(5, "eval")[0]
    assert shortest_path_actions(layout, start=(4, 4)) == []
    back = shortest_path_actions(layout, start=(4, 4), goal=(0, 0))
    assert len(back) == len(shortest_path_actions(layout))


def test_expert_rejects_image_observations():
    env = MazeEnv(size=5, obs_mode="image")
    obs, _ = env.reset(seed=0)
    with pytest.raises(ValueError, match="vector"):
        ShortestPathExpert().act(obs[None])
    assert ShortestPathExpert.meta == {"kind": "shortest-path"}


# Dynamics and rewards

def test_actions_are_named_n_s_w_e():
    assert (N, S, W, E) == (0, 1, 2, 3) and ACTION_NAMES == ("N", "S", "W", "E")
    assert get_env("maze5").action_names == ACTION_NAMES


def test_blocked_moves_keep_the_position():
    env = MazeEnv(size=5, obs_mode="vector")
    for seed in range(10):
        env.reset(seed=seed)
        _, reward, terminated, _, info = env.step(N)  # the outer wall is always closed
        assert info["position"] == (0, 0) == env.position and not terminated
        assert reward == pytest.approx(-0.1 / 25)
        for a in range(4):
            if not env.layout[0, 0] & (1, 2, 4, 8)[a]:
                _, _, _, _, info = env.step(a)
                assert info["position"] == (0, 0)
            else:
                _, _, _, _, info = env.step(a)
                assert info["position"] == move(env.layout, (0, 0), a)
                break


@pytest.mark.parametrize("size", SIZES)
def test_goal_reward_termination_and_step_penalty(size):
    env = MazeEnv(size=size, obs_mode="vector")
    env.reset(seed=3)
    path = shortest_path_actions(env.layout)
    rewards, infos, flags = run(env, path)
    assert rewards[:-1] == [pytest.approx(-0.1 / size**2)] * (len(path) - 1)
    assert rewards[-1] == 1.0 and flags[-1] == (True, False) and infos[-1]["at_goal"]
    assert not any(info["at_goal"] for info in infos[:-1]) and not any(t for t, _ in flags[:-1])
    assert infos[-1]["position"] == (size - 1, size - 1)
    assert sequential_sum(rewards) == pytest.approx(env.expert_return())


def test_truncation_at_max_steps():
    env = MazeEnv(size=5, obs_mode="vector", max_steps=5)
    env.reset(seed=0)
    _, _, flags = run(env, [N] * 5)
    assert flags[:4] == [(False, False)] * 4 and flags[4] == (False, True)


def test_deadlock_guard_ends_with_return_exactly_minus_one():
    env = MazeEnv(size=5, obs_mode="vector", deadlock_guard=True)
    env.reset(seed=0)
    rewards, infos, flags = run(env, [N, N, N])  # the start counts once: bumping 3 times is the 4th visit
    assert flags[-1] == (True, False) and infos[-1]["deadlocked"] and not infos[-1]["at_goal"]
    assert not any(i["deadlocked"] for i in infos[:-1])
    assert sequential_sum(rewards) == -1.0
    # random walks: every episode either reaches the goal or sums to exactly -1
    rng = np.random.default_rng(0)
    for size in SIZES:
        env = MazeEnv(size=size, obs_mode="vector", deadlock_guard=True)
        for seed in range(30):
            env.reset(seed=seed)
            rewards, done = [], False
            while not done:
                _, reward, terminated, truncated, info = env.step(int(rng.integers(4)))
                rewards.append(reward)
                done = terminated or truncated
            assert terminated and (info["at_goal"] or sequential_sum(rewards) == -1.0)
    # without the guard the same walk goes on
    env = MazeEnv(size=5, obs_mode="vector")
    env.reset(seed=0)
    _, infos, flags = run(env, [N] * 10)
    assert not any(t for t, _ in flags) and not any(i["deadlocked"] for i in infos)


# Observations and rendering

def test_vector_observation_encodes_position_and_walls():
    size = 5
    env = MazeEnv(size=size, obs_mode="vector")
    obs, _ = env.reset(seed=4)
    assert obs.shape == (size * size * 5,) and obs.dtype == np.float32 and env.observation_space.contains(obs)
    layout = env.layout
    walls = obs[size * size:].reshape(size, size, 4)
    for (r, c), open_sides in np.ndenumerate(layout):
        assert list(walls[r, c]) == [float(bool(open_sides & bit)) for bit in (1, 2, 4, 8)]
    assert obs[:size * size].sum() == 1 and obs[0] == 1
    obs, _, _, _, info = env.step(shortest_path_actions(layout)[0])
    r, c = info["position"]
    assert obs[:size * size].argmax() == r * size + c and obs[:size * size].sum() == 1
    assert np.array_equal(obs[size * size:], walls.ravel())


def is_blue(pixel):
    return pixel[2] > 150 and pixel[0] < 120 and pixel[1] < 150


def is_red(pixel):
    return pixel[0] > 150 and pixel[1] < 100 and pixel[2] < 100


def test_image_observation_colours_and_agent():
    env = MazeEnv(size=5, obs_mode="image", image_size=64)
    obs, _ = env.reset(seed=1)
    assert obs.shape == (64, 64, 3) and obs.dtype == np.uint8 and env.observation_space.contains(obs)
    assert is_blue(obs[2, 2]) and is_red(obs[-3, -3])
    assert np.array_equal(env.render(), obs)
    path = shortest_path_actions(env.layout)
    moved, _, _, _, _ = env.step(path[0])
    assert not np.array_equal(moved, obs)
    bumped, _, _, _, _ = env.step(N if not env.layout[env.position] & 1 else W)
    if env.position == move(env.layout, env.position, N):  # the bump did not move the agent
        assert np.array_equal(bumped, moved)
    agent_pixels = (moved[..., 0] < 30) & (moved[..., 1] < 30) & (moved[..., 2] > 90)
    assert agent_pixels.any()


def test_walls_stay_visible_in_small_images():
    layout = layout_pool(10, "eval")[0]
    image = render_maze(layout, (5, 5), image_size=32)
    assert image.shape == (32, 32, 3)
    black = (image.sum(axis=2) == 0)
    assert black[0].all() and black[-1].all() and black[:, 0].all() and black[:, -1].all()
    edges = [round(i * 32 / 10) for i in range(11)]
    for r in range(9):  # every closed wall between vertically neighbouring cells shows in its column middle
        for c in range(10):
            x = (edges[c] + edges[c + 1]) // 2
            if not layout[r, c] & BITS["S"]:
                assert black[edges[r + 1], x]
            else:
                assert not black[edges[r + 1], x]  # open, and the agent stays off the wall lines


def test_reset_with_the_same_seed_is_deterministic():
    for mode in ("vector", "image"):
        a, b = MazeEnv(size=5, obs_mode=mode), MazeEnv(size=5, obs_mode=mode)
        obs_a, info_a = a.reset(seed=123)
        obs_b, info_b = b.reset(seed=123)
        assert np.array_equal(obs_a, obs_b) and info_a == info_b
        assert info_a["layout_index"] == 123 % len(a.pool)
        assert np.array_equal(a.layout, a.pool[123 % len(a.pool)])
    env = MazeEnv(size=5, obs_mode="vector")
    env.reset(seed=0)
    picks = {env.reset()[1]["layout_index"] for _ in range(20)}
    assert len(picks) > 1  # without a seed the layout is drawn from the pool


def test_reset_with_an_explicit_layout():
    env = MazeEnv(size=5, obs_mode="vector")
    layout = generate_layout(5, 42)
    _, info = env.reset(options={"layout": layout})
    assert info["layout_index"] == -1 and np.array_equal(env.layout, layout)
    with pytest.raises(ValueError):
        env.reset(options={"layout": np.full((5, 5), 15, dtype=np.uint8)})


@pytest.mark.filterwarnings("ignore:.*alternative render modes")  # needs gymnasium.make; we have one mode
@pytest.mark.parametrize("mode", ["vector", "image"])
def test_passes_the_gymnasium_env_checker(mode):
    check_env(MazeEnv(size=5, obs_mode=mode, image_size=32), skip_render_check=False)


# References and integration

def test_reference_returns():
    layout = layout_pool(5, "eval")[0]
    expert = MazeEnv(size=5).expert_return(layout)
    assert expert == pytest.approx(1 - (len(shortest_path_actions(layout)) - 1) * 0.1 / 25)
    rand = random_return(layout, 5, episodes=20, seed=0)
    assert rand == random_return(layout, 5, episodes=20, seed=0)
    assert -0.1 / 25 * 1000 <= rand < expert


def test_spec_makes_the_maze_and_its_goal_test_reads_at_goal():
    from ifo.envs.rollout import EnvPool, run_episodes

    spec = get_env("maze5")
    pool = EnvPool(spec, obs_mode="vector", split="eval")
    expert = ShortestPathExpert()

    def act(obs):
        actions = expert.act(obs)
        return actions, actions

    rollouts = run_episodes(pool, act, seeds=range(8))
    assert rollouts.goals.all()
    assert all(e.info["at_goal"] for e in rollouts.episodes)
    assert rollouts.states.shape[1] == 5 * 5 * 5


def test_skipping_cycles_gives_exactly_the_returns_of_stepping_to_the_limit():
    """A deterministic policy that loops: fast-forwarding the cycle changes nothing but the time."""
    from ifo.envs import get_env
    from ifo.envs.rollout import EnvPool, run_episodes

    spec = get_env("maze5")

    def east_else_south_else_north(obs):
        # decode the one-hot cell and open sides from vector observations; loops in dead ends
        n = 25
        cell = obs[:, :n].argmax(1)
        sides = obs[:, n:].reshape(len(obs), n, 4)[np.arange(len(obs)), cell]
        a = np.where(sides[:, 3] > 0, 3, np.where(sides[:, 1] > 0, 1, 0))
        return a, a

    pool = EnvPool(spec, split="eval", obs_mode="vector", max_steps=300)
    full = run_episodes(pool, east_else_south_else_north, range(20))
    fast = run_episodes(pool, east_else_south_else_north, range(20), skip_cycles=True)
    np.testing.assert_allclose(fast.returns, full.returns)
    np.testing.assert_array_equal(fast.lengths, full.lengths)
    np.testing.assert_array_equal(fast.goals, full.goals)
    assert (full.lengths == 300).any() and len(fast.actions) < len(full.actions)


def test_a_fixed_world_of_the_first_n_layouts():
    full = layout_pool(5, "train")
    env = MazeEnv(5, split="train", obs_mode="vector", n_layouts=100)
    assert len(env.pool) == 100
    seen = set()
    for seed in (0, 99, 100, 12_345, 1_000_000):  # any seed lands on one of the 100
        env.reset(seed=seed)
        assert any(np.array_equal(env.layout, full[k]) for k in range(100))
        seen.add(env.layout_index)
    assert seen <= set(range(100))
    with pytest.raises(ValueError, match="n_layouts"):
        MazeEnv(5, n_layouts=0)


# The braided world (mazes with loops)

def passages(layout):
    return int((layout[:-1] & BITS["S"] > 0).sum() + (layout[:, :-1] & BITS["E"] > 0).sum())


@pytest.mark.parametrize("size", SIZES)
def test_braided_mazes_have_loops_and_no_dead_ends_and_the_expert_still_walks_a_shortest_path(size):
    spec = get_env(f"maze{size}-loops")
    assert spec.is_maze and spec.kwargs == {"size": size, "loops": 1.0} and spec.settings_name == f"maze{size}"
    pool = layout_pool(size, "eval", 1.0)
    for layout in pool[:20]:
        open_sides = [bin(int(x)).count("1") for x in layout.ravel()]
        assert min(open_sides) >= 2  # no dead end left
        assert passages(layout) > size * size - 1  # more passages than a tree: loops
        assert np.array_equal(layout[1:] & BITS["N"] > 0, layout[:-1] & BITS["S"] > 0)  # open from both sides
        assert not (layout[0] & BITS["N"]).any() and not (layout[:, -1] & BITS["E"]).any()
        env = MazeEnv(size=size, split="eval", obs_mode="vector", loops=1.0)
        obs, _ = env.reset(options={"layout": layout})
        actions = shortest_path_actions(layout)
        assert len(actions) == bfs_distance(layout)  # BFS on the graph with loops
        _, _, flags = run(env, actions)
        assert flags[-1] == (True, False)
    # braiding draws from its own stream: the perfect maze of a seed is unchanged, and loops=0 is it
    assert np.array_equal(generate_layout(size, 3, 0.0), generate_layout(size, 3))
    assert not set(map(bytes, layout_pool(size, "train", 1.0))) & set(map(bytes, pool))  # train and eval disjoint


def test_the_braided_world_is_closer_to_the_thesis_references():
    """The thesis's expert returns 0.966 / 0.971 / 0.982 (3×3 / 5×5 / 10×10); a random walk finds the goal
    more often with loops than in a perfect maze."""
    for size, thesis_expert in ((3, 0.966), (5, 0.971), (10, 0.982)):
        perfect, braided = get_env(f"maze{size}").references(), get_env(f"maze{size}-loops").references()
        assert abs(braided["expert_aer"] - thesis_expert) < abs(perfect["expert_aer"] - thesis_expert) + 1e-9
        assert braided["random_aer"] > perfect["random_aer"]


def test_a_braided_maze_run_uses_its_own_demonstrations_and_the_perfect_twins_settings():
    from ifo.config import RunConfig

    cfg = RunConfig(env="maze5-loops", method="iupe").resolved()
    twin = RunConfig(env="maze5", method="iupe").resolved()
    assert cfg.learner == twin.learner and cfg.rollout_max_steps == twin.rollout_max_steps
    from ifo.data.shipped import load_shipped_demonstrations

    demos = load_shipped_demonstrations(get_env("maze5-loops"))
    assert demos.n_episodes == 1000 and float(np.mean(demos.episode_returns)) == pytest.approx(0.970, abs=1e-3)
