"""Iterations trained on Ray workers, for a class that outgrows one machine (issue 13).

    trainer = RemoteTrainer("ray://head:10001")      # or None: a local Ray (tests, one machine)
    run = Run(config, cache=cache, trainer=trainer)
    run.step()   # the iteration trains on a worker; this process only takes its result

An iteration is a pure function of the configuration, the iteration number and the learner's
state before it (the iteration cache relies on the same fact). So a Step sends exactly that to
a worker as one Ray task; the worker trains the iteration with an ordinary `Run` and sends back
the state after it, the record and the policy's weights: an `Entry`, as the iteration cache
stores it. The page, the records and the saved run are the same as when training here, number
for number (tests/test_remote.py).

- Workers keep their last few `Run`s (built from the configuration: demonstrations, I_pre,
  environments), so a class stepping through one lesson does not rebuild them every Step.
- Runs on a user's own demonstrations stay on the app's machine (the file is not shipped).
- Cancelling a Step cancels its task; the run is left as it was (a Step is all or nothing).
- The connection is Ray's own (`ifo.sweep.start_ray`): RAY_ADDRESS or the address given, the
  checkout shipped to a cluster's workers as the sweeps do.
"""
from __future__ import annotations

import threading
from collections import OrderedDict

import numpy as np

from ifo.iteration_cache import Entry
from ifo.learners.base import StepCancelled

WORKER_RUNS = 4  # Runs a worker keeps between tasks (one per configuration it served last)
_worker_runs: "OrderedDict[str, object]" = OrderedDict()


_worker_runs_lock = threading.Lock()


def kept_run(config: dict):
    """A `Run` of `config` (everything but its iterations) built once and kept among the last WORKER_RUNS:
    a worker's, or the app's computing ahead (ifo.ahead). The caller trains it with `Run.train_from`,
    which needs nothing of the run's own past; one caller at a time per process."""
    import json

    from ifo.config import RunConfig
    from ifo.run import Run

    key = json.dumps({**config, "iterations": None}, sort_keys=True, default=str)
    with _worker_runs_lock:
        run = _worker_runs.pop(key, None)
    if run is None:
        run = Run(RunConfig.from_dict(config))
    with _worker_runs_lock:
        _worker_runs[key] = run
        while len(_worker_runs) > WORKER_RUNS:
            _worker_runs.popitem(last=False)
    return run


def train_iteration(config: dict, iteration: int, arrays: dict, meta: dict) -> Entry:
    """On a worker: iteration `iteration + 1` of a run of `config` whose learner state is (arrays, meta)."""
    run = kept_run(config)
    return run.train_from(iteration, {k: np.array(v) for k, v in arrays.items()}, meta)  # Ray's are read-only


class RemoteTrainer:
    """Sends each iteration of a `Run` to a Ray worker. `address`: a Ray cluster (ray://HOST:10001);
    None: RAY_ADDRESS if set, else a local Ray on `local_cpus` CPUs (started at the first Step)."""

    def __init__(self, address: str | None = None, local_cpus: int = 2, poll_seconds: float = 0.2):
        self.address, self.local_cpus, self.poll_seconds = address, local_cpus, poll_seconds
        self._task = None
        self._lock = threading.Lock()

    def _remote(self):
        with self._lock:
            if self._task is None:
                from ifo.sweep import start_ray

                ray = start_ray(self.address, self.local_cpus)
                self._task = ray.remote(num_cpus=1, max_retries=0)(train_iteration)
            return self._task

    def train(self, run) -> Entry:
        """The next iteration of `run`, trained on a worker (the run itself is not changed)."""
        import ray

        task = self._remote()
        arrays, meta = run.learner.state()
        ref = task.remote(run.config.to_dict(), run.iteration, arrays, meta)
        while True:
            done, _ = ray.wait([ref], timeout=self.poll_seconds)
            if done:
                entry = ray.get(ref)  # its arrays are read-only views of Ray's object store: copy them
                return Entry({k: np.array(v) for k, v in entry.arrays.items()}, entry.meta, entry.record)
            if run.cancel_requested:
                ray.cancel(ref, force=True)
                raise StepCancelled("the iteration was cancelled")
