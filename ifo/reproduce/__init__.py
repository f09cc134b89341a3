"""Reproduction benchmark: the thesis's tables, ours beside theirs.

    python -m ifo bench reproduce --table 6.1 --seeds 3 [--envs cartpole,acrobot] [--out docs/...]

Every row is a configuration (ablation switches are plain fields), trained from scratch per
seed; the table shows mean ± sd over seeds of Performance and AER at the last iteration, the
thesis's numbers, and wall-clock seconds per run. Learners are evaluated with MAP actions;
rows that explore are also evaluated with sampled actions (the authors reported IUPE's AER
from stochastic rollouts).

The tables themselves live one module per chapter in this package (`chapter5_6.py`, ...), each
calling `register(Table(...))`; every module here is imported, so a new chapter is a new file.
A row whose method is not built (and has no `runner` of its own) shows the thesis's numbers only.

The trainings (row × environment × seed) run through the sweep engine (`ifo.sweep`): the command
line runs them on Ray (`--address`, else a local Ray on 2 CPUs) and, with `--store DIR`, keeps each
finished training in DIR so a rerun skips it; the table is rendered from the stored results.
`reproduce()` takes the sweep's options as keywords (or from a `with sweep_defaults(...)` block, as
the command line gives them): `store` (a folder; default a temporary one),
`address` (a Ray cluster), `ray` (False: in this process, one after another, the default when
called from Python), `progress` (the progress bar) and `train` (False: only render what `store` holds).
"""
from __future__ import annotations

import sys
import time
import importlib
import pkgutil
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ifo.config import RunConfig
from ifo.envs import get_env
from ifo.metrics import sample_sd
from ifo.run import Run

@dataclass(frozen=True)
class Row:
    label: str
    method: str  # a method of ifo.methods, or "expert" / "random" (their reference returns)
    overrides: dict = field(default_factory=dict)  # settings of this row (flat names)
    runner: Callable | None = None  # runner(env, seed, iterations, **settings) -> result dict, for rows that
    #                                 are not one of our runs (stable-baselines3's DQN and PPO, say)


@dataclass(frozen=True)
class Column:
    """A further column pair of a table: ours (summarised over seeds) beside the thesis's number."""

    title: str  # "AER min"
    value: Callable[[dict], float | None]  # from one seed's result (run_row's dict; "record" is the last record)
    summary: str = "mean_sd"  # over seeds: "mean_sd", "min", "max" or "sd"
    thesis: int | tuple[int, int] | None = None  # index of the thesis's number in its tuple, or (mean, sd)
    fmt: str = ".3f"  # how its numbers are written


@dataclass(frozen=True)
class Table:
    title: str
    envs: tuple[str, ...]
    rows: tuple[Row, ...]
    thesis: dict  # row label -> env -> (P, AER, ...); None where the thesis has no number
    targets: dict = field(default_factory=dict)  # (row, env) -> (metric, threshold) from the issue
    settings: dict = field(default_factory=dict)  # applied to every row (e.g. one expert episode)
    table_id: str = ""  # "6.1": set by register()
    columns: tuple[Column, ...] = ()  # further columns (Tables 9.2, 9.3), after the generic ones
    note: str = ""  # a sentence under the table's footer
    # (row, env, "performance" | "aer") -> why a thesis cell is not what its table prints (a fill-in from
    # another table, a likely typo): marked in the cell, said under the table
    thesis_notes: dict = field(default_factory=dict)


TABLES: dict[str, Table] = {}


def register(table_id: str, table: Table) -> Table:
    """Add a thesis table (called by the chapter modules of this package)."""
    if table_id in TABLES:
        raise ValueError(f"table {table_id} is registered twice")
    TABLES[table_id] = table = replace(table, table_id=table_id)
    return table


def implemented(row: Row) -> bool:
    from ifo.methods import METHODS

    return row.runner is not None or row.method in ("expert", "random") or row.method in METHODS


