"""A bounded background queue of training runs, shared by every session of one server process.

The compare page (and "Train on these demonstrations" on the runs page) queue whole runs
here instead of training them in the page: a run of 10-20 iterations is too long for one
script run, and a class of thirty students must not start thirty trainings at once.

- ONE queue per process (`get_queue()`), with at most IFO_LAB_MAX_JOBS worker threads
  (default 1). Workers are daemon threads started on first use; they never call `st.*`
  (the page reads their status), and they outlive the tab that queued the job.
- A job = `Run(config)` stepped iteration by iteration, saved to the user's folder after
  each iteration (`storage.save_run`), so a finished or half-done job is an ordinary saved
  run: it shows on the run list and opens on the step page.
- Each iteration also takes the step page's training gate (`ifo.ui.session._TRAININGS`),
  so queued jobs and live Step presses together never train more than
  IFO_LAB_MAX_TRAININGS iterations at once on the shared cores.
- Jobs belong to the user id that queued them: `jobs(user)` and `cancel(user, id)` only
  see that user's jobs. Cancelling a queued job drops it; a running one stops between
  iterations (what it trained so far stays saved).
- Scheduling is round robin over users (first come, first served within a user): one
  student's sweep of twenty runs cannot hold the queue for the whole class. At most
  MAX_QUEUED_PER_USER jobs wait per user.
- A failing job records its error message; the worker goes on with the next job.

Status is read through `jobs(user)`, which returns copies (`JobStatus`) taken under the
queue's lock, so a page never sees a half-updated job.
"""
from __future__ import annotations

import itertools
import logging
import os
import threading
import time
import uuid
from collections import deque
from dataclasses import dataclass, field, replace
from typing import Callable

log = logging.getLogger(__name__)

MAX_QUEUED_PER_USER = int(os.environ.get("IFO_LAB_MAX_QUEUED", "40"))
KEEP_FINISHED_PER_USER = 50  # older finished jobs are forgotten (their runs stay saved on disk)

QUEUED, RUNNING, DONE, FAILED, CANCELLED = "queued", "running", "done", "error", "cancelled"
FINISHED = (DONE, FAILED, CANCELLED)


class QueueFull(RuntimeError):
    pass


class _Stopped(Exception):
    pass


@dataclass
class JobStatus:
    """What a page may know about a job (a copy; changing it changes nothing)."""

    id: str
    user: str
    label: str  # display name of this job (configuration + seed)
    group: str  # the configuration it belongs to, for mean ± sd over seeds ("" = its own)
    config: object  # the RunConfig
    run_id: str  # where it is saved in the user's folder
    state: str = QUEUED
    iteration: int = 0
    total: int = 0
    phase: str = ""
    position: int = 0  # 1 = next to start (queued jobs only)
    error: str | None = None
    cancel_requested: bool = False
    records: list = field(default_factory=list)  # the records so far (shared, never mutated)
    thesis: tuple | None = None  # (P, AER) the thesis reports for this configuration, if any
    queued_at: float = 0.0
    started_at: float | None = None
    finished_at: float | None = None
    seq: int = 0

    @property
    def active(self) -> bool:
        return self.state in (QUEUED, RUNNING)


def _default_make_run(config):
    from ifo.run import Run
    from ifo.ui.storage import run_services

    return Run(config, **run_services())


def _default_save(run, user: str, run_id: str, label: str) -> None:
    from ifo.ui import storage

    storage.save_run(run, user, run_id, label)


def _default_gate():
    try:
        from ifo.ui.session import _TRAININGS  # the step page's bound on concurrent iterations
        return _TRAININGS
    except Exception:  # noqa: BLE001 - the queue works without it
        return None


