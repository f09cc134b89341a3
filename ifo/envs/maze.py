"""The thesis's Gym-Maze: perfect mazes, start top-left, goal bottom-right, four moves.

A layout is a (size, size) uint8 array; each cell holds a bitmask of its OPEN sides
(N=1, S=2, W=4, E=8; row 0 is the top, so N means row - 1). Layouts are made by
depth-first backtracking from a random cell, as Gym-Maze makes them. With `loops` > 0 that
share of the dead ends is then opened into a neighbour ("braiding"): the maze gains loops,
random walks find the goal sooner, and there is more than one way through, closer to the
world the thesis's random and expert returns suggest (see docs/CHOICES.md).

Unlike the thesis (100 fixed layouts, no held-out set), layouts come from two disjoint
pools: "train" for demonstrations and learning, "eval" for measuring generalisation.
"""
from __future__ import annotations

from collections import deque
from functools import lru_cache
from math import isqrt

import gymnasium as gym
import numpy as np

from ifo.envs.drawing import pixels3d, pygame
from ifo.runtime import BoundedCache

# Actions; each leaves its cell through one side.
N, S, W, E = 0, 1, 2, 3
ACTION_NAMES = ("N", "S", "W", "E")
OPEN_BIT = (1, 2, 4, 8)  # the side an action leaves through
OPPOSITE_BIT = (2, 1, 8, 4)  # the same passage seen from the neighbour
ROW_STEP = (-1, 1, 0, 0)
COL_STEP = (0, 0, -1, 1)
OPPOSITE_ACTION = (S, N, E, W)

# Pools of layouts.
TRAIN_POOL_SIZE = 1000
EVAL_POOL_SIZE = 100
EVAL_FIRST_SEED = 1_000_000
MAX_SEEDS_SCANNED = 20_000
# Small mazes run out of new layouts (DFS yields only 88 distinct 3x3 mazes); stop
# scanning once this many seeds in a row brought nothing new.
SCAN_PATIENCE = 3_000

STEP_PENALTY_TOTAL = 0.1  # per-step reward is -0.1 / (size * size), as in Gym-Maze
GOAL_REWARD = 1.0
DEADLOCK_VISITS = 4  # the authors' evaluation guard: the 4th visit to a cell ends the episode
DEADLOCK_RETURN = -1.0

WHITE = (255, 255, 255)
WALL_COLOR = (0, 0, 0)
START_COLOR = (60, 100, 230)  # blue
GOAL_COLOR = (230, 40, 40)  # red
AGENT_COLOR = (0, 0, 130)  # dark blue


# --------------------------------------------------------------------------- layouts

def generate_layout(size: int, seed: int, loops: float = 0.0) -> np.ndarray:
    """A perfect maze (exactly one path between any two cells) by depth-first backtracking,
    then (`loops` > 0) braided: that share of its dead ends opened into a neighbour.

    All randomness of the perfect maze is drawn up front from `default_rng(seed)`: one number
    picks the start cell, then one per carved passage picks among the unvisited neighbours. The
    braiding draws from a stream of its own, so `loops=0` gives exactly the perfect maze.
    """
    if size < 2:
        raise ValueError(f"maze size must be at least 2, got {size}")
    draws = np.random.default_rng(seed).random(size * size).tolist()
    layout = np.zeros((size, size), dtype=np.uint8)
    start = int(draws[0] * size * size)
    visited = [[False] * size for _ in range(size)]
    r, c = divmod(start, size)
    visited[r][c] = True
    stack = [(r, c)]
    carved = 0
    while stack:
        r, c = stack[-1]
        choices = []
        for a in (N, S, W, E):
            nr, nc = r + ROW_STEP[a], c + COL_STEP[a]
            if 0 <= nr < size and 0 <= nc < size and not visited[nr][nc]:
                choices.append((a, nr, nc))
        if not choices:
            stack.pop()  # dead end: backtrack
            continue
        carved += 1
        a, nr, nc = choices[int(draws[carved] * len(choices))]
        layout[r, c] |= OPEN_BIT[a]
        layout[nr, nc] |= OPPOSITE_BIT[a]
        visited[nr][nc] = True
        stack.append((nr, nc))
    return braid(layout, loops, np.random.default_rng([seed, 1])) if loops > 0 else layout


