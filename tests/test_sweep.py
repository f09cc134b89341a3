"""The sweep engine (ifo/sweep.py): the results store, trainings on a local Ray equal to the same trainings
in-process, and an interrupted sweep that resumes without redoing its finished rows.

Ray starts in two tests only (a local instance on 2 CPUs takes 3-40 s to start on a busy machine)."""
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from ifo import sweep
from ifo.reproduce import Row, TABLES, reproduce, row_task, train_row
from ifo.sweep import ResultStore, StoreError, Task, run_sweep

ROOT = Path(__file__).resolve().parents[1]
TINY = {"eval_episodes": 5, "expert_episodes": 2}  # a training of a few seconds


def double(x: int) -> dict:
    return {"y": 2 * x}


def fails(x: int) -> dict:
    raise RuntimeError(f"no {x}")


# ----------------------------------------------------------------------------- the store
def test_the_store_appends_rows_reads_them_back_and_keeps_the_latest_success(tmp_path):
    store = ResultStore(tmp_path / "s")
    assert store.rows() == [] and store.done() == {}
    store.append({"key": "a", "status": "failed", "error": "boom"})
    store.append({"key": "a", "status": "done", "result": {"y": 1}})
    store.append({"key": "a", "status": "failed", "error": "later"})  # a later failure does not hide a success
    store.append({"key": "b", "status": "failed", "error": "x"})
    assert store.done() == {"a": {"key": "a", "status": "done", "result": {"y": 1}}}
    assert store.latest()["b"]["error"] == "x"
    with open(store.path, "a") as f:  # a writer killed mid-line
        f.write('{"key": "c", "status": "do')
    store.append({"key": "d", "status": "done", "result": {}})  # starts on a fresh line
    assert [r["key"] for r in store.rows()] == ["a", "a", "a", "b", "d"]
    assert (tmp_path / "s" / "results.lock").exists()


def test_the_store_refuses_oversized_files_and_rows(tmp_path, monkeypatch):
    store = ResultStore(tmp_path)
    store.append({"key": "a", "status": "done", "result": {"v": [1.0] * 100}})
    monkeypatch.setattr(sweep, "MAX_STORE_BYTES", 100)
    with pytest.raises(StoreError, match="over the limit"):
        store.rows()
    monkeypatch.setattr(sweep, "MAX_ROW_BYTES", 50)
    with pytest.raises(StoreError, match="over the store's limit"):
        store.append({"key": "b", "status": "done", "result": {"v": [1.0] * 100}})


def test_in_process_sweeps_skip_what_is_done_and_retry_what_failed(tmp_path):
    store = ResultStore(tmp_path)
    tasks = [Task({"x": x}, double, {"x": x}) for x in range(3)] + [Task({"x": 9}, fails, {"x": 9})]
    rows, report = run_sweep(tasks, store, local=True, progress=False)
    assert (report.done, report.failed, report.skipped) == (3, 1, 0)
    assert sorted(r["result"]["y"] for r in rows.values()) == [0, 2, 4]
    row = next(iter(rows.values()))
    assert row["machine"]["hostname"] and row["machine"]["cpus"] >= 1 and "commit" in row and "spec" in row
    failed = next(r for r in store.rows() if r["status"] == "failed")
    assert "RuntimeError: no 9" in failed["error"]
    rows, report = run_sweep(tasks, store, local=True, progress=False)  # a rerun: only the failure again
    assert (report.done, report.failed, report.skipped) == (0, 1, 3) and len(rows) == 3


def edits_the_code(checkout: str) -> dict:
    (Path(checkout) / "ifo" / "lesson.py").write_text("CHANGED = True\n")
    return {"y": 1}


