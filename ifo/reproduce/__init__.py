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
"""
from __future__ import annotations

import sys
import time
import importlib
import pkgutil
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from ifo.config import RunConfig
from ifo.envs import get_env
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


def mean_sd(values: list) -> str:
    """'mean ± sd' over seeds for a table cell; one value as is; '—' when there is none."""
    values = [v for v in values if v is not None]
    if not values:
        return "—"
    if len(values) == 1:
        return f"{values[0]:.3f}"
    return f"{np.mean(values):.3f} ± {np.std(values):.3f}"


def number(v) -> str:
    return "—" if v is None else f"{v:.3f}"


def summarise(values: list, how: str = "mean_sd", fmt: str = ".3f") -> str:
    """A further column's cell over seeds: mean ± sd, or the min, max or sd."""
    values = [v for v in values if v is not None]
    if not values:
        return "—"
    if how == "mean_sd":
        return (format(values[0], fmt) if len(values) == 1
                else f"{format(float(np.mean(values)), fmt)} ± {format(float(np.std(values)), fmt)}")
    return format(float({"min": np.min, "max": np.max, "sd": np.std}[how](values)), fmt)


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
             if extra.get("deadlock_guard") else "")
    demos = f"; {extra['expert_episodes']} demonstrations" if extra.get("expert_episodes") else ""
    return f"held-out seeds for the vector tasks, {layouts}{guard}{demos}"


def reproduce(table_id: str, seeds: int = 3, envs: list[str] | None = None, iterations: int | None = None,
              log=lambda m: print(m, file=sys.stderr, flush=True), rows: list[str] | None = None, **extra) -> str:
    if table_id not in TABLES:
        raise ValueError(f"unknown table {table_id!r}; choose from {', '.join(TABLES)}")
    table = TABLES[table_id]
    env_names = [get_env(e).name for e in (envs or table.envs)]
    unknown = [e for e in env_names if e not in table.envs]
    if unknown:
        raise ValueError(f"table {table_id} has no column for {', '.join(unknown)}")
    more = "".join(f"| {c.title} (ours) | {c.title} (thesis) " for c in table.columns)
    out = [f"## {table.title}", "",
           "| row | environment | P (ours) | P (thesis) | AER (ours) | AER (thesis) | AER sampled actions (ours) "
           f"{more}| seconds per run | target |",
           "|---|---|---|---|---|---|---|---|---|" + "---|---|" * len(table.columns)]
    chosen = [r for r in table.rows if rows is None or r.label in rows]
    if rows is not None and len(chosen) != len(set(rows)):
        raise ValueError(f"table {table_id} has no row {', '.join(set(rows) - {r.label for r in chosen})}; its rows: "
                         f"{', '.join(r.label for r in table.rows)}")
    for row in chosen:
        for env in env_names:
            theirs = table.thesis.get(row.label, {}).get(env, (None, None))
            if not implemented(row):
                more = "".join(f"| — | {thesis_cell(theirs, c.thesis, c.fmt)} " for c in table.columns)
                out.append(f"| {row.label} | {env} | not implemented | {number(theirs[0])} | — | {number(theirs[1])} "
                           f"| — {more}| — | |")
                continue
            results = []
            for seed in range(seeds if row.method not in ("expert", "random") else 1):
                r = run_row(row, env, seed, iterations, **{**table.settings, **extra})
                results.append(r)
                log(f"[{table_id}] {row.label} on {env}, seed {seed}: P {r['performance']} AER {r['aer']} "
                    f"({r['seconds']:.0f} s)")
            target = table.targets.get((row.label, env))
            verdict = ""
            if target:
                metric, threshold = target
                mean = np.mean([r[metric] for r in results])
                verdict = f"{metric} ≥ {threshold:g}: {'met' if mean >= threshold - 1e-9 else 'MISSED'}"
            out.append(
                f"| {row.label} | {env} | {mean_sd([r['performance'] for r in results])} | {number(theirs[0])} "
                f"| {mean_sd([r['aer'] for r in results])} | {number(theirs[1])} "
                f"| {mean_sd([r.get('aer_sampled') for r in results])} "
                + "".join(f"| {summarise([_value(c, r) for r in results], c.summary, c.fmt)} "
                          f"| {thesis_cell(theirs, c.thesis, c.fmt)} " for c in table.columns)
                + f"| {np.mean([r['seconds'] for r in results]):.0f} | {verdict} |")
    out += ["", f"Seeds: {seeds}. Iterations: {'per-environment defaults' if iterations is None else iterations}. "
            f"P and AER at the last iteration over 100 evaluation episodes (MAP actions; {_protocol(extra)}). "
            "Rows marked 'not implemented' show the thesis's numbers only. The thesis's BCO rows are compared with "
            "our BCO(α)."]
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
