"""The command line as a researcher uses it: --json contracts and clear errors."""
import json
import subprocess
import sys

import pytest

FAST = ["--iterations", "2", "--pre-size", "2000", "--episodes-per-iteration", "10", "--eval-episodes", "10",
        "--policy-epochs", "2", "--expert-episodes", "2"]


def run_cli(*args, timeout=300):
    return subprocess.run([sys.executable, "-m", "ifo", *args], capture_output=True, text=True, timeout=timeout)


def test_train_json_contract_and_saved_run(tmp_path):
    out = tmp_path / "run"
    res = run_cli("train", "--env", "cartpole", "--method", "bco-alpha", "--seed", "1", "--json", "--quiet",
                  "--out", str(out), *FAST)
    assert res.returncode == 0, res.stderr
    lines = res.stdout.strip().splitlines()
    assert lines[0].startswith("iteration   1")  # per-iteration AER and P
    summary = json.loads(lines[-1])
    assert {"env", "method", "seed", "iterations", "aer", "performance", "seconds"} <= set(summary)
    assert summary["env"] == "cartpole" and summary["method"] == "bco-alpha" and summary["seed"] == 1
    assert summary["iterations"] == 2 and summary["seconds"] > 0
    assert (out / "LATEST").exists() and (out / "config.json").exists()

    from ifo.run import Run

    run = Run.load(out)
    assert run.iteration == 2 and run.records[-1]["evaluation"]["aer"] == pytest.approx(summary["aer"])


def test_gymnasium_ids_and_aliases_are_accepted(tmp_path):
    res = run_cli("train", "--env", "CartPole-v1", "--method", "BCO", "--json", "--quiet", "--out", str(tmp_path), *FAST)
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout.strip().splitlines()[-1])
    assert summary["method"] == "bco" and summary["iterations"] == 1


@pytest.mark.parametrize("args,message", [
    (["--env", "pong", "--method", "bco"], "unknown environment 'pong'"),
    (["--env", "cartpole", "--method", "dagger"], "unknown method 'dagger'"),
    (["--env", "cartpole", "--method", "bco-alpha", "--iterations", "0"], "iterations must be at least 1, got 0"),
    (["--env", "cartpole", "--method", "bco-alpha", "--seed", "-1"], "seed must be at least 0, got -1"),
    (["--env", "cartpole", "--method", "bco-alpha", "--seed", str(2**64)], "seed must be at most 4294967295"),
    (["--env", "cartpole", "--method", "bco-alpha", "--pre-size", "1"], "pre_size must be at least 10, got 1"),
    (["--env", "cartpole", "--method", "bco-alpha", "--seed", "x"], "expected a whole number, got 'x'"),
    (["--env", "cartpole", "--method", "iupe", "--td-updates", "3"], "--td-updates does not apply to IUPE"),
    (["--env", "cartpole", "--method", "iupe", "--expert-episodes", "5000"],
     "expert_episodes is 5000, but the demonstrations hold only"),
    (["--env", "cartpole", "--method", "iupe", "--sampling", "everything"], "invalid choice: 'everything'"),
    (["--env", "cartpole", "--method", "bco", "--demos", "/nonexistent/demos.npz"], "no such file"),
])
def test_bad_input_gives_one_clear_line_and_exit_2(args, message, tmp_path):
    out = tmp_path / "run"
    res = run_cli("train", *args, "--quiet", "--out", str(out))
    assert res.returncode == 2
    assert message in res.stderr and "Traceback" not in res.stderr
    assert not out.exists()  # no empty run folder left behind (some settings fail once the run is built)


def test_experts_evaluate_json_contract():
    res = run_cli("experts", "evaluate", "--env", "cartpole", "--episodes", "5", "--json")
    assert res.returncode == 0, res.stderr
    out = json.loads(res.stdout.strip().splitlines()[-1])
    assert out["env"] == "cartpole" and out["episodes"] == 5 and out["aer"] == 500.0


