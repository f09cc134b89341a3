"""The background queue (ifo.ui.queue) with stand-in runs: order, bound, status, errors, cancel, users.

No timing asserts: runs block on events the test releases, and every wait has a generous timeout.
"""
import threading
import time
from dataclasses import dataclass

import pytest

from ifo.ui.queue import JobQueue


@dataclass(frozen=True)
class FakeConfig:
    name: str
    iterations: int = 2
    fail: bool = False


class Recorder:
    """Stand-in runs that note when they start and how many step at once."""

    def __init__(self, hold: bool = False):
        self.lock = threading.Lock()
        self.started: list[str] = []
        self.running = 0
        self.max_running = 0
        self.saves: list[tuple[str, int]] = []
        self.release = threading.Event()
        if not hold:
            self.release.set()
        self.stepped = threading.Event()

    def make_run(self, config):
        if config.fail:
            raise ValueError(f"{config.name} cannot be built")
        rec = self

        class FakeRun:
            def __init__(self):
                self.config, self.records = config, []
                with rec.lock:
                    rec.started.append(config.name)

            @property
            def iteration(self):
                return len(self.records)

            def step(self):
                with rec.lock:
                    rec.running += 1
                    rec.max_running = max(rec.max_running, rec.running)
                try:
                    assert rec.release.wait(30)
                    time.sleep(0.01)
                    self.records.append({"iteration": len(self.records) + 1,
                                         "evaluation": {"aer": 1.0, "performance": 0.5}})
                finally:
                    with rec.lock:
                        rec.running -= 1
                    rec.stepped.set()

        return FakeRun()

    def save(self, run, user, run_id, label):
        with self.lock:
            self.saves.append((run_id, run.iteration))


def wait_for(predicate, timeout=30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return False


@pytest.fixture
def make_queue():
    queues = []

    def make(max_workers=1, **kwargs):
        rec = Recorder(**kwargs)
        q = JobQueue(max_workers, make_run=rec.make_run, save=rec.save)
        queues.append(q)
        return q, rec

    yield make
    for q in queues:
        q.shutdown()


def submit(q, user, name, **kw):
    return q.submit(user, FakeConfig(name, **kw), label=name, run_id=f"run-{name}")


def test_jobs_run_in_order_one_at_a_time(make_queue):
    q, rec = make_queue(1)
    for name in "abcd":
        submit(q, "user01", name)
    assert q.wait_idle(60)
    assert rec.started == list("abcd")
    assert rec.max_running == 1
    assert [j.state for j in q.jobs("user01")] == ["done"] * 4
    # saved after every iteration
    assert rec.saves.count(("run-a", 1)) == 1 and rec.saves.count(("run-a", 2)) == 1


def test_at_most_n_workers_train_at_once(make_queue):
    q, rec = make_queue(2)
    for k in range(6):
        submit(q, f"user{k:02d}x", str(k), iterations=3)
    assert q.wait_idle(60)
    assert rec.max_running <= 2
    assert len(rec.started) == 6


def test_status_shows_position_and_progress(make_queue):
    q, rec = make_queue(1, hold=True)
    first = submit(q, "user01", "a", iterations=2)
    second = submit(q, "user01", "b")
    assert wait_for(lambda: q.job("user01", first).state == "running")
    status = {j.id: j for j in q.jobs("user01")}
    assert status[first].iteration == 0 and status[first].total == 2
    assert status[second].state == "queued" and status[second].position == 1
    rec.release.set()
    assert q.wait_idle(60)
    done = q.job("user01", first)
    assert done.state == "done" and done.iteration == 2 and len(done.records) == 2


def test_a_failing_job_records_its_error_and_the_worker_goes_on(make_queue):
    q, rec = make_queue(1)
    bad = submit(q, "user01", "bad", fail=True)
    good = submit(q, "user01", "good")
    assert q.wait_idle(60)
    assert q.job("user01", bad).state == "error"
    assert q.job("user01", bad).error == "bad cannot be built"
    assert q.job("user01", good).state == "done"


def test_cancel_a_queued_and_a_running_job(make_queue):
    q, rec = make_queue(1, hold=True)
    running = submit(q, "user01", "long", iterations=5)
    waiting = submit(q, "user01", "waiting")
    assert wait_for(lambda: q.job("user01", running).state == "running")
    assert wait_for(lambda: rec.running == 1)  # inside its first Step (a cancel before it stops at 0)
    assert q.cancel("user01", waiting)
    assert q.cancel("user01", running)
    rec.release.set()
    assert q.wait_idle(60)
    assert q.job("user01", waiting).state == "cancelled"
    assert "waiting" not in rec.started
    job = q.job("user01", running)
    assert job.state == "cancelled" and 1 <= job.iteration < 5  # stopped between iterations
    assert not q.cancel("user01", running)  # already ended


def test_a_user_only_sees_and_cancels_their_own_jobs(make_queue):
    q, rec = make_queue(1, hold=True)
    mine = submit(q, "alice01", "a")
    submit(q, "bobby01", "b")
    assert [j.id for j in q.jobs("alice01")] == [mine]
    assert [j.label for j in q.jobs("bobby01")] == ["b"]
    assert not q.cancel("bobby01", mine)
    assert q.job("bobby01", mine) is None
    rec.release.set()
    assert q.wait_idle(60)


def test_users_with_nothing_running_go_first(make_queue):
    q, rec = make_queue(1, hold=True)
    submit(q, "alice01", "a1")
    assert wait_for(lambda: rec.started == ["a1"])
    submit(q, "alice01", "a2")
    submit(q, "bobby01", "b1")
    rec.release.set()
    assert q.wait_idle(60)
    assert rec.started == ["a1", "b1", "a2"]
