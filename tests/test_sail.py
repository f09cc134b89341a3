"""SAIL (thesis Ch. 9): its discriminator, generator and replay buffer, its runs, tables and app page."""
import json
from pathlib import Path

import numpy as np
import pytest
import torch

import ifo.learners.sail as sail_mod
from ifo.components.sail_models import (Discriminator, EpisodeMemory, Generator, accept, pad, sample_windows,
                                        split_episodes, teacher_probability, train_discriminator)
from ifo.config import RunConfig
from ifo.learners import StepCancelled
from ifo.run import Run

ROOT = Path(__file__).resolve().parents[1]


def tiny_sail(**overrides) -> RunConfig:
    base = dict(env="cartpole", method="sail", iterations=2, pre_size=2000, episodes_per_iteration=6,
                eval_episodes=10, policy_epochs=2, expert_episodes=2, discriminator_updates=5, adversarial_steps=5)
    return RunConfig.from_dict({**base, **overrides})


def strip_timing(records):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in records]


def all_weights(run):
    return {f"{name}.{k}": v.clone() for name, m in run.learner.modules.items() for k, v in m.state_dict().items()}


def assert_same_weights(a, b):
    assert a.keys() == b.keys()
    for k, v in a.items():
        torch.testing.assert_close(b[k], v)


# ----------------------------------------------------------------------------- the discriminator
def teacher_like(rng, n):
    """A pendulum-like swing: position and velocity change every step (lengths vary)."""
    out = []
    for _ in range(n):
        t = np.arange(int(rng.integers(12, 60)))
        phase, speed = rng.uniform(0, 2 * np.pi), rng.uniform(0.2, 0.4)
        out.append(np.stack([np.sin(speed * t + phase), np.cos(speed * t + phase)], 1).astype(np.float32))
    return out


def constant(rng, n):
    """An agent that does nothing: the same state, step after step."""
    return [np.repeat(rng.uniform(-1, 1, (1, 2)), int(rng.integers(5, 60)), 0).astype(np.float32) for _ in range(n)]


def test_the_discriminator_lets_teacher_like_sequences_in_and_keeps_constant_ones_out():
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    teacher, still = teacher_like(rng, 40), constant(rng, 40)
    d = Discriminator(2)
    d.fit_input_scaling(torch.as_tensor(np.concatenate(teacher)))
    opt = torch.optim.Adam(d.parameters(), lr=1e-2)
    first = train_discriminator(d, opt, teacher, still, 10, 16, 16, rng)
    last = train_discriminator(d, opt, teacher, still, 140, 16, 16, rng)
    assert last < first
    fresh_teacher, fresh_still = teacher_like(np.random.default_rng(1), 20), constant(np.random.default_rng(1), 20)
    assert accept(d, fresh_teacher, 16).mean() >= 0.9  # read in windows of 16, whatever their length
    assert accept(d, fresh_still, 16).mean() <= 0.1


def test_a_sequence_is_judged_the_same_whatever_the_padding_around_it():
    """The published code padded the student's sequences and D learnt the padding; here a sequence's score
    does not depend on the longer sequences batched with it."""
    torch.manual_seed(0)
    d = Discriminator(3)
    rng = np.random.default_rng(0)
    short, long_ = rng.normal(size=(5, 3)).astype(np.float32), rng.normal(size=(40, 3)).astype(np.float32)
    d.eval()
    with torch.no_grad():
        alone = d(*pad([short]))[0, :5]
        batched = d(*pad([long_, short]))
    torch.testing.assert_close(batched[1, :5], alone)
    assert torch.all(batched[1, 5:] == 0)  # nothing is said about steps that are not there
    p = teacher_probability(d, [short, long_], window=50)
    assert p[0] == pytest.approx(torch.sigmoid(alone).mean().item(), abs=1e-6)


def test_sequences_are_split_by_episode_with_the_last_next_state():
    states = np.arange(10, dtype=np.float32)[:, None]
    episodes = np.array([0, 0, 0, 1, 1, 2, 2, 2, 2, 2])
    seqs = split_episodes(states, states + 0.5, episodes)
    assert [len(s) for s in seqs] == [4, 3, 6]
    assert seqs[0][:, 0].tolist() == [0, 1, 2, 2.5] and seqs[1][-1, 0] == 4.5


