"""A researcher's own gymnasium environment (`ifo.envs.register_env`, examples/parking.py): every method
trains in it on the researcher's demonstrations (IUPE learns it), from Python, the command line and the
app; a saved run opens in a fresh process; what IfO Lab cannot learn in is refused in plain words."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import examples.parking as parking
from ifo.config import RunConfig
from ifo.data.demos import DemoError
from ifo.envs import UnknownEnvironment, get_env, reached_terminal, register_env
from ifo.envs.rollout import random_returns
from ifo.methods import METHODS
from ifo.run import Run

ROOT = Path(__file__).resolve().parents[1]
ENV = "examples.parking:parking"


@pytest.fixture(scope="module")
def demos_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("parking") / "demos.npz"
    np.savez(path, **parking.demonstrations(50))
    return path


def config(demos, method="iupe", **extra) -> RunConfig:
    return RunConfig.from_dict({"env": ENV, "method": method, "demos": str(demos), "iterations": 5,
                                "eval_episodes": 20, **extra})


def test_iupe_learns_to_park_from_the_researchers_demonstrations(demos_file):
    run = Run(config(demos_file))
    run.run()
    performance = [r["evaluation"]["performance"] for r in run.records]
    assert run.config.env == ENV and run.config.expert_episodes == 50  # every demonstration brought
    assert performance[-1] >= 0.9 > performance[0], performance
    again = Run(config(demos_file))
    again.run()
    assert [r["evaluation"]["returns"] for r in again.records] == [r["evaluation"]["returns"] for r in run.records]


@pytest.mark.parametrize("method", sorted(METHODS))
def test_every_method_steps_in_a_registered_environment(demos_file, method):
    run = Run(config(demos_file, method, iterations=1, eval_episodes=5))
    record = run.step()
    assert np.isfinite(record["evaluation"]["aer"]) and len(record["evaluation"]["returns"]) == 5


def test_performance_runs_from_the_random_policy_to_the_demonstrator(demos_file):
    run = Run(config(demos_file, iterations=1))
    record = run.step()
    demonstrated = parking.demonstrations(50)
    expert = demonstrated["rewards"].sum() / 50
    random = random_returns(get_env(ENV), 100).mean()
    assert run.references["expert"] == pytest.approx(expert) and run.references["random"] == pytest.approx(random)
    assert record["evaluation"]["performance"] == pytest.approx(
        (record["evaluation"]["aer"] - random) / (expert - random))


def test_an_ifo_method_learns_the_same_whatever_the_demonstrators_actions_say(demos_file, tmp_path):
    """The actions in the researcher's file are only ever shown beside the IDM's guesses."""
    arrays = dict(np.load(demos_file, allow_pickle=False))
    shuffled, absent = tmp_path / "shuffled.npz", tmp_path / "absent.npz"
    np.savez(shuffled, **{**arrays, "actions": np.random.default_rng(1).permutation(arrays["actions"])})
    np.savez(absent, **{k: v for k, v in arrays.items() if k != "actions"})
    outcomes = []
    for path in (demos_file, shuffled, absent):
        run = Run(config(path, iterations=2))
        assert run.ctx.expert_actions is None
        run.run()
        outcomes.append(([r["evaluation"]["returns"] for r in run.records], run.policy.state_dict()))
    for returns, weights in outcomes[1:]:
        assert returns == outcomes[0][0]
        for name, value in weights.items():
            torch.testing.assert_close(value, outcomes[0][1][name])


def test_the_command_line_trains_it_and_a_fresh_process_continues_the_saved_run(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    demos, out = tmp_path / "demos.npz", tmp_path / "run"
    made = subprocess.run([sys.executable, "-m", "examples.parking", str(demos), "--episodes", "30"], cwd=tmp_path,
                          env=env, capture_output=True, text=True, timeout=300)
    assert made.returncode == 0 and "30 episodes" in made.stdout, made.stderr
    trained = subprocess.run([sys.executable, "-m", "ifo", "train", "--env", ENV, "--method", "bco-alpha", "--demos",
                              str(demos), "--iterations", "3", "--eval-episodes", "5", "--out", str(out)],
                             cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert trained.returncode == 0, trained.stderr
    continued = subprocess.run([sys.executable, "-c", "import json; from ifo.run import Run\n"
                                f"run = Run.load({str(out)!r}); first = run.iteration\n"
                                "run.config = run.config.with_values(iterations=4); run.step()\n"
                                "print(json.dumps([run.config.env, first, run.iteration]))"],
                               cwd=tmp_path, env=env, capture_output=True, text=True, timeout=300)
    assert continued.returncode == 0, continued.stderr
    assert json.loads(continued.stdout.splitlines()[-1]) == [ENV, 3, 4]


class _Image(gym.Env):
    observation_space = gym.spaces.Box(0, 255, (8, 8, 3), np.uint8)
    action_space = gym.spaces.Discrete(2)


gym.register("ifo-tests/Image-v0", entry_point=_Image, max_episode_steps=10)
gym.register("ifo-tests/NoTimeLimit-v0", entry_point=parking.Parking)


@pytest.mark.parametrize("name,gym_id,extra,message", [
    ("cartpole", "CartPole-v1", {}, "one of IfO Lab's own environments"),
    ("my parking", parking.GYM_ID, {}, "one word without spaces"),
    ("swing", "Pendulum-v1", {}, "discrete actions"),
    ("pictures", "ifo-tests/Image-v0", {}, "must be vectors"),
    ("forever", "ifo-tests/NoTimeLimit-v0", {}, "no time limit"),
    ("nowhere", "ifo-tests/NoSuchEnv-v0", {}, "gymnasium could not make"),
    ("parking2", parking.GYM_ID, {"action_names": ("back", "forward")}, "3 actions, but 2 action names"),
    ("parking3", parking.GYM_ID, {"goal": "reached"}, "goal must be a test"),
    ("parking", "CartPole-v1", {}, "already registered as ifo-examples/Parking-v0"),
])
def test_what_ifo_lab_cannot_learn_in_is_refused_in_plain_words(name, gym_id, extra, message):
    with pytest.raises(ValueError, match=message):
        register_env(name, gym_id, **{"goal": reached_terminal, **extra})


def test_a_time_limit_given_at_registration_is_enough():
    spec = register_env("limited", "ifo-tests/NoTimeLimit-v0", goal=reached_terminal, max_episode_steps=20)
    assert spec.make().spec.max_episode_steps == 20 and get_env("limited") is spec


@pytest.mark.parametrize("name,message", [
    ("no_such_module_here:parking", "could not import 'no_such_module_here'"),
    ("examples.parking:nothing", "registered no environment 'nothing'"),
])
def test_an_environment_that_is_nowhere_says_where_it_looked(name, message):
    with pytest.raises(UnknownEnvironment, match=message):
        get_env(name)


def test_a_module_whose_registration_is_refused_says_why(tmp_path, monkeypatch):
    (tmp_path / "swinging.py").write_text("from ifo.envs import reached_terminal, register_env\n"
                                          "register_env('swinging', 'Pendulum-v1', goal=reached_terminal)\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(UnknownEnvironment, match="could not import 'swinging' .ValueError: Pendulum-v1 has actions"):
        get_env("swinging:swinging")


def test_without_demonstrations_it_asks_for_them():
    with pytest.raises(DemoError, match="ships no demonstrations for examples.parking:parking"):
        Run(RunConfig(env=ENV, method="iupe"))


@pytest.fixture
def app_env(tmp_path, monkeypatch):
    """The app as a server with IFO_LAB_ENVS naming Parking (and a name that is nowhere: left out, logged)."""
    monkeypatch.setenv("IFO_LAB_ENVS", f"{ENV}, no_such_module_here:x")
    monkeypatch.setenv("IFO_LAB_FAST", "1")
    monkeypatch.setenv("IFO_LAB_RUNS", str(tmp_path / "runs"))


def open_page(path: str, user: str, **query):
    from streamlit.testing.v1 import AppTest

    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    at.query_params.update({"user": user, **query})
    at.run()
    at.switch_page(path).run()
    assert not at.exception, at.exception
    return at


def test_the_app_offers_it_and_trains_it_on_uploaded_demonstrations(demos_file, app_env, monkeypatch):
    """IFO_LAB_ENVS names it: Your runs takes its demonstrations and trains on them, the Step page opens
    that run as trained (also once the server no longer names it), and chosen without demonstrations it
    says where to bring them."""
    from ifo.ui import storage
    from ifo.ui.queue import get_queue

    user = "ownenv001"

    def page(path: str, **query):
        return open_page(path, user, **query)

    runs = page("views/runs.py")
    assert runs.selectbox(key="runs.upload_env").options[-1] == "Parking"
    storage.save_demos(user, ENV, "parking.npz", demos_file.read_bytes())  # as the upload form saves it
    runs.run()
    runs.button(key="runs.train.parking-parking").click().run()
    assert not runs.exception and not runs.error
    [job] = get_queue().jobs(user)
    get_queue().wait_idle(120)
    assert get_queue().job(user, job.id).state == "done", get_queue().job(user, job.id).error
    [saved] = storage.list_runs(user)
    assert saved.config["env"] == ENV

    step = page("views/step_through.py", run=saved.run_id)  # as Your runs opens it
    run = step.session_state["ifo.slot.step"].run
    assert step.selectbox(key="step.env").value == ENV and not step.error
    assert run.iteration == run.config.iterations == saved.iterations_done > 0  # the trained run, all of it

    fresh = page("views/step_through.py", **{"step.env": ENV})
    assert any("upload yours on *Your runs*" in e.value for e in fresh.error), [e.value for e in fresh.error]

    # the server started again without IFO_LAB_ENVS: the saved run still opens, with its environment
    from ifo import envs

    monkeypatch.delenv("IFO_LAB_ENVS")
    monkeypatch.setattr(envs, "_FOUND_BY_MODULE", {})
    again = page("views/step_through.py", run=saved.run_id)
    assert again.selectbox(key="step.env").value == ENV and not again.error, [e.value for e in again.error]
    assert again.session_state["ifo.slot.step"].run.iteration == saved.iterations_done


class _Undrawn(parking.Parking):
    render = gym.Env.render  # gymnasium's own: draws nothing


gym.register("ifo-tests/Undrawn-v0", entry_point=_Undrawn, max_episode_steps=50)


def test_an_environment_that_draws_nothing_says_so_instead_of_a_video(demos_file):
    from ifo.video import policy_rollout_frames

    register_env("undrawn", "ifo-tests/Undrawn-v0", goal=reached_terminal)
    run = Run(RunConfig.from_dict({"env": "undrawn", "method": "bco-alpha", "demos": str(demos_file),
                                   "iterations": 1, "eval_episodes": 5}))
    with pytest.raises(ValueError, match="undrawn draws no pictures"):
        policy_rollout_frames(run)
    assert len(policy_rollout_frames(Run(config(demos_file, iterations=1)))[0]) >= 2  # parking draws itself


def test_compare_methods_on_it_from_the_users_demonstrations(demos_file, app_env):
    """Compare and ablate on a researcher's own environment: without demonstrations it says where to bring
    them and queues nothing; with them, two methods train on that file and their curves and rows appear."""
    from ifo.ui import storage
    from ifo.ui.queue import get_queue

    user = "ownenv002"

    def compare_page():
        at = open_page("views/compare.py", user)
        at.selectbox(key="compare.env").set_value(ENV).run()
        assert not at.exception, at.exception
        return at

    at = compare_page()
    assert any("upload them on *Your runs* first" in i.value for i in at.info)
    assert at.button(key="compare.queue_methods").disabled

    storage.save_demos(user, ENV, "parking.npz", demos_file.read_bytes())
    at = compare_page()
    assert at.selectbox(key=f"compare.demos.{ENV}").value == "parking-parking"
    at.number_input(key=f"compare.iterations.{ENV}").set_value(2)
    at.multiselect(key="compare.methods").set_value(["bco-alpha", "iupe"])
    at.button(key="compare.queue_methods").click().run()
    assert not at.exception and not at.error, [e.value for e in at.error]
    assert get_queue().wait_idle(180)
    jobs = get_queue().jobs(user)
    assert [j.state for j in jobs] == ["done", "done"] and {j.config.demos for j in jobs} == {
        str(storage.list_demos(user)[0].path)}
    at.run()
    rows = {r["configuration"]: r for r in at.dataframe[0].value.to_dict("records")}
    assert set(rows) == {"BCO(α) · Parking · 2 it. · your demos", "IUPE · Parking · 2 it. · your demos"}
    assert all(r["P (ours)"] != "—" and r["P (thesis)"] == "—" for r in rows.values())
    assert len(at.get("plotly_chart")) == 2
