"""Write the shipped demonstrations and measure the reference returns Performance uses.

    python -m ifo experts demos --env cartpole        # assets/demos/cartpole.npz (+ -actions.npz)
    python -m ifo experts references --env cartpole   # random and expert AER -> assets/references.json
    python -m ifo experts demos --env cartpole --level 3   # assets/demos/cartpole-level3.npz (+ -actions.npz)

Demonstrations use training seeds 0, 1, ...; every evaluation (the references included)
uses separate seeds (`ifo.seeds.EVAL_SEED_BASE`) or, for the maze, held-out layouts.
Like the thesis's experts, level-1 episodes below a quality threshold are not kept; the
sub-optimal levels (2-5, Ch. 7) keep every episode, so their demonstrations show that expert as it
is (their mean return is the level's AER on seeds 0..episodes-1).
"""
from __future__ import annotations

import json

import numpy as np

from ifo.data.demos import shipped_actions_path, shipped_demos_path
from ifo.envs import ASSETS, EnvSpec, get_env, load_references
from ifo.envs.rollout import EnvPool, random_returns, run_episodes
from ifo.experts import load_expert
from ifo.io import atomic_write_bytes, atomic_write_json, npz_bytes
from ifo.seeds import EVAL_SEED_BASE

# Keep demonstration episodes at least this good (the thesis's expert filtering, FIELD-NOTES).
KEEP_THRESHOLD = {"cartpole": 475, "acrobot": -100, "mountaincar": -108, "lunarlander": 200}


def _greedy(expert):
    def act(obs):
        a = expert.act(obs)
        return a, a

    return act


def make_demonstrations(env: str, episodes: int = 100, log=print, level: int = 1) -> dict:
    from ifo.data.shipped import level_demos_path

    spec = get_env(env)
    if spec.is_maze:
        if level != 1:
            raise ValueError(f"{spec.name} has one expert (shortest paths): no level {level}")
        return _make_maze_demonstrations(spec, episodes, log)
    expert = load_expert(spec, level)
    pool = EnvPool(spec)
    kept, seed, batches = [], 0, 0
    threshold = KEEP_THRESHOLD.get(spec.name, -np.inf) if level == 1 else -np.inf
    while len(kept) < episodes and batches < 20:
        seeds = np.arange(seed, seed + episodes)
        ro = run_episodes(pool, _greedy(expert), seeds)
        for e, ep in enumerate(ro.episodes):
            if ep.ret >= threshold and len(kept) < episodes:
                kept.append((ro, e))
        seed += episodes
        batches += 1
    if len(kept) < episodes:
        log(f"{spec.name}: only {len(kept)} episodes reached the threshold {threshold}")
    obs, next_obs, actions, rewards, starts = [], [], [], [], []
    for ro, e in kept:
        idx = np.flatnonzero(ro.episode_index == e)
        obs.append(ro.states[idx])
        next_obs.append(ro.next_states[idx])
        actions.append(ro.actions[idx])
        rewards.append(ro.rewards[idx])
        s = np.zeros(len(idx), dtype=np.int8)
        s[0] = 1
        starts.append(s)
    arrays = {"obs": np.concatenate(obs).astype(np.float32), "next_obs": np.concatenate(next_obs).astype(np.float32),
              "rewards": np.concatenate(rewards).astype(np.float32), "episode_starts": np.concatenate(starts)}
    returns = np.array([ro.episodes[e].ret for ro, e in kept])
    arrays["episode_returns"] = returns.astype(np.float32)
    all_actions = np.concatenate(actions).astype(np.int64)
    if level == 1:  # the level-1 files keep the true actions apart (`*-actions.npz`)
        atomic_write_bytes(shipped_demos_path(spec), npz_bytes(arrays))
        atomic_write_bytes(shipped_actions_path(spec), npz_bytes({"actions": all_actions}))
        size = shipped_demos_path(spec).stat().st_size + shipped_actions_path(spec).stat().st_size
    else:  # levels 2-5: one file that also holds the actions (only BC and GAIL ever see them); it loads
        #    as anyone's demonstrations too (`train --demos assets/demos/<env>-level<K>.npz`)
        path = level_demos_path(spec, level)
        atomic_write_bytes(path, npz_bytes({**arrays, "actions": all_actions}))
        size = path.stat().st_size
    summary = {"env": spec.name, "level": level, "episodes": len(kept), "transitions": int(len(arrays["obs"])),
               "mean_return": float(returns.mean()), "bytes": size}
    if level != 1:
        from ifo.experts.train import _write_level_info

        _write_level_info(spec.name, level, {"demos_episodes": len(kept), "demos_transitions": summary["transitions"],
                                             "demos_mean_return": round(summary["mean_return"], 3),
                                             "demos_bytes": size}, merge=True)
    log(json.dumps(summary))
    return summary


