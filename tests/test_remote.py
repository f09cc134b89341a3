"""Iterations trained on Ray workers (ifo.remote, a class that outgrows one machine): the page and the
records must not be able to tell where an iteration trained. A local Ray stands in for a cluster."""
from pathlib import Path

import pytest
import torch

from conftest import make_tiny_config
from ifo.iteration_cache import IterationCache
from ifo.remote import RemoteTrainer
from ifo.run import Run


def strip(records):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in records]


@pytest.fixture(scope="module")
def trainer():
    import ray

    remote = RemoteTrainer(local_cpus=1)
    yield remote
    ray.shutdown()


def test_iterations_trained_on_a_worker_are_the_iterations_trained_here(trainer):
    cfg = make_tiny_config(method="iupe", iterations=3)
    here, there = Run(cfg), Run(cfg, trainer=trainer)
    for _ in range(2):
        here.step()
        there.step()
    assert strip(there.records) == strip(here.records)
    assert not there.last_step_cached
    for (name, a), b in zip(here.policy.state_dict().items(), there.policy.state_dict().values()):
        assert torch.equal(a, b), name
    there.trainer = None  # the worker's state is the run's own: it continues here exactly
    here.step()
    there.step()
    assert strip(there.records) == strip(here.records)


def test_a_workers_iteration_is_shared_through_the_cache(trainer, tmp_path):
    cache = IterationCache(tmp_path / "cache")
    cfg = make_tiny_config(method="bco-alpha", iterations=2)
    teacher = Run(cfg, cache=cache, trainer=trainer)
    teacher.step()
    student = Run(cfg, cache=cache)  # a session on the app's machine, no training
    student.step()
    assert student.last_step_cached and student.records == teacher.records


def test_a_run_on_a_users_own_demonstrations_trains_here(trainer, tmp_path):
    """The user's file is not shipped to workers: such a run never goes to the trainer."""
    import shutil

    from ifo.envs import ASSETS

    class Refuses:  # a trainer that fails the test if used
        def train(self, run):
            raise AssertionError("sent to a worker")

    path = tmp_path / "mine.npz"
    shutil.copy(ASSETS / "demos" / "cartpole.npz", path)
    cfg = make_tiny_config(method="bco-alpha", iterations=1, demos=str(path))
    run = Run(cfg, trainer=Refuses())
    run.step()
    assert run.iteration == 1


def test_the_step_page_trains_on_ray_workers_when_told_to(trainer, monkeypatch, tmp_path):
    """IFO_LAB_RAY sends the page's Steps to Ray: the same counter and records, the phase says where."""
    from streamlit.testing.v1 import AppTest

    from ifo.config import RunConfig
    from ifo.ui import storage

    monkeypatch.setenv("IFO_LAB_FAST", "1")
    monkeypatch.setenv("IFO_LAB_RUNS", str(tmp_path / "runs"))
    monkeypatch.setenv("IFO_LAB_CACHE_MB", "0")
    monkeypatch.setenv("IFO_LAB_RAY", "ray://a-cluster:10001")
    monkeypatch.setattr(storage, "_TRAINER", {"ray://a-cluster:10001": trainer})  # a local Ray stands in
    at = AppTest.from_file(str(Path(__file__).resolve().parents[1] / "app.py"), default_timeout=120)
    at.run()
    at.switch_page("views/step_through.py").run()
    at.button(key="step").click().run()
    assert not at.exception and not at.error
    run = at.session_state["ifo.slot.step"].run
    assert run.trainer is trainer and run.iteration == 1
    here = Run(RunConfig.from_dict(run.config.to_dict()))
    here.step()
    assert strip(run.records) == strip(here.records)
