"""Command line: `python -m ifo {train, experts, demos, bench} ...`.

Bad input (unknown environment or method, impossible values, a malformed file) ends
with one line `error: ...` on stderr and exit status 2, never a traceback.
"""
from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

from ifo.config import RunConfig
from ifo.envs import ENV_NAMES, UnknownEnvironment, env_file_name, get_env
from ifo.methods import METHODS, UnknownMethod
from ifo.options import parse_bool

RUNS_DIR = Path("runs")
DEFAULT_BENCH_ENVS = "cartpole,acrobot,mountaincar,lunarlander,maze5"


class CliError(Exception):
    pass


def _learner_classes():
    from ifo.learners import LEARNERS

    return [learner.Config for learner in LEARNERS.values()]


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """Flags generated from the configuration classes (ifo/config.py, ifo/learners/): one per field,
    with the field's own help and bounds; each learner's settings in a group of their own."""
    from ifo.options import add_arguments, specs

    p.add_argument("--env", required=True, help=f"one of {', '.join(ENV_NAMES)}, a gymnasium id, or your own as "
                                                    "module:name (ifo.envs.register_env)")
    p.add_argument("--method", required=True, help=f"one of {', '.join(METHODS)}")
    add_arguments(p.add_argument_group("run settings"), RunConfig, skip=("env", "method"))
    seen: set[str] = set()
    for cls in _learner_classes():
        fresh = [s.name for s in specs(cls) if s.name not in seen]
        if fresh:
            methods = ", ".join(m.title for m in METHODS.values() if issubclass(m.learner_class.Config, cls))
            add_arguments(p.add_argument_group(f"{cls.__name__} settings ({methods})"), cls,
                          skip=tuple(n for n in (s.name for s in specs(cls)) if n in seen))
            seen |= set(fresh)


def config_from_args(a: argparse.Namespace) -> RunConfig:
    from ifo.methods import get_method
    from ifo.options import given

    values = given(a, RunConfig)
    values.update(env=a.env, method=a.method)
    method = get_method(a.method)
    own = method.learner_class.Config
    for cls in _learner_classes():
        for name, value in given(a, cls).items():
            if name not in own.field_names():
                raise CliError(f"--{name.replace('_', '-')} does not apply to {method.title}")
            values[name] = value
    return RunConfig.from_dict(values).resolved()


def _fmt(v, spec=".3f") -> str:
    return "n/a" if v is None else format(v, spec)


def cmd_train(a: argparse.Namespace) -> int:
    from ifo import checkpoint

    cfg = config_from_args(a)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    out = Path(a.out) if a.out else RUNS_DIR / f"{env_file_name(cfg.env)}-{cfg.method}-s{cfg.seed}-{stamp}"
    created = not out.exists()
    checkpoint.prepare_out_dir(out, overwrite=a.overwrite)  # before minutes of training, not after
    start = time.perf_counter()
    try:
        run = _train(cfg, out, a)
    except BaseException:
        if created:  # a run that failed before its first save (bad settings, Ctrl-C) leaves no empty folder
            try:
                out.rmdir()
            except OSError:  # not empty: the iterations saved so far stay
                pass
        raise
    ev = run.records[-1]["evaluation"]
    summary = {"env": cfg.env, "method": cfg.method, "seed": cfg.seed, "iterations": run.iteration,
               "aer": ev["aer"], "aer_std": ev["aer_std"], "performance": ev["performance"],
               "goal_rate": ev["goal_rate"], "seconds": round(time.perf_counter() - start, 3), "run_dir": str(out)}
    if a.json:
        print(json.dumps(summary))
    else:
        print(f"saved to {out}: AER {ev['aer']:.2f} ± {ev['aer_std']:.2f}, P {_fmt(ev['performance'])}")
    return 0