def run_row(row: Row, env: str, seed: int, iterations: int | None, **extra) -> dict:
    """Train one configuration from scratch; evaluate the last policy with MAP and sampled actions."""
    spec = get_env(env)
    if row.method in ("expert", "random"):
        refs = spec.references()
        aer = refs.get(f"{row.method}_aer")
        return {"aer": aer, "performance": 1.0 if row.method == "expert" else 0.0, "seconds": 0.0}
    if row.runner is not None:
        return row.runner(env, seed, iterations, **row.overrides, **extra)
    start = time.perf_counter()
    run = Run(RunConfig.from_dict({"env": env, "method": row.method, "seed": seed, "iterations": iterations,
                                   **row.overrides, **extra}))
    run.run()
    ev = run.records[-1]["evaluation"]
    out = {"aer": ev["aer"], "performance": ev["performance"], "seconds": time.perf_counter() - start,
           "seconds_per_iteration": float(np.mean([r["seconds"]["total"] for r in run.records])),
           "record": run.records[-1], "records": run.records}
    if any(getattr(run.config.learner, switch, False) for switch in ("explore_labels", "explore_rollouts")):
        sampled = run.evaluate(explore=True)
        out["aer_sampled"], out["performance_sampled"] = sampled["aer"], sampled["performance"]
    return out


def mean_sd(values: list, fmt: str = ".3f") -> str:
    """'mean ± sd' over seeds for a table cell (the sample sd, n − 1); one value as is; '—' when there is none."""
    values = [v for v in values if v is not None]
    if not values:
        return "—"
    if len(values) == 1:
        return format(values[0], fmt)
    return f"{format(float(np.mean(values)), fmt)} ± {format(sample_sd(values), fmt)}"


def interval95(values: list) -> tuple[float, float] | None:
    """The 95 % confidence interval of the mean over seeds (Student's t, n − 1 degrees of freedom); None
    for fewer than two values. With 3 seeds it is mean ± 2.48 sd, with 5 ± 1.24 sd, with 10 ± 0.72 sd."""
    from scipy import stats

    values = [v for v in values if v is not None]
    if len(values) < 2:
        return None
    mean, sd = float(np.mean(values)), sample_sd(values)
    half = float(stats.t.ppf(0.975, len(values) - 1)) * sd / np.sqrt(len(values))
    return mean - half, mean + half


def interval_cell(values: list) -> str:
    ci = interval95(values)
    return "—" if ci is None else f"[{ci[0]:.3f}, {ci[1]:.3f}]"


def verdict(values: list, threshold: float) -> str:
    """A target's verdict that claims only what the seeds support: 'met' when the whole 95 % interval is at
    or above the threshold, 'met on average' when only the mean is (more seeds would settle it), 'MISSED'."""
    values = [v for v in values if v is not None]
    mean, ci = float(np.mean(values)), interval95(values)
    if mean < threshold - 1e-9:
        return "MISSED"
    if ci is None:
        return "met (one seed)"
    return "met" if ci[0] >= threshold - 1e-9 else "met on average (the 95 % interval reaches below)"


def number(v) -> str:
    return "—" if v is None else f"{v:.3f}"


def summarise(values: list, how: str = "mean_sd", fmt: str = ".3f") -> str:
    """A further column's cell over seeds: mean ± sd, or the min, max or sd."""
    values = [v for v in values if v is not None]
    if not values:
        return "—"
    if how == "mean_sd":
        return mean_sd(values, fmt)
    return format(float({"min": np.min, "max": np.max, "sd": sample_sd}[how](values)), fmt)


def thesis_cell(theirs: tuple, where, fmt: str = ".3f") -> str:
    """The thesis's number for a further column: theirs[where], or 'mean ± sd' for where = (mean, sd)."""
    at = lambda i: theirs[i] if i is not None and i < len(theirs) else None  # noqa: E731
    m, s = (at(where[0]), at(where[1])) if isinstance(where, tuple) else (at(where), None)
    if m is None:
        return "—"
    return format(m, fmt) if s is None else f"{format(m, fmt)} ± {format(s, fmt)}"


def _protocol(extra: dict) -> str:
    """How the evaluation episodes were chosen, in words, for the table's footnote."""
    layouts = ("the demonstrations' maze layouts" if extra.get("maze_eval_layouts") == "demonstration"
               else "held-out maze layouts")
    guard = (", an episode ending with return −1 on the 4th visit to a cell (deadlock guard)"
             if extra.get("deadlock_guard", True) else ", no deadlock guard")
    demos = f"; {extra['expert_episodes']} demonstrations" if extra.get("expert_episodes") else ""
    return f"held-out seeds for the vector tasks, {layouts}{guard}{demos}"


