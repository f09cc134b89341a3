"""The baselines the thesis compares against: GAIL, GAIfO (one adversarial learner) and ILPO.

Short runs on CartPole (a few PPO rounds, a couple of ILPO iterations); every training here is
well under a minute on one core.
"""
from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from streamlit.testing.v1 import AppTest

from ifo.components.discriminator import Discriminator, logits_of, train_discriminator
from ifo.config import RunConfig
from ifo.data.demos import ExpertTransitions
from ifo.data.shipped import load_shipped_demonstrations
from ifo.envs import EnvSpec, get_env
from ifo.envs.rollout import EnvPool
from ifo.learners import LEARNERS
from ifo.learners.base import Context, HiddenTruth
from ifo.learners.ilpo import ILPOConfig, ILPOLearner
from ifo.methods import METHODS
from ifo.run import Run
from ifo.seeds import Seeds

ROOT = Path(__file__).resolve().parents[1]
RANDOM_CARTPOLE = 22.0  # a random policy's AER on CartPole is about 20


def config(method: str, **overrides) -> RunConfig:
    """A short CartPole run of a baseline."""
    base = {"gail": dict(iterations=2, round_steps=512, expert_episodes=2, eval_episodes=10),
            "gaifo": dict(iterations=2, round_steps=512, expert_episodes=2, eval_episodes=10),
            "ilpo": dict(iterations=2, expert_episodes=1, eval_episodes=10, pre_size=400, episodes_per_iteration=4,
                         min_updates=50)}[method]
    return RunConfig.from_dict({"env": "cartpole", "method": method, **base, **overrides})


def without_timing(records: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if k != "seconds"} for r in records]


def weights(run: Run) -> dict:
    return {f"{name}.{k}": v.detach().clone() for name, m in run.learner.modules.items()
            for k, v in m.state_dict().items()}


def assert_same_weights(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0, msg=k)


# --------------------------------------------------------------------------- the methods exist
def test_the_three_baselines_are_methods_of_two_learners():
    assert METHODS["gail"].learner == METHODS["gaifo"].learner == "adversarial"
    assert METHODS["ilpo"].learner == "ilpo"
    assert {"adversarial", "ilpo"} <= set(LEARNERS)
    assert METHODS["gail"].sees_expert_actions  # a reference, like BC
    assert not METHODS["gaifo"].sees_expert_actions and not METHODS["ilpo"].sees_expert_actions
    assert RunConfig(method="gail").resolved().learner.discriminator_input == "state-action"
    assert RunConfig(method="gaifo").resolved().learner.discriminator_input == "state-transition"


# --------------------------------------------------------------------------- the discriminator
@pytest.mark.parametrize("inputs", ["state-action", "state-transition"])
def test_the_discriminator_separates_expert_from_random_samples(inputs):
    """Hand-made expert: a = 1 exactly when s_0 > 0 (and s' = s + 0.1 in the direction of a); the
    agent's samples choose a at random."""
    rng = np.random.default_rng(0)

    def samples(expert: bool, n: int = 2000):
        s = rng.normal(size=(n, 3)).astype(np.float32)
        a = (s[:, 0] > 0).astype(np.int64) if expert else rng.integers(0, 2, n)
        s2 = s + 0.1 * (2 * a[:, None] - 1) * np.array([1.0, 0.0, 0.0], dtype=np.float32)
        return s, (a if inputs == "state-action" else s2)

    expert, agent = samples(True), samples(False)
    torch.manual_seed(0)
    d = Discriminator(3, 2, inputs, hidden=(32, 32))
    d.fit_input_scaling(*map(torch.as_tensor, expert))
    fit = train_discriminator(d, torch.optim.Adam(d.parameters(), lr=3e-3), expert, agent, updates=400,
                              batch_size=128, rng=rng)
    assert fit.accuracy_expert > 0.9 and fit.loss < 0.6  # (near s_0 = 0 the two actions are close calls)
    # half of the random samples do what the expert would have done and cannot be told apart (D ≈ 2/3
    # there, "expert"); the other half D calls "agent"
    s, x = agent
    did_otherwise = (x if inputs == "state-action" else (x[:, 0] > s[:, 0])) != (s[:, 0] > 0)
    logits = logits_of(d, s, x)
    assert np.mean(logits[did_otherwise] < 0) > 0.9
    assert fit.accuracy_agent == pytest.approx(np.mean(logits < 0)) and 0.45 < fit.accuracy_agent < 0.6