def _train(cfg, out: Path, a: argparse.Namespace):
    """Every iteration of a run of `cfg`, each saved to `out` as it ends."""
    from tqdm import tqdm

    from ifo.run import Run

    run = Run(cfg)
    bar = tqdm(total=cfg.iterations, desc=f"{cfg.method} on {cfg.env}", file=sys.stderr, disable=a.quiet)
    for _ in range(cfg.iterations):
        rec = run.step()
        ev = rec["evaluation"]
        bar.update(1)
        idm = rec.get("idm", {})
        idm_text = (f"IDM on T_e {_fmt(idm.get('expert_accuracy'))} (I_pre val {_fmt(idm.get('val_accuracy'))})  "
                    if idm else "")
        bar.write(f"iteration {rec['iteration']:>3}  AER {ev['aer']:9.2f}  P {_fmt(ev['performance'])}  "
                  f"goal {ev['goal_rate']:.2f}  {idm_text}{rec['seconds']['total']:.2f}s", file=sys.stdout)
        run.save(out, overwrite=a.overwrite and run.iteration == 1)
    bar.close()
    return run


def cmd_demos_check(a: argparse.Namespace) -> int:
    from ifo.data.demos import load_demonstrations, summarize

    if not 16 <= a.image_size <= 256:  # checked before a maze env allocates images of that size
        raise CliError(f"--image-size must be between 16 and 256 pixels, got {a.image_size}")
    spec = get_env(a.env)
    env = spec.make(**({"obs_mode": a.obs_mode, "image_size": a.image_size} if spec.is_maze else {}))
    shape = tuple(env.observation_space.shape)
    env.close()
    demos = load_demonstrations(a.file, spec, shape, require_actions=a.require_actions)
    s = summarize(demos)
    print(f"ok: {a.file} holds {s['episodes']} episodes, {s['transitions']} transitions for {spec.name}; "
          f"mean return {s['mean_return']:.2f}; actions {'present' if s['has_actions'] else 'absent (IfO only)'}")
    return 0


def cmd_experts(a: argparse.Namespace) -> int:
    if a.episodes < 1:
        raise CliError(f"--episodes must be a whole number >= 1, got {a.episodes}")
    if a.timesteps is not None and a.timesteps < 1:
        raise CliError(f"--timesteps must be a whole number >= 1, got {a.timesteps}")
    from ifo.experts.train import parse_levels

    levels = parse_levels(a.level)
    envs = ENV_NAMES if a.env == "all" else [get_env(a.env).name]
    if levels != [1]:  # expert levels exist for the control tasks only
        mazes = [e for e in envs if get_env(e).is_maze]
        if a.env != "all" and mazes:
            raise CliError(f"{mazes[0]} has one expert (shortest paths): --level applies to the control tasks")
        envs = [e for e in envs if not get_env(e).is_maze]
    if a.action == "train":
        from ifo.experts.train import describe_level1, train_expert, train_levels

        steps = {"timesteps": a.timesteps} if a.timesteps else {}
        for env in envs:
            if get_env(env).is_maze:
                continue
            if 1 in levels:
                train_expert(env, seed=a.seed, **steps)
            if any(level > 1 for level in levels):
                train_levels(env, [level for level in levels if level > 1], seed=a.seed,
                             log=lambda m: print(m, flush=True), **steps)
                describe_level1(env)  # levels.json's level-1 entry, measured the same way
        return 0
    if a.action == "evaluate":
        from ifo.experts.demos import evaluate_expert

        for env in envs:
            for level in levels:
                r = evaluate_expert(env, a.episodes, level=level)
                print(json.dumps(r) if a.json else
                      f"{env} level {level}: AER {r['aer']:.2f} ± {r['std']:.2f} over {r['episodes']} episodes")
        return 0
    if a.action == "demos":
        from ifo.experts.demos import make_demonstrations

        for env in envs:
            for level in levels:
                make_demonstrations(env, a.episodes, level=level)
        return 0
    if a.action == "references":
        from ifo.experts.demos import measure_references

        for env in envs:
            measure_references(env, a.episodes)
        return 0
    raise CliError(f"unknown experts action {a.action!r}")