def braid(layout: np.ndarray, loops: float, rng: np.random.Generator) -> np.ndarray:
    """Open `loops` (0..1) of the dead ends (cells with one open side) into a walled-off neighbour,
    preferring a neighbour that is a dead end too (one opening then removes two), in row-major
    order; a copy."""
    if not 0.0 <= loops <= 1.0:
        raise ValueError(f"loops must be between 0 and 1, got {loops}")
    layout = layout.copy()
    size = layout.shape[0]

    def dead_end(r: int, c: int) -> bool:
        return bin(int(layout[r, c])).count("1") == 1

    for r in range(size):
        for c in range(size):
            if not dead_end(r, c) or rng.random() >= loops:
                continue
            closed = [(a, r + ROW_STEP[a], c + COL_STEP[a]) for a in (N, S, W, E)
                      if not layout[r, c] & OPEN_BIT[a]
                      and 0 <= r + ROW_STEP[a] < size and 0 <= c + COL_STEP[a] < size]
            if not closed:
                continue
            preferred = [x for x in closed if dead_end(x[1], x[2])] or closed
            a, nr, nc = preferred[int(rng.integers(len(preferred)))]
            layout[r, c] |= OPEN_BIT[a]
            layout[nr, nc] |= OPPOSITE_BIT[a]
    return layout


def _distinct_layouts(size: int, first_seed: int, want: int, loops: float = 0.0) -> list[np.ndarray]:
    """Distinct layouts from seeds first_seed, first_seed + 1, ... (bounded scan)."""
    found: dict[bytes, np.ndarray] = {}
    since_new = 0
    for seed in range(first_seed, first_seed + MAX_SEEDS_SCANNED):
        layout = generate_layout(size, seed, loops)
        key = layout.tobytes()
        if key in found:
            since_new += 1
            if since_new >= SCAN_PATIENCE:
                break
            continue
        found[key] = layout
        since_new = 0
        if len(found) >= want:
            break
    return list(found.values())