# --------------------------------------------------------------------------- who sees the expert's actions
def test_gaifo_never_reads_the_expert_actions():
    """Whatever the hidden actions say (true, shuffled, absent), GAIfO learns exactly the same: its
    context holds no actions at all. (tests/test_run.py checks every IfO method the same way.)"""
    spec = get_env("cartpole")
    cfg = config("gaifo")
    outcomes = []
    for variant in ("true", "shuffled", "absent"):
        demos = load_shipped_demonstrations(spec)
        if variant == "shuffled":
            demos.hidden_actions = np.random.default_rng(1).permutation(demos.hidden_actions)
        elif variant == "absent":
            demos.hidden_actions = None
        run = Run(cfg, demos=demos)
        assert run.ctx.expert_actions is None
        run.run()
        outcomes.append((weights(run), [r["evaluation"]["returns"] for r in run.records],
                         [r["discriminator"] for r in run.records]))
        # the diagnostic shown to people uses the hidden actions when there are some
        assert ("policy" in run.records[0]) == (variant != "absent")
    for w, returns, disc in outcomes[1:]:
        assert returns == outcomes[0][1] and disc == outcomes[0][2]
        assert_same_weights(w, outcomes[0][0])


def test_gail_is_a_reference_that_needs_the_expert_actions():
    """GAIL is left out of test_run's "IfO methods never learn from expert actions": its discriminator
    compares the expert's (s, a) pairs with the agent's, as the method is defined (Sec 3.3)."""
    run = Run(config("gail"))
    assert run.ctx.expert_actions is not None
    demos = load_shipped_demonstrations(get_env("cartpole"))
    demos.hidden_actions = None
    with pytest.raises(ValueError, match="GAIL needs demonstrations with actions"):
        Run(config("gail"), demos=demos)
    # an (s, a) discriminator under GAIfO's name gets no actions either: refused, not silently fed
    with pytest.raises(ValueError, match="learns from the expert's actions"):
        Run(config("gaifo", discriminator_input="state-action"))


def test_ilpo_never_reads_the_expert_actions():
    spec = get_env("cartpole")
    outcomes = []
    for variant in ("true", "absent"):
        demos = load_shipped_demonstrations(spec)
        if variant == "absent":
            demos.hidden_actions = None
        run = Run(config("ilpo", iterations=1), demos=demos)
        assert run.ctx.expert_actions is None
        run.run()
        outcomes.append((weights(run), run.records[0]["evaluation"]["returns"], run.records[0]["latent"]))
        assert ("expert_accuracy" in run.records[0]["idm"]) == (variant == "true")
    assert outcomes[0][1] == outcomes[1][1] and outcomes[0][2] == outcomes[1][2]
    assert_same_weights(outcomes[0][0], outcomes[1][0])


# --------------------------------------------------------------------------- ILPO's remapping
PERMUTATION = (2, 0, 3, 1)  # real action k moves the point along MOVES[PERMUTATION[k]]
MOVES = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]], dtype=np.float32) * 0.1


class PermutedMoves(gym.Env):
    """A point in the plane; action k moves it by MOVES[PERMUTATION[k]]. 20 steps an episode."""

    observation_space = gym.spaces.Box(-10, 10, (2,), np.float32)
    action_space = gym.spaces.Discrete(4)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.s = self.np_random.uniform(-1, 1, 2).astype(np.float32)
        self.t = 0
        return self.s.copy(), {}

    def step(self, action):
        self.s = (self.s + MOVES[PERMUTATION[int(action)]]).astype(np.float32)
        self.t += 1
        return self.s.copy(), 0.0, False, self.t >= 20, {}