SWEEP_OPTIONS = ("store", "address", "ray", "progress", "train")  # reproduce()'s keywords for the sweep, not runs
_SWEEP_DEFAULTS: dict = {}  # what `sweep_defaults` sets (the command line: Ray, --store, --address)


@contextmanager
def sweep_defaults(**options):
    """Within the block, reproduce() runs its trainings so unless told otherwise (the command line wraps its
    call in this, so `reproduce(table, ...)` keeps its signature)."""
    unknown = set(options) - set(SWEEP_OPTIONS)
    if unknown:
        raise ValueError(f"unknown sweep option(s): {', '.join(sorted(unknown))}")
    old = dict(_SWEEP_DEFAULTS)
    _SWEEP_DEFAULTS.update(options)
    try:
        yield
    finally:
        _SWEEP_DEFAULTS.clear()
        _SWEEP_DEFAULTS.update(old)


def row_seeds(row: Row, seeds: int) -> int:
    """How many trainings a row needs per environment: one for reference rows (no training, no seed)."""
    return 1 if row.method in ("expert", "random") or getattr(row.runner, "seedless", False) else seeds


def _slim(result: dict) -> dict:
    """A result as the store keeps it: every iteration's record is replaced by its curve (AER, P, fidelity,
    and the samples used so far where the learner counts them: Table 8.3)."""
    out = {k: v for k, v in result.items() if k != "records"}
    if result.get("records"):
        out["curve"] = [{"iteration": r.get("iteration"),
                         **{k: r.get("evaluation", {}).get(k) for k in ("aer", "performance", "fidelity")},
                         **({"samples": r["samples"]} if "samples" in r else {})}
                        for r in result["records"]]
    return out


def train_row(row: Row, env: str, seed: int, iterations: int | None, settings: dict) -> dict:
    """One training of a table (a sweep task): `run_row`, its result as the store keeps it."""
    return _slim(run_row(row, env, seed, iterations, **settings))


def row_task(table: Table, row: Row, env: str, seed: int, iterations: int | None, settings: dict):
    """The sweep task of one row × environment × seed; its key names everything that makes it this training."""
    from ifo.sweep import Task

    spec = {"table": table.table_id, "row": row.label, "method": row.method, "overrides": dict(row.overrides),
            "env": env, "seed": seed, "iterations": iterations, "settings": dict(settings)}
    return Task(spec, train_row, {"row": row, "env": env, "seed": seed, "iterations": iterations,
                                  "settings": dict(settings)}, light=row_seeds(row, 2) == 1)


def train_rows(table: Table, chosen: list[Row], env_names: list[str], seeds: int, iterations: int | None,
               settings: dict, log, store=None, address: str | None = None, ray: bool = False,
               progress: bool = True, train: bool = True) -> tuple[dict, int]:
    """Every training of the chosen rows through the sweep engine; (row label, env) -> results over seeds
    (the finished ones), and how many failed."""
    import tempfile

    from ifo.sweep import ResultStore, run_sweep

    from ifo.methods import METHODS

    tasks = {(row.label, env, seed): row_task(table, row, env, seed, iterations, settings)
             for row in chosen if implemented(row) for env in env_names for seed in range(row_seeds(row, seeds))}
    for row in chosen:  # impossible settings: one clear error now, not a failed training per seed later
        if row.method in METHODS:
            for env in env_names:
                RunConfig.from_dict({"env": env, "method": row.method, "seed": 0, "iterations": iterations,
                                     **row.overrides, **settings}).resolved()

    def on_row(task, stored) -> None:
        r, spec = stored["result"], task.spec
        log(f"[{table.table_id}] {spec['row']} on {spec['env']}, seed {spec['seed']}: P {r.get('performance')} "
            f"AER {r.get('aer')} ({r.get('seconds', 0.0):.0f} s)")

    scratch = tempfile.TemporaryDirectory(prefix="ifo-sweep-") if store is None else None
    results_store = ResultStore.at(store if store is not None else scratch.name)
    try:
        if train:
            done, report = run_sweep(list(tasks.values()), results_store, address=address,
                                     local=not (ray or address), on_row=on_row, desc=f"Table {table.table_id}",
                                     progress=progress)
        else:  # render only: what the store holds
            done, report = results_store.done(), None
        errors = [r["error"] for r in results_store.latest().values() if r.get("error")]
    finally:
        if scratch is not None:
            scratch.cleanup()
    if report is not None and (store is not None or report.failed):
        log(f"[{table.table_id}] {report.line()}" + (f"; results in {store}" if store is not None else ""))
    if tasks and not done:  # nothing to show: say why instead of a table of failures
        raise RuntimeError(f"every training of table {table.table_id} failed" +
                           (f"; one error: {errors[-1].strip().splitlines()[-1]}" if errors else ""))
    results: dict = {}
    for (label, env, seed), task in tasks.items():
        if task.key in done:
            results.setdefault((label, env), []).append(done[task.key]["result"])
    return results, sum(task.key not in done for task in tasks.values())


