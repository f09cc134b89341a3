"""Benchmark: `python -m ifo bench` trains BC, BCO and BCO(α) per environment over seeds and
prints a markdown table of random/expert AER, each method's Performance (mean ± sd over
seeds, last iteration) and BCO(α)'s seconds per iteration.

Speed is measured here (a command that prints figures), never in timed tests.
"""
from __future__ import annotations

import functools
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ifo.config import RunConfig
from ifo.envs import get_env
from ifo.methods import METHODS
from ifo.reproduce import mean_sd
from ifo.run import Run

BASELINE_METHODS = ("bc", "bco", "bco-alpha")
QUICK = dict(eval_episodes=10, episodes_per_iteration=10, pre_size=2000, policy_epochs=2, expert_episodes=2)


def run_once(env: str, method: str, seed: int, iterations: int | None, quick: bool, **overrides) -> dict:
    cfg = RunConfig.from_dict({"env": env, "method": method, "seed": seed, "iterations": iterations,
                               **(QUICK if quick else {}), **overrides})
    start = time.perf_counter()
    run = Run(cfg)
    setup = time.perf_counter() - start
    run.run()
    ev = run.records[-1]["evaluation"]
    per_iteration = [r["seconds"]["total"] for r in run.records]
    return {"performance": ev["performance"], "aer": ev["aer"], "setup_seconds": setup,
            "seconds_per_iteration": float(np.mean(per_iteration)), "iterations": len(run.records)}


def bench_table(envs: list[str], seeds: int = 3, iterations: int | None = None, quick: bool = False,
                log=lambda msg: print(msg, file=sys.stderr)) -> str:
    header = ("| environment | random AER | expert AER | " + " | ".join(f"{METHODS[m].title} P" for m in BASELINE_METHODS)
              + " | BCO(α) s/iteration | BCO(α) AER |")
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for env in envs:
        spec = get_env(env)
        results = {m: [] for m in BASELINE_METHODS}
        for method in BASELINE_METHODS:
            for seed in range(seeds):
                r = run_once(spec.name, method, seed, iterations if method != "bco" else None, quick)
                results[method].append(r)
                log(f"{spec.name} {method} seed {seed}: P {r['performance']} AER {r['aer']:.2f} "
                    f"({r['seconds_per_iteration']:.2f} s/iteration, {r['iterations']} iterations)")
        alpha = results["bco-alpha"]
        row = [spec.thesis_name, f"{spec.random_return:.2f}" if spec.random_return is not None else "n/a",
               f"{spec.expert_return:.2f}" if spec.expert_return is not None else "n/a"]
        row += [mean_sd([r["performance"] for r in results[m]]) for m in BASELINE_METHODS]
        row += [f"{np.mean([r['seconds_per_iteration'] for r in alpha]):.2f}",
                mean_sd([r["aer"] for r in alpha], ".2f")]
        lines.append("| " + " | ".join(row) + " |")
    lines.append("")
    lines.append(f"Seeds: {seeds}; iterations: {'per-environment defaults' if iterations is None else iterations}"
                 f"{' (quick settings)' if quick else ''}; P and AER at the last iteration, 100 evaluation "
                 "episodes on held-out seeds (maze: held-out layouts).")
    return "\n".join(lines)


SPEED_CASES = tuple(("cartpole", m) for m in ("bc", "bco", "bco-alpha", "abco", "iupe", "cril", "sail", "gail", "gaifo",
                                             "ilpo")) + tuple((e, "iupe") for e in ("acrobot", "mountaincar",
                                                                                   "lunarlander", "maze3", "maze5",
                                                                                   "maze10"))
SPEED_BASELINE = Path(__file__).resolve().parents[1] / "docs" / "speed-baseline.json"


def step_floor(steps: int = 400) -> dict[str, float]:
    """Milliseconds for one training step of a 4-32-32-2 MLP at batch 128 on this machine, the unit an
    iteration makes hundreds of: with autograd and `optimizer.step()` (fused Adam), and as `fit` trains
    the vector models (`MLP.loss_and_gradients`, Adam's kernels called directly) for IUPE's gated MLP."""
    import torch
    import torch.nn.functional as F

    from ifo.components.learning import make_optimizer, optimizer_step
    from ifo.nets import MLP

    x, y = torch.randn(128, 4), torch.randint(0, 2, (128,))
    best_of = functools.partial(_best_ms, steps=steps)

    out = {}
    for attention in ("none", "gated"):
        mlp = MLP(4, 2, (32, 32), attention)
        opt = make_optimizer(mlp, 1e-3)

        def autograd_step() -> None:
            loss = F.cross_entropy(mlp(x), y)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()

        adam = optimizer_step(opt)

        def hand_step() -> None:
            mlp.loss_and_gradients(x, y)
            adam()

        out[f"{attention}/autograd"], out[f"{attention}/by hand"] = best_of(autograd_step), best_of(hand_step)
    return out