def test_a_training_whose_code_changed_during_the_sweep_says_so(tmp_path, monkeypatch):
    """Workers import `ifo` from the checkout as they start, so an edit made while a long sweep runs reaches
    its later trainings under the commit recorded at the start (one possible reason why Tables 7.5-7.6's 40-round
    IUPE trainings do not train again to their numbers with their commit). Their rows, the report and
    `bench seeds` say so."""
    checkout = tmp_path / "checkout"
    (checkout / "ifo").mkdir(parents=True)
    (checkout / "ifo" / "lesson.py").write_text("CHANGED = False\n")
    monkeypatch.setattr(sweep, "ROOT", checkout)
    tasks = [Task({"x": 0}, double, {"x": 0}), Task({"x": 1}, edits_the_code, {"checkout": str(checkout)}),
             Task({"x": 2}, double, {"x": 2})]
    rows, report = run_sweep(tasks, ResultStore(tmp_path / "s"), local=True, progress=False)
    assert {r["spec"]["x"]: r["code_changed"] for r in rows.values()} == {0: False, 1: True, 2: True}
    assert report.code_changed == 2 and "(2 on code that changed during the sweep" in report.line()
    assert sweep.seeds_table(rows.values()).count("(code changed during the sweep)") == 2
    rows, report = run_sweep(tasks + [Task({"x": 3}, double, {"x": 3})], ResultStore(tmp_path / "s"), local=True,
                             progress=False)  # a new sweep starts from the code as it is now
    assert rows[Task({"x": 3}, double).key]["code_changed"] is True  # this process trained from the old code
    assert "code that changed" in report.line()


def test_task_keys_name_the_training_not_the_order_of_its_settings():
    assert Task({"a": 1, "b": [1, 2]}, double).key == Task({"b": [1, 2], "a": 1}, double).key
    assert Task({"a": 1}, double).key != Task({"a": 2}, double).key


# ----------------------------------------------------------------------------- on a local Ray
def _tiny_tasks():
    table = TABLES["6.1"]
    rows = [Row("BC", "bc"), Row("BCO(α)", "bco-alpha", {"pre_size": 400})]
    return [row_task(table, row, "cartpole", seed, 1, TINY) for row in rows for seed in (0, 1)]


def test_a_sweep_on_a_local_ray_gives_the_same_results_as_in_process(tmp_path):
    tasks = _tiny_tasks()
    assert len({t.key for t in tasks}) == 4  # 2 configurations x 2 seeds
    on_ray, report = run_sweep(tasks, ResultStore(tmp_path / "ray"), progress=False)
    assert report.mode.startswith("local Ray") and (report.done, report.failed) == (4, 0), report
    here, _ = run_sweep(tasks, ResultStore(tmp_path / "here"), local=True, progress=False)
    assert set(on_ray) == set(here) == {t.key for t in tasks}
    for key in here:
        a, b = on_ray[key]["result"], here[key]["result"]
        assert a["aer"] == b["aer"] and a["performance"] == b["performance"]
        assert a["record"]["evaluation"]["returns"] == b["record"]["evaluation"]["returns"]
        assert a["curve"] == b["curve"]
        assert on_ray[key]["machine"]["hostname"] == here[key]["machine"]["hostname"]
        assert on_ray[key]["code_changed"] is here[key]["code_changed"] is False  # the workers ran this checkout
    direct = train_row(Row("BC", "bc"), "cartpole", 1, 1, dict(TINY))  # and the same as a plain call
    key = next(t.key for t in tasks if t.spec["row"] == "BC" and t.spec["seed"] == 1)
    assert direct["aer"] == here[key]["result"]["aer"]


DRIVER = textwrap.dedent("""
    import sys, time
    from pathlib import Path
    from ifo.sweep import ResultStore, Task, run_sweep

    MARKS = Path(sys.argv[2])

    def work(x, delay):
        with open(MARKS / f"{x}.{time.time_ns()}", "w"):
            pass
        time.sleep(delay)
        return {"y": x * x}

    delay = float(sys.argv[3])
    tasks = [Task({"x": x}, work, {"x": x, "delay": delay if x >= 2 else 0.1}) for x in range(6)]
    rows, report = run_sweep(tasks, ResultStore(sys.argv[1]), local=sys.argv[4] == "local", progress=False)
    print(report.line(), flush=True)
""")