def test_ilpo_remapping_recovers_a_permutation_of_the_actions():
    """The expert's states show four kinds of move; which real action makes which move is permuted.
    ILPO finds the four moves as latent actions from the states alone and the remapping learns,
    from random steps, which real action each one is."""
    if "ifo-test/PermutedMoves-v0" not in gym.registry:
        gym.register("ifo-test/PermutedMoves-v0", entry_point=PermutedMoves)
    spec = EnvSpec("permuted-moves", "ifo-test/PermutedMoves-v0", ("a0", "a1", "a2", "a3"), lambda ep: False)
    # the expert's states: 40 episodes of 20 moves, every move equally often (its actions stay hidden)
    rng = np.random.default_rng(0)
    states, next_states, episodes, actions = [], [], [], []
    for e in range(40):
        s = rng.uniform(-1, 1, 2).astype(np.float32)
        for _ in range(20):
            a = int(rng.integers(4))
            s2 = s + MOVES[PERMUTATION[a]]
            states.append(s), next_states.append(s2), episodes.append(e), actions.append(a)
            s = s2
    expert = ExpertTransitions(np.array(states), np.array(next_states), np.array(episodes))
    ctx = Context(spec, None, EnvPool(spec, batched=False), expert, HiddenTruth(np.array(actions), 4), Seeds(0))
    torch.manual_seed(0)
    cfg = ILPOConfig(pre_size=400, episodes_per_iteration=0, policy_epochs=20, remap_epochs=20).resolved({}, spec)
    learner = ILPOLearner(ctx, cfg)
    for i in range(3):
        record = learner.step(i, np.random.default_rng(i))
    latent = record["latent"]
    assert sorted(latent["assignment_counts"]) == [200, 200, 200, 200] or min(latent["assignment_counts"]) > 150
    remap = np.array(latent["remap"])  # latent x real action counts of the remapping's data
    assert sorted(remap.argmax(1).tolist()) == [0, 1, 2, 3]  # each latent action is one real action
    assert (remap.max(1) / remap.sum(1)).min() > 0.95
    # the inverse dynamics ILPO implies names the expert's hidden action every time
    assert record["idm"]["expert_accuracy"] > 0.97 and record["idm"]["val_accuracy"] > 0.97


def test_ilpo_refuses_images_with_a_clear_message():
    with pytest.raises(ValueError, match="vector states only.*\"Maze observations\": vector; --obs-mode vector"):
        Run(RunConfig.from_dict(dict(env="maze3", method="ilpo", expert_episodes=2, eval_episodes=2,
                                     pre_size=100)))


# --------------------------------------------------------------------------- they learn
@pytest.mark.slow
@pytest.mark.parametrize("method,iterations", [("gaifo", 6), ("gail", 6), ("ilpo", 2)])
def test_each_baseline_beats_random_on_cartpole_in_a_short_run(method, iterations):
    overrides = dict(iterations=iterations, eval_episodes=20)
    if method != "ilpo":
        overrides.update(round_steps=2048, expert_episodes=10)
    run = Run(config(method, **overrides))
    run.run()
    aers = [r["evaluation"]["aer"] for r in run.records]
    assert max(aers) > 5 * RANDOM_CARTPOLE, aers
    json.dumps(run.records)  # plain data


