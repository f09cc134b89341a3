"""The run stepper: records, determinism, save/load, and the IfO rule (no expert actions)."""
import json

import numpy as np
import pytest
import torch

import ifo.learners.bco as bco_mod
from ifo.config import RunConfig
from ifo.data.shipped import load_shipped_demonstrations
from ifo.envs import get_env
from ifo.learners import StepCancelled
from ifo.methods import METHODS
from ifo.run import Run, RunFinished


def strip_timing(records):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in records]


def learned_weights(run):
    return {k: v.clone() for k, v in run.policy.state_dict().items()}


def test_a_step_returns_a_record_with_every_signal(tiny_config):
    run = Run(tiny_config())
    rec = run.step()
    assert rec["iteration"] == 1 and run.iteration == 1
    idm = rec["idm"]
    for key in ("loss", "train_accuracy", "val_accuracy", "prediction_counts", "true_counts", "expert_accuracy"):
        assert key in idm
    assert sum(idm["prediction_counts"]) == sum(idm["true_counts"]) == len(run.expert)
    assert {"loss", "agreement"} <= set(rec["policy"])
    ro = rec["rollouts"]
    assert len(ro["returns"]) == len(ro["goals"]) == 10 and 0 <= ro["win_probability"] <= 1
    ev = rec["evaluation"]
    assert len(ev["returns"]) == 10 and ev["aer"] == pytest.approx(np.mean(ev["returns"]))
    assert ev["performance"] is not None and ev["fidelity"] >= 0
    assert set(rec["seconds"]) >= {"idm", "label", "policy", "rollout", "sampling", "evaluate", "total"}
    json.dumps(rec)  # plain data only


def test_same_seed_same_numbers_and_different_seed_different_numbers(tiny_config):
    a = Run(tiny_config(seed=3))
    b = Run(tiny_config(seed=3))
    assert strip_timing(a.run()) == strip_timing(b.run())
    c = Run(tiny_config(seed=4))
    assert strip_timing(c.run()) != strip_timing(a.records)


def test_save_then_load_continues_exactly_like_an_uninterrupted_run(tiny_config, tmp_path):
    cfg = tiny_config(iterations=3)
    straight = Run(cfg)
    straight.run()

    first = Run(cfg)
    first.step()
    first.save(tmp_path / "run")
    resumed = Run.load(tmp_path / "run")
    assert resumed.iteration == 1
    resumed.run()
    assert strip_timing(resumed.records) == strip_timing(straight.records)
    for k, v in learned_weights(straight).items():
        torch.testing.assert_close(learned_weights(resumed)[k], v)


