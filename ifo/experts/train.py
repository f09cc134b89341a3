"""Training the experts for the control tasks with Stable-Baselines3: level 1, and levels 2-5 (Ch. 7).

The thesis (Table 7.1) used SB3 PPO/DQN experts; we train the same kind of agents with
the rl-baselines3-zoo tuned hyperparameters, keep the best checkpoint (judged on
held-out seeds, never on the 0..99 seeds used for reporting), and export its greedy
network to a plain `ExpertMLP` (.npz arrays, no pickles).

    python -m ifo.experts.train --env lunarlander      # train and save
    python -m ifo.experts.train --env all --eval-only  # evaluate the shipped files
    python -m ifo experts train --env cartpole --level 2-5   # the sub-optimal experts of Table 7.1

Levels 2-5 come from one training run per environment (same algorithm and hyperparameters as
level 1, and by default its seed; `--seed` picks another run and `--level` the levels it replaces:
LunarLander's levels 3 and 4 come from seed 2, whose checks fall inside their windows; levels.json
records each level's seed), checked greedily every `LEVEL_EVAL_EVERY` steps on the 100 evaluation
episodes (seeds 10^9 + k, the ones every learner and every reference in assets/references.json is measured on) and
stopped once it reaches the thesis's level-1 AER. Each level keeps the check whose AER meets its
Table 7.1 threshold most closely (the lowest AER at or above it) if that is within 5% of the
random-to-Expert¹ range, else the check closest to the thesis's AER (`select_levels`): that AER is
the level's reference for Performance. Its demonstrations are recorded on the training seeds 0, 1, ...
(`python -m ifo experts demos --level K`), never on the evaluation seeds.

stable_baselines3 is imported inside the functions only: `import ifo` must not load it.
"""
from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch

from ifo.envs import EnvSpec, get_env
from ifo.envs.rollout import EnvPool, run_episodes
from ifo.experts import ExpertMLP, expert_path

# Per environment: SB3 algorithm, number of DummyVecEnv copies, training steps and the
# algorithm's keyword arguments.  Values are the rl-baselines3-zoo tuned ones;
# "lin_X" means a learning rate / clip range decaying linearly from X to 0.
HYPERPARAMS: dict[str, dict[str, Any]] = {
    "cartpole": {
        "algo": "PPO", "n_envs": 8, "timesteps": 100_000,
        "kwargs": dict(n_steps=32, batch_size=256, gae_lambda=0.8, gamma=0.98, n_epochs=20,
                       ent_coef=0.0, learning_rate="lin_1e-3", clip_range="lin_0.2"),
    },
    "acrobot": {
        "algo": "DQN", "n_envs": 1, "timesteps": 100_000,
        "kwargs": dict(learning_rate=6.3e-4, batch_size=128, buffer_size=50_000, learning_starts=0,
                       gamma=0.99, target_update_interval=250, train_freq=4, gradient_steps=-1,
                       exploration_fraction=0.12, exploration_final_eps=0.1,
                       policy_kwargs=dict(net_arch=[256, 256])),
    },
    "mountaincar": {
        "algo": "DQN", "n_envs": 1, "timesteps": 120_000,
        "kwargs": dict(learning_rate=4e-3, batch_size=128, buffer_size=10_000, learning_starts=1000,
                       gamma=0.98, target_update_interval=600, train_freq=16, gradient_steps=8,
                       exploration_fraction=0.2, exploration_final_eps=0.07,
                       policy_kwargs=dict(net_arch=[256, 256])),
    },
    "lunarlander": {
        "algo": "PPO", "n_envs": 16, "timesteps": 1_000_000,
        "kwargs": dict(n_steps=1024, batch_size=64, gae_lambda=0.98, gamma=0.999, n_epochs=4,
                       ent_coef=0.01),
    },
}