RECHECKED = {"aer": "AER", "performance": "P", "fidelity": "fidelity"}  # a curve point's numbers that must come back


def _digits(value, other) -> str:
    """`value` with as many digits as it takes to tell it from `other` (6 at least, all 17 at most)."""
    if not isinstance(value, float) or not isinstance(other, float):
        return str(value)
    return next((f"{value:.{d}g}" for d in range(6, 17) if f"{value:.{d}g}" != f"{other:.{d}g}"), repr(value))


def _follows_iteration_count(row: Row, spec: dict) -> bool:
    """Whether a stored training's learner changes what each round does with the round count (CRIL's Eq 8.2)."""
    from ifo.methods import METHODS

    if row.method not in METHODS:
        return False
    cfg = RunConfig.from_dict({"env": spec["env"], "method": row.method, "seed": spec["seed"],
                               "iterations": spec.get("iterations"), **row.overrides, **(spec.get("settings") or {})})
    return cfg.resolved().learner.follows_iteration_count()


def recheck(stored: list[dict], rounds: int, seeds: int, envs: list[str] | None = None,
            rows: list[str] | None = None, address: str | None = None, ray: bool = False,
            progress: bool = True) -> str:
    """Same seed, same numbers, checked after the fact: train again the first `rounds` rounds of stored
    trainings (seeds below `seeds`, of the chosen environments and rows) with this checkout's code, and
    compare them, round by round, with the curves the store kept. A learner whose schedule does not follow
    its round count (`LearnerConfig.follows_iteration_count`) gives its longer training's first rounds; a
    difference means other code, or code run differently, made the stored row."""
    import tempfile

    from ifo.sweep import ResultStore, code_commit, machine, run_sweep, where_trained

    chosen = []
    for r in stored:
        spec, result = r.get("spec") or {}, r.get("result") or {}
        curve = result.get("curve")
        if (r.get("status") != "done" or not isinstance(curve, list) or not curve
                or spec.get("method") in ("expert", "random") or not isinstance(spec.get("seed"), int)
                or spec["seed"] >= seeds or (envs and spec.get("env") not in envs)
                or (rows and spec.get("row") not in rows)):
            continue
        chosen.append(r)
    if not chosen:
        return "No stored training with a curve matches these environments, rows and seeds."
    order = lambda r: (r["spec"].get("table", ""), str(r["spec"].get("row")), str(r["spec"].get("env")),  # noqa: E731
                       str(r["spec"].get("settings")), r["spec"]["seed"])
    chosen.sort(key=order)
    tasks, why_not = {}, {}  # by position in `chosen`
    for i, r in enumerate(chosen):
        spec = r["spec"]
        table = TABLES.get(str(spec.get("table")))
        row = next((row for row in table.rows if row.label == spec.get("row")), None) if table else None
        n = min(rounds, len(r["result"]["curve"]))
        if row is None or dict(row.overrides) != spec.get("overrides", {}):
            why_not[i] = "its table no longer has this row with these settings"
        elif n < len(r["result"]["curve"]) and _follows_iteration_count(row, spec):
            why_not[i] = "its schedule follows its round count: give --rounds its iterations"
        else:
            tasks[i] = row_task(table, row, spec["env"], spec["seed"], n, dict(spec.get("settings") or {}))
    with tempfile.TemporaryDirectory(prefix="ifo-recheck-") as scratch:
        unique = list({task.key: task for task in tasks.values()}.values())  # a 5- and a 40-round row: one run
        done, report = run_sweep(unique, ResultStore.at(scratch), address=address,
                                 local=not (ray or address), desc="recheck", progress=progress) \
            if tasks else ({}, None)
    lines = ["| table | row | environment | settings | seed | stored from (commit, machine) | rounds compared | "
             "the same? |", "|---|---|---|---|---|---|---|---|"]
    same = compared = 0
    for i, r in enumerate(chosen):
        spec = r["spec"]
        settings = ", ".join(f"{k} {v}" for k, v in sorted((spec.get("settings") or {}).items())) or "—"
        head = (f"| {spec.get('table')} | {spec.get('row')} | {spec.get('env')} | {settings} | {spec['seed']} | "
                f"{str(r.get('commit') or '?')[:7]}, {where_trained(r)} | ")
        if i in why_not:
            lines.append(head + f"— | not rechecked: {why_not[i]} |")
            continue
        task = tasks[i]
        again = done.get(task.key)
        if again is None:
            lines.append(head + "— | the training failed here (see the log) |")
            continue
        n, compared = task.spec["iterations"], compared + 1
        old, new = r["result"]["curve"][:n], again["result"]["curve"][:n]
        parts_at = next((at for at, (was, now) in enumerate(zip(old, new))
                         if any(was.get(k) != now.get(k) for k in RECHECKED)), None)
        if parts_at is None:
            same += 1
            lines.append(head + f"{n} | yes |")
        else:
            a, b = old[parts_at], new[parts_at]
            parted = "; ".join(f"stored {name} {_digits(a.get(k), b.get(k))}, now {_digits(b.get(k), a.get(k))}"
                               for k, name in RECHECKED.items() if a.get(k) != b.get(k))
            lines.append(head + f"{n} | **no**, from round {parts_at + 1}: {parted} |")
    where = machine()
    lines.append("")
    lines.append(f"{same} of {compared} trainings trained again to their stored numbers, round by round, with "
                 f"this checkout's code ({(code_commit() or '?')[:7]}, {where_trained({'machine': where})})"
                 + (f"; {report.line()}" if report else "") + ".")
    return "\n".join(lines)