@lru_cache(maxsize=None)
def _pools(size: int, loops: float = 0.0) -> dict[str, tuple[np.ndarray, ...]]:
    supply = _distinct_layouts(size, 0, TRAIN_POOL_SIZE + EVAL_POOL_SIZE, loops)
    eval_candidates = _distinct_layouts(size, EVAL_FIRST_SEED, EVAL_POOL_SIZE, loops)
    # When few mazes exist (3x3), share them evenly rather than leave train empty.
    total = len({l.tobytes() for l in supply} | {l.tobytes() for l in eval_candidates})
    eval_pool = eval_candidates[:min(EVAL_POOL_SIZE, total // 2)]
    eval_keys = {l.tobytes() for l in eval_pool}
    train_pool = [l for l in supply if l.tobytes() not in eval_keys][:TRAIN_POOL_SIZE]
    for layout in eval_pool + train_pool:
        layout.flags.writeable = False  # shared by every environment: keep them intact
    return {"train": tuple(train_pool), "eval": tuple(eval_pool)}


def layout_pool(size: int, split: str, loops: float = 0.0) -> list[np.ndarray]:
    """The layouts of one split (of the perfect mazes, or of the braided ones with `loops`);
    deterministic, and train and eval never share a layout.

    eval: the first 100 distinct layouts from seeds 1_000_000, 1_000_001, ...
    train: distinct layouts from seeds 0, 1, ... that are not in eval, up to 1000.
    Depth-first backtracking makes only 88 distinct 3x3 mazes; there each split gets 44.
    """
    if split not in ("train", "eval"):
        raise ValueError(f"split must be 'train' or 'eval', got {split!r}")
    return list(_pools(int(size), float(loops))[split])


def _validate_layout(layout, size: int) -> np.ndarray:
    layout = np.asarray(layout)
    if layout.shape != (size, size):
        raise ValueError(f"layout must have shape ({size}, {size}), got {layout.shape}")
    layout = layout.astype(np.uint8)
    if (layout[0] & 1).any() or (layout[-1] & 2).any() or (layout[:, 0] & 4).any() or (layout[:, -1] & 8).any():
        raise ValueError("layout opens to the outside of the maze")
    if not (np.array_equal(layout[1:] & 1 > 0, layout[:-1] & 2 > 0)
            and np.array_equal(layout[:, 1:] & 4 > 0, layout[:, :-1] & 8 > 0)):
        raise ValueError("layout walls differ between neighbouring cells")
    return layout


# ------------------------------------------------------------------- shortest paths

def _neighbour_table(layout: np.ndarray) -> list[tuple[int, ...]]:
    """Per cell (row-major index) and action, the cell the move ends in (itself if blocked)."""
    size = layout.shape[0]
    table = []
    for cell, open_sides in enumerate(layout.ravel().tolist()):
        table.append(tuple(cell + ROW_STEP[a] * size + COL_STEP[a] if open_sides & OPEN_BIT[a] else cell
                           for a in (N, S, W, E)))
    return table


def shortest_path_actions(layout: np.ndarray, start: tuple[int, int] = (0, 0),
                          goal: tuple[int, int] | None = None) -> list[int]:
    """Actions of a shortest path from start to goal (default bottom-right), by BFS."""
    layout = np.asarray(layout)
    size = layout.shape[0]
    if goal is None:
        goal = (size - 1, size - 1)
    source, target = start[0] * size + start[1], goal[0] * size + goal[1]
    moves = _neighbour_table(layout)
    came_from: dict[int, tuple[int, int]] = {source: (-1, -1)}
    queue = deque([source])
    while queue and target not in came_from:
        cell = queue.popleft()
        for a, nxt in enumerate(moves[cell]):
            if nxt not in came_from:
                came_from[nxt] = (cell, a)
                queue.append(nxt)
    if target not in came_from:
        raise ValueError(f"goal {goal} cannot be reached from {start}")
    actions = []
    cell = target
    while cell != source:
        cell, a = came_from[cell]
        actions.append(a)
    return actions[::-1]


def _actions_towards_goal(layout: np.ndarray) -> np.ndarray:
    """For every cell, the first action of its shortest path to the goal (BFS from the goal)."""
    size = layout.shape[0]
    goal = size * size - 1
    moves = _neighbour_table(layout)
    best = np.zeros(size * size, dtype=np.int64)
    seen = {goal}
    queue = deque([goal])
    while queue:
        cell = queue.popleft()
        for a, nxt in enumerate(moves[cell]):
            if nxt not in seen:  # nxt reaches cell by the opposite move
                seen.add(nxt)
                best[nxt] = OPPOSITE_ACTION[a]
                queue.append(nxt)
    return best


def step_penalty(size: int) -> float:
    return STEP_PENALTY_TOTAL / (size * size)


def shortest_path_return(layout: np.ndarray) -> float:
    """Return of the shortest path: +1 at the goal, the step penalty for every other step."""
    size = np.asarray(layout).shape[0]
    length = len(shortest_path_actions(layout))
    return GOAL_REWARD - (length - 1) * step_penalty(size)


def random_return(layout: np.ndarray, size: int | None = None, episodes: int = 20, seed: int = 0,
                  max_steps: int = 1000) -> float:
    """Monte Carlo mean return of the uniform-random policy (no deadlock guard).

    All episodes walk at once on a table of moves, so no environment or rendering is involved.
    """
    layout = np.asarray(layout)
    size = layout.shape[0] if size is None else int(size)
    if layout.shape != (size, size):
        raise ValueError(f"layout shape {layout.shape} does not match size {size}")
    moves = np.array(_neighbour_table(layout), dtype=np.int64)
    goal = size * size - 1
    actions = np.random.default_rng(seed).integers(0, 4, size=(episodes, max_steps))
    cells = np.zeros(episodes, dtype=np.int64)
    steps_to_goal = np.zeros(episodes, dtype=np.int64)  # 0: never reached
    walking = np.ones(episodes, dtype=bool)
    for t in range(max_steps):
        cells = moves[cells, actions[:, t]]
        arrived = walking & (cells == goal)
        steps_to_goal[arrived] = t + 1
        walking &= ~arrived
        if not walking.any():
            break
    penalty = step_penalty(size)
    returns = np.where(steps_to_goal > 0, GOAL_REWARD - (steps_to_goal - 1) * penalty, -max_steps * penalty)
    return float(returns.mean())


# ------------------------------------------------------------------------ rendering

_backgrounds = BoundedCache(512)  # drawn backgrounds, so many layouts cannot eat the memory


def _cell_edges(size: int, image_size: int) -> list[int]:
    return [round(i * image_size / size) for i in range(size + 1)]


def _draw_background(layout: np.ndarray, image_size: int) -> tuple[pygame.Surface, list[tuple[int, int]], int]:
    """Walls, start and goal: everything that does not move during an episode."""
    size = layout.shape[0]
    edges = _cell_edges(size, image_size)
    cell_px = image_size / size
    wall = max(1, round(cell_px / 16))  # stays >= 1 px, so walls survive small images
    surface = pygame.Surface((image_size, image_size))
    surface.fill(WHITE)
    last = size - 1
    surface.fill(START_COLOR, pygame.Rect(edges[0], edges[0], edges[1] - edges[0], edges[1] - edges[0]))
    surface.fill(GOAL_COLOR, pygame.Rect(edges[last], edges[last], edges[size] - edges[last],
                                         edges[size] - edges[last]))

    def line_start(at: int) -> int:  # centre the line on the edge, keep it inside the image
        return min(max(at - wall // 2, 0), image_size - wall)

    for (r, c), open_sides in np.ndenumerate(layout):
        x0, x1, y0, y1 = edges[c], edges[c + 1], edges[r], edges[r + 1]
        if not open_sides & OPEN_BIT[N]:
            surface.fill(WALL_COLOR, pygame.Rect(line_start(x0), line_start(y0), x1 - x0 + wall, wall))
        if not open_sides & OPEN_BIT[S]:
            surface.fill(WALL_COLOR, pygame.Rect(line_start(x0), line_start(y1), x1 - x0 + wall, wall))
        if not open_sides & OPEN_BIT[W]:
            surface.fill(WALL_COLOR, pygame.Rect(line_start(x0), line_start(y0), wall, y1 - y0 + wall))
        if not open_sides & OPEN_BIT[E]:
            surface.fill(WALL_COLOR, pygame.Rect(line_start(x1), line_start(y0), wall, y1 - y0 + wall))
    # The part of a cell between its wall lines; a pygame circle of radius k centred at x
    # covers x-k .. x+k-1, so centre and radius are chosen to keep the agent off the walls.
    inside = [(e0 - wall // 2 + wall, e1 - wall // 2 - 1) for e0, e1 in zip(edges, edges[1:])]
    middles = [(first + last + 1) // 2 for first, last in inside]
    narrowest = min(last - first + 1 for first, last in inside)
    radius = max(1, min(round(cell_px * 0.3), narrowest // 2))
    centres = [(middles[c], middles[r]) for r in range(size) for c in range(size)]
    return surface, centres, radius


def _background(layout: np.ndarray, image_size: int, key: bytes | None = None):
    """The layout's background, drawn once per (size, image size, layout)."""
    cache_key = (layout.shape[0], image_size, layout.tobytes() if key is None else key)
    return _backgrounds.get_or_build(cache_key, lambda: _draw_background(layout, image_size))


def _frame(background, cell: int) -> np.ndarray:
    surface, centres, radius = background
    canvas = surface.copy()  # a fresh surface per frame: safe when threads render at once
    pygame.draw.circle(canvas, AGENT_COLOR, centres[cell], radius)
    # surfarray indexes (x, y); images are (row, column)
    return np.ascontiguousarray(pixels3d(canvas).transpose(1, 0, 2))


def render_maze(layout: np.ndarray, position: tuple[int, int], image_size: int = 64) -> np.ndarray:
    """RGB image (image_size, image_size, 3) uint8 of the maze with the agent at position."""
    layout = np.asarray(layout, dtype=np.uint8)
    size = layout.shape[0]
    return _frame(_background(layout, image_size), position[0] * size + position[1])


# ---------------------------------------------------------------------- environment

class MazeEnv(gym.Env):
    """Gym-Maze with layouts drawn from a train or eval pool.

    Reward +1 and termination at the goal, -0.1/(size*size) for every other step,
    truncation after max_steps. `n_layouts` keeps only the split's first n layouts.
    deadlock_guard=True reproduces the authors' evaluation:
    the 4th visit to any cell (bumping into a wall counts as a visit) ends the episode
    with a total return of exactly -1.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, size: int = 5, split: str = "train", obs_mode: str = "image", image_size: int = 64,
                 max_steps: int = 1000, deadlock_guard: bool = False, render_mode: str | None = "rgb_array",
                 n_layouts: int | None = None, loops: float = 0.0):
        if obs_mode not in ("image", "vector"):
            raise ValueError(f"obs_mode must be 'image' or 'vector', got {obs_mode!r}")
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be 'rgb_array' or None, got {render_mode!r}")
        self.size = int(size)
        self.split = split
        self.loops = float(loops)
        self.pool = layout_pool(self.size, split, self.loops)
        if n_layouts is not None:  # a fixed world of the split's first n layouts (the authors had 100)
            if n_layouts < 1:
                raise ValueError(f"n_layouts must be >= 1, got {n_layouts}")
            self.pool = self.pool[:n_layouts]
        self.obs_mode = obs_mode
        self.image_size = int(image_size)
        self.max_steps = int(max_steps)
        self.deadlock_guard = bool(deadlock_guard)
        self.render_mode = render_mode
        self.action_space = gym.spaces.Discrete(4)
        n_cells = self.size * self.size
        if obs_mode == "image":
            self.observation_space = gym.spaces.Box(0, 255, (self.image_size, self.image_size, 3), np.uint8)
        else:
            self.observation_space = gym.spaces.Box(0.0, 1.0, (n_cells * 5,), np.float32)
        self._step_penalty = step_penalty(self.size)
        self._goal_cell = n_cells - 1
        self._set_layout(self.pool[0], 0)

    # -- state
    def _set_layout(self, layout: np.ndarray, index: int) -> None:
        self.layout = layout
        self.layout_index = index
        self._layout_key = layout.tobytes()
        self._moves = _neighbour_table(layout)
        n_cells = self.size * self.size
        open_sides = (layout.reshape(-1, 1) & np.array(OPEN_BIT, dtype=np.uint8)) > 0
        # vector observation without the agent: zeros for the one-hot, then the walls
        self._obs_template = np.concatenate([np.zeros(n_cells, np.float32),
                                             open_sides.astype(np.float32).ravel()])
        self._background = None  # drawn on first use, then taken from the shared cache
        self._cell = 0
        self._visits = [0] * n_cells
        self._visits[0] = 1
        self._steps = 0
        self._return = 0.0

    @property
    def position(self) -> tuple[int, int]:
        return divmod(self._cell, self.size)

    def _observation(self) -> np.ndarray:
        if self.obs_mode == "vector":
            obs = self._obs_template.copy()
            obs[self._cell] = 1.0
            return obs
        return self._image(self.image_size)

    def _image(self, image_size: int) -> np.ndarray:
        if self._background is None or self._background_size != image_size:
            self._background = _background(self.layout, image_size, self._layout_key)
            self._background_size = image_size
        return _frame(self._background, self._cell)

    # -- gymnasium API
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = options or {}
        if "layout" in options:
            layout, index = _validate_layout(options["layout"], self.size), -1
        else:
            if "layout_index" in options:
                index = int(options["layout_index"])
            elif seed is not None:
                index = int(seed)
            else:
                index = int(self.np_random.integers(len(self.pool)))
            index %= len(self.pool)
            layout = self.pool[index]
        self._set_layout(layout, index)
        info = {"layout_index": index, "position": self.position, "at_goal": False, "deadlocked": False}
        return self._observation(), info

    def step(self, action):
        action = int(action)
        if not 0 <= action < 4:
            raise ValueError(f"action must be 0..3 (N, S, W, E), got {action}")
        cell = self._moves[self._cell][action]  # a blocked move leaves the cell unchanged
        self._cell = cell
        self._steps += 1
        at_goal = cell == self._goal_cell
        deadlocked = False
        if at_goal:
            reward = GOAL_REWARD
        else:
            reward = -self._step_penalty
            self._visits[cell] += 1
            if self.deadlock_guard and self._visits[cell] >= DEADLOCK_VISITS:
                deadlocked = True
                reward = DEADLOCK_RETURN - self._return  # the episode sums to exactly -1
        self._return += reward
        terminated = at_goal or deadlocked
        truncated = not terminated and self._steps >= self.max_steps
        info = {"position": divmod(cell, self.size), "at_goal": at_goal, "layout_index": self.layout_index,
                "deadlocked": deadlocked}
        return self._observation(), reward, terminated, truncated, info

    def render(self):
        if self.render_mode is None:
            return None
        return self._image(self.image_size)

    def expert_return(self, layout: np.ndarray | None = None) -> float:
        """Return of the shortest path on layout (default: the current one)."""
        return shortest_path_return(self.layout if layout is None else layout)


# --------------------------------------------------------------------------- expert

class ShortestPathExpert:
    """Acts along the shortest path; reads walls and agent cell from vector observations."""

    meta = {"kind": "shortest-path"}

    def __init__(self, cache_size: int = 4096):
        self._plans = BoundedCache(cache_size)  # layout bytes -> the action towards the goal, per cell

    def _plan(self, layout: np.ndarray) -> np.ndarray:
        return self._plans.get_or_build(layout.tobytes(), lambda: _actions_towards_goal(layout))

    def act(self, obs: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs)
        if obs.ndim == 1:
            obs = obs[None]
        n_cells = obs.shape[-1] // 5
        size = isqrt(n_cells)
        if obs.ndim != 2 or size < 2 or size * size * 5 != obs.shape[-1]:
            raise ValueError("ShortestPathExpert needs vector observations (MazeEnv(obs_mode='vector')), "
                             f"shape (batch, size*size*5); got shape {obs.shape}")
        cells = obs[:, :n_cells].argmax(axis=1)
        open_bits = obs[:, n_cells:].reshape(len(obs), n_cells, 4) > 0.5
        layouts = (open_bits @ np.array(OPEN_BIT)).astype(np.uint8).reshape(len(obs), size, size)
        return np.array([self._plan(layout)[cell] for layout, cell in zip(layouts, cells)], dtype=np.int64)


def observation(layout: np.ndarray, position, obs_mode: str = "image", image_size: int = 64) -> np.ndarray:
    """The observation MazeEnv would give with the agent at `position` (used to render stored demos)."""
    size = layout.shape[0]
    row, col = (int(v) for v in position)
    if obs_mode == "vector":
        open_sides = (layout.reshape(-1, 1) & np.array(OPEN_BIT, dtype=np.uint8)) > 0
        obs = np.concatenate([np.zeros(size * size, np.float32), open_sides.astype(np.float32).ravel()])
        obs[row * size + col] = 1.0
        return obs
    return render_maze(layout, (row, col), image_size)