def _ctrl_c_reaches_it():
    # as in a terminal: a shell without job control starts a background job (`make test &`) with SIGINT
    # ignored, and the ignore is inherited down to this driver, which then never sees the Ctrl-C
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def test_an_interrupted_sweep_resumes_without_redoing_finished_rows(tmp_path):
    store, marks = tmp_path / "store", tmp_path / "marks"
    marks.mkdir()
    script = tmp_path / "driver.py"
    script.write_text(DRIVER)
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.Popen([sys.executable, str(script), str(store), str(marks), "600", "ray"], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=_ctrl_c_reaches_it)
    try:
        deadline = time.monotonic() + 240
        while len(ResultStore(store).done()) < 2:  # tasks 0 and 1 are quick; 2.. would take 10 minutes
            assert proc.poll() is None, proc.communicate()
            assert time.monotonic() < deadline, "the sweep did not finish its first trainings in 4 minutes"
            time.sleep(0.5)
        while len(list(marks.iterdir())) < 4:  # two long trainings in flight
            assert time.monotonic() < deadline
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)  # Ctrl-C: the trainings in flight are lost, the finished ones kept
        proc.wait(120)  # and the driver stops (ray.shutdown() included) instead of waiting for them
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    done_before = ResultStore(store).done()
    assert {r["spec"]["x"] for r in done_before.values()} == {0, 1}
    started = sorted(p.name.split(".")[0] for p in marks.iterdir())
    assert started.count("0") == started.count("1") == 1
    # resume (in this process, without the long sleeps): only the four unfinished trainings run
    res = subprocess.run([sys.executable, str(script), str(store), str(marks), "0", "local"], env=env,
                         capture_output=True, text=True, timeout=240)
    assert res.returncode == 0, res.stderr
    assert "4 trainings done, 0 failed, 2 already in the store" in res.stdout
    started = sorted(p.name.split(".")[0] for p in marks.iterdir())
    assert started.count("0") == started.count("1") == 1  # the finished rows were not redone
    assert all(started.count(str(x)) == 2 for x in (2, 3)) and all(started.count(str(x)) == 1 for x in (4, 5))
    assert sorted(r["result"]["y"] for r in ResultStore(store).done().values()) == [0, 1, 4, 9, 16, 25]


# ----------------------------------------------------------------------------- reproduce() through the engine
def test_reproduce_renders_its_table_from_the_store_and_resumes_from_it(tmp_path):
    store = tmp_path / "store"
    kw = dict(log=lambda m: None, store=str(store), progress=False, **TINY)
    first = reproduce("6.1", seeds=1, envs=["cartpole"], iterations=1, rows=["Random", "BC"], **kw)
    rows = [json.loads(line) for line in (store / "results.jsonl").read_text().splitlines()]
    assert sorted(r["spec"]["row"] for r in rows) == ["BC", "Random"]
    said = []
    again = reproduce("6.1", seeds=1, envs=["cartpole"], iterations=1, rows=["Random", "BC"],
                      **{**kw, "log": said.append})
    assert len((store / "results.jsonl").read_text().splitlines()) == 2  # nothing retrained
    assert any("nothing trained now: all 2 results were already in the store" in line for line in said), said
    strip = lambda text: [line.rsplit("|", 3)[0] for line in text.splitlines()]  # noqa: E731 - seconds aside
    assert strip(first) == strip(again)
    assert "| BC | cartpole |" in first and first.startswith("## Table 6.1")
    # rendering one row from a store that holds more: nothing counted as failed
    only_bc = reproduce("6.1", seeds=1, envs=["cartpole"], iterations=1, rows=["BC"], **{**kw, "train": False})
    assert "failed" not in only_bc and "| BC | cartpole |" in only_bc