def image_step_ms(obs_shape: tuple[int, ...], n_actions: int, attention: str = "self", batch: int = 128,
                  steps: int = 10) -> dict[str, float]:
    """Milliseconds for one training step (fused Adam, a mini-batch of `batch`) of the maze's image policy and
    IDM, the convolutions an iteration's fits are made of: best of three runs of `steps` steps."""
    import torch
    import torch.nn.functional as F

    from ifo.components.learning import make_optimizer
    from ifo.nets import InverseDynamics, Policy

    generator = torch.Generator().manual_seed(0)
    images = torch.randint(0, 256, (batch, *obs_shape), dtype=torch.uint8, generator=generator)
    labels = torch.randint(0, n_actions, (batch,), generator=generator)
    out = {}
    for role, model, inputs in (("policy", Policy(obs_shape, n_actions, attention=attention), (images,)),
                                ("idm", InverseDynamics(obs_shape, n_actions, attention=attention), (images, images))):
        opt = make_optimizer(model, 1e-3)

        def step() -> None:
            loss = F.cross_entropy(model(*inputs), labels)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()

        step()  # the first step builds Adam's state
        out[role] = _best_ms(step, steps)
    return out


def _best_ms(step: Callable[[], None], steps: int) -> float:
    """Milliseconds per call of `step`: the best of three runs of `steps` calls (the least disturbed by
    whatever else the machine does)."""
    best = np.inf
    for _ in range(3):
        start = time.perf_counter()
        for _ in range(steps):
            step()
        best = min(best, (time.perf_counter() - start) / steps * 1000)
    return best


def fit_steps(record: dict, learner_config) -> dict[str, int]:
    """How many mini-batch steps an iteration's fits made: the IDM's passes over I_s (its record's
    train_size) and the policy's over T_e, as `ifo.components.learning.fit` cuts them."""
    def batches(n: int) -> int:
        full, rest = divmod(n, learner_config.batch_size)
        return full + (rest >= 2 or (rest == 1 and n == 1))  # fit skips a last batch of one sample

    return {"idm": learner_config.idm_epochs * batches(record.get("idm", {}).get("train_size", 0)),
            "policy": learner_config.policy_epochs * batches(record["samples"]["expert_samples"])}


def box2d_step_us(run: Run) -> float:
    """Microseconds of one Box2D world step in the episodes `run`'s policy flies (gymnasium's solver
    iterations; a step costs most with the legs on the ground): one evaluation of the policy under cProfile,
    reading only the time spent inside Box2D's `b2World_Step`."""
    import cProfile
    import pstats

    profiler = cProfile.Profile()
    profiler.enable()
    run.evaluate()
    profiler.disable()
    calls, seconds = 0, 0.0
    for (_file, _line, name), (_, ncalls, tottime, _, _) in pstats.Stats(profiler).stats.items():
        if "b2World_Step" in name:
            calls, seconds = calls + ncalls, seconds + tottime
    return seconds / calls * 1e6 if calls else float("nan")


def environment_steps(records: list[dict], eval_episodes: int) -> dict[str, float]:
    """Environment steps of the last iteration: the learner's own runs (the growth of its step count since the
    iteration before; 0 after the first, whose count also holds I_pre) and the evaluation (its episodes' mean
    length times their number)."""
    last = records[-1]
    own = last["samples"]["environment_steps"] - records[-2]["samples"]["environment_steps"] if len(records) > 1 else 0
    return {"rollout": own, "evaluate": last["evaluation"]["mean_length"] * eval_episodes}