class JobQueue:
    def __init__(self, max_workers: int = 1, make_run: Callable = _default_make_run,
                 save: Callable = _default_save, gate=None, max_queued_per_user: int = MAX_QUEUED_PER_USER):
        self.max_workers = max(1, int(max_workers))
        self.make_run, self.save, self.gate = make_run, save, gate
        self.max_queued_per_user = max_queued_per_user
        self._lock = threading.Condition()
        self._jobs: dict[str, JobStatus] = {}
        self._pending: deque[str] = deque()
        self._running_users: dict[str, int] = {}
        self._workers: list[threading.Thread] = []
        self._seq = itertools.count(1)
        self._starts = itertools.count(1)
        self._last_start: dict[str, int] = {}  # user -> when their last job started (round robin)
        self._stopping = False

    # ------------------------------------------------------------------ for pages
    def submit(self, user: str, config, label: str, group: str = "", run_id: str | None = None,
               thesis: tuple | None = None) -> str:
        """Queue a run of `config` for `user`; returns the job id. QueueFull if the user has too many waiting."""
        config = config.resolved() if hasattr(config, "resolved") else config
        if run_id is None:
            from ifo.ui.storage import new_run_id

            run_id = new_run_id(config)
        with self._lock:
            waiting = sum(1 for j in self._jobs.values() if j.user == user and j.state == QUEUED)
            if waiting >= self.max_queued_per_user:
                raise QueueFull(f"you already have {waiting} runs waiting; let some finish or cancel them first")
            job = JobStatus(uuid.uuid4().hex[:12], user, label, group or label, config, run_id,
                            total=int(getattr(config, "iterations", 0) or 0), thesis=thesis,
                            queued_at=time.time(), seq=next(self._seq))
            self._jobs[job.id] = job
            self._pending.append(job.id)
            self._forget_old(user)
            self._ensure_workers()
            self._lock.notify()
        return job.id

    def jobs(self, user: str) -> list[JobStatus]:
        """This user's jobs, in the order they were queued (copies)."""
        with self._lock:
            positions = {jid: k + 1 for k, jid in enumerate(self._pending)}
            out = [replace(j, position=positions.get(j.id, 0), records=list(j.records))
                   for j in self._jobs.values() if j.user == user]
        return sorted(out, key=lambda j: j.seq)

    def job(self, user: str, job_id: str) -> JobStatus | None:
        return next((j for j in self.jobs(user) if j.id == job_id), None)

    def active(self, user: str) -> bool:
        with self._lock:
            return any(j.user == user and j.active for j in self._jobs.values())

    def cancel(self, user: str, job_id: str) -> bool:
        """Cancel one of the user's jobs: a queued one at once, a running one after its current
        iteration. False if there is no such active job of this user."""
        with self._lock:
            job = self._jobs.get(job_id)
            if job is None or job.user != user or not job.active:
                return False
            if job.state == QUEUED:
                self._pending.remove(job_id)
                job.state, job.finished_at = CANCELLED, time.time()
            else:
                job.cancel_requested = True
            return True

    def cancel_all(self, user: str) -> int:
        with self._lock:
            ids = [j.id for j in self._jobs.values() if j.user == user and j.active]
        return sum(self.cancel(user, jid) for jid in ids)

    def clear_finished(self, user: str) -> None:
        with self._lock:
            for jid in [j.id for j in self._jobs.values() if j.user == user and j.state in FINISHED]:
                del self._jobs[jid]

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Block until no job is queued or running (for tests and scripts)."""
        deadline = time.monotonic() + timeout
        with self._lock:
            while any(j.active for j in self._jobs.values()):
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._lock.wait(min(left, 0.1))
        return True

    def shutdown(self, timeout: float = 10.0) -> None:
        """Stop the workers after their current iteration (tests; the app never calls it)."""
        with self._lock:
            self._stopping = True
            for j in self._jobs.values():
                if j.state == RUNNING:
                    j.cancel_requested = True
            self._lock.notify_all()
        for t in self._workers:
            t.join(timeout)

    # ------------------------------------------------------------------ workers
    def _forget_old(self, user: str) -> None:
        finished = sorted((j for j in self._jobs.values() if j.user == user and j.state in FINISHED),
                          key=lambda j: j.seq)
        for j in finished[:max(0, len(finished) - KEEP_FINISHED_PER_USER)]:
            del self._jobs[j.id]

    def _ensure_workers(self) -> None:
        self._workers = [t for t in self._workers if t.is_alive()]
        while len(self._workers) < min(self.max_workers, len(self._pending) + self._busy()):
            t = threading.Thread(target=self._work, name=f"ifo-queue-{len(self._workers)}", daemon=True)
            self._workers.append(t)
            t.start()

    def _busy(self) -> int:
        return sum(self._running_users.values())

    def _next(self) -> JobStatus | None:
        """Called with the lock held: the next job to start (None if none is waiting)."""
        if not self._pending:
            return None
        # round robin over users (the one served longest ago first), first come first served within a user
        def rank(jid: str) -> tuple:
            job = self._jobs[jid]
            return (self._running_users.get(job.user, 0), self._last_start.get(job.user, 0), job.seq)

        jid = min(self._pending, key=rank)
        self._pending.remove(jid)
        self._last_start[self._jobs[jid].user] = next(self._starts)
        return self._jobs[jid]

    def _work(self) -> None:
        from ifo.runtime import limit_threads

        limit_threads()
        while True:
            with self._lock:
                job = None
                while not self._stopping and (job := self._next()) is None:
                    self._lock.wait(5.0)
                if self._stopping:
                    return
                job.state, job.started_at = RUNNING, time.time()
                self._running_users[job.user] = self._running_users.get(job.user, 0) + 1
            try:
                self._run(job)
            except _Stopped:
                pass
            except Exception as e:  # noqa: BLE001 - a failing job must not kill the worker
                log.exception("queued job %s failed", job.id)
                with self._lock:
                    job.state, job.error = FAILED, str(e) or type(e).__name__
            finally:
                with self._lock:
                    if job.state == RUNNING:
                        job.state = DONE if job.iteration >= job.total else CANCELLED
                    job.finished_at, job.phase = time.time(), ""
                    self._running_users[job.user] -= 1
                    if not self._running_users[job.user]:
                        del self._running_users[job.user]
                    self._lock.notify_all()

    def _gated(self, fn):
        """Run `fn` holding the shared training gate (if any); gives up if the queue shuts down."""
        if self.gate is None:
            return fn()
        while not self.gate.acquire(timeout=0.5):
            with self._lock:
                if self._stopping:
                    raise _Stopped()
        try:
            return fn()
        finally:
            self.gate.release()

    def _run(self, job: JobStatus) -> None:
        def progress(phase: str, iteration: int) -> None:
            with self._lock:
                job.phase = phase

        with self._lock:
            job.phase = "preparing"
        run = self._gated(lambda: self.make_run(job.config))
        if hasattr(run, "progress"):
            run.progress = progress
        total = int(run.config.iterations)
        with self._lock:
            job.total = total
        while run.iteration < total:
            with self._lock:
                if job.cancel_requested or self._stopping:
                    job.state = CANCELLED
                    return
            self._gated(run.step)
            self.save(run, job.user, job.run_id, job.label)
            with self._lock:
                job.iteration = run.iteration
                job.records = list(run.records)


_QUEUE: JobQueue | None = None
_QUEUE_LOCK = threading.Lock()


def get_queue() -> JobQueue:
    """The process's one queue (IFO_LAB_MAX_JOBS workers, default 1)."""
    global _QUEUE
    with _QUEUE_LOCK:
        if _QUEUE is None:
            _QUEUE = JobQueue(int(os.environ.get("IFO_LAB_MAX_JOBS", "1")), gate=_default_gate())
        return _QUEUE
