"""Sweeps: many trainings (configuration × seed) on Ray, resumable, their results kept in a store.

    from ifo.sweep import ResultStore, Task, run_sweep
    store = ResultStore("runs/sweeps/ch7")
    tasks = [Task({"env": "cartpole", "method": "bc", "seed": s}, train_fn, {...}) for s in range(3)]
    rows = run_sweep(tasks, store)            # local Ray on 2 CPUs; address="ray://HOST:10001" for a cluster

- Every training runs as one Ray task (`num_cpus=1`, torch at one thread inside). Ray is started
  here only (`start_ray`), never on the app's path or a single run's, and shut down at the end.
  `address=None` honours RAY_ADDRESS, else starts a local Ray (`ray.init(num_cpus=2,
  include_dashboard=False, log_to_driver=False)`); `local=True` runs the trainings one after
  another in this process, without Ray (tests, and the one-after-another timing).
- Resumable: each finished training is appended to the store as it completes, one JSON line per
  configuration × seed, with the code's commit and the machine that ran it; a rerun skips the rows
  already there, so an interrupted sweep loses only the trainings in flight. Failed trainings are
  written too (with their error) and retried on the next run.
- A training's row says whether the code it ran was the code the sweep started from (`code_changed`):
  workers import `ifo` from the checkout when they start, so an edit made while a long sweep runs can
  reach its later trainings under the commit recorded at the start (`bench seeds` marks such rows).
- At most as many trainings are in flight as the Ray cluster has CPUs, so "running" on the progress
  bar means running, and an interruption loses at most that many.

The store is a folder: `results.jsonl` plus `results.lock` (filelock), so two sweeps may write into
one store. Reads are size-checked (MAX_STORE_BYTES, MAX_ROW_BYTES); a torn last line (a writer
killed mid-line) is skipped.
"""
from __future__ import annotations

import functools
import hashlib
import json
import math
import os
import platform
import re
import socket
import subprocess
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable, Sequence

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
STORE_FILE, LOCK_FILE = "results.jsonl", "results.lock"
MAX_STORE_BYTES = 256 * 1024 * 1024
MAX_ROW_BYTES = 16 * 1024 * 1024
_ANSI = re.compile(r"\x1b\[[0-9;]*m")
LOCAL_CPUS = 2  # this machine's cores; a local Ray never takes more
DONE, FAILED = "done", "failed"


# ----------------------------------------------------------------------------- tasks
@dataclass
class Task:
    """One training: `fn(**kwargs)` returns a dict of JSON-able results. `spec` names it (a flat dict of
    what makes it this training: table, row, environment, seed, settings); its key is a hash of `spec`."""

    spec: dict
    fn: Callable[..., dict]
    kwargs: dict = field(default_factory=dict)
    light: bool = False  # a lookup, not a training (a reference row): always run here, never sent to Ray

    @property
    def key(self) -> str:
        return task_key(self.spec)


def task_key(spec: dict) -> str:
    text = json.dumps(_jsonable(spec), sort_keys=True, separators=(",", ":"))
    return hashlib.sha1(text.encode()).hexdigest()[:16]


def _jsonable(x: Any) -> Any:
    """Plain JSON types: numpy scalars and arrays become numbers and lists; other objects their repr."""
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.generic):
        return x.item()
    if x is None or isinstance(x, (bool, int, float, str)):
        return x
    return repr(x)


# ----------------------------------------------------------------------------- where it ran
def code_commit() -> str | None:
    """`git rev-parse HEAD` of this checkout, None when there is no git."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.SubprocessError):
        return None
    return out.stdout.strip() or None if out.returncode == 0 else None


def code_dirty() -> bool | None:
    """Whether tracked files differ from the commit (None when there is no git)."""
    try:
        out = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT, capture_output=True,
                             text=True, timeout=30)
    except (OSError, subprocess.SubprocessError):
        return None
    return bool(out.stdout.strip()) if out.returncode == 0 else None


def code_fingerprint() -> str:
    """A hash of the `ifo` package's Python sources as they are on disk now (paths and contents)."""
    package = ROOT / "ifo"
    digest = hashlib.sha256()
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]


_CODE_WHEN_FIRST_RUN: dict[str, str] = {}  # checkout -> its fingerprint when this process first trained from it