# The level-1 targets (thesis Table 7.1), on 100 greedy episodes with seeds 0..99.
TARGETS = {"cartpole": 500.0, "acrobot": -85.0, "mountaincar": -110.0, "lunarlander": 200.0}
# What a training attempt must reach not to be retried (LunarLander: a margin for imitation).
AIMS = {"cartpole": 500.0, "acrobot": -85.0, "mountaincar": -110.0, "lunarlander": 230.0}

# Thesis Table 7.1: the AER (mean, sd over 1,000 episodes) of Expert^1 .. Expert^5 per environment.
LEVEL_TARGETS = {
    "cartpole": (500.0, 435.0, 354.0, 220.0, 112.0),
    "acrobot": (-82.0, -97.0, -138.0, -199.0, -243.0),
    "mountaincar": (-99.0, -129.0, -137.0, -149.0, -156.0),
    "lunarlander": (228.0, 151.0, 98.0, 60.0, 4.0),
}
LEVEL_THESIS_SD = {
    "cartpole": (0.0, 70.51, 137.07, 47.42, 7.50),
    "acrobot": (22.46, 24.41, 58.15, 79.85, 136.82),
    "mountaincar": (8.60, 25.50, 25.89, 32.02, 47.76),
    "lunarlander": (62.33, 106.18, 103.76, 119.35, 110.92),
}
# How often the level run is checked (steps): PPO after every update (n_envs x n_steps steps: 256 on
# CartPole, 16,384 on LunarLander), DQN every 1,000 steps (Acrobot: 250, its greedy policy jumps between
# -500 and -80 from one check to the next). The untrained network is never checked.
LEVEL_EVAL_EVERY = {"cartpole": 256, "acrobot": 250, "mountaincar": 1000, "lunarlander": 16_384}
LEVEL_EPISODES = 100  # greedy episodes per check, on the evaluation seeds
# A check that meets a level's threshold is kept if it is within this share of the random-to-Expert¹
# range above the thesis's AER; else the closest check either way (`select_levels`).
LEVEL_TOLERANCE = 0.05

SELECTION_SEED = 1_000_000  # checkpoints are compared on seeds from here, not on 0..99
SELECTION_EPISODES = 50
EVAL_FREQ = {"cartpole": 5_000, "acrobot": 5_000, "mountaincar": 5_000, "lunarlander": 50_000}


def _schedule(value):
    """'lin_X' -> a function of SB3's progress_remaining (1 -> 0) decaying from X to 0."""
    if isinstance(value, str) and value.startswith("lin_"):
        start = float(value[4:])
        return lambda progress_remaining: progress_remaining * start
    return value


def _greedy_episodes(spec: EnvSpec, act: Callable[[np.ndarray], np.ndarray], seeds) -> np.ndarray:
    """Returns of one greedy episode per seed (env.reset(seed=s)), run in lockstep."""
    pool = EnvPool(spec)
    try:
        def act_fn(obs):
            a = np.asarray(act(obs))
            return a, a

        rollouts = run_episodes(pool, act_fn, list(seeds), record=False)
    finally:
        pool.close()
    return rollouts.returns


def evaluate_expert(env_name: str, episodes: int = 100, seed: int = 0, path: str | Path | None = None,
                    level: int = 1) -> dict:
    """AER of the saved expert: greedy actions, one episode per seed in seed..seed+episodes-1."""
    spec = get_env(env_name)
    expert = ExpertMLP.load(path or expert_path(spec, level))
    returns = _greedy_episodes(spec, expert.act, range(seed, seed + episodes))
    return {"aer": float(returns.mean()), "std": float(returns.std()), "returns": returns.tolist()}