def test_bench_reproduce_passes_the_maze_protocol_to_every_run(monkeypatch, capsys):
    import ifo.reproduce as reproduce_mod
    from ifo.cli import main

    seen = {}

    def fake_reproduce(table_id, seeds, envs, iterations, rows=None, **extra):
        seen.update(table=table_id, seeds=seeds, envs=envs, iterations=iterations, extra=extra)
        return f"(table; {reproduce_mod._protocol(extra)})"

    monkeypatch.setattr(reproduce_mod, "reproduce", fake_reproduce)
    assert main(["bench", "reproduce", "--table", "6.1", "--envs", "maze5", "--seeds", "1", "--iterations", "40",
                 "--maze-eval-layouts", "demonstration", "--deadlock-guard", "true", "--expert-episodes", "1000"]) == 0
    assert seen == {"table": "6.1", "seeds": 1, "envs": ["maze5"], "iterations": 40,
                    "extra": {"maze_eval_layouts": "demonstration", "deadlock_guard": True, "expert_episodes": 1000}}
    out = capsys.readouterr().out
    assert "the demonstrations' maze layouts" in out and "deadlock guard" in out and "1000 demonstrations" in out


def test_bench_reproduce_rows_may_name_a_row_whose_label_has_a_comma(monkeypatch, capsys):
    """Table 6.1's "BCO(α), appending I_s (Torabi et al.)" holds a comma: --rows still selects it alone."""
    import ifo.reproduce as reproduce_mod
    from ifo.cli import main

    real_reproduce, seen = reproduce_mod.reproduce, {}

    def fake_reproduce(table_id, seeds, envs, iterations, rows=None, **extra):
        seen["rows"] = rows
        return "(table)"

    monkeypatch.setattr(reproduce_mod, "reproduce", fake_reproduce)
    assert main(["bench", "reproduce", "--table", "6.1", "--envs", "maze3", "--seeds", "1", "--local",
                 "--rows", "IUPE,BCO(α), appending I_s (Torabi et al.),BCO(α)"]) == 0
    assert seen["rows"] == ["IUPE", "BCO(α), appending I_s (Torabi et al.)", "BCO(α)"]
    with pytest.raises(ValueError, match="has no row appending"):  # a label's tail alone is no row
        real_reproduce("6.1", 1, ["maze3"], rows=reproduce_mod.row_labels("BCO(α), appending"))


def test_bench_speed_times_only_the_environments_asked_for(monkeypatch, capsys):
    import ifo.bench as bench_mod
    from ifo.cli import main

    seen = []
    monkeypatch.setattr(bench_mod, "speed_table", lambda cases, **kw: seen.extend(cases) or "(speed table)")
    assert main(["bench", "speed", "--envs", "lunarlander,maze5", "--iterations", "1"]) == 0
    assert seen == [("lunarlander", "iupe"), ("maze5", "iupe")]
    assert main(["bench", "speed", "--envs", "atlantis"]) == 2
    assert "no speed case for 'atlantis'" in capsys.readouterr().err