def test_adversarial_records_have_the_sections_the_panels_draw():
    run = Run(config("gaifo"))
    rec = run.step()
    assert {"discriminator", "generator", "samples", "evaluation", "policy"} <= set(rec)
    d, g = rec["discriminator"], rec["generator"]
    assert set(d) == {"loss", "accuracy_expert", "accuracy_agent", "mean_reward"}
    assert 0 <= d["accuracy_expert"] <= 1 and 0 <= d["accuracy_agent"] <= 1 and d["mean_reward"] > 0
    assert set(g) == {"loss", "value_loss", "entropy", "environment_steps"} and g["environment_steps"] == 512
    # the first round ran the untrained policy once for the discriminator's first agent samples
    assert rec["samples"]["environment_steps"] == 512 + 256 and rec["samples"]["expert_samples"] == len(run.expert)
    assert set(rec["seconds"]) >= {"collect", "discriminator", "generator", "evaluate"}
    assert "collect" not in run.step()["seconds"]  # later rounds judge the last round's samples


# --------------------------------------------------------------------------- same seed, same numbers; save/load
@pytest.mark.parametrize("method", ["gaifo", "ilpo"])
def test_same_seed_same_numbers(method):
    runs = [Run(config(method)) for _ in range(2)]
    for run in runs:
        run.run()
    assert without_timing(runs[0].records) == without_timing(runs[1].records)
    assert_same_weights(weights(runs[0]), weights(runs[1]))
    other = Run(config(method, seed=1))
    other.run()
    assert without_timing(other.records) != without_timing(runs[0].records)


@pytest.mark.parametrize("method", ["gail", "gaifo", "ilpo"])
def test_a_saved_run_continues_exactly(method, tmp_path):
    straight = Run(config(method, iterations=3))
    straight.run()
    first = Run(config(method, iterations=3))
    first.step()
    first.save(tmp_path / "run")
    first.step()  # the original keeps going after saving
    loaded = Run.load(tmp_path / "run")
    loaded.run()
    assert without_timing(loaded.records) == without_timing(straight.records)
    assert without_timing(first.records) == without_timing(straight.records[:2])
    assert_same_weights(weights(loaded), weights(straight))


def test_a_cancelled_round_is_undone_exactly():
    """Cancelled after the discriminator trained: D, PPO and the agent samples are put back, so the
    retry gives the numbers an uninterrupted run gives."""
    straight = Run(config("gaifo"))
    straight.run()
    phases = []

    def progress(phase, iteration):
        phases.append(phase)
        if iteration == 2 and phase == "discriminator" and phases.count("discriminator") == 2:
            run.cancel()

    run = Run(config("gaifo"), progress=progress)
    run.step()
    from ifo.learners import StepCancelled

    with pytest.raises(StepCancelled):
        run.step()
    run.step()
    assert without_timing(run.records) == without_timing(straight.records)
    assert_same_weights(weights(run), weights(straight))


# --------------------------------------------------------------------------- the step page
@pytest.mark.parametrize("title,panel", [("GAIL", "panel.discriminator"), ("GAIfO", "panel.discriminator"),
                                         ("ILPO", "panel.latent")])
def test_the_step_page_steps_each_baseline_and_shows_its_panels(title, panel, monkeypatch, tmp_path):
    import ifo.ui.settings as settings

    monkeypatch.setenv("IFO_LAB_FAST", "1")
    monkeypatch.setenv("IFO_LAB_RUNS", str(tmp_path / "runs"))
    if title != "ILPO":  # the fast settings name BCO-loop sizes a PPO learner does not have (see the report)
        monkeypatch.setattr(settings, "FAST_OVERRIDES", {"eval_episodes": 10, "round_steps": 512})
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=90)
    at.query_params.update({"step.method": title})
    at.run()
    at.switch_page(str(ROOT / "views" / "step_through.py")).run()
    assert not at.exception, at.exception
    assert at.session_state["ifo.slot.step"].run.config.method == title.lower()
    at.button(key="step").click().run()
    assert not at.exception and not at.error, [e.value for e in at.error]
    keys = [c.key for c in at.get("plotly_chart")]
    assert panel in keys and "panel.aer" in keys
    if title != "ILPO":
        assert "panel.generator" in keys
    else:
        assert "panel.idm" in keys  # the inverse dynamics ILPO implies, against the hidden truth
    assert len(at.session_state["ifo.slot.step"].run.records) == 1