def export_policy(model) -> ExpertMLP:
    """The greedy network of an SB3 PPO (logits) or DQN (Q-values) model as an `ExpertMLP`."""
    from stable_baselines3 import DQN, PPO

    policy = model.policy
    if isinstance(model, PPO):
        if not isinstance(policy.mlp_extractor.policy_net, torch.nn.Sequential):
            raise TypeError("unexpected PPO policy network")
        linears = [m for m in policy.mlp_extractor.policy_net if isinstance(m, torch.nn.Linear)]
        linears.append(policy.action_net)
        act_cls = policy.activation_fn
    elif isinstance(model, DQN):
        linears = [m for m in policy.q_net.q_net if isinstance(m, torch.nn.Linear)]
        act_cls = policy.q_net.activation_fn
    else:
        raise TypeError(f"cannot export {type(model).__name__}")
    names = {torch.nn.Tanh: "tanh", torch.nn.ReLU: "relu"}
    if act_cls not in names:
        raise TypeError(f"unsupported activation {act_cls}")
    in_dim = linears[0].in_features
    if int(np.prod(model.observation_space.shape)) != in_dim:
        raise TypeError("the policy has a features extractor ExpertMLP cannot represent")
    expert = ExpertMLP(in_dim, [m.out_features for m in linears[:-1]], linears[-1].out_features, names[act_cls])
    mine = [m for m in expert.net if isinstance(m, torch.nn.Linear)]
    with torch.no_grad():
        for dst, src in zip(mine, linears):
            dst.weight.copy_(src.weight.detach().cpu())
            dst.bias.copy_(src.bias.detach().cpu())
    return expert.eval()


def verify_export(model, expert: ExpertMLP, spec: EnvSpec, n_states: int = 5000, seed: int = 0) -> tuple[int, int]:
    """Compare expert.act with model.predict(deterministic=True) on visited states.

    States come from episodes of the model where, with probability 0.3, a random action is
    taken instead (so states off the greedy path are checked too). Returns (mismatches, n).
    """
    rng = np.random.default_rng(seed)
    env = spec.make()
    states = []
    ep = 0
    try:
        while len(states) < n_states:
            obs, _ = env.reset(seed=2_000_000 + seed + ep)
            ep += 1
            done = False
            while not done and len(states) < n_states:
                states.append(obs)
                if rng.random() < 0.3:
                    a = int(env.action_space.sample())
                else:
                    a = int(model.predict(obs, deterministic=True)[0])
                obs, _, term, trunc, _ = env.step(a)
                done = term or trunc
    finally:
        env.close()
    states = np.asarray(states, dtype=np.float32)
    sb3 = np.asarray(model.predict(states, deterministic=True)[0]).reshape(-1)
    mine = expert.act(states).reshape(-1)
    return int((sb3 != mine).sum()), len(states)


def _make_model(spec: EnvSpec, hp: dict, seed: int):
    from stable_baselines3 import DQN, PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import DummyVecEnv

    env = make_vec_env(spec.gym_id, n_envs=hp["n_envs"], seed=seed, vec_env_cls=DummyVecEnv,
                       env_kwargs=dict(spec.kwargs))
    kwargs = {k: _schedule(v) for k, v in hp["kwargs"].items()}
    cls = {"PPO": PPO, "DQN": DQN}[hp["algo"]]
    return cls("MlpPolicy", env, seed=seed, verbose=0, device="cpu", **kwargs)