@pytest.mark.parametrize("n", [1, 2, 127, 128, 129, 130, 256, 257])
def test_bench_counts_the_training_steps_fit_really_makes(n):
    """The maze floor multiplies a training step's time by `fit_steps`: it must count the mini-batches `fit`
    trains (a last batch of one sample is skipped unless it is the only sample)."""
    from types import SimpleNamespace

    import numpy as np
    import torch

    from ifo.bench import fit_steps
    from ifo.components.learning import fit, make_optimizer

    module, calls = torch.nn.Linear(3, 2), []

    def forward(x):
        calls.append(len(x))
        return module(x)

    epochs = 2
    fit(forward, module, make_optimizer(module, 1e-3), [np.zeros((n, 3), np.float32)], np.zeros(n, np.int64),
        epochs, 128, torch.Generator().manual_seed(0))
    config = SimpleNamespace(batch_size=128, idm_epochs=epochs, policy_epochs=1)
    record = {"idm": {"train_size": n}, "samples": {"expert_samples": n}}
    assert fit_steps(record, config) == {"idm": len(calls), "policy": len(calls) // epochs}


def test_bench_speed_states_the_arithmetic_floor_of_a_maze_iteration():
    """The line bench speed prints under its table for an image maze: the fits' steps from the run's records,
    and a training step's time measured here."""
    import re

    from ifo.bench import arithmetic_floors
    from ifo.config import RunConfig
    from ifo.run import Run

    run = Run(RunConfig.from_dict(dict(env="maze3", method="iupe", iterations=1, pre_size=300, policy_epochs=2,
                                       episodes_per_iteration=4, eval_episodes=4, expert_episodes=10)))
    run.run()
    [line] = arithmetic_floors([("maze3", "iupe", 0.0, run.records, run)])
    made = re.search(r"made (\d+) IDM and (\d+) policy steps at batch 128; one step takes (\d+) / (\d+) ms", line)
    expert, train_size = run.records[-1]["samples"]["expert_samples"], run.records[-1]["idm"]["train_size"]
    batches = lambda n: n // 128 + (n % 128 >= 2)  # noqa: E731  (a last batch of one sample is skipped)
    assert int(made[1]) == batches(train_size) and int(made[2]) == 2 * batches(expert)
    assert int(made[3]) > 0 and int(made[4]) > 0 and " s of convolutions, against " in line


def test_bench_speed_states_the_simulation_floor_of_a_lunarlander_iteration():
    """For LunarLander the floor is Box2D: the last iteration's environment steps (its own runs and the
    evaluation, from the records) times a world step's time in the policy's episodes."""
    import math
    import re

    from ifo.bench import arithmetic_floors, box2d_step_us
    from ifo.config import RunConfig
    from ifo.run import Run

    run = Run(RunConfig.from_dict(dict(env="lunarlander", method="iupe", iterations=2, pre_size=300,
                                       policy_epochs=1, episodes_per_iteration=2, eval_episodes=2,
                                       expert_episodes=2)))
    run.run()
    [line] = arithmetic_floors([("lunarlander", "iupe", 0.0, run.records, run)])
    steps = re.search(r"stepped ([\d,]+) environment steps \(its runs ([\d,]+), evaluation ([\d,]+)\)", line)
    own = run.records[1]["samples"]["environment_steps"] - run.records[0]["samples"]["environment_steps"]
    evaluation = run.records[1]["evaluation"]["mean_length"] * 2
    assert [int(g.replace(",", "")) for g in steps.groups()] == [round(own + evaluation), own, round(evaluation)]
    assert math.isfinite(box2d_step_us(run)) and box2d_step_us(run) > 0


@pytest.mark.parametrize("seeds, cell", [(1, "-87.70"), (2, "-86.70 ± 1.41")])
def test_bench_baselines_aer_cell_with_one_seed_or_more(monkeypatch, seeds, cell):
    """`python -m ifo bench --seeds 1` prints BCO(α)'s AER as a value, not "± 0.00"; more seeds, mean ± sample sd."""
    import ifo.bench as bench_mod

    aers = iter([-87.7, -85.7] * 3)
    monkeypatch.setattr(bench_mod, "run_once", lambda env, method, seed, iterations, quick: dict(
        performance=0.9, aer=next(aers), setup_seconds=0.0, seconds_per_iteration=0.5, iterations=2))
    row = bench_mod.bench_table(["acrobot"], seeds=seeds, log=lambda msg: None).splitlines()[2]
    assert row.rstrip(" |").endswith(cell)


def test_bench_seeds_lists_each_finished_training_of_a_store(tmp_path, capsys, monkeypatch):
    """A table's mean ± sd hides which seed failed: `bench seeds` prints one line per finished training,
    rows in the order they first finished, seeds in order; a failure later retried shows its success only."""
    from ifo.cli import main
    from ifo.sweep import ResultStore

    store = ResultStore(tmp_path / "store")

    def row(name, seed, status="done", performance=None):
        spec = {"table": "6.2", "row": name, "env": "maze10", "seed": seed, "iterations": 40}
        out = {"key": f"{name}-{seed}", "spec": spec, "status": status, "commit": "0123456789ab",
               "driver": {"hostname": "lab-7"}, "machine": {"hostname": "node-2", "cpu_capability": "AVX512"}}
        if name == "BCO(α)":  # a row from before workers reported their machine
            del out["machine"]
        if status == "done":
            out["result"] = {"performance": performance, "aer": performance - 1, "seconds": 151.4}
        if name == "IUPE" and seed == 0:  # learned at iteration 2, dipped at the last: the curve tells
            out["result"]["curve"] = [{"iteration": i + 1, "performance": p}
                                      for i, p in enumerate([-0.1, 1.0] + [0.9] * 10 + [performance])]
        return out

    for r in (row("IUPE", 1, performance=0.25), row("BCO(α)", 0, "failed"), row("IUPE", 0, performance=0.5),
              row("BCO(α)", 0, performance=-0.0867)):
        store.append(r)
    assert main(["bench", "seeds", "--store", str(store.dir)]) == 0
    lines = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| 6.2")]
    assert lines == ["| 6.2 | IUPE | maze10 | 40 | 0 | 0.500 | -0.500 | 0.860 | 1.000 (2) | 151 | 0123456 | node-2 (AVX512) |",
                     "| 6.2 | IUPE | maze10 | 40 | 1 | 0.250 | -0.750 | — | — | 151 | 0123456 | node-2 (AVX512) |",
                     "| 6.2 | BCO(α) | maze10 | 40 | 0 | -0.087 | -1.087 | — | — | 151 | 0123456 | lab-7 |"]
    # a longer training's start against a shorter one's end: P and AER at a chosen iteration, from the curve
    assert main(["bench", "seeds", "--store", str(store.dir), "--at-iteration", "2"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "| P at iteration 2 | AER at iteration 2 |" in out[0] and out[1].count("|---") == 14
    assert [line for line in out if line.startswith("| 6.2 | IUPE")] == [
        "| 6.2 | IUPE | maze10 | 40 | 0 | 0.500 | -0.500 | 1.000 | — | 0.860 | 1.000 (2) | 151 | 0123456 | node-2 (AVX512) |",
        "| 6.2 | IUPE | maze10 | 40 | 1 | 0.250 | -0.750 | — | — | — | — | 151 | 0123456 | node-2 (AVX512) |"]
    assert main(["bench", "seeds", "--store", str(store.dir), "--at-iteration", "0"]) == 2
    assert "counts from 1" in capsys.readouterr().err
    assert main(["bench", "seeds", "--store", str(tmp_path / "nowhere")]) == 2
    assert "no results store" in capsys.readouterr().err
    # a results file lists the same (the shipped assets/resilience/*.jsonl, checkable on a fresh clone)
    assert main(["bench", "seeds", "--store", str(store.path)]) == 0
    assert [line for line in capsys.readouterr().out.splitlines() if line.startswith("| 6.2")] == lines
    assert main(["bench", "seeds"]) == 2
    assert "needs --store" in capsys.readouterr().err
    # a hand-edited or hostile file: rows not shaped as a sweep writes them are skipped, the good row listed
    hostile = tmp_path / "hostile.jsonl"
    hostile.write_text('{"key": "a", "status": "done", "spec": [1]}\n{"key": "b", "status": "done", "result": 5}\n'
                       '{"key": 3, "status": "done", "spec": {}}\n'
                       '{"key": "f", "status": "done", "spec": {"seed": 2, "table": [7], "row": {"x": 1}}}\n'
                       '{"key": "c", "status": "done", "spec": {"seed": "zero"}}\n'
                       '{"key": "d", "status": "done", "spec": {"seed": 1}, "result": [2]}\n'
                       '{"key": "e", "status": "done", "spec": {"seed": 1}, "machine": {"hostname": 7}}\n'
                       '{"key": "g", "status": "done", "spec": {"seed": 3}, "result": {"curve": [1, {"performance": '
                       '"x"}, {"performance": NaN}]}}\n'
                       '[1, 2]\n' + store.path.read_text().splitlines()[-1] + "\n")
    assert main(["bench", "seeds", "--store", str(hostile)]) == 0
    out = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ")][1:]  # under the header
    assert out == ["| [7] | {'x': 1} | — | default | 2 | — | — | — | — | — | ? | ? |",
                   "| — | — | — | default | 1 | — | — | — | — | — | ? | 7 |",
                   "| — | — | — | default | 3 | — | — | — | — | — | ? | ? |", lines[2]]
    import torch

    from ifo.sweep import execute

    monkeypatch.setenv("IFO_TORCH_THREADS", "1")  # execute sets it: restored after the test
    ran = execute(lambda: {"aer": 1.0}, {})  # a worker says which CPU kernels trained its rows
    assert ran["machine"]["cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    # and which processor: two machines with the same kernels trained the same seed to other numbers
    from ifo.sweep import cpu_model, where_trained

    assert ran["machine"].get("cpu_model") == cpu_model()
    assert where_trained({"machine": {"hostname": "node-3", "cpu_model": "AMD EPYC", "cpu_capability": "AVX512"}}) \
        == "node-3 (AMD EPYC, AVX512)"


def test_train_takes_the_same_defaults_as_the_app_and_the_maze_protocol():
    from ifo.cli import build_parser, config_from_args
    from ifo.config import RunConfig

    args = build_parser().parse_args(["train", "--env", "maze5", "--method", "iupe"])
    assert config_from_args(args) == RunConfig(env="maze5", method="iupe").resolved()  # per-env epochs, not 2/10
    args = build_parser().parse_args(["train", "--env", "maze5", "--method", "iupe", "--policy-epochs", "3",
                                      "--maze-eval-layouts", "demonstration", "--deadlock-guard", "true"])
    cfg = config_from_args(args)
    assert (cfg.learner.policy_epochs, cfg.maze_eval_layouts, cfg.deadlock_guard) == (3, "demonstration", True)


def test_every_setting_has_a_flag_generated_from_its_declaration():
    from ifo.cli import build_parser
    from ifo.config import RunConfig
    from ifo.learners import LEARNERS
    from ifo.options import specs

    train = next(a for a in build_parser()._subparsers._group_actions[0].choices.values() if a.prog.endswith("train"))
    flags = {opt for action in train._actions for opt in action.option_strings}
    for cls in [RunConfig] + [learner.Config for learner in LEARNERS.values()]:
        for s in specs(cls):
            assert s.flag in flags, s.flag
            assert s.help  # one plain sentence, shown by --help and the app


def test_train_refuses_to_overwrite_a_run_before_training(tmp_path):
    out = tmp_path / "run"
    assert run_cli("train", "--env", "cartpole", "--method", "bco", "--quiet", "--out", str(out), *FAST).returncode == 0
    before = sorted(p.name for p in out.iterdir())
    res = run_cli("train", "--env", "cartpole", "--method", "bco", "--quiet", "--out", str(out), *FAST)
    assert res.returncode == 2 and "--overwrite" in res.stderr and "iteration" not in res.stdout
    assert sorted(p.name for p in out.iterdir()) == before  # nothing touched
    mine = out / "ckpt-mine"
    mine.mkdir()
    res = run_cli("train", "--env", "cartpole", "--method", "bco", "--quiet", "--out", str(out), "--overwrite", *FAST)
    assert res.returncode == 0, res.stderr
    assert mine.is_dir()  # a user's own folder is never deleted
    a_file = tmp_path / "file"
    a_file.write_text("x")
    res = run_cli("train", "--env", "cartpole", "--method", "bco", "--quiet", "--out", str(a_file / "run"), *FAST)
    assert res.returncode == 2 and "iteration" not in res.stdout and "Traceback" not in res.stderr


def test_bench_seeds_lists_the_seeds_behind_a_shipped_resilience_cell(capsys):
    """REPRODUCTION.md's Chapter 7 numbers are checkable on a fresh clone: the shipped results file lists each
    seed of a 10-seed cell (ILPO on LunarLander with Expert⁵, 40 rounds), and their mean is the one documented."""
    import re

    from ifo.cli import main
    from ifo.reproduce.chapter7 import shipped_results_path

    assert main(["bench", "seeds", "--store", str(shipped_results_path("lunarlander"))]) == 0
    cell = [line.split(" | ") for line in capsys.readouterr().out.splitlines()
            if re.match(r"\| 7\.6 \| ILPO \| lunarlander \| 40 \|", line)]
    assert sorted(int(c[4]) for c in cell) == list(range(10))
    assert round(sum(float(c[6]) for c in cell) / len(cell), 1) == -66.5


def test_bench_recheck_trains_stored_trainings_again_and_says_which_come_back(tmp_path, capsys):
    """Same seed, same numbers, after the fact: `bench recheck` trains the first rounds of a store's trainings
    again with this checkout and compares them round by round with the curves the store kept. A stored curve
    that other code made (here: edited) is named with the round it parts at; a row its table no longer has is
    said, not trained."""
    import json

    from ifo.cli import main
    from ifo.reproduce import reproduce

    store = tmp_path / "table.jsonl"
    reproduce("6.1", seeds=2, envs=["cartpole"], iterations=2, rows=["IUPE"], log=lambda m: None, store=str(store),
              progress=False, eval_episodes=5, expert_episodes=2)
    argv = ["bench", "recheck", "--store", str(store), "--rounds", "1", "--seeds", "2", "--local"]
    assert main(argv) == 0
    out = capsys.readouterr().out
    assert out.count("| 6.1 | IUPE | cartpole |") == 2 and out.count("| 1 | yes |") == 2
    assert "2 of 2 trainings trained again to their stored numbers" in out
    rows = [json.loads(line) for line in store.read_text().splitlines()]
    seed1 = next(r for r in rows if r["spec"]["seed"] == 1)
    stored_aer = seed1["result"]["curve"][0]["aer"]
    seed1["result"]["curve"][0]["aer"] = stored_aer + 1.0  # a row another code made
    gone = json.loads(json.dumps(rows[0]))
    gone["key"], gone["spec"]["row"] = "gone", "Gone"  # a row its table dropped
    store.write_text("".join(json.dumps(r) + "\n" for r in [*rows, gone]))
    before = store.read_bytes()
    assert main(argv + ["--rows", "IUPE,Gone"]) == 0
    out = capsys.readouterr().out
    assert f"| 1 | **no**, from round 1: stored AER {stored_aer + 1.0:.6g}, now {stored_aer:.6g} |" in out
    assert "| Gone | cartpole |" in out and "not rechecked: its table no longer has this row" in out
    assert "1 of 2 trainings trained again" in out
    assert store.read_bytes() == before  # the store is read, never written
    assert main(["bench", "recheck", "--store", str(tmp_path / "nowhere")]) == 2
    assert "needs --store" in capsys.readouterr().err
    assert main(argv[:-1] + ["--rounds", "0"]) == 2
    assert "--rounds must be 1..1000" in capsys.readouterr().err


def test_bench_recheck_leaves_out_a_training_whose_rounds_follow_its_round_count(tmp_path, capsys):
    """CRIL's Eq 8.2 reaches its share limit at the run's last iteration (share_n defaults to the iteration count),
    so a 1-round CRIL is not the start of a 2-round one: recheck says so instead of reporting a false difference,
    and rechecks it when asked for all its rounds or when share_n is fixed."""
    from ifo.cli import main
    from ifo.learners.cril import CRILLearner
    from ifo.reproduce import reproduce

    assert CRILLearner.Config().follows_iteration_count() and not CRILLearner.Config(share_n=5).follows_iteration_count()
    store = tmp_path / "table.jsonl"
    reproduce("8.2", seeds=1, envs=["cartpole"], iterations=2, rows=["CRIL"], log=lambda m: None, store=str(store),
              progress=False, eval_episodes=5)
    argv = ["bench", "recheck", "--store", str(store), "--seeds", "1", "--local"]
    assert main(argv + ["--rounds", "1"]) == 0
    assert "| — | not rechecked: its schedule follows its round count: give --rounds its iterations |" in \
        capsys.readouterr().out
    assert main(argv + ["--rounds", "2"]) == 0
    assert "| 8.2 | CRIL | cartpole |" in (out := capsys.readouterr().out) and "| 2 | yes |" in out