# ----------------------------------------------------------------------------- the generator
def test_the_generator_learns_a_linear_system_and_its_error_reaches_the_policy_logits():
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    a_mat = np.array([[1.0, 0.1], [0.0, 0.95]], dtype=np.float32)
    b_mat = np.array([[0.0, 0.0], [-0.2, 0.2]], dtype=np.float32)  # the action pushes the velocity
    s = rng.normal(size=(2000, 2)).astype(np.float32)
    actions = rng.integers(0, 2, 2000)
    s2 = s @ a_mat.T + b_mat[:, actions].T
    logits = torch.as_tensor(np.eye(2, dtype=np.float32)[actions] * 4 - 2)  # a policy that knows the action
    g = Generator(2, 2)
    s_t, s2_t = torch.as_tensor(s), torch.as_tensor(s2)
    g.fit_scaling(s_t, s2_t)
    opt = torch.optim.Adam(g.parameters(), lr=3e-3)
    errors = []
    for epoch in range(30):
        for idx in torch.randperm(2000).split(128):
            loss, error = g.losses(s_t[idx], logits[idx], s2_t[idx])
            opt.zero_grad()
            loss.backward()
            opt.step()
        errors.append(g.losses(s_t, logits, s2_t)[1].item())
    assert errors[-1] < 0.1 * errors[0] and errors[-1] < 1e-3
    assert g(s_t[:3], logits[:3]).shape == (3, 2)
    # G's error flows back into the conditioning logits (the policy's output) unless they are detached
    live = logits[:64].clone().requires_grad_(True)
    g.losses(s_t[:64], live, s2_t[:64] + 0.1)[0].backward()
    assert live.grad.abs().sum() > 0


# ----------------------------------------------------------------------------- the replay buffer
def test_the_replay_buffer_keeps_the_newest_trajectories_and_samples_windows_from_them():
    memory = EpisodeMemory(capacity=25)
    seqs = [np.full((n, 2), k, dtype=np.float32) for k, n in enumerate((10, 8, 12))]
    memory.add(seqs[:2])
    assert len(memory) == 18
    memory.add(seqs[2:])  # 30 > 25: the oldest leaves
    assert len(memory) == 20 and [s[0, 0] for s in memory.sequences] == [1, 2]
    rng = np.random.default_rng(0)
    windows = memory.sample(200, 5, rng)
    assert all(len(w) == 5 for w in windows)
    assert {w[0, 0] for w in windows} == {1.0, 2.0}  # every stored trajectory is drawn
    assert all((w == w[0, 0]).all() for w in windows)  # a window never straddles two trajectories
    again = memory.sample(200, 5, np.random.default_rng(0))
    assert all((a == b).all() for a, b in zip(windows, again))  # same stream, same windows
    short = sample_windows([np.zeros((3, 2), np.float32)], 4, 10, rng)
    assert [len(w) for w in short] == [3] * 4  # a short trajectory is taken whole, never padded
    arrays = memory.arrays("rb.")
    arrays["rb.states"][:] = -1  # a copy: changing it leaves the memory alone
    assert memory.sequences[0][0, 0] == 1
    restored = EpisodeMemory(25)
    restored.load_arrays(memory.arrays("rb."), "rb.")
    assert [s.tolist() for s in restored.sequences] == [s.tolist() for s in memory.sequences]
    empty = EpisodeMemory(5)
    empty.load_arrays(EpisodeMemory(5).arrays("x."), "x.")
    assert len(empty) == 0


# ----------------------------------------------------------------------------- runs
def test_a_sail_step_writes_its_sections():
    run = Run(tiny_sail(iterations=1))
    assert {"idm", "policy", "generator", "discriminator"} <= set(run.learner.modules)
    rec = run.step()
    d = rec["discriminator"]
    assert {"loss", "accuracy_expert", "accuracy_agent", "accepted_share"} <= set(d)
    assert 0 <= d["accepted_share"] <= 1 and 0 <= d["accuracy_expert"] <= 1 and 0 <= d["accuracy_agent"] <= 1
    assert rec["generator"]["loss"] >= 0
    assert rec["replay"]["size"] == sum(rec["rollouts"]["lengths"]) + len(rec["rollouts"]["lengths"])
    assert rec["replay"]["capacity"] >= rec["replay"]["size"]
    assert rec["sampling"]["mode"] == "discriminator"
    assert rec["sampling"]["size"] == rec["idm"]["train_size"] + sum(rec["sampling"]["from_pos"])
    assert rec["labels"]["sampled"] and rec["rollouts"]["sampled"]
    assert set(rec["seconds"]) >= {"idm", "label", "policy", "rollout", "sampling", "discriminator", "evaluate"}
    assert {"expert_accuracy", "confusion"} <= set(rec["idm"])  # the hidden truth, for people
    json.dumps(rec)
    from ifo.ui.diagram import BOXES

    assert {p.box for p in run.learner.phases} <= set(BOXES)