def _train_once(spec: EnvSpec, hp: dict, seed: int, timesteps: int, log: Callable[[str], Any]) -> dict:
    """One SB3 run; returns the best checkpoint (by held-out greedy evaluations)."""
    from stable_baselines3.common.callbacks import BaseCallback

    model = _make_model(spec, hp, seed)
    eval_freq = EVAL_FREQ.get(spec.name, max(timesteps // 20, 1000))
    selection_seeds = range(SELECTION_SEED + 1000 * seed, SELECTION_SEED + 1000 * seed + SELECTION_EPISODES)
    best: dict[str, Any] = {"score": -np.inf}
    start = time.perf_counter()

    def evaluate_now(steps: int, label: str = "") -> None:
        expert = export_policy(model)
        returns = _greedy_episodes(spec, expert.act, selection_seeds)
        score = float(returns.mean())
        mark = ""
        if score >= best["score"]:  # ties go to the later (longer trained) checkpoint
            best.update(score=score, steps=steps, policy=copy.deepcopy(model.policy.state_dict()))
            mark = "  * best"
        log(f"[{spec.name} seed {seed}] {steps:>8d} steps{label:4s} {time.perf_counter() - start:6.0f}s  "
            f"held-out AER {score:8.2f} ± {returns.std():6.2f}  min {returns.min():8.2f}{mark}")

    class PeriodicEval(BaseCallback):
        def __init__(self):
            super().__init__()
            self.next_eval = eval_freq

        def _on_step(self) -> bool:
            if self.num_timesteps >= self.next_eval:
                self.next_eval += eval_freq
                evaluate_now(self.num_timesteps)
            return True

    model.learn(total_timesteps=timesteps, callback=PeriodicEval())
    # the model after the last update (a callback evaluation can precede the final update)
    evaluate_now(model.num_timesteps, " end")
    seconds = time.perf_counter() - start
    model.policy.load_state_dict(best["policy"])
    expert = export_policy(model)
    mismatches, n = verify_export(model, expert, spec, seed=seed)
    log(f"[{spec.name} seed {seed}] export check: {n - mismatches}/{n} states give SB3's action")
    if mismatches:
        raise RuntimeError(f"exported network disagrees with SB3 on {mismatches}/{n} states")
    model.env.close()
    return {"expert": expert, "seed": seed, "steps": best["steps"], "total_steps": int(model.num_timesteps),
            "selection_aer": best["score"], "train_seconds": seconds, "checked_states": n}


def train_expert(env_name: str, seed: int = 0, timesteps: int | None = None, out: str | Path | None = None,
                 log: Callable[[str], Any] = print, retries: int = 2) -> Path:
    """Train a level-1 expert with SB3, export its greedy network and save it as .npz.

    Keeps the best checkpoint of each run (held-out seeds); measures it on seeds 0..99 and,
    if it misses `AIMS[env]`, trains again with the next seed (at most `retries` times),
    saving the best attempt either way. Returns the path written.
    """
    spec = get_env(env_name)
    if spec.name not in HYPERPARAMS:
        raise ValueError(f"no expert training for {spec.name} (maze experts are shortest paths)")
    hp = HYPERPARAMS[spec.name]
    timesteps = int(timesteps or hp["timesteps"])
    out = Path(out) if out is not None else expert_path(spec)
    aim = AIMS[spec.name]

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    best = None
    total_seconds = 0.0
    try:
        for attempt in range(retries + 1):
            s = seed + attempt
            log(f"[{spec.name}] training {hp['algo']} for {timesteps} steps, seed {s} (attempt {attempt + 1})")
            run = _train_once(spec, hp, s, timesteps, log)
            total_seconds += run["train_seconds"]
            returns = _greedy_episodes(spec, run["expert"].act, range(100))
            run["aer"], run["std"] = float(returns.mean()), float(returns.std())
            log(f"[{spec.name} seed {s}] best checkpoint at {run['steps']} steps: "
                f"AER {run['aer']:.2f} ± {run['std']:.2f} on seeds 0..99 (aim {aim}); "
                f"trained {run['train_seconds']:.0f}s")
            if best is None or run["aer"] > best["aer"]:
                best = run
            if run["aer"] >= aim:
                break
            if attempt < retries:
                log(f"[{spec.name}] below the aim {aim}; retrying with seed {s + 1}")
    finally:
        torch.set_num_threads(threads)

    meets = best["aer"] >= TARGETS[spec.name]
    if best["aer"] < aim:
        log(f"[{spec.name}] WARNING: best attempt (seed {best['seed']}) reached {best['aer']:.2f}, "
            f"aim {aim}, target {TARGETS[spec.name]}")
    meta = {
        "env": spec.name, "gym_id": spec.gym_id, "algo": hp["algo"], "seed": best["seed"],
        "timesteps": best["steps"], "total_timesteps": best["total_steps"],
        "train_seconds": round(best["train_seconds"], 1), "all_attempts_seconds": round(total_seconds, 1),
        "attempts": attempt + 1, "n_envs": hp["n_envs"],
        "hyperparams": {k: v for k, v in hp["kwargs"].items()},
        "selection": f"best of greedy evaluations every {EVAL_FREQ.get(spec.name)} steps on "
                     f"{SELECTION_EPISODES} held-out seeds",
        "selection_aer": round(best["selection_aer"], 3),
        "aer_seeds_0_99": round(best["aer"], 3), "std_seeds_0_99": round(best["std"], 3),
        "meets_target": bool(meets), "target": TARGETS[spec.name],
        "export_checked_states": best["checked_states"],
    }
    best["expert"].save(out, extra_meta=meta)
    log(f"[{spec.name}] saved {out} ({out.stat().st_size / 1024:.0f} KB)")
    return out


# ----------------------------------------------------------------------------- levels 2-5 (Ch. 7)
def select_levels(checks: list[dict], targets: dict[int, float], tolerance: float = 0.0) -> dict[int, int]:
    """For each level, the index of the check (dicts with "aer") to keep: the one that meets its threshold
    most closely (the lowest AER at or above the target, the earliest on ties) when that one is within
    `tolerance` of the target; otherwise the check closest to the target either way (the thesis's AER
    matched as closely as the checks allow, its threshold then possibly missed by a little, which
    levels.json records). Pure: the rule is tested on its own."""
    chosen = {}
    for level, target in targets.items():
        if not checks:
            break
        meets = [k for k, c in enumerate(checks) if c["aer"] >= target]
        lowest = min(meets, key=lambda k: (checks[k]["aer"], k)) if meets else None
        if lowest is not None and checks[lowest]["aer"] - target <= tolerance:
            chosen[level] = lowest
        else:
            chosen[level] = min(range(len(checks)), key=lambda k: (abs(checks[k]["aer"] - target), k))
    return chosen


def parse_levels(text: str | int) -> list[int]:
    """'3' -> [3]; '2,4' -> [2, 4]; '2-5' -> [2, 3, 4, 5]; 'all' -> [1, 2, 3, 4, 5] (ValueError otherwise)."""
    from ifo.experts import LEVELS, check_level

    text = str(text).strip().lower()
    if text == "all":
        return list(LEVELS)
    out: list[int] = []
    for part in text.split(","):
        part = part.strip()
        try:
            if "-" in part:
                lo, hi = (int(x) for x in part.split("-", 1))
                out += list(range(lo, hi + 1)) if lo <= hi else [lo, hi]
            else:
                out.append(int(part))
        except ValueError:
            raise ValueError(f"--level must be 1..5, a list (2,4), a range (2-5) or 'all'; got {text!r}") from None
    for level in out:
        check_level(level)
    return sorted(set(out))


def _write_level_info(env: str, level: int, info: dict, merge: bool = False) -> None:
    """Write one level's entry of assets/experts/levels.json (`merge`: keep the entry's other keys)."""
    from filelock import FileLock

    from ifo.experts import LEVELS_FILE, load_levels
    from ifo.io import atomic_write_json

    import tempfile

    lock = Path(tempfile.gettempdir()) / "ifo-expert-levels.lock"  # not in assets/: nothing to ship
    with FileLock(str(lock), timeout=120):  # several environments may train at once
        levels = load_levels()
        old = levels.get(env, {}).get(str(level), {}) if merge else {}
        levels.setdefault(env, {})[str(level)] = {**old, **info}
        atomic_write_json(LEVELS_FILE, levels)


def _reference_aer(spec: EnvSpec, expert: ExpertMLP, episodes: int = LEVEL_EPISODES) -> np.ndarray:
    """Returns on the held-out evaluation seeds (10^9 + k): the seeds every learner is measured on."""
    from ifo.seeds import EVAL_SEED_BASE

    return _greedy_episodes(spec, expert.act, range(EVAL_SEED_BASE, EVAL_SEED_BASE + episodes))


def describe_level1(env_name: str, log: Callable[[str], Any] = print) -> dict:
    """levels.json's entry for the shipped level-1 expert (measured, never retrained)."""
    spec = get_env(env_name)
    expert = ExpertMLP.load(expert_path(spec, 1))
    ref = _reference_aer(spec, expert, LEVEL_EPISODES)
    target = LEVEL_TARGETS[spec.name][0]
    info = {"level": 1, "target": target, "thesis_sd": LEVEL_THESIS_SD[spec.name][0],
            "aer": round(float(ref.mean()), 3), "std": round(float(ref.std()), 3),
            "steps": int(expert.meta.get("timesteps", 0)), "algo": expert.meta.get("algo"),
            "seed": expert.meta.get("seed"), "meets_target": bool(ref.mean() >= target),
            "how": "the shipped level-1 expert: the best checkpoint of its own training run (held-out selection "
                   "seeds), measured here on the evaluation seeds"}
    try:  # the shipped level-1 demonstrations (episodes kept above KEEP_THRESHOLD)
        from ifo.data.shipped import load_shipped_demonstrations

        demos = load_shipped_demonstrations(spec)
        info.update(demos_episodes=demos.n_episodes, demos_mean_return=round(float(np.mean(demos.episode_returns)), 3),
                    demos_transitions=len(demos.transitions))
    except Exception:  # noqa: BLE001 - demonstrations not made yet: the entry just lacks them
        pass
    _write_level_info(spec.name, 1, info, merge=True)
    log(f"[{spec.name} level 1] AER {info['aer']:.2f} ± {info['std']:.2f} on the evaluation seeds "
        f"(thesis {target:g})")
    return info



def train_levels(env_name: str, levels=(2, 3, 4, 5), seed: int = 0, timesteps: int | None = None,
                 log: Callable[[str], Any] = print) -> dict[int, Path]:
    """One SB3 run (level 1's algorithm, hyperparameters and seed), checked greedily every
    LEVEL_EVAL_EVERY steps on seeds 0..99 and stopped once it reaches the thesis's level-1 AER (or
    its step budget); each requested level keeps the check chosen by `select_levels`, exported to
    assets/experts/<env>-level<K>.npz with its measurements in assets/experts/levels.json."""
    from stable_baselines3.common.callbacks import BaseCallback

    spec = get_env(env_name)
    if spec.name not in HYPERPARAMS:
        raise ValueError(f"no expert training for {spec.name} (maze experts are shortest paths)")
    levels = [lv for lv in levels if lv != 1]
    if not levels:
        return {}
    hp = HYPERPARAMS[spec.name]
    timesteps = int(timesteps or hp["timesteps"])
    targets = LEVEL_TARGETS[spec.name]
    every = LEVEL_EVAL_EVERY[spec.name]
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    checks: list[dict] = []
    start = time.perf_counter()
    try:
        model = _make_model(spec, hp, seed)

        def check(steps: int) -> bool:
            expert = export_policy(model)
            returns = _reference_aer(spec, expert, LEVEL_EPISODES)
            checks.append({"steps": steps, "aer": float(returns.mean()), "std": float(returns.std()),
                           "policy": copy.deepcopy(model.policy.state_dict())})
            log(f"[{spec.name} levels] {steps:>8d} steps {time.perf_counter() - start:6.0f}s  "
                f"AER {returns.mean():8.2f} ± {returns.std():6.2f}")
            return returns.mean() < targets[0]  # False: it is an expert now, stop

        class Checks(BaseCallback):
            """Checks at the start of a rollout: right after an update (PPO: the policy that collected
            `steps` steps and trained on them; DQN: after its latest gradient steps)."""

            def __init__(self):
                super().__init__()
                self.next, self.go_on = every, True

            def _on_rollout_start(self) -> None:
                if self.num_timesteps >= self.next:
                    self.next = (self.num_timesteps // every + 1) * every
                    self.go_on = check(self.num_timesteps)

            def _on_step(self) -> bool:
                return self.go_on

        model.learn(total_timesteps=timesteps, callback=Checks())  # never the untrained network: it is no expert
        train_seconds = time.perf_counter() - start
        random_aer = spec.references().get("random_aer")
        tolerance = LEVEL_TOLERANCE * abs(targets[0] - random_aer) if random_aer is not None else 0.0
        chosen = select_levels(checks, {lv: targets[lv - 1] for lv in levels}, tolerance)
        out = {}
        for level in levels:
            c = checks[chosen[level]]
            model.policy.load_state_dict(c["policy"])
            expert = export_policy(model)
            mismatches, n = verify_export(model, expert, spec, seed=seed)
            if mismatches:
                raise RuntimeError(f"exported network disagrees with SB3 on {mismatches}/{n} states")
            ref = _reference_aer(spec, expert, LEVEL_EPISODES)
            if abs(ref.mean() - c["aer"]) > 1e-6:
                raise RuntimeError(f"the exported level-{level} network measures {ref.mean()} on the evaluation "
                                   f"seeds, its check measured {c['aer']}")
            target = targets[level - 1]
            info = {"level": level, "target": target, "thesis_sd": LEVEL_THESIS_SD[spec.name][level - 1],
                    "aer": round(float(ref.mean()), 3), "std": round(float(ref.std()), 3),
                    "steps": int(c["steps"]), "algo": hp["algo"], "seed": seed,
                    "meets_target": bool(c["aer"] >= target), "tolerance": round(tolerance, 3),
                    "same_checkpoint_as": sorted(lv for lv in levels if lv != level and chosen[lv] == chosen[level]),
                    "how": f"check at {c['steps']} steps of one {hp['algo']} run (seed {seed}; checked every {every} "
                           f"steps on the evaluation seeds, {len(checks)} checks, stopped at the level-1 AER "
                           f"{targets[0]:g} or {timesteps} steps; {train_seconds:.0f} s)"}
            path = expert_path(spec, level)
            expert.save(path, extra_meta={"env": spec.name, "gym_id": spec.gym_id, **info,
                                          "hyperparams": dict(hp["kwargs"]), "n_envs": hp["n_envs"],
                                          "export_checked_states": n})
            _write_level_info(spec.name, level, info)
            log(f"[{spec.name} level {level}] thesis {target:g}: AER {c['aer']:.2f} ± {c['std']:.2f} "
                f"at {c['steps']} steps; saved {path} ({path.stat().st_size / 1024:.0f} KB)")
            out[level] = path
        model.env.close()
    finally:
        torch.set_num_threads(threads)
    return out


def main(argv: list[str] | None = None) -> None:
    import argparse

    parser = argparse.ArgumentParser(description="Train / evaluate the level-1 control experts")
    parser.add_argument("--env", default="all", help=f"one of {', '.join(HYPERPARAMS)} or 'all'")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--timesteps", type=int, default=None)
    parser.add_argument("--retries", type=int, default=2)
    parser.add_argument("--eval-only", action="store_true")
    args = parser.parse_args(argv)
    names = list(HYPERPARAMS) if args.env == "all" else [get_env(args.env).name]
    for name in names:
        if not args.eval_only:
            train_expert(name, seed=args.seed, timesteps=args.timesteps, retries=args.retries,
                         log=lambda m: print(m, flush=True))
        r = evaluate_expert(name)
        size = expert_path(get_env(name)).stat().st_size
        print(f"{name}: AER {r['aer']:.2f} ± {r['std']:.2f} over 100 episodes "
              f"(min {min(r['returns']):.1f}), target {TARGETS[name]}, file {size / 1024:.0f} KB", flush=True)


if __name__ == "__main__":
    main()