def cmd_bench(a: argparse.Namespace) -> int:
    if a.what == "reproduce":
        from ifo.reproduce import reproduce

        if not a.table:
            from ifo.reproduce import TABLES

            raise CliError(f"bench reproduce needs --table ({', '.join(TABLES)})")
        envs = a.envs.split(",") if a.envs else None
        extra = {"maze_eval_layouts": a.maze_eval_layouts} if a.maze_eval_layouts else {}
        if a.deadlock_guard is not None:
            extra["deadlock_guard"] = a.deadlock_guard
        if a.expert_episodes:
            extra["expert_episodes"] = a.expert_episodes
        from ifo.reproduce import row_labels, sweep_defaults

        rows = row_labels(a.rows) if a.rows else None

        try:
            with sweep_defaults(**_sweep_options(a)):  # on Ray unless --local; --store to resume
                text = reproduce(a.table, a.seeds, envs, a.iterations, rows=rows, **extra)
        except RuntimeError as exc:  # every training failed: say why in one line
            raise CliError(str(exc)) from exc
    elif a.what == "resilience":
        from ifo.reproduce import row_labels
        from ifo.reproduce.chapter7 import resilience_study

        extra = {"expert_episodes": a.expert_episodes} if a.expert_episodes else {}
        levels = [int(v) for v in a.levels.split(",")] if a.levels else None
        text = resilience_study(a.envs.split(",") if a.envs else None, a.seeds, a.iterations, levels=levels,
                                rows=row_labels(a.rows) if a.rows else None,
                                ship=a.ship, figures_dir=a.figures, **extra, **_sweep_options(a))
    elif a.what == "seeds":
        from ifo.sweep import ResultStore, StoreError, seeds_table

        if not a.store:
            raise CliError("bench seeds needs --store DIR (a results store of reproduce or resilience, or a "
                           "results file such as assets/resilience/cartpole.jsonl)")
        if not Path(a.store).exists():
            raise CliError(f"--store: no results store or file at {a.store}")
        if a.at_iteration is not None and a.at_iteration < 1:
            raise CliError(f"--at-iteration counts from 1, got {a.at_iteration}")
        try:
            text = seeds_table(ResultStore.at(a.store).done().values(), a.at_iteration)
        except StoreError as exc:  # over the size limit: say so, read nothing
            raise CliError(f"--store: {exc}") from exc
    elif a.what == "recheck":
        from ifo.reproduce import recheck, row_labels
        from ifo.sweep import ResultStore, StoreError

        if not a.store or not Path(a.store).exists():
            raise CliError("bench recheck needs --store DIR|FILE.jsonl: the stored trainings to train again (e.g. "
                           "assets/resilience/cartpole.jsonl)" + (f"; nothing at {a.store}" if a.store else ""))
        if not 1 <= a.rounds <= 1000 or a.seeds < 1:
            raise CliError(f"--rounds must be 1..1000 and --seeds at least 1, got {a.rounds} and {a.seeds}")
        try:
            stored = list(ResultStore.at(a.store).done().values())
        except StoreError as exc:
            raise CliError(f"--store: {exc}") from exc
        opts = _sweep_options(a)
        text = recheck(stored, a.rounds, a.seeds, envs=a.envs.split(",") if a.envs else None,
                       rows=row_labels(a.rows) if a.rows else None, address=opts["address"], ray=opts["ray"])
    elif a.what == "sweep":
        from ifo.bench import sweep_table

        if not 2 <= a.trainings <= 10_000:
            raise CliError(f"--trainings must be 2..10000, got {a.trainings}")
        text = sweep_table(a.trainings)
    elif a.what == "vanishing":
        from ifo.bench import vanishing_table

        text = vanishing_table(a.seeds)
    elif a.what == "export":
        from ifo.bench import export_table

        text = export_table()
    elif a.what == "speed":
        from ifo.bench import SPEED_CASES, speed_table

        envs = a.envs.split(",") if a.envs else None
        cases = [case for case in SPEED_CASES if envs is None or case[0] in envs]
        if not cases:
            raise CliError(f"--envs: no speed case for {a.envs!r}; the cases' environments are "
                           + ", ".join(dict.fromkeys(env for env, _ in SPEED_CASES)))
        if a.save_baseline and envs is not None:
            raise CliError("--save-baseline records every case: leave out --envs")
        text = speed_table(cases, iterations=a.iterations or 5, save_baseline=a.save_baseline)
    else:
        from ifo.bench import bench_table

        text = bench_table((a.envs or DEFAULT_BENCH_ENVS).split(","), a.seeds, a.iterations, quick=a.quick)
    command = "python -m ifo " + shlex.join(sys.argv[1:]) if a.out else ""  # quoted: pastes into a shell
    print(text)
    if a.out:
        from ifo.io import atomic_write_text

        atomic_write_text(a.out, f"{text}\n\nMade with `{command}`.\n")
    return 0