def test_the_models_are_the_thesis_sizes():
    run = Run(tiny_sail(iterations=1))
    learner = run.learner
    assert [m.normalized_shape for m in learner.idm.modules() if isinstance(m, torch.nn.LayerNorm)] == [(32,), (32,)]
    assert not any(isinstance(m, torch.nn.LayerNorm) for m in learner.policy.modules())
    gates = [type(m).__name__ for m in learner.policy.modules() if type(m).__name__ == "GatedResidual"]
    assert len(gates) == 2
    linears = [m for m in learner.generator.modules() if isinstance(m, torch.nn.Linear)]
    assert [(m.in_features, m.out_features) for m in linears] == [(4 + 2, 10), (10, 10), (10, 4)]  # 2 x (|s| + 1)
    lstm = learner.discriminator.lstm
    assert (lstm.hidden_size, lstm.num_layers, lstm.dropout) == (32, 2, 0.5)


def test_a_short_sail_run_beats_the_random_policy_on_cartpole():
    cfg = RunConfig.from_dict(dict(env="cartpole", method="sail", iterations=2, seed=0, eval_episodes=20,
                                   expert_episodes=5, pre_size=3000, episodes_per_iteration=10, policy_epochs=4))
    run = Run(cfg)
    run.run()
    random_aer = run.references["random"]
    assert run.records[-1]["evaluation"]["aer"] > 5 * random_aer  # random: about 21


def test_same_seed_same_numbers_and_a_saved_run_continues_exactly(tmp_path):
    cfg = tiny_sail(iterations=3, seed=5)
    straight = Run(cfg)
    straight.run()
    again = Run(cfg)
    again.run()
    assert strip_timing(again.records) == strip_timing(straight.records)
    assert strip_timing(Run(tiny_sail(iterations=1, seed=6)).run()) != strip_timing(straight.records[:1])

    first = Run(cfg)
    first.step()
    first.save(tmp_path / "run")
    resumed = Run.load(tmp_path / "run")
    assert len(resumed.learner.replay.sequences) == len(first.learner.replay.sequences)
    resumed.run()
    assert strip_timing(resumed.records) == strip_timing(straight.records)
    assert_same_weights(all_weights(straight), all_weights(resumed))


def test_a_failed_or_cancelled_sail_iteration_is_undone(monkeypatch):
    cfg = tiny_sail(iterations=2)
    straight = Run(cfg)
    straight.run()

    run = Run(cfg)
    run.step()
    before = all_weights(run), len(run.learner.replay), len(run.learner.train_set)
    real = sail_mod.train_discriminator
    calls = {"n": 0}

    def fails_once(*args, **kwargs):  # the last phase: RB, I_s, π, G and the IDM have all moved on
        calls["n"] += 1
        if calls["n"] == 1:
            raise RuntimeError("disk filled up")
        return real(*args, **kwargs)

    monkeypatch.setattr(sail_mod, "train_discriminator", fails_once)
    with pytest.raises(RuntimeError, match="disk filled up"):
        run.step()
    assert run.iteration == 1 and (len(run.learner.replay), len(run.learner.train_set)) == before[1:]
    assert_same_weights(before[0], all_weights(run))

    def cancel_at_discriminator(phase, iteration):
        if phase == "discriminator":
            run.cancel()

    run.progress = cancel_at_discriminator
    with pytest.raises(StepCancelled):
        run.step()
    run.progress = None
    run.step()
    assert strip_timing(run.records) == strip_timing(straight.records)
    assert_same_weights(all_weights(straight), all_weights(run))


def test_detached_logits_keep_gs_error_out_of_the_policy():
    """generator_into_policy=False (the published code): G's error no longer moves π."""
    def policy_after(**settings):
        run = Run(tiny_sail(iterations=1, adversarial_weight=0.0, **settings))
        run.step()
        return {k: v.clone() for k, v in run.policy.state_dict().items()}

    detached = policy_after(generator_into_policy=False, generator_weight=1.0)
    assert_same_weights(detached, policy_after(generator_into_policy=False, generator_weight=0.0))
    with pytest.raises(AssertionError):
        assert_same_weights(detached, policy_after(generator_into_policy=True, generator_weight=1.0))