def row_labels(text: str) -> list[str]:
    """A --rows value as row labels. Split at commas, except inside a label that has one
    ("BCO(α), appending I_s (Torabi et al.)"): the longest known label wins at each place."""
    known = {row.label for table in TABLES.values() for row in table.rows}
    parts, labels, i = [p.strip() for p in text.split(",")], [], 0
    while i < len(parts):
        end = next((j for j in range(len(parts), i, -1) if ", ".join(parts[i:j]) in known), i + 1)
        labels.append(", ".join(parts[i:end]))
        i = end
    return labels


def reproduce(table_id: str, seeds: int = 3, envs: list[str] | None = None, iterations: int | None = None,
              log=lambda m: print(m, file=sys.stderr, flush=True), rows: list[str] | None = None, **extra) -> str:
    sweep = {**_SWEEP_DEFAULTS, **{k: extra.pop(k) for k in SWEEP_OPTIONS if k in extra}}
    if table_id not in TABLES:
        raise ValueError(f"unknown table {table_id!r}; choose from {', '.join(TABLES)}")
    table = TABLES[table_id]
    env_names = [get_env(e).name for e in (envs or table.envs)]
    unknown = [e for e in env_names if e not in table.envs]
    if unknown:
        raise ValueError(f"table {table_id} has no column for {', '.join(unknown)}")
    more = "".join(f"| {c.title} (ours) | {c.title} (thesis) " for c in table.columns)
    out = [f"## {table.title}", "",
           "| row | environment | P (ours) | P (thesis) | AER (ours) | AER 95 % interval (ours) | AER (thesis) "
           f"| AER sampled actions (ours) {more}| seconds per run | target |",
           "|---|---|---|---|---|---|---|---|---|---|" + "---|---|" * len(table.columns)]
    notes: list[str] = []

    def thesis_number(row: str, env: str, metric: str, value) -> str:
        why = table.thesis_notes.get((row, env, metric))
        if why is None:
            return number(value)
        if why not in notes:
            notes.append(why)
        return f"{number(value)} (note {notes.index(why) + 1})"
    chosen = [r for r in table.rows if rows is None or r.label in rows]
    if rows is not None and len(chosen) != len(set(rows)):
        raise ValueError(f"table {table_id} has no row {', '.join(set(rows) - {r.label for r in chosen})}; its rows: "
                         f"{', '.join(r.label for r in table.rows)}")
    trained, failed = train_rows(table, chosen, env_names, seeds, iterations, {**table.settings, **extra}, log,
                                 **sweep)
    for row in chosen:
        for env in env_names:
            theirs = table.thesis.get(row.label, {}).get(env, (None, None))
            if not implemented(row):
                more = "".join(f"| — | {thesis_cell(theirs, c.thesis, c.fmt)} " for c in table.columns)
                out.append(f"| {row.label} | {env} | not implemented "
                           f"| {thesis_number(row.label, env, 'performance', theirs[0])} "
                           f"| — | — | {thesis_number(row.label, env, 'aer', theirs[1])} | — {more}| — | |")
                continue
            results = trained.get((row.label, env), [])
            if not results:
                more = "".join(f"| — | {thesis_cell(theirs, c.thesis, c.fmt)} " for c in table.columns)
                out.append(f"| {row.label} | {env} | failed | {thesis_number(row.label, env, 'performance', theirs[0])} "
                           f"| — | — | {thesis_number(row.label, env, 'aer', theirs[1])} | — {more}| — | |")
                continue
            target = table.targets.get((row.label, env))
            judged = ""
            if target:
                metric, threshold = target
                judged = f"{metric} ≥ {threshold:g}: {verdict([r[metric] for r in results], threshold)}"
            aers = [r['aer'] for r in results]
            out.append(
                f"| {row.label} | {env} | {mean_sd([r['performance'] for r in results])} "
                f"| {thesis_number(row.label, env, 'performance', theirs[0])} "
                f"| {mean_sd(aers)} | {interval_cell(aers)} | {thesis_number(row.label, env, 'aer', theirs[1])} "
                f"| {mean_sd([r.get('aer_sampled') for r in results])} "
                + "".join(f"| {summarise([_value(c, r) for r in results], c.summary, c.fmt)} "
                          f"| {thesis_cell(theirs, c.thesis, c.fmt)} " for c in table.columns)
                + f"| {np.mean([r['seconds'] for r in results]):.0f} | {judged} |")
    out += ["", f"Seeds: {seeds}. Iterations: {'per-environment defaults' if iterations is None else iterations}. "
            f"P and AER at the last iteration over 100 evaluation episodes (MAP actions; {_protocol(extra)}); "
            "mean ± sample sd over seeds, and the 95 % interval of the mean AER (Student's t). A target is 'met' "
            "only when the whole interval clears it. Our experts are not the thesis's (their AERs differ: see the "
            "Expert rows of Tables 6.1 and 9.1), so P, which divides by the expert's gain over random, is not the "
            "thesis's P: compare AER first. Rows marked 'not implemented' show the thesis's numbers "
            "only. The thesis's BCO rows are compared with our BCO(α)."]
    if notes:
        out += [""] + [f"- Note {k}: {why}" for k, why in enumerate(notes, start=1)]
    if failed:
        out += ["", f"{failed} training(s) failed: their cells average the seeds that finished (the store keeps "
                    "each failure's error; a rerun with the same --store retries them)."]
    if table.note:
        out += ["", table.note]
    return "\n".join(out)


def _value(column: Column, result: dict):
    """A further column's value for one seed, None where the row's result has no such number."""
    try:
        return column.value(result)
    except (KeyError, TypeError):
        return None


for _module in pkgutil.iter_modules(__path__):  # every chapter's tables
    importlib.import_module(f"{__name__}.{_module.name}")