def arithmetic_floors(rows: list[tuple]) -> list[str]:
    """Lines saying how much of the last iteration is arithmetic that no overhead removal can take away:
    for image mazes, the fits' convolutions at this machine's speed for a training step; for LunarLander,
    Box2D's world steps."""
    lines, step_ms, box2d_us = [], {}, None
    for env, method, _setup, records, run in rows:
        spec, cfg = get_env(env), run.config
        image_fits = (len(run.ctx.obs_shape) == 3 and "train_size" in records[-1].get("idm", {})
                      and hasattr(cfg.learner, "policy_epochs"))  # the BCO family's IDM and policy on images
        if image_fits:
            key = (run.ctx.obs_shape, spec.n_actions, cfg.learner.attention, cfg.learner.batch_size)
            if key not in step_ms:
                step_ms[key] = image_step_ms(*key)
            ms, counts = step_ms[key], fit_steps(records[-1], cfg.learner)
            floor = sum(counts[role] * ms[role] for role in counts) / 1000
            spent = sum(records[-1]["seconds"].get(role, 0.0) for role in counts)
            lines.append(f"{env} {method}: the last iteration's fits made {counts['idm']} IDM and "
                         f"{counts['policy']} policy steps at batch {cfg.learner.batch_size}; one step takes "
                         f"{ms['idm']:.0f} / {ms['policy']:.0f} ms here (`ifo.bench.image_step_ms`), so "
                         f"{floor:.2f} s of convolutions, against {spent:.2f} s in its idm and policy phases.")
        elif spec.name == "lunarlander":
            box2d_us = box2d_us or box2d_step_us(run)
            steps = environment_steps(records, cfg.eval_episodes)
            total = steps["rollout"] + steps["evaluate"]
            spent = sum(records[-1]["seconds"].get(p, 0.0) for p in ("rollout", "evaluate"))
            runs = (f"its runs {steps['rollout']:,.0f}" if len(records) > 1
                    else "its runs not counted: the first iteration's count holds I_pre")
            lines.append(f"{env} {method}: the last iteration stepped {total:,.0f} environment steps ({runs}, "
                         f"evaluation {steps['evaluate']:,.0f}); Box2D's world step "
                         f"alone takes {box2d_us:.1f} µs in the policy's episodes (`ifo.bench.box2d_step_us`), so "
                         f"{total * box2d_us / 1e6:.2f} s of simulation, against {spent:.2f} s in its rollout "
                         "and evaluate phases.")
    return lines


def speed_table(cases=SPEED_CASES, iterations: int = 5, log=lambda msg: print(msg, file=sys.stderr),
                baseline: Path | None = SPEED_BASELINE, save_baseline: Path | None = None) -> str:
    """Seconds per iteration and per phase (median over iterations) for the interactive settings, with the
    ratio to a saved baseline (docs/speed-baseline.json: what docs/BENCH.md reports) when there is one."""
    import json

    before = json.loads(Path(baseline).read_text()) if baseline and Path(baseline).exists() else {}
    rows, phases = [], []
    for env, method in cases:
        start = time.perf_counter()
        run = Run(RunConfig(env=env, method=method, iterations=iterations))
        setup = time.perf_counter() - start
        run.run()
        phases += [p for p in run.phases() if p not in phases]
        rows.append((env, method, setup, run.records, run))
        log(f"{env} {method}: {np.median([r['seconds']['total'] for r in run.records]):.2f} s/iteration")
    lines = ["| environment | method | setup s | s/iteration (median) | × baseline | " + " | ".join(phases) + " |",
             "|" + "---|" * (5 + len(phases))]
    now = {}
    for env, method, setup, records, _run in rows:
        med = lambda key: float(np.median([r["seconds"].get(key, 0.0) for r in records]))  # noqa: E731
        now[f"{env}/{method}"] = round(med("total"), 3)
        ratio = f"{med('total') / before[f'{env}/{method}']:.2f}" if before.get(f"{env}/{method}") else "—"
        lines.append(f"| {env} | {method} | {setup:.2f} | {med('total'):.2f} | {ratio} | "
                     + " | ".join(f"{med(p):.2f}" for p in phases) + " |")
    floor = step_floor()
    import torch

    lines += ["", f"{iterations} iterations each, default settings, torch threads: {torch.get_num_threads()} "
              "(IFO_TORCH_THREADS, ifo.runtime.limit_threads). The floor on this machine, one "
              "training step of a 4-32-32-2 MLP at batch 128 (an iteration makes hundreds): plain MLP "
              f"{floor['none/autograd']:.2f} ms with autograd and optimizer.step(), {floor['none/by hand']:.2f} ms as "
              f"`fit` trains it; IUPE's gated MLP {floor['gated/autograd']:.2f} ms and {floor['gated/by hand']:.2f} ms."]
    floors = arithmetic_floors(rows)
    if floors:
        lines += ["", "Arithmetic floors of the last iteration (what removing overhead cannot take away):", ""]
        lines += [f"- {line}" for line in floors]
    if save_baseline:
        Path(save_baseline).write_text(json.dumps(now, indent=1, sort_keys=True) + "\n")
    return "\n".join(lines)