def test_sail_refuses_image_states_and_expert_labels():
    with pytest.raises(ValueError, match="vector states"):
        Run(RunConfig.from_dict(dict(env="maze3", method="sail", expert_episodes=2, pre_size=100)))
    with pytest.raises(ValueError, match="labels must be 'idm'"):
        RunConfig.from_dict(dict(env="cartpole", method="sail", labels="expert")).resolved()


# ----------------------------------------------------------------------------- the thesis's tables
def test_chapter_9_tables_are_registered_with_the_thesis_numbers():
    from ifo.reproduce import TABLES

    t91, t92, t93 = TABLES["9.1"], TABLES["9.2"], TABLES["9.3"]
    assert [r.method for r in t91.rows] == ["expert", "random", "bc", "gail", "gaifo", "iupe", "sail"]
    assert t91.settings == {"expert_episodes": 25}
    assert t91.thesis["SAIL"]["mountaincar"][:2] == (0.99, -99.35) and t91.thesis["SAIL"]["lunarlander"][1] == 183.62
    assert t91.targets[("SAIL", "cartpole")] == ("aer", 475.0) and t91.targets[("SAIL", "lunarlander")] == ("aer", 150.0)
    assert [r.overrides["expert_episodes"] for r in t92.rows] == [1, 25, 50, 75, 100]
    from ifo.data.shipped import load_shipped_demonstrations
    from ifo.envs import get_env

    for env in t92.envs:  # the shipped demonstrations hold every row's trajectories
        assert load_shipped_demonstrations(get_env(env)).n_episodes >= 100
    assert t93.thesis["SAIL"]["acrobot"][2:] == (50.13, 3.21, 0.8685)


def test_the_table_printer_shows_further_columns_and_leaves_other_tables_as_they_were(monkeypatch):
    import ifo.reproduce as reproduce

    def fake(row, env, seed, iterations, **extra):
        if row.method in ("expert", "random"):
            return {"aer": 1.0, "performance": 1.0, "seconds": 0.0}
        return {"aer": 100.0 + seed, "performance": 0.5, "seconds": 1.0,
                "record": {"discriminator": {"accuracy_expert": 0.6, "accuracy_agent": 0.4},
                           "generator": {"loss": 0.00123}}}

    monkeypatch.setattr(reproduce, "run_row", fake)
    quiet = dict(log=lambda m: None)
    t93 = reproduce.reproduce("9.3", seeds=2, envs=["acrobot"], **quiet).splitlines()
    assert "D's accuracy (%) (ours) | D's accuracy (%) (thesis) | G's loss (ours) | G's loss (thesis)" in t93[2]
    assert "| 50.000 ± 0.000 | 50.130 ± 3.210 | 0.00123 ± 0 | 0.8685 |" in t93[4]
    t92 = reproduce.reproduce("9.2", seeds=2, envs=["mountaincar"], **quiet)
    assert "| 100.000 | -114.400 | 101.000 | -103.600 | 0.707 | 4.210 |" in t92  # 25 trajectories: min, max, sample sd
    t61 = reproduce.reproduce("6.1", seeds=1, envs=["cartpole"], **quiet).splitlines()
    assert t61[2] == ("| row | environment | P (ours) | P (thesis) | AER (ours) | AER 95 % interval (ours) "
                      "| AER (thesis) | AER sampled actions (ours) | seconds per run | target |")
    assert all(line.count("|") == 11 for line in t61 if line.startswith("|"))


# ----------------------------------------------------------------------------- the app
def test_the_step_page_steps_sail_and_shows_its_panels(monkeypatch, tmp_path):
    from streamlit.testing.v1 import AppTest

    monkeypatch.setenv("IFO_LAB_FAST", "1")
    monkeypatch.setenv("IFO_LAB_RUNS", str(tmp_path / "runs"))
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.query_params.update({"step.method": "SAIL"})
    at.run()
    at.switch_page("views/step_through.py").run()
    assert not at.exception
    assert at.session_state["ifo.slot.step"].run.config.method == "sail"
    at.button(key="step").click().run()
    assert not at.exception and not at.error
    keys = [c.key for c in at.get("plotly_chart")]
    assert {"panel.discriminator", "panel.generator", "panel.replay", "panel.idm"} <= set(keys)
    records = at.session_state["ifo.slot.step"].run.records
    assert len(records) == 1 and "discriminator" in records[0]
