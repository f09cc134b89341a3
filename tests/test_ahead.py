"""Computing the next iteration ahead (ifo.ahead): what a Step then takes is what it would have trained,
the run a session holds is never touched, and the background gives way to the class."""
import shutil
import threading
from pathlib import Path

import pytest

from conftest import make_tiny_config
from ifo.ahead import ComputeAhead
from ifo.iteration_cache import IterationCache
from ifo.run import Run

ROOT = Path(__file__).resolve().parents[1]


def strip(records):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in records]


@pytest.fixture
def cache(tmp_path):
    return IterationCache(tmp_path / "cache")


def test_a_step_takes_the_iteration_computed_ahead_number_for_number(cache):
    fresh = Run(make_tiny_config(iterations=3))
    fresh.run()
    run = Run(make_tiny_config(iterations=3), cache=cache)
    ahead = ComputeAhead(cache)
    run.step()
    weights = {k: v.clone() for k, v in run.policy.state_dict().items()}
    assert ahead.request(run)
    assert not ahead.request(run)  # asked for already: once is enough
    assert ahead.wait_idle(120) and ahead.computed == 1
    assert run.iteration == 1 and all((v == weights[k]).all() for k, v in run.policy.state_dict().items())
    run.step()
    assert run.last_step_cached  # taken, not trained
    ahead.request(run)
    assert ahead.wait_idle(120)
    run.step()
    assert run.last_step_cached and strip(run.records) == strip(fresh.records)


def test_a_step_of_something_else_makes_the_background_give_way_and_a_step_of_the_same_waits_for_it(cache):
    started, go_on = threading.Event(), threading.Event()

    def on_phase(phase):  # hold the iteration trained ahead at its first phase until the test says
        started.set()
        go_on.wait(60)

    ahead = ComputeAhead(cache, on_phase=on_phase)
    run = Run(make_tiny_config(method="iupe"), cache=cache)
    key = run.next_key()
    assert ahead.request(run) and started.wait(120) and ahead.working_on(key)
    with ahead.stepping(key), ahead.stepping("another session's iteration"):
        go_on.set()
        assert ahead.wait_idle(60)
    assert ahead.cancelled == 1 and ahead.computed == 0 and not cache.has(key)
    run.step()  # the run trains it itself, as if nothing had happened
    assert not run.last_step_cached and run.iteration == 1

    started.clear()
    go_on.clear()
    assert ahead.request(run) and started.wait(120)
    with ahead.stepping(run.next_key()):  # the teacher presses Step while it trains: it goes on
        go_on.set()
        assert ahead.wait_idle(60)
    assert ahead.computed == 1 and cache.has(run.next_key())


def test_the_background_waits_while_another_session_steps_and_until_the_class_is_quiet(cache):
    import time

    ahead = ComputeAhead(cache, quiet_seconds=1.5, poll_seconds=0.05)
    run = Run(make_tiny_config(), cache=cache)
    with ahead.stepping("another session's iteration"):
        assert ahead.request(run)
        assert not ahead.wait_idle(1.0) and not cache.has(run.next_key())
    for _ in range(10):  # students keep taking ready iterations: the class is busy
        ahead.stepped()
        time.sleep(0.1)
        assert not cache.has(run.next_key())
    assert ahead.wait_idle(120) and cache.has(run.next_key())


def test_the_background_trains_only_with_a_free_slot_of_the_training_gate(cache):
    gate = threading.BoundedSemaphore(1)
    ahead = ComputeAhead(cache, gate=gate, poll_seconds=0.05)
    run = Run(make_tiny_config(), cache=cache)
    key = run.next_key()
    gate.acquire()  # a session's Step trains
    try:
        assert ahead.request(run)
        assert not ahead.wait_idle(1.0) and not cache.has(key)  # it waits for the slot
    finally:
        gate.release()
    assert ahead.wait_idle(120) and cache.has(key)
    assert gate.acquire(blocking=False)  # and gave the slot back
    gate.release()


def test_nothing_is_computed_ahead_for_a_finished_run_or_one_on_a_users_own_demonstrations(cache, tmp_path):
    ahead = ComputeAhead(cache)
    finished = Run(make_tiny_config(iterations=1), cache=cache)
    finished.step()
    assert not ahead.request(finished)
    path = tmp_path / "mine.npz"
    shutil.copy(ROOT / "assets" / "demos" / "cartpole.npz", path)
    own = Run(make_tiny_config(demos=str(path)), cache=cache)
    assert own.lineage is None and not ahead.request(own)  # never shared, so never trained ahead either


def test_an_iteration_whose_training_ahead_failed_is_not_asked_for_again(cache, monkeypatch, caplog):
    ahead = ComputeAhead(cache, quiet_seconds=0)
    run = Run(make_tiny_config(), cache=cache)

    def broken(self, *args, **kwargs):
        raise RuntimeError("out of memory")

    with monkeypatch.context() as patch:
        patch.setattr(Run, "train_from", broken)
        assert ahead.request(run) and ahead.wait_idle(120)
    assert ahead.computed == 0 and not cache.has(run.next_key())
    assert sum("training an iteration ahead failed" in r.getMessage() for r in caplog.records) == 1
    assert not ahead.request(run)  # every page run asks: once is enough
    run.step()  # the Step trains it itself
    assert not run.last_step_cached and run.iteration == 1
    assert ahead.request(run) and ahead.wait_idle(120) and ahead.computed == 1  # the next one is asked for