def export_table(run_dir: str | None = None, log=lambda msg: print(msg, file=sys.stderr)) -> str:
    """Server-side export speed: browser start, then seconds per figure and format, and a slide pack."""
    from ifo import export

    if run_dir is None:
        run = Run(RunConfig.from_dict(dict(env="cartpole", method="iupe", iterations=2, **QUICK)))
        run.run()
        records, config = run.records, run.config.to_dict()
    else:
        records, config, _ = export.load_run_files(run_dir)
    figs = export.run_figures(records, config)
    start = time.perf_counter()
    export.figure_bytes(next(iter(figs.values())), "svg")  # starts the browser
    lines = [f"browser start and first figure: {time.perf_counter() - start:.2f} s", "",
             "| format | figures | median s per figure | max s |", "|---|---|---|---|"]
    for fmt in export.FORMATS:
        times = []
        for fig in figs.values():
            t = time.perf_counter()
            export.figure_bytes(fig, fmt)
            times.append(time.perf_counter() - t)
        log(f"{fmt}: {np.median(times):.2f} s per figure")
        lines.append(f"| {fmt} | {len(times)} | {np.median(times):.2f} | {max(times):.2f} |")
    t = time.perf_counter()
    size = len(export.slide_pack(records, config))
    lines += ["", f"slide pack ({len(figs)} figures × {len(export.FORMATS)} formats, {size / 2**20:.1f} MiB): "
              f"{time.perf_counter() - t:.2f} s"]
    return "\n".join(lines)


# A small I_pre gives a weak first IDM and a poor first policy; its runs then hold mostly one
# action. BCO(α) retrains the IDM on those runs alone (I_s = I_pos) and can collapse to predicting
# that action for every expert pair (the thesis's "vanishing actions", Sec 6.1); IUPE keeps only
# successful runs and fills the rest of I_s from I_pre.
VANISHING = dict(pre_size=300, iterations=5, eval_episodes=20)


def vanishing_actions_case(method: str, seed: int, **overrides) -> dict:
    """One CartPole run with a small I_pre: last AER, and how much of T_e the IDM gives one action."""
    run = Run(RunConfig.from_dict({"env": "cartpole", "method": method, "seed": seed, **VANISHING, **overrides}))
    run.run()
    last = run.records[-1]
    counts = np.asarray(last["idm"]["prediction_counts"])
    return {"aer": last["evaluation"]["aer"], "aer_curve": [r["evaluation"]["aer"] for r in run.records],
            "largest_label_share": float(counts.max() / counts.sum())}