def _sweep_options(a: argparse.Namespace) -> dict:
    """How `bench reproduce` / `bench resilience` run their trainings: on Ray (a local one by default, or
    --address / RAY_ADDRESS), or --local in this process; --store DIR keeps results so a rerun resumes."""
    if a.local and a.address:
        raise CliError("--local runs here without Ray; it cannot go with --address")
    return {"store": a.store, "address": a.address, "ray": not a.local}


def cmd_export(a: argparse.Namespace) -> int:
    from ifo.export import ExportError, export_run

    formats = [f.strip().lower() for f in a.formats.split(",") if f.strip()]
    if not formats or any(f not in ("svg", "png", "pdf") for f in formats):
        raise CliError(f"--formats must be a comma-separated list of svg, png, pdf; got {a.formats!r}")
    if not Path(a.run_dir).is_dir():
        raise CliError(f"no run folder {a.run_dir}")
    start = time.perf_counter()
    try:
        paths = export_run(a.run_dir, a.out, formats, as_zip=a.zip)
    except ExportError as exc:  # no Chromium, or it would not start
        raise CliError(str(exc)) from exc
    for path in paths:
        print(path)
    print(f"wrote {len(paths)} file(s) to {a.out} in {time.perf_counter() - start:.1f}s", file=sys.stderr)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m ifo", description="IfO Lab: imitation learning from observation")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("train", help="train a method and save the run")
    _add_run_options(p)
    p.add_argument("--out", help="run folder (default runs/ENV-METHOD-sSEED-TIME); must be new or empty")
    p.add_argument("--overwrite", action="store_true", help="replace the run already saved in --out")
    p.add_argument("--json", action="store_true", help="end with one JSON line summarising the run")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_train)

    p = sub.add_parser("experts", help="expert policies, their demonstrations and reference returns")
    p.add_argument("action", choices=["train", "evaluate", "demos", "references"])
    p.add_argument("--env", default="all")
    p.add_argument("--episodes", type=int, default=100, help="episodes to evaluate or record (>= 1)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--timesteps", type=int, help="expert training steps (>= 1; default: per env)")
    p.add_argument("--level", default="1",
                   help="expert level of Table 7.1: 1 (the best, default) .. 5, a list (2,4), a range (2-5) or all; "
                        "train: levels 2-5 are checkpoints of one training run per environment")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_experts)

    p = sub.add_parser("demos", help="demonstration files")
    dsub = p.add_subparsers(dest="demos_command", required=True)
    c = dsub.add_parser("check", help="validate a demonstrations .npz for an environment")
    c.add_argument("file")
    c.add_argument("--env", required=True)
    c.add_argument("--require-actions", action="store_true", help="also require 'actions' (needed for BC)")
    c.add_argument("--obs-mode", choices=["image", "vector"], default="image")
    c.add_argument("--image-size", type=int, default=32, help="maze image side in pixels (16..256)")
    c.set_defaults(func=cmd_demos_check)

    p = sub.add_parser("bench", help="benchmarks printed as markdown tables")
    p.add_argument("what", nargs="?",
                   choices=["baselines", "reproduce", "resilience", "speed", "export", "vanishing", "sweep", "seeds",
                            "recheck"],
                   default="baselines",
                   help="baselines: random/expert AER and BC, BCO, BCO(α) Performance; reproduce: a thesis "
                        "table; resilience: Tables 7.2-7.6 (Ch. 7) as one sweep; speed: seconds per iteration and "
                        "per phase; export: server-side figure export speed; "
                        "vanishing: BCO(α) against IUPE on CartPole with a small I_pre; sweep: the sweep engine's "
                        "throughput in process and on Ray, and a resume after a kill; seeds: every finished "
                        "training of a --store, one line per seed; recheck: train again the first --rounds "
                        "rounds of a --store's trainings here and say which come back to their stored numbers")
    p.add_argument("--trainings", type=int, default=100, help="sweep: how many small trainings")
    from ifo.reproduce import TABLES

    p.add_argument("--table", choices=sorted(TABLES, key=lambda t: tuple(map(int, t.split(".")))),
                   help="which thesis table to reproduce")
    p.add_argument("--envs", help=f"comma-separated (default: {DEFAULT_BENCH_ENVS}, or the table's columns)")
    p.add_argument("--rows", help="reproduce: only these rows of the table (comma-separated labels, e.g. CRIL,IUPE)")
    p.add_argument("--save-baseline", help="speed: also write the seconds per iteration to this JSON (docs/"
                                           "speed-baseline.json is what later runs compare with)")
    p.add_argument("--out", help="also write the table (and the command that made it) to this file")
    p.add_argument("--maze-eval-layouts", choices=["held-out", "demonstration"],
                   help="reproduce: evaluate mazes on held-out layouts (default) or on the demonstrations' layouts "
                        "(the thesis authors' protocol)")
    p.add_argument("--deadlock-guard", type=parse_bool, metavar="BOOL", nargs="?", const=True,
                   help="reproduce: maze evaluation ends an episode on the 4th visit to a cell with return -1 "
                        "(the thesis authors' evaluation; on unless false; the bare flag, as the older tables "
                        "were made, means true)")
    p.add_argument("--expert-episodes", type=int,
                   help="reproduce: how many demonstrations every method gets (default: per env; the shipped "
                        "5×5 and 10×10 maze demonstrations hold 1,000, one per training layout)")
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--iterations", type=int, help="iterations for the iterative methods (default: per env)")
    p.add_argument("--quick", action="store_true", help="small settings, for a smoke test")
    p.add_argument("--store", metavar="DIR|FILE.jsonl",
                   help="reproduce/resilience: keep every finished training in DIR, or in one results file "
                        "FILE.jsonl (JSON lines); a rerun skips the ones already there, so a complete store "
                        "renders its table without training (default: a temporary folder, nothing resumed); "
                        "seeds: the store to list (a folder, or a file such as assets/resilience/cartpole.jsonl)")
    p.add_argument("--at-iteration", type=int, metavar="N",
                   help="seeds: also each training's P and AER at iteration N (from its stored curve; — where the "
                        "curve has no such iteration)")
    p.add_argument("--rounds", type=int, default=2,
                   help="recheck: how many first rounds of each stored training to train again (default 2)")
    p.add_argument("--address", help="reproduce/resilience: a Ray cluster (ray://HOST:10001); default RAY_ADDRESS, "
                                     "else a local Ray on 2 CPUs")
    p.add_argument("--local", action="store_true",
                   help="reproduce/resilience/recheck: train in this process, one after another, without Ray")
    p.add_argument("--levels", help="resilience: expert levels (comma-separated, default 1,2,3,4,5)")
    p.add_argument("--figures", metavar="DIR", help="resilience: also draw Fig 7.1 per environment into DIR (SVG)")
    p.add_argument("--ship", action="store_true",
                   help="resilience: also write the results to assets/resilience/<env>.jsonl (the app's page)")
    p.set_defaults(func=cmd_bench)

    p = sub.add_parser("export", help="a saved run's figures (slide theme) as SVG/PNG/PDF, metrics.csv, config.json")
    p.add_argument("run_dir", metavar="RUN_DIR", help="a run folder saved by `train` or the app")
    p.add_argument("--out", required=True, metavar="DIR", help="folder to write into (made if missing)")
    p.add_argument("--formats", default="svg,png,pdf", help="comma-separated, of svg, png, pdf (default: all)")
    p.add_argument("--zip", action="store_true", help="write one DIR/<run>-slides.zip instead of loose files")
    p.set_defaults(func=cmd_export)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from ifo.runtime import limit_threads

    limit_threads()
    from ifo.data.demos import DemoError

    try:
        return args.func(args)
    except (CliError, UnknownEnvironment, UnknownMethod, DemoError, ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