def _make_maze_demonstrations(spec: EnvSpec, episodes: int, log) -> dict:
    from ifo.envs.maze import MazeEnv, ShortestPathExpert

    env = MazeEnv(**spec.kwargs, split="train", obs_mode="vector")
    expert = ShortestPathExpert()
    layouts, positions, next_positions, actions, rewards, starts, returns = [], [], [], [], [], [], []
    for ep in range(episodes):
        obs, info = env.reset(seed=ep)
        layouts.append(env.layout.copy())
        done, first, total = False, True, 0.0
        while not done:
            a = int(expert.act(obs[None])[0])
            pos = env.position
            obs, r, term, trunc, info = env.step(a)
            positions.append(pos)
            next_positions.append(env.position)
            actions.append(a)
            rewards.append(r)
            starts.append(1 if first else 0)
            first, done, total = False, term or trunc, total + r
        returns.append(total)
    arrays = {"layouts": np.stack(layouts).astype(np.uint8), "episode_layout": np.arange(episodes),
              "positions": np.asarray(positions, dtype=np.int16), "next_positions": np.asarray(next_positions, dtype=np.int16),
              "rewards": np.asarray(rewards, dtype=np.float32), "episode_starts": np.asarray(starts, dtype=np.int8),
              "episode_returns": np.asarray(returns, dtype=np.float32)}
    atomic_write_bytes(shipped_demos_path(spec), npz_bytes(arrays))
    atomic_write_bytes(shipped_actions_path(spec), npz_bytes({"actions": np.asarray(actions, dtype=np.int64)}))
    summary = {"env": spec.name, "episodes": episodes, "transitions": len(actions),
               "mean_return": float(np.mean(returns))}
    log(json.dumps(summary))
    return summary


def measure_references(env: str, episodes: int = 100, log=print) -> dict:
    """Random-policy and expert AER over the evaluation episodes, saved to assets/references.json."""
    spec = get_env(env)
    if spec.is_maze:
        from ifo.envs.maze import layout_pool, random_return, shortest_path_return

        size, loops = spec.kwargs["size"], spec.kwargs.get("loops", 0.0)

        def per_layout(layouts):
            return {"random": [round(random_return(l, size, episodes=20, seed=k), 6) for k, l in enumerate(layouts)],
                    "expert": [round(shortest_path_return(l), 6) for l in layouts]}

        held_out = per_layout(layout_pool(size, "eval", loops))
        # the layouts demonstrations come from (seeds 0..99): the authors' evaluation protocol
        demo_layouts = layout_pool(size, "train", loops)[:episodes]
        refs = {"random_aer": float(np.mean(held_out["random"])), "expert_aer": float(np.mean(held_out["expert"])),
                "per_layout": held_out, "per_layout_demonstration": per_layout(demo_layouts),
                "episodes": len(held_out["expert"])}
    else:
        seeds = EVAL_SEED_BASE + np.arange(episodes)
        pool = EnvPool(spec)
        rnd = random_returns(spec, episodes)
        exp = run_episodes(pool, _greedy(load_expert(spec)), seeds, record=False).returns
        refs = {"random_aer": float(rnd.mean()), "random_std": float(rnd.std()),
                "expert_aer": float(exp.mean()), "expert_std": float(exp.std()), "episodes": episodes}
    all_refs = dict(load_references())
    all_refs[spec.name] = refs
    atomic_write_json(ASSETS / "references.json", all_refs)
    log(json.dumps({"env": spec.name, **{k: v for k, v in refs.items() if not k.startswith("per_layout")}}))
    return refs


def evaluate_expert(env: str, episodes: int = 100, level: int = 1) -> dict:
    """The expert's AER over the evaluation episodes (held-out seeds, or held-out maze layouts)."""
    spec = get_env(env)
    if spec.is_maze:
        from ifo.envs.maze import ShortestPathExpert

        pool, seeds = EnvPool(spec, split="eval", obs_mode="vector"), np.arange(episodes)
        expert = ShortestPathExpert()
    else:
        pool, seeds = EnvPool(spec), EVAL_SEED_BASE + np.arange(episodes)
        expert = load_expert(spec, level)
    ro = run_episodes(pool, _greedy(expert), seeds, record=False)
    returns = ro.returns
    return {"env": spec.name, "level": level, "episodes": episodes, "aer": float(returns.mean()), "std": float(returns.std()),
            "goal_rate": float(ro.goals.mean())}