def vanishing_table(seeds: int = 10, log=lambda msg: print(msg, file=sys.stderr)) -> str:
    """BCO(α) against IUPE on CartPole from the same seeds with a 300-transition I_pre."""
    lines = ["| seed | BCO(α) AER per iteration | BCO(α) largest label share | IUPE AER per iteration "
             "| IUPE largest label share |", "|---|---|---|---|---|"]
    finals = {"bco-alpha": [], "iupe": []}
    for seed in range(seeds):
        cells = [str(seed)]
        for method in ("bco-alpha", "iupe"):
            r = vanishing_actions_case(method, seed)
            finals[method].append(r["aer"])
            cells += [" → ".join(f"{a:.0f}" for a in r["aer_curve"]), f"{r['largest_label_share']:.2f}"]
            log(f"seed {seed} {method}: AER {r['aer']:.1f}, largest label share {r['largest_label_share']:.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    solved = {m: sum(a >= 475 for a in v) for m, v in finals.items()}
    lines += ["", f"Last-iteration AER ≥ 475 on {solved['bco-alpha']}/{seeds} seeds for BCO(α) and "
              f"{solved['iupe']}/{seeds} for IUPE; mean {np.mean(finals['bco-alpha']):.1f} against "
              f"{np.mean(finals['iupe']):.1f}. Settings: {VANISHING}, other values CartPole's defaults; "
              "label share = the largest share of the expert's pairs the IDM gives one action."]
    return "\n".join(lines)


# ----------------------------------------------------------------------------- the sweep engine
# Small trainings for measuring the engine (not the methods): BC and BCO(α) on CartPole, 2 iterations
# with the quick sizes, alternating, one seed each.
SWEEP_BENCH = dict(env="cartpole", iterations=2)


def sweep_tasks(trainings: int) -> list:
    from ifo.sweep import Task

    tasks = []
    for i in range(trainings):
        method, seed = ("bc", "bco-alpha")[i % 2], i // 2
        spec = {"bench": "sweep", "method": method, "seed": seed, **SWEEP_BENCH}
        tasks.append(Task(spec, run_once, {"env": SWEEP_BENCH["env"], "method": method, "seed": seed,
                                           "iterations": SWEEP_BENCH["iterations"], "quick": True}))
    return tasks


def sweep_child(trainings: int, store: str) -> None:
    """The sweep the resume measurement starts in its own process (and kills)."""
    from ifo.sweep import ResultStore, run_sweep

    run_sweep(sweep_tasks(trainings), ResultStore(store), progress=False)


def _descendants(pid: int) -> list[int]:
    """Every process below `pid` (Linux /proc), so a killed sweep's Ray workers go with it."""
    children: dict[int, list[int]] = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
            children.setdefault(int(fields[1]), []).append(int(stat.parent.name))
        except (OSError, ValueError, IndexError):
            continue
    out, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.append(child)
            todo.append(child)
    return out


def sweep_table(trainings: int = 100, log=lambda msg: print(msg, file=sys.stderr)) -> str:
    """The sweep engine measured: `trainings` small trainings one after another in this process, then on a
    local Ray (throughput of each, and whether both gave the same numbers); then the Ray sweep started
    in its own process, killed (SIGKILL, workers included) once half its rows are stored, and run again:
    how many finished rows the rerun skipped and how many trainings the kill cost."""
    import os
    import signal
    import subprocess
    import tempfile

    from ifo.sweep import ResultStore, run_sweep

    tasks = sweep_tasks(trainings)
    with tempfile.TemporaryDirectory(prefix="ifo-sweep-bench-") as tmp:
        log(f"{trainings} trainings one after another in this process ...")
        here, one_by_one = run_sweep(tasks, ResultStore(f"{tmp}/here"), local=True, desc="in-process")
        log(one_by_one.line())
        log(f"the same {trainings} on a local Ray ...")
        on_ray, ray_report = run_sweep(tasks, ResultStore(f"{tmp}/ray"), desc="local Ray")
        log(ray_report.line())
        differ = sum(here[k]["result"]["aer"] != on_ray[k]["result"]["aer"] for k in here if k in on_ray)

        store = f"{tmp}/killed"
        child = subprocess.Popen([sys.executable, "-c", f"from ifo.bench import sweep_child; "
                                  f"sweep_child({trainings}, {store!r})"], start_new_session=True,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            while len(ResultStore(store).done()) < trainings // 2:
                if child.poll() is not None:
                    raise RuntimeError("the sweep to be killed ended on its own before half its rows")
                time.sleep(0.5)
            for pid in [child.pid] + _descendants(child.pid):
                try:
                    os.kill(pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
            child.wait(60)
        finally:
            if child.poll() is None:
                child.kill()
        kept = len(ResultStore(store).done())
        log(f"killed with {kept} of {trainings} rows stored; resuming ...")
        _, resumed = run_sweep(tasks, ResultStore(store), desc="resumed")
        log(resumed.line())
        rows = ResultStore(store).rows()
        lost = resumed.done - (trainings - kept)  # > 0 only if the rerun redid stored rows
        complete = len(ResultStore(store).done()) == trainings
    return "\n".join([
        "| how | trainings | seconds | trainings per hour |", "|---|---|---|---|",
        f"| one after another, in process | {one_by_one.done} | {one_by_one.seconds:.0f} "
        f"| {one_by_one.per_hour or 0:.0f} |",
        f"| {ray_report.mode} | {ray_report.done} | {ray_report.seconds:.0f} (Ray start "
        f"{ray_report.ray_start_seconds:.0f}) | {ray_report.per_hour or 0:.0f} |",
        "",
        f"Speed-up on Ray: {(ray_report.per_hour or 0) / (one_by_one.per_hour or 1):.2f}×. Results that differ "
        f"between the two: {differ} of {len(here)} (same seed, same numbers). Killed after {kept} stored rows "
        f"(SIGKILL of the driver and its Ray workers): the rerun skipped {resumed.skipped}, trained "
        f"{resumed.done}, redid {max(lost, 0)} stored rows; {len(rows)} rows in the store, "
        f"{'all' if complete else 'NOT all'} {trainings} trainings done. Trainings: {SWEEP_BENCH['iterations']} "
        f"iterations of BC and BCO(α) on {SWEEP_BENCH['env']} with the quick sizes ({QUICK})."])
