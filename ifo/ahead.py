"""Computing the next iteration ahead, while the class looks at this one (issue 13).

An iteration of IUPE on LunarLander or on a maze trains for seconds (docs/BENCH.md); a teacher talks
over each iteration for longer than that. So when a Step ends, the app asks for the *next* iteration
to be trained in the background into the shared iteration cache (ifo.iteration_cache): when the
teacher presses Step it is already there, or half done and the Step waits only for the rest. The
records are those the Step would have trained, number for number: an iteration is a pure function of
the configuration, its number and the learner's state before it (what the cache and the Ray workers
of ifo.remote rely on too).

- One background thread per process, one iteration at a time. Only the newest request waits: a run
  stepped again, or another run stepped, makes an older one that has not started moot.
- It gives way. It starts only once no session has stepped for `quiet_seconds` (a class stepping its
  own runs, or catching up on the teacher's, has the machine), and with a slot of the app's training
  gate (never more trainings at once than the gate allows); a Step that trains anything else cancels
  it at its next phase (`stepping`).
- It trains its own copy of the run (`ifo.remote.kept_run`, the last few kept), from the state the run
  had when it asked; the run a session holds is never touched.
- Nothing to do without a cache, for a run on a user's own demonstrations (never shared), for a
  finished run, or for a run that trains on Ray (the cluster trains its Steps). An iteration whose
  training here failed is not asked for again (it is logged once; the Step trains it and shows why).
"""
from __future__ import annotations

import atexit
import logging
import threading
import time
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Callable

import numpy as np
from filelock import Timeout

from ifo.iteration_cache import IterationCache
from ifo.learners.base import StepCancelled

log = logging.getLogger(__name__)


@dataclass
class _Request:
    key: str  # the cache key of the iteration to train: the run's next lineage
    config: dict
    iteration: int  # iterations done: the request trains iteration + 1
    arrays: dict[str, np.ndarray]  # the learner's state after them
    meta: dict


class ComputeAhead:
    def __init__(self, cache: IterationCache, gate: threading.Semaphore | None = None, quiet_seconds: float = 1.0,
                 poll_seconds: float = 0.2, on_phase: Callable[[str], None] | None = None):
        self.cache, self.gate, self.quiet_seconds, self.poll_seconds = cache, gate, quiet_seconds, poll_seconds
        self._last_step = -float("inf")  # time.monotonic() of the last Step's start or end, any session's
        self.on_phase = on_phase  # tests: called as each phase of an iteration trained ahead starts
        self._cond = threading.Condition()
        self._pending: _Request | None = None
        self._working: str | None = None  # the key being trained
        self._stepping: Counter = Counter()  # the keys sessions' Steps train or wait for right now
        self._failed: set[str] = set()  # keys whose training ahead raised: each page run would ask again
        self._closed = False
        self._thread: threading.Thread | None = None
        self.computed = self.cancelled = 0

    # ------------------------------------------------------------------ for the app's sessions
    def request(self, run) -> bool:
        """Train `run`'s next iteration in the background (not `run` itself: a copy of it). False when
        there is nothing to do (see the module's docstring) or it is stored, asked for or training already."""
        if run.lineage is None or run.finished or run.trainer is not None:
            return False
        key = run.next_key()
        with self._cond:
            if key in (self._working, self._pending and self._pending.key) or key in self._failed \
                    or self.cache.has(key):
                return False
        arrays, meta = run.learner.state()  # copies of the weights; the data arrays are never changed in place
        with self._cond:
            if self._closed:
                return False
            self._pending = _Request(key, run.config.to_dict(), run.iteration, arrays, meta)
            if self._thread is None or not self._thread.is_alive():
                self._thread = threading.Thread(target=self._work, name="ifo-ahead", daemon=True)
                self._thread.start()
                atexit.register(self.close)
            self._cond.notify_all()
        return True

    @contextmanager
    def stepping(self, key: str | None):
        """A session's Step trains `key` (or waits for it) while the block runs (None: a run never shared).
        Meanwhile nothing else trains ahead: a request for another key waiting to start is dropped, and
        one training stops at its next phase. One for `key` goes on: the Step waits for the rest of it."""
        with self._cond:
            self._stepping[key] += 1
            self._last_step = time.monotonic()
            if self._pending is not None and self._pending.key != key:
                self._pending = None
        try:
            yield
        finally:
            with self._cond:
                self._stepping[key] -= 1
                if not self._stepping[key]:
                    del self._stepping[key]
                self._last_step = time.monotonic()
                self._cond.notify_all()

    def stepped(self) -> None:
        """A session took a ready iteration (no training): the class is busy, so nothing starts for a moment."""
        with self._cond:
            self._last_step = time.monotonic()

    def _gives_way(self, key: str) -> bool:
        """Called with the lock held: whether `key` must wait or stop (a Step of something else, or closing)."""
        return self._closed or any(k != key for k in self._stepping)

    def working_on(self, key: str) -> bool:
        """Whether `key` is being trained ahead right now (a Step for it waits for the rest)."""
        with self._cond:
            return self._working == key

    def close(self, timeout: float = 30.0) -> None:
        """Stop at the next phase and end the thread (at exit: a thread killed inside torch aborts the process)."""
        with self._cond:
            self._closed, self._pending = True, None
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout)

    def wait_idle(self, timeout: float = 60.0) -> bool:
        """Block until nothing is asked for or training (tests and benchmarks)."""
        with self._cond:
            return self._cond.wait_for(lambda: self._pending is None and self._working is None, timeout)

    # ------------------------------------------------------------------ the background thread
    def _work(self) -> None:
        from ifo.runtime import limit_threads

        limit_threads()
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or self._closed)
                if self._closed:
                    return
                request, self._pending = self._pending, None
                self._working = request.key
            try:
                if self._take_gate(request.key):
                    try:
                        self._train(request)
                    finally:
                        if self.gate is not None:
                            self.gate.release()
            except Exception:  # noqa: BLE001 - the Step will train it; the lesson goes on
                log.exception("training an iteration ahead failed; it is not asked for again")
                with self._cond:
                    self._failed.add(request.key)
            finally:
                with self._cond:
                    self._working = None
                    self._cond.notify_all()

    def _take_gate(self, key: str) -> bool:
        """Once no Step of anything else trains, none has for `quiet_seconds`, and a slot of the training
        gate is free: that slot. False if the request was overtaken meanwhile (a newer one, or closing)."""
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._pending is not None or self._closed, self.poll_seconds)
                if self._pending is not None or self._closed:
                    return False
                if self._gives_way(key) or time.monotonic() - self._last_step < self.quiet_seconds:
                    continue
            if self.gate is None or self.gate.acquire(timeout=self.poll_seconds):
                return True

    def _train(self, request: _Request) -> None:
        from ifo.remote import kept_run

        run = kept_run(request.config)  # built once per configuration (its I_pre is kept per process)
        run.progress = self._check
        try:
            with self.cache.lock(request.key, timeout=0):  # a session training it already: leave it
                if self.cache.has(request.key):
                    return
                entry = run.train_from(request.iteration, request.arrays, request.meta)
                self.cache.put(request.key, entry)
                self.computed += 1
        except Timeout:
            return
        except StepCancelled:
            self.cancelled += 1
        finally:
            run.progress = None

    def _check(self, phase: str, iteration: int) -> None:
        """The copy's progress callback: the point where an iteration trained ahead gives way."""
        if self.on_phase is not None:
            self.on_phase(phase)
        with self._cond:
            if self._gives_way(self._working):
                raise StepCancelled("a Step needs the machine")


__all__ = ["ComputeAhead"]