def test_a_crash_mid_save_leaves_the_previous_save_intact(tiny_config, tmp_path, monkeypatch):
    run = Run(tiny_config(iterations=2))
    run.step()
    run.save(tmp_path / "run")
    run.step()

    import ifo.checkpoint as checkpoint

    real = checkpoint._write_new

    def crash(path, data, *args, **kwargs):
        real(path, data[: len(data) // 3])  # half-written file...
        raise OSError("disk full")  # ...then the process dies

    monkeypatch.setattr(checkpoint, "_write_new", crash)
    with pytest.raises(OSError):
        run.save(tmp_path / "run")
    monkeypatch.undo()
    loaded = Run.load(tmp_path / "run")
    assert loaded.iteration == 1
    assert strip_timing(loaded.records) == strip_timing(run.records[:1])


def test_loading_a_folder_without_a_run_says_so(tmp_path):
    with pytest.raises(FileNotFoundError, match="no saved run"):
        Run.load(tmp_path)


IFO_METHODS = [m for m, method in METHODS.items() if not method.sees_expert_actions]


@pytest.mark.parametrize("env,method", [("cartpole", m) for m in IFO_METHODS] + [("maze3", "abco"), ("maze3", "iupe")])
def test_ifo_methods_never_learn_from_the_expert_actions(tiny_config, env, method):
    """Whatever the hidden actions say (true, shuffled or absent), an IfO learner learns the same."""
    cfg = tiny_config(method=method, env=env, **({"expert_episodes": 5, "pre_size": 400, "attention_probes": False}
                                                 if env == "maze3" else {}))
    spec = get_env(env)
    outcomes, diagnostics = [], []
    for variant in ("true", "shuffled", "absent"):
        demos = load_shipped_demonstrations(spec, episodes=cfg.expert_episodes)
        if variant == "shuffled":
            demos.hidden_actions = np.random.default_rng(1).permutation(demos.hidden_actions)
        elif variant == "absent":
            demos.hidden_actions = None
        run = Run(cfg, demos=demos)
        assert run.ctx.expert_actions is None  # the learner's context holds no actions at all
        run.run()
        rec = run.records[0]
        diagnostics.append("expert_accuracy" in (rec.get("idm") or rec.get("policy") or {}))
        outcomes.append((learned_weights(run), [r["evaluation"]["returns"] for r in run.records],
                         [r.get("idm", {}).get("prediction_counts") for r in run.records]))
    for weights, returns, predictions in outcomes[1:]:
        assert returns == outcomes[0][1] and predictions == outcomes[0][2]
        for k, v in weights.items():
            torch.testing.assert_close(v, outcomes[0][0][k])
    # ...while the diagnostics shown to people use them when present
    assert diagnostics == [True, True, False]


def test_bc_is_the_one_method_that_needs_actions(tiny_config):
    demos = load_shipped_demonstrations(get_env("cartpole"))
    demos.hidden_actions = None
    with pytest.raises(ValueError, match="BC learns from the expert's actions"):
        Run(tiny_config(method="bc"), demos=demos)
    run = Run(tiny_config(method="bc"))
    rec = run.step()
    assert "idm" not in rec and rec["policy"]["expert_accuracy"] > 0.6


def test_stepping_past_the_end_is_refused(tiny_config):
    run = Run(tiny_config(method="bco"))
    assert run.config.iterations == 1  # BCO is one pass
    run.step()
    assert run.finished
    with pytest.raises(RunFinished):
        run.step()


@pytest.mark.parametrize("field,value,message", [
    ("iterations", 0, "iterations must be at least 1"),
    ("eval_episodes", -5, "eval_episodes must be at least 1"),
    ("lr", 0.0, "lr must be at least"),
    ("seed", -1, "seed must be at least 0"),
    ("seed", 2**64, "seed must be at most 4294967295"),
    ("pre_size", 1, "pre_size must be at least 10"),
    ("attention", "magic", "attention must be one of"),
    ("sampling", "all", "sampling must be one of"),
    ("method", "dagger", "unknown method"),
    ("env", "pong", "unknown environment"),
])
def test_impossible_settings_are_refused_with_a_clear_message(field, value, message):
    with pytest.raises(ValueError, match=message):
        RunConfig.from_dict({"env": "cartpole", "method": "bco-alpha", field: value}).resolved()


@pytest.mark.slow
def test_a_short_bco_alpha_run_clearly_beats_the_random_policy():
    cfg = RunConfig.from_dict(dict(env="cartpole", method="bco-alpha", iterations=3, seed=0, eval_episodes=30,
                                   episodes_per_iteration=20))
    run = Run(cfg)
    run.run()
    random_aer = get_env("cartpole").random_return
    best = max(r["evaluation"]["aer"] for r in run.records)
    assert best > 5 * random_aer  # random ~21; the learner balances for hundreds of steps
    assert run.records[-1]["evaluation"]["performance"] > 0.5


def test_phases_name_what_an_iteration_does(tiny_config):
    assert Run(tiny_config()).phases() == ["idm", "label", "policy", "rollout", "sampling", "evaluate"]
    assert Run(tiny_config()).phase_text("idm") == "training the inverse dynamics model (IDM) on I_s"
    assert Run(tiny_config(method="bco")).phases() == ["idm", "label", "policy", "evaluate"]
    assert Run(tiny_config(method="bc")).phases() == ["policy", "evaluate"]


def test_the_number_of_iterations_can_grow_but_not_below_what_is_done(tiny_config):
    run = Run(tiny_config(iterations=1))
    run.step()
    run.set_iterations(3)
    assert not run.finished and run.config.iterations == 3
    with pytest.raises(ValueError, match=">= 1"):
        run.set_iterations(0)
    with pytest.raises(ValueError, match="single pass"):
        Run(tiny_config(method="bco")).set_iterations(4)



def _layout_keys(pool):
    return {layout.tobytes() for layout in pool.envs(1)[0].pool}


@pytest.mark.parametrize("protocol", ["held-out", "demonstration"])
def test_maze_worlds_keep_evaluation_layouts_where_the_protocol_says(protocol):
    from ifo.envs.maze import layout_pool

    run = Run(RunConfig.from_dict(dict(env="maze5", method="iupe", pre_size=200, iterations=1, eval_episodes=5,
                                       maze_eval_layouts=protocol, attention_probes=False)))
    training, evaluation = _layout_keys(run.pool), _layout_keys(run.eval_pool)
    demonstration_layouts = {layout.tobytes() for layout in layout_pool(5, "train")[:100]}
    if protocol == "held-out":  # never trained on, never demonstrated
        assert not training & evaluation and not evaluation & demonstration_layouts
    else:  # the thesis authors' world: the demonstrations' 100 layouts, for everything
        assert training == evaluation == demonstration_layouts


@pytest.mark.parametrize("explore_labels", [True, False])
def test_exploring_labels_draws_them_afresh_for_every_pass_over_the_demonstrations(
        tiny_config, monkeypatch, explore_labels):
    given = []
    real_fit = bco_mod.fit

    def spy(forward, module, optimizer, inputs, targets, *args, **kwargs):
        if module is run.policy:
            given.append(np.asarray(targets))
        return real_fit(forward, module, optimizer, inputs, targets, *args, **kwargs)

    monkeypatch.setattr(bco_mod, "fit", spy)
    run = Run(tiny_config(method="iupe", policy_epochs=3, pre_size=300, explore_labels=explore_labels))
    record = run.step()
    (targets,) = given
    if explore_labels:  # one draw per epoch: the policy is not fitted to one unlucky draw 3 times
        assert targets.shape == (3, len(run.expert)) and not (targets[0] == targets[1:]).all()
        assert record["labels"]["exploration_rate"] > 0
    else:  # MAP labels: the same every epoch
        assert targets.shape == (3, len(run.expert)) and (targets == targets[0]).all()
        assert record["labels"]["exploration_rate"] == 0


def test_fit_refuses_a_label_set_per_epoch_that_does_not_match_the_epochs():
    from ifo.components.learning import fit, make_optimizer
    from ifo.nets import Policy

    policy = Policy((4,), 2)
    with pytest.raises(ValueError, match="rows of targets"):
        fit(policy, policy, make_optimizer(policy, 1e-3), [np.zeros((8, 4), np.float32)],
            np.zeros((2, 8), int), 3, 4, torch.Generator())


# --------------------------------------------------------------------------- an iteration is all or nothing
def _fails_once(monkeypatch, module, name):
    """Make `module.name` raise the first time it is called, then behave."""
    real, calls = getattr(module, name), []

    def flaky(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            raise RuntimeError("the disk filled up")
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, flaky)


@pytest.mark.parametrize("method", ["bco-alpha", "iupe"])
def test_a_failed_iteration_leaves_the_run_exactly_as_it_was(tiny_config, monkeypatch, method):
    cfg = tiny_config(method=method, iterations=3)
    straight = Run(cfg)
    straight.run()

    run = Run(cfg)
    run.step()
    before = learned_weights(run), run.learner.train_set
    _fails_once(monkeypatch, bco_mod, "build_training_set")  # late in the round: IDM and policy have moved on
    with pytest.raises(RuntimeError, match="disk filled up"):
        run.step()
    assert run.iteration == 1 and run.learner.train_set is before[1]
    for k, v in before[0].items():
        torch.testing.assert_close(learned_weights(run)[k], v)
    run.run()  # the retry: same seed, same numbers
    assert strip_timing(run.records) == strip_timing(straight.records)
    for k, v in learned_weights(straight).items():
        torch.testing.assert_close(learned_weights(run)[k], v)


def test_a_cancelled_iteration_is_undone_and_can_be_retried(tiny_config):
    cfg = tiny_config(iterations=2)
    straight = Run(cfg)
    straight.run()

    def cancel_at_rollout(phase, iteration):
        if phase == "rollout" and iteration == 2:
            run.cancel()

    run = Run(cfg, progress=cancel_at_rollout)
    run.step()
    with pytest.raises(StepCancelled):
        run.step()
    assert run.iteration == 1
    run.progress = None
    run.step()
    assert strip_timing(run.records) == strip_timing(straight.records)


def test_seed_streams_are_disjoint_whatever_the_seed():
    from ifo.seeds import Seeds, evaluation_seeds

    evaluation = set(evaluation_seeds(100, maze=False).tolist())
    for seed in (0, 1, 100, 2**31, 2**32 - 1):
        s = Seeds(seed)
        pre = set(s.episodes("pre", 32, 0).tolist()) | set(s.episodes("pre", 32, 1).tolist())
        rollouts = set(s.episodes("rollouts", 50, 0).tolist())
        assert not pre & rollouts and not (pre | rollouts) & evaluation  # seed 100 once hit the evaluation seeds
        assert min(pre | rollouts) > 10**6  # nor the demonstrations' seeds 0, 1, ...
        assert (s.rng("iteration", 3).random(4) == Seeds(seed).rng("iteration", 3).random(4)).all()
        assert not (s.rng("iteration", 3).random(4) == s.rng("iteration", 4).random(4)).any()


# --------------------------------------------------------------------------- history and branches
def test_the_policy_of_any_past_iteration_can_be_replayed_and_is_saved(tiny_config, tmp_path):
    run = Run(tiny_config(iterations=3))
    run.step()
    after_one = learned_weights(run)
    run.run()
    latest = learned_weights(run)
    with run.policy_at(1):
        for k, v in after_one.items():
            torch.testing.assert_close(run.policy.state_dict()[k], v)
    for k, v in latest.items():  # and back to the current policy afterwards
        torch.testing.assert_close(run.policy.state_dict()[k], v)
    run.save(tmp_path / "run")
    loaded = Run.load(tmp_path / "run")
    assert sorted(loaded.policy_history) == [1, 2, 3]
    with loaded.policy_at(1):
        for k, v in after_one.items():
            torch.testing.assert_close(loaded.policy.state_dict()[k], v)


def test_a_branch_goes_on_from_the_same_point_with_one_switch_changed(tiny_config):
    run = Run(tiny_config(method="bco-alpha", iterations=3))
    run.run(2)
    branch = run.branch(sampling="iupe", explore_labels=True)
    assert branch.config.learner.sampling == "iupe" and branch.config.learner.explore_labels
    assert branch.records == run.records and branch.iteration == 2  # the history so far
    for k, v in learned_weights(run).items():  # the same models so far
        torch.testing.assert_close(learned_weights(branch)[k], v)
    np.testing.assert_array_equal(branch.learner.pre.train.states, run.learner.pre.train.states)  # the same I_pre
    branch.step()
    assert branch.records[-1]["labels"]["sampled"] and run.iteration == 2  # the original is untouched
    with pytest.raises(ValueError, match="change the networks or the data"):
        run.branch(attention="gated")


def test_a_planned_method_says_so(monkeypatch):
    import ifo.methods

    monkeypatch.setattr(ifo.methods, "PLANNED", ("dac",))  # every method of the thesis is built: pretend one is not
    with pytest.raises(ValueError, match="planned but not implemented"):
        RunConfig(env="cartpole", method="dac").resolved()



@pytest.mark.parametrize("method", ["iupe", "ilpo"])
def test_a_run_built_again_in_the_same_process_reuses_i_pre_with_the_same_numbers(tiny_config, method,
                                                                                     monkeypatch):
    """Every session of a lesson builds the same run: I_pre's random transitions are collected once per
    process, and a run built from the kept set (its random stream put where the collection left it)
    gives the numbers of one that collected them itself."""
    import ifo.learners.base as base_mod
    from ifo.data.transitions import RANDOM_TRANSITIONS

    cfg = tiny_config(method=method, iterations=2)
    RANDOM_TRANSITIONS.clear()  # the first run collects
    collected = Run(cfg)
    calls = []
    real = base_mod.collect_random_transitions
    monkeypatch.setattr(base_mod, "collect_random_transitions", lambda *a, **k: calls.append(1) or real(*a, **k))
    reused = Run(cfg)
    assert calls == []  # built from the kept set
    assert strip_timing(reused.run()) == strip_timing(collected.run())
    for k, v in learned_weights(collected).items():
        torch.testing.assert_close(learned_weights(reused)[k], v, rtol=0, atol=0)
    Run(tiny_config(method=method, iterations=2, seed=cfg.seed + 1))
    assert calls == [1]  # another seed: collected afresh


def test_a_kept_i_pre_is_not_held_up_by_another_sessions_collection():
    """A session whose I_pre is already kept builds its run at once, even while another session (another
    configuration) is still collecting its own; the kept set and the random stream are as collected."""
    import threading

    from ifo.data.transitions import Transitions, random_transitions_once

    def collect_with(rng, note=None):
        if note is not None:
            note()
        states = rng.normal(size=(6, 4)).astype(np.float32)
        return Transitions(states, rng.integers(0, 2, 6), states + 1), 6

    first_rng = np.random.default_rng(7)
    kept, _ = random_transitions_once({"lesson": "kept"}, first_rng, lambda: collect_with(first_rng))
    started, release = threading.Event(), threading.Event()

    def slow_collection():  # another configuration, still collecting
        rng = np.random.default_rng(8)
        random_transitions_once({"lesson": "slow"}, rng,
                                lambda: (started.set(), release.wait(30), collect_with(rng))[-1])

    slow = threading.Thread(target=slow_collection)
    slow.start()
    try:
        assert started.wait(10)
        rng, got = np.random.default_rng(7), {}
        reader = threading.Thread(target=lambda: got.update(value=random_transitions_once(
            {"lesson": "kept"}, rng, lambda: pytest.fail("a kept set was collected again"))))
        reader.start()
        reader.join(10)
        assert not reader.is_alive(), "a kept I_pre waited for another configuration's collection"
        assert got["value"][0] is kept
        assert rng.bit_generator.state == first_rng.bit_generator.state  # as if it had collected
    finally:
        release.set()
        slow.join(30)


def train_at_once(runs) -> list[Exception]:
    """Trains each run in its own thread, all at once; returns what they raised."""
    import threading

    errors = []

    def train(run):
        try:
            run.run()
        except Exception as e:  # noqa: BLE001 - reported by the caller
            errors.append(e)

    threads = [threading.Thread(target=train, args=(run,)) for run in runs]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return errors


def test_trainings_in_threads_of_one_process_give_the_numbers_they_give_alone(tiny_config):
    """The app trains several sessions' iterations at once in threads of one process. PPO (GAIfO) draws from
    torch's and numpy's process-wide generators: without the lock the threads interleaved their draws and the
    same seed gave other numbers (shared with a class through the iteration cache). The maze's image heads
    draw their dropout masks from their run's own generator, and CartPole's IUPE draws nothing: they run
    beside it."""
    configs = [tiny_config(env="maze3", method="iupe", expert_episodes=10, iterations=2),
               tiny_config(method="gaifo", iterations=2),
               tiny_config(env="maze3", method="bco-alpha", expert_episodes=10, iterations=2, seed=1),
               tiny_config(method="iupe", iterations=3)]
    alone = [strip_timing(Run(c).run()) for c in configs]
    runs = [Run(c) for c in configs]
    errors = train_at_once(runs)
    assert not errors
    assert [strip_timing(run.records) for run in runs] == alone
    assert [run.learner.draws_global_rng for run in runs] == [False, True, False, False]


def test_two_maze_trainings_run_at_once_and_give_the_numbers_they_give_alone(tiny_config):
    """Dropout in the maze's image heads once made every maze step hold the process-wide lock, so a class's
    second maze training waited for the first. Both steps now meet inside the learner at once (a barrier
    that a lock would leave waiting), and each run's records are those it gives alone."""
    import threading

    configs = [tiny_config(env="maze3", method="iupe", expert_episodes=10, iterations=2),
               tiny_config(env="maze3", method="cril", expert_episodes=10, iterations=2, seed=1)]
    alone = [strip_timing(Run(c).run()) for c in configs]
    runs = [Run(c) for c in configs]
    both_inside = threading.Barrier(2, timeout=60)
    for run in runs:
        def step(iteration, rng, _step=run.learner.step):
            both_inside.wait()  # BrokenBarrierError if the other step cannot start until this one ends
            return _step(iteration, rng)
        run.learner.step = step
    errors = train_at_once(runs)
    assert not errors, errors
    assert [strip_timing(run.records) for run in runs] == alone
