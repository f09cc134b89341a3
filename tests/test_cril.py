"""CRIL (thesis Ch. 8): Eq 8.2's schedule, the replay memory's size, ε from the exploration ratio,
the clipping bounds, the policy maps (Figs 8.2, 8.3), and a short run that beats random."""
import numpy as np
import pytest
import torch

from ifo import figures
from ifo.config import RunConfig
from ifo.envs import get_env
from ifo.learners.cril import share_limit
from ifo.probes import policy_map_record
from ifo.run import Run


def cril(**overrides) -> Run:
    base = dict(env="cartpole", method="cril", iterations=2, pre_size=2000, episodes_per_iteration=6,
                eval_episodes=10, policy_epochs=2, expert_episodes=1, td_updates=4)
    return Run(RunConfig.from_dict({**base, **overrides}))


def test_eq_8_2_schedule_of_the_share_of_I_pos():
    n = 10
    assert share_limit(1, n) == pytest.approx(1 - 1 / (1 + 9 ** -2))  # 1.2% at the first iteration
    assert share_limit(n // 2, n) == pytest.approx(0.5)  # half way
    assert share_limit(n, n) == 1.0 and share_limit(n + 5, n) == 1.0  # 100% from e = n on
    values = [share_limit(e, n) for e in range(1, n + 1)]
    assert values == sorted(values)  # it only grows
    assert share_limit(2, 10, k=4) < share_limit(2, 10, k=2)  # a steeper curve starts lower


def test_the_replay_memory_holds_ten_expert_episodes():
    run = cril(expert_episodes=2)
    lengths = np.bincount(run.expert.episode_index)
    assert run.learner.replay.capacity == 10 * int(lengths.mean())  # Sec 8.2: 10x the average expert episode
    record = run.step()
    assert record["replay"] == {"size": len(run.learner.replay), "capacity": run.learner.replay.capacity}
    assert 0 < record["replay"]["size"] <= record["replay"]["capacity"]


def test_epsilon_is_the_exploration_ratio_of_the_imitation_step():
    run = cril()
    learner = run.learner
    learner.expert_probabilities = np.array([[0.9, 0.1]] * 5000)  # a policy 90% sure on every expert state
    eps = learner.exploration_ratio(np.random.default_rng(0))
    assert eps == pytest.approx(0.1, abs=0.015)
    record = run.step()
    td, ro = record["td"], record["rollouts"]
    assert 0 <= td["epsilon"] <= 1 and td["updates"] == 4 * 6
    # ε-greedy: a random action is the MAP one half the time with two actions
    assert ro["exploration_rate"] == pytest.approx(td["epsilon"] / 2, abs=0.06)
    assert "stop_rule_met" in td and record["samples"]["expert_samples"] == len(run.expert)


def test_clipping_bounds_are_applied(monkeypatch):
    seen = []
    real = torch.nn.utils.clip_grad_value_

    def spy(parameters, clip_value, *args, **kwargs):
        seen.append(clip_value)
        return real(parameters, clip_value, *args, **kwargs)

    monkeypatch.setattr(torch.nn.utils, "clip_grad_value_", spy)
    cril().step()
    assert set(seen) == {1.0, 0.5}  # imitation ±1, TD ±0.5 (Sec 8.3)
    assert seen.count(0.5) == 4 * 6  # one per TD update


def test_the_td_share_limit_reaches_the_sampling():
    run = cril(iterations=4, share_n=4)
    record = run.step()
    assert record["sampling"]["cap"] == pytest.approx(share_limit(1, 4))
    assert record["sampling"]["realised_share"] <= record["sampling"]["cap"] + 0.01


def test_cril_has_layer_normalisation_and_attention():
    run = cril()
    kinds = {type(m).__name__ for m in run.policy.modules()} & {type(m).__name__ for m in run.learner.idm.modules()}
    assert {"LayerNorm", "GatedResidual"} <= kinds


def test_same_seed_same_numbers_and_save_load_continues(tmp_path):
    strip = lambda records: [{k: v for k, v in r.items() if k != "seconds"} for r in records]  # noqa: E731
    straight = cril(iterations=3)
    straight.run()
    first = cril(iterations=3)
    first.step()
    first.save(tmp_path / "run")
    resumed = Run.load(tmp_path / "run")
    resumed.run()
    assert strip(resumed.records) == strip(straight.records)


def test_the_stop_rule_ends_the_run_when_the_policy_no_longer_changes():
    run = cril(iterations=10, stop_rule=True)
    learner = run.learner
    learner.expert_probabilities = np.array([[0.9, 0.1], [0.2, 0.8]])
    assert not learner.check_stop_rule({"policy": {"loss": 1.0}})  # the first iteration has nothing to compare
    assert learner.check_stop_rule({"policy": {"loss": 0.5}})  # the same actions as before
    assert run.finished and run.iteration == 0  # with stop_rule on, the run is over
    off = cril(iterations=10)
    off.learner.stop = True
    assert not off.finished  # off by default


@pytest.mark.slow
def test_a_short_cril_run_beats_the_random_policy_on_cartpole():
    run = cril(iterations=4, pre_size=4000, episodes_per_iteration=10, eval_episodes=20, policy_epochs=10)
    run.run()
    best = max(r["evaluation"]["aer"] for r in run.records)
    assert best > 5 * get_env("cartpole").random_return  # random ~21


# --------------------------------------------------------------------------- policy maps (Figs 8.2, 8.3)
class PushWithVelocity(torch.nn.Module):
    """A hand-built reference: Q-values that say 'push the way you move' (a good MountainCar policy)."""

    def forward(self, s):
        v = s[:, 1:2] * 100
        return torch.cat([-v, torch.zeros_like(v), v], dim=1)


def test_policy_map_on_a_hand_built_policy():
    axes = get_env("mountaincar").policy_map_axes
    always_right = lambda states: np.tile([0.1, 0.1, 0.8], (len(states), 1))  # noqa: E731
    rec = policy_map_record(always_right, axes, PushWithVelocity(), cells=20)
    assert np.array(rec["action"]).shape == (20, 20) and set(np.ravel(rec["action"])) == {2}
    assert np.allclose(rec["probability"], 0.8)
    reference = np.array(rec["reference_action"])
    assert (reference[np.array(rec["y"]) > 0.001] == 2).all() and (reference[np.array(rec["y"]) < -0.001] == 0).all()
    # half the grid disagrees with the reference: one-hot KL is -log 0.8 where they agree, -log 0.1 elsewhere
    agree = np.mean(reference == 2)
    assert rec["onehot_kl"] == pytest.approx(-(agree * np.log(0.8) + (1 - agree) * np.log(0.1)), rel=1e-3)
    assert rec["kl"] > 0
    same = policy_map_record(lambda s: torch.softmax(PushWithVelocity()(torch.as_tensor(s)), -1).numpy(), axes,
                             PushWithVelocity())
    assert same["kl"] == pytest.approx(0, abs=1e-4)  # a policy equal to the reference: no divergence
    fig = figures.policy_map([{"iteration": 1, "policy_map": rec}], action_names=get_env("mountaincar").action_names)
    assert fig.layout.title.text and len(fig.data) >= 2  # the policy and the reference side by side


def test_every_method_on_mountaincar_records_its_policy_map():
    run = Run(RunConfig.from_dict(dict(env="mountaincar", method="bco-alpha", iterations=1, pre_size=2000,
                                       episodes_per_iteration=4, eval_episodes=4, policy_epochs=1,
                                       expert_episodes=1)))
    rec = run.step()["policy_map"]
    assert rec["x_name"] == "position" and rec["y_name"] == "velocity" and rec["kl"] is not None


def test_cril_learns_from_the_mazes_images():
    """The replay memory keeps the observations' own type: the maze's images stay pixels (uint8), which
    the CNN reads as such (stored as floats, they reached it unpermuted and the first TD update failed)."""
    run = cril(env="maze3", expert_episodes=10)
    record = run.step()
    assert run.learner.replay.states.dtype == np.uint8
    assert record["td"]["updates"] > 0 and np.isfinite(record["td"]["loss"])