def test_a_table_kept_in_one_results_file_renders_again_from_a_copy_of_it(tmp_path):
    """docs/reproduction ships a table's results file beside it: the documented command, run on a fresh
    clone with --store that file, renders the table without training anything."""
    kept = tmp_path / "work" / "table-6.1.jsonl"
    kw = dict(log=lambda m: None, progress=False, **TINY)
    first = reproduce("6.1", seeds=2, envs=["cartpole"], iterations=1, rows=["BC"], store=str(kept), **kw)
    assert len(kept.read_text().splitlines()) == 2 and (kept.parent / ".table-6.1.jsonl.lock").exists()
    assert [p.name for p in kept.parent.iterdir() if not p.name.startswith(".")] == ["table-6.1.jsonl"]
    shipped = tmp_path / "clone" / "table-6.1.jsonl"
    shipped.parent.mkdir()
    shipped.write_bytes(kept.read_bytes())
    again = reproduce("6.1", seeds=2, envs=["cartpole"], iterations=1, rows=["BC"], store=str(shipped), **kw)
    assert shipped.read_bytes() == kept.read_bytes()  # nothing trained, nothing appended
    strip = lambda text: [line.rsplit("|", 3)[0] for line in text.splitlines()]  # noqa: E731 - seconds aside
    assert strip(first) == strip(again) and "| BC | cartpole |" in again
    # a folder that is not there yet stays a folder store, whatever its name
    assert ResultStore.at(tmp_path / "new-store").path == tmp_path / "new-store" / "results.jsonl"


def test_the_command_line_passes_the_sweep_options(monkeypatch, capsys, tmp_path):
    import ifo.reproduce as reproduce_mod
    from ifo.cli import main

    seen = {}

    def fake(table_id, seeds, envs, iterations, rows=None, **extra):
        seen.update(extra=extra, sweep=dict(reproduce_mod._SWEEP_DEFAULTS))
        return "(table)"

    monkeypatch.setattr(reproduce_mod, "reproduce", fake)
    assert main(["bench", "reproduce", "--table", "7.1", "--store", str(tmp_path), "--address", "ray://h:10001"]) == 0
    assert seen == {"extra": {}, "sweep": {"store": str(tmp_path), "address": "ray://h:10001", "ray": True}}
    assert main(["bench", "reproduce", "--table", "7.1", "--local"]) == 0
    assert seen["sweep"] == {"store": None, "address": None, "ray": False}
    assert reproduce_mod._SWEEP_DEFAULTS == {}  # only for the command's own call
    assert main(["bench", "reproduce", "--table", "7.1", "--local", "--address", "ray://h:1"]) == 2
    assert "cannot go with --address" in capsys.readouterr().err


def test_the_store_keeps_what_table_8_3_needs_from_the_records():
    """The store drops per-iteration records; Table 8.3's samples-to-best still reads the same from the curve."""
    from ifo.reproduce import _slim
    from ifo.reproduce.chapter8 import samples_to_best

    records = [{"iteration": i, "evaluation": {"aer": aer, "performance": None, "fidelity": None},
                "samples": {"environment_steps": 100 * i, "expert_samples": 50}}
               for i, aer in enumerate([20.0, 480.0, 500.0, 500.0, 490.0], start=1)]
    result = {"aer": 490.0, "records": records}
    slim = _slim(result)
    assert "records" not in slim and samples_to_best(result) == samples_to_best(slim) == 350
    assert samples_to_best(_slim({"aer": 1.0, "records": [{"iteration": 1, "evaluation": {"aer": 1.0}}]})) is None


def test_the_sweep_benchmark_refuses_an_impossible_size(capsys):
    from ifo.cli import main

    assert main(["bench", "sweep", "--trainings", "1"]) == 2
    assert "--trainings must be 2..10000" in capsys.readouterr().err


def test_the_sweep_benchmark_kills_the_whole_process_tree():
    """The resume measurement kills the sweep's driver and every process below it (its Ray workers)."""
    from ifo.bench import _descendants

    parent = subprocess.Popen([sys.executable, "-c", "import subprocess, sys, time; "
                               "subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)']); time.sleep(60)"])
    try:
        deadline = time.monotonic() + 30
        while not _descendants(parent.pid):
            assert time.monotonic() < deadline
            time.sleep(0.1)
        [child] = _descendants(parent.pid)
        assert child != parent.pid and Path(f"/proc/{child}").exists()
    finally:
        for pid in _descendants(parent.pid):
            os.kill(pid, signal.SIGKILL)
        parent.kill()
        parent.wait()