def machine() -> dict:
    """Where a training ran: the host, its processor's model and, with torch loaded (a worker), the CPU kernels
    torch chose (AVX2, AVX512, ...). Machines round differently, and the same seed can train to other numbers
    there: two machines with AVX512 kernels did (Ch. 7's Acrobot GAIL), so the kernels alone do not tell them apart."""
    out = {"hostname": socket.gethostname(), "cpus": os.cpu_count()}
    if model := cpu_model():
        out["cpu_model"] = model
    torch = sys.modules.get("torch")
    if torch is not None:
        out["cpu_capability"] = torch.backends.cpu.get_cpu_capability()
    return out


@functools.lru_cache(maxsize=1)
def cpu_model() -> str | None:
    """The processor's model name ("AMD EPYC", "Intel(R) Xeon(R) Platinum 8375C CPU @ 2.90GHz"), None if unknown."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()[:120] or None
    except OSError:
        pass
    return platform.processor()[:120] or None


# ----------------------------------------------------------------------------- the store
class StoreError(ValueError):
    pass


class ResultStore:
    """A folder of results: one JSON line per finished (or failed) training, appended under a file lock."""

    def __init__(self, directory: str | os.PathLike):
        self.dir = Path(directory)
        self.path = self.dir / STORE_FILE
        self.lock_path = self.dir / LOCK_FILE

    @classmethod
    def at(cls, path: str | os.PathLike) -> "ResultStore":
        """The store in folder `path`, or the results file `path` itself (a shipped assets/resilience/*.jsonl,
        docs/reproduction/*.jsonl): a path that is a file, or is not there yet and ends in .jsonl."""
        path = Path(path)
        if path.is_dir() or (not path.exists() and path.suffix != ".jsonl"):
            return cls(path)
        store = cls(path.parent)
        store.path = path
        store.lock_path = path.with_name(f".{path.name}.lock")  # its own: two files of one folder are two stores
        return store

    def _lock(self):
        from filelock import FileLock

        self.dir.mkdir(parents=True, exist_ok=True)
        return FileLock(str(self.lock_path), timeout=60)

    def append(self, row: dict) -> None:
        line = json.dumps(_jsonable(row), separators=(",", ":"), allow_nan=True)
        if len(line) > MAX_ROW_BYTES:
            raise StoreError(f"a result row of {len(line)} bytes is over the store's limit of {MAX_ROW_BYTES}")
        with self._lock():
            with open(self.path, "a", encoding="utf-8") as f:
                if f.tell() > 0:  # a writer killed mid-line leaves no newline: start a fresh line
                    with open(self.path, "rb") as r:
                        r.seek(-1, os.SEEK_END)
                        if r.read(1) != b"\n":
                            f.write("\n")
                f.write(line + "\n")
                f.flush()
                os.fsync(f.fileno())

    def rows(self) -> list[dict]:
        """Every row, in the order written (a torn or unreadable line is skipped)."""
        if not self.path.exists():
            return []
        size = self.path.stat().st_size
        if size > MAX_STORE_BYTES:
            raise StoreError(f"{self.path} is {size} bytes, over the limit of {MAX_STORE_BYTES}")
        out = []
        with open(self.path, "rb") as f:
            for raw in f:
                if len(raw) > MAX_ROW_BYTES:
                    continue
                try:
                    row = json.loads(raw)
                except ValueError:  # torn last line
                    continue
                if _well_formed(row):
                    out.append(row)
        return out

    def latest(self) -> dict[str, dict]:
        """key -> its latest row (a later success replaces an earlier failure)."""
        out: dict[str, dict] = {}
        for row in self.rows():
            if row.get("status") == DONE or out.get(row["key"], {}).get("status") != DONE:
                out[row["key"]] = row
        return out

    def done(self) -> dict[str, dict]:
        """key -> row of every finished training."""
        return {k: r for k, r in self.latest().items() if r.get("status") == DONE}


def _well_formed(row) -> bool:
    """A row as a sweep writes it: a text key; spec, result, machine and driver objects where present; a
    whole-number seed. Anything else (a hand-edited or hostile file) is skipped, as a torn line is."""
    if not (isinstance(row, dict) and isinstance(row.get("key"), str)
            and all(row.get(k) is None or isinstance(row[k], dict) for k in ("spec", "result", "machine", "driver"))):
        return False
    seed = (row.get("spec") or {}).get("seed", 0)
    return isinstance(seed, int) and not isinstance(seed, bool)


def read_rows(path: str | os.PathLike) -> list[dict]:
    """Rows of a results file or store folder (the shipped assets/resilience/*.jsonl are such files)."""
    return ResultStore.at(path).rows()


# ----------------------------------------------------------------------------- running one task
def execute(fn: Callable[..., dict], kwargs: dict) -> dict:
    """Run one training here (in a Ray worker or in-process): torch at one thread; the result with the
    wall-clock seconds, the machine that ran it and the fingerprints of the code it ran (when this process
    first trained, its modules just imported, and after this training). Exceptions propagate."""
    loaded = _CODE_WHEN_FIRST_RUN.setdefault(str(ROOT), code_fingerprint())
    os.environ["IFO_TORCH_THREADS"] = "1"
    from ifo.runtime import limit_threads

    limit_threads(1)
    start = time.perf_counter()
    result = fn(**kwargs)
    return {"result": _jsonable(result), "seconds": time.perf_counter() - start, "machine": machine(),
            "pid": os.getpid(), "code": [loaded, code_fingerprint()]}


# ----------------------------------------------------------------------------- Ray
def start_ray(address: str | None = None, num_cpus: int = LOCAL_CPUS):
    """Connect to `address` (or RAY_ADDRESS), else start a local Ray on `num_cpus` CPUs. Returns the module."""
    try:
        import ray
    except ImportError as exc:  # pragma: no cover - requirements.txt pins it
        raise RuntimeError("sweeps need Ray: pip install ray==2.58.0 (or run with --local)") from exc
    address = address or os.environ.get("RAY_ADDRESS") or None
    if ray.is_initialized():
        return ray
    env = {"env_vars": {"IFO_TORCH_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}}
    if address:  # a cluster's workers get this checkout (code and assets) shipped by Ray
        env["working_dir"] = str(ROOT)
        env["excludes"] = [".venv", ".git", "runs", "artifacts", "**/__pycache__", "*.jsonl"]
        ray.init(address=address, include_dashboard=False, log_to_driver=False, runtime_env=env)
    else:  # local workers inherit the environment Ray starts with: `ifo` from this checkout, one thread
        paths = [str(ROOT)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p]
        values = {**env["env_vars"], "PYTHONPATH": os.pathsep.join(dict.fromkeys(paths))}
        saved = {k: os.environ.get(k) for k in values}
        os.environ.update(values)
        try:
            ray.init(num_cpus=num_cpus, include_dashboard=False, log_to_driver=False)
        finally:
            for k, v in saved.items():
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    return ray


# ----------------------------------------------------------------------------- the sweep
class _Bar:
    """tqdm with trainings done, running, failed and the time left (from the mean time per training)."""

    def __init__(self, total: int, desc: str, disable: bool):
        from tqdm import tqdm

        self.bar = tqdm(total=total, desc=desc, unit="training", file=sys.stderr, disable=disable,
                        dynamic_ncols=True)
        self.done = self.failed = self.running = 0

    def update(self, running: int, finished: int = 0, failed: int = 0) -> None:
        self.running = running
        self.failed += failed
        self.bar.set_postfix_str(f"running {running}, failed {self.failed}", refresh=False)
        self.bar.update(finished)
        self.bar.refresh()

    def close(self) -> None:
        self.bar.close()


@dataclass
class SweepReport:
    total: int  # tasks asked for
    skipped: int  # already in the store
    done: int  # finished by this sweep
    failed: int
    seconds: float  # wall clock of this sweep (Ray start included)
    mode: str  # "local Ray, 2 CPUs, ...", "Ray at ray://...", "in-process, one after another"
    ray_start_seconds: float = 0.0
    light: int = 0  # reference rows done here (lookups, counted in `done`, not in the rate)
    code_changed: int = 0  # trainings whose code was not the code the sweep started from

    @property
    def per_hour(self) -> float | None:
        trainings = self.done - self.light
        return 3600.0 * trainings / self.seconds if trainings > 0 and self.seconds > 0 else None

    def line(self) -> str:
        if self.done == 0 and self.failed == 0 and self.skipped:  # a table rendered again from a complete store
            return (f"nothing trained now: all {self.skipped} results were already in the store (each one's "
                    "seconds, commit and machine: `python -m ifo bench seeds --store` on this store)")
        rate = f"{self.per_hour:.0f} trainings per hour" if self.per_hour else "no training ran"
        refs = f" (and {self.light} reference rows)" if self.light else ""
        start = f" (Ray took {self.ray_start_seconds:.0f} s to start)" if self.ray_start_seconds else ""
        changed = (f" ({self.code_changed} on code that changed during the sweep: their rows say code_changed)"
                   if self.code_changed else "")
        return (f"{self.done - self.light} trainings done{refs}{changed}, {self.failed} failed, {self.skipped} already "
                f"in the store, in {self.seconds:.0f} s on {self.mode}{start}: {rate}")


def run_sweep(tasks: Sequence[Task], store: ResultStore, address: str | None = None, local: bool = False,
              num_cpus: int = LOCAL_CPUS, on_row: Callable[[Task, dict], Any] | None = None,
              desc: str = "sweep", progress: bool = True) -> tuple[dict[str, dict], SweepReport]:
    """Run every task not yet in `store`; append each result as it finishes. Returns (key -> row of every
    task asked for that is done, the report). `on_row(task, row)` is called for each finished row here."""
    start = time.perf_counter()
    unique: dict[str, Task] = {}
    for t in tasks:
        unique.setdefault(t.key, t)
    finished = store.done()
    todo = [t for k, t in unique.items() if k not in finished]
    commit, dirty, code = code_commit(), code_dirty(), code_fingerprint()
    n_failed = n_done = n_light = n_changed = 0
    ray_seconds = 0.0
    mode = "in-process, one after another"

    def record(task: Task, out: dict | None, error: str | None) -> dict:
        nonlocal n_changed
        row = {"key": task.key, "spec": task.spec, "status": DONE if error is None else FAILED,
               "commit": commit, "dirty": dirty, "driver": machine(), "finished_at": time.time()}
        if error is None:
            row.update(result=out["result"], seconds=out["seconds"], machine=out["machine"],
                       code_changed=any(ran != code for ran in out.get("code") or [None]))
            n_changed += row["code_changed"]
        else:
            row["error"] = error
        store.append(row)
        if on_row is not None and error is None:
            on_row(task, row)
        return row

    for task in [t for t in todo if t.light]:  # lookups: here, before (and whether or not) Ray starts
        try:
            out, err = execute(task.fn, task.kwargs), None
        except Exception:  # noqa: BLE001
            out, err = None, traceback.format_exc(limit=20)
        record(task, out, err)
        n_done, n_failed, n_light = n_done + (err is None), n_failed + (err is not None), n_light + (err is None)
    todo = [t for t in todo if not t.light]
    bar = _Bar(len(todo), desc, disable=not progress or not todo)
    try:
        if todo and local:
            for task in todo:
                bar.update(running=1)
                try:
                    out, err = execute(task.fn, task.kwargs), None
                except KeyboardInterrupt:
                    raise
                except Exception:  # noqa: BLE001 - one failing training must not end the sweep
                    out, err = None, traceback.format_exc(limit=20)
                record(task, out, err)
                n_done, n_failed = n_done + (err is None), n_failed + (err is not None)
                bar.update(running=0, finished=1, failed=int(err is not None))
        elif todo:
            t0 = time.perf_counter()
            ray = start_ray(address, num_cpus)
            ray_seconds = time.perf_counter() - t0
            try:
                cpus = max(1, int(ray.cluster_resources().get("CPU", 1)))
                mode = (f"Ray at {address or os.environ.get('RAY_ADDRESS')}" if (address or os.environ.get("RAY_ADDRESS"))
                        else f"local Ray, {cpus} CPUs") + f", {cpus} trainings at once"
                remote = ray.remote(num_cpus=1, max_retries=0)(execute)
                pending = list(todo)
                in_flight: dict[Any, Task] = {}
                while pending or in_flight:
                    while pending and len(in_flight) < cpus:
                        task = pending.pop(0)
                        in_flight[remote.remote(task.fn, task.kwargs)] = task
                    bar.update(running=len(in_flight))
                    ready, _ = ray.wait(list(in_flight), num_returns=1)
                    for ref in ready:
                        task = in_flight.pop(ref)
                        try:
                            out, err = ray.get(ref), None
                        except KeyboardInterrupt:
                            raise
                        except Exception as exc:  # noqa: BLE001 - RayTaskError wraps the training's own error
                            out, err = None, _ANSI.sub("", f"{type(exc).__name__}: {exc}")[-4000:]
                        record(task, out, err)
                        n_done, n_failed = n_done + (err is None), n_failed + (err is not None)
                        bar.update(running=len(in_flight), finished=1, failed=int(err is not None))
            finally:
                ray.shutdown()
    finally:
        bar.close()
    report = SweepReport(len(unique), len(finished.keys() & unique.keys()), n_done, n_failed,
                         time.perf_counter() - start, mode, ray_seconds, n_light, n_changed)
    done = store.done()
    return {k: done[k] for k in unique if k in done}, report


def where_trained(row: dict) -> str:
    """The machine that trained a row (its worker's; rows before workers reported it: the driver's)."""
    where = row.get("machine") or row.get("driver") or {}
    known = [str(where[k]) for k in ("cpu_model", "cpu_capability") if where.get(k)]
    return f"{where.get('hostname', '?')}" + (f" ({', '.join(known)})" if known else "")


LAST_ITERATIONS = 10  # bench seeds: P over this many last iterations tells a last-iteration dip from a failure


def seeds_table(done: Iterable[dict], at_iteration: int | None = None) -> str:
    """Finished trainings (`ResultStore.done()`), one line per seed (a table's mean ± sd hides which seed
    failed): P and AER at the last iteration, P over the last iterations and its best (from the training's
    curve, where the store kept one), the seconds it took, the commit and machine that trained it.
    `at_iteration`: also P and AER at that iteration of the curve (is a longer training's start a shorter
    one's whole? Compare the two stores' lines)."""
    done = list(done)
    if not done:
        return "No finished training in this store."
    def spec_of(r: dict) -> dict:
        return r.get("spec") or {}

    def cell_of(r: dict) -> tuple:  # as text: a hand-edited file's values need not be hashable
        return tuple(str(spec_of(r).get(k)) for k in ("table", "row", "env"))

    order: dict = {}  # cells in the order their first seed finished, then by seed
    for r in done:
        order.setdefault(cell_of(r), len(order))

    def cell(value, pattern: str) -> str:
        return "—" if not isinstance(value, (int, float)) or math.isnan(value) else pattern.format(value)

    def along_the_curve(result: dict) -> str:  # a dip at the last iteration, or never learned?
        curve = result.get("curve") if isinstance(result.get("curve"), list) else []
        points = [(p["performance"], p.get("iteration")) for p in curve if isinstance(p, dict)
                  and isinstance(p.get("performance"), (int, float)) and math.isfinite(p["performance"])]
        if not points:
            return "— | —"
        last = [p for p, _ in points[-LAST_ITERATIONS:]]
        best, when = max(points, key=lambda point: point[0])
        return f"{sum(last) / len(last):.3f} | {best:.3f} ({when})"

    def at(result: dict) -> str:  # P and AER at iteration `at_iteration`, as the curve stored them
        curve = result.get("curve") if isinstance(result.get("curve"), list) else []
        point = next((p for p in curve if isinstance(p, dict) and p.get("iteration") == at_iteration), {})
        return f"{cell(point.get('performance'), '{:.3f}')} | {cell(point.get('aer'), '{:.3f}')} | "

    extra = "" if at_iteration is None else f"P at iteration {at_iteration} | AER at iteration {at_iteration} | "
    lines = [f"| table | row | environment | iterations | seed | P | AER | {extra}P, mean of the last "
             f"{LAST_ITERATIONS} iterations | best P (iteration) | seconds | commit | machine |",
             "|---" * (12 + 2 * (at_iteration is not None)) + "|"]
    for r in sorted(done, key=lambda r: (order[cell_of(r)], spec_of(r).get("seed", 0))):
        spec, result = spec_of(r), r.get("result") or {}
        lines.append(f"| {spec.get('table', '—')} | {spec.get('row', '—')} | {spec.get('env', '—')} | "
                     f"{spec.get('iterations') or 'default'} | {spec.get('seed', '—')} | "
                     f"{cell(result.get('performance'), '{:.3f}')} | {cell(result.get('aer'), '{:.3f}')} | "
                     f"{'' if at_iteration is None else at(result)}{along_the_curve(result)} | "
                     f"{cell(result.get('seconds'), '{:.0f}')} | {str(r.get('commit') or '?')[:7]}"
                     f"{' (code changed during the sweep)' if r.get('code_changed') else ''} | "
                     f"{where_trained(r)} |")
    return "\n".join(lines)


def summarise_store(rows: Iterable[dict]) -> dict:
    """Counts and timings of a store's rows (for the report of a sweep)."""
    rows = list(rows)
    done = [r for r in rows if r.get("status") == DONE]
    secs = [r["seconds"] for r in done if isinstance(r.get("seconds"), (int, float))]
    return {"rows": len(rows), "done": len(done), "failed": len(rows) - len(done),
            "mean_seconds": float(np.mean(secs)) if secs else math.nan,
            "machines": sorted({r.get("machine", {}).get("hostname", "?") for r in done}),
            "commits": sorted({str(r.get("commit")) for r in done})}
