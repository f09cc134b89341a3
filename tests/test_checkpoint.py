"""ifo.checkpoint: the run folder's layout, its lock, and saved work that survives concurrent
writers, readers during saves, kill -9, damaged files and cut-short copies.

Independent of Run: synthetic configs, records and arrays (tests/checkpoint_worker.py). The
concurrency tests print what they measured (run with -s to see it).
"""
import errno
import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from filelock import FileLock, Timeout

from checkpoint_worker import consistent, payload
from ifo import checkpoint as C

ROOT = Path(__file__).resolve().parents[1]
WORKER = Path(__file__).with_name("checkpoint_worker.py")
SHIPPED = ROOT / "assets" / "runs"


def save(run, i, parent=None, **kw):
    return C.save(run, **payload(i), parent=parent, **kw)


def leftovers(run: Path) -> list[str]:
    return sorted(n for n in os.listdir(run) if C.LEFTOVER_RE.fullmatch(n))


def checkpoints(run: Path) -> list[str]:
    return sorted(n for n in os.listdir(run) if C.CKPT_RE.fullmatch(n))


def assert_sound(run: Path, most: int = 2) -> C.Checkpoint:
    """LATEST valid, the run loads with every part from one save, at most `most` checkpoints
    (2 after a save: the new one and the last good one)."""
    ckpt = C.load(run)
    assert consistent(ckpt), ckpt.meta
    assert C.latest(run) == ckpt.name and ckpt.name in checkpoints(run) and len(checkpoints(run)) <= most
    return ckpt


# ----------------------------------------------------------------------------- layout and the optimistic check
def test_save_load_and_the_layout(tmp_path):
    run = tmp_path / "run"
    a = save(run, 1)
    b = save(run, 2, parent=a)
    assert C.latest(run) == b and checkpoints(run) == sorted([a, b])  # the previous one is kept
    assert b.startswith("ckpt-00002-")
    ckpt = C.load(run)
    assert (ckpt.name, ckpt.config, ckpt.records) == (b, payload(2)["config"], payload(2)["records"])
    assert np.array_equal(ckpt.arrays["w"], payload(2)["arrays"]["w"]) and ckpt.demos is None
    assert ckpt.meta["iteration"] == 2 and ckpt.meta["checkpoint"]["parent"] == a
    assert ckpt.meta["checkpoint"]["format"] == C.FORMAT
    assert sorted(os.listdir(run / b)) == ["config.json", "meta.json", "records.json", "state.npz"]
    assert json.loads((run / "config.json").read_text()) == ckpt.config  # the copy for people
    c = save(run, 3, parent=b)
    assert checkpoints(run) == sorted([b, c])  # the one before the previous is gone
    assert set(os.listdir(run)) == {".lock", "LATEST", "config.json", b, c}
    assert C.read_records(run) == payload(3)["records"] and C.read_config(run) == payload(3)["config"]
    assert C.load(run, with_arrays=False).arrays is None
    info = C.inspect(run)
    assert (info.ok, info.checkpoint, info.iterations_done, info.label) == (True, c, 3, "run")
    assert info.last == {"aer": 2.0, "performance": None, "goal_rate": 0.5}


def test_a_second_writer_gets_run_changed_and_nothing_is_lost(tmp_path):
    run = tmp_path / "run"
    a = save(run, 1)
    with pytest.raises(C.RunChanged, match="another session saved this run"):
        save(run, 5)  # a new run (no parent) over a saved one
    b = save(run, 2, parent=a)
    with pytest.raises(C.RunChanged) as err:
        save(run, 9, parent=a)  # the other tab, still at a
    assert err.value.reason == "another session saved this run meanwhile"
    assert C.latest(run) == b and C.load(run).meta["iteration"] == 2
    c = save(run, 9, parent=a, overwrite=True)
    assert C.latest(run) == c and b in checkpoints(run)  # overwrite still keeps the last good one
    (run / "LATEST").write_text("garbage")
    with pytest.raises(C.DamagedRun, match="not saving over it"):
        save(run, 10, parent=c)
    d = save(run, 10, parent=c, overwrite=True)
    assert_sound(run).name == d


def test_saves_refuse_bad_places_and_unreadable_sizes(tmp_path, monkeypatch):
    (tmp_path / "file").write_text("x")
    with pytest.raises(C.CheckpointError, match="is a file, not a folder"):
        save(tmp_path / "file", 1)
    with pytest.raises(C.CheckpointError, match=r"lies under .*file, which is a file"):
        save(tmp_path / "file" / "run", 1)
    monkeypatch.setattr(C, "MAX_RECORDS_BYTES", 100)
    with pytest.raises(C.CheckpointError, match="the records would be .* over the 100 bytes a checkpoint may hold"):
        save(tmp_path / "run", 5)
    with pytest.raises(C.CheckpointError, match="no pickles"):
        C.save(tmp_path / "run", config={}, records=[], arrays={"x": np.array([{}], dtype=object)}, meta={},
               parent=None)
    assert not (tmp_path / "run" / "LATEST").exists()


def test_the_shipped_runs_in_the_old_layout_load(tmp_path):
    runs = sorted(p for p in SHIPPED.iterdir() if p.is_dir())
    assert len(runs) >= 7
    for run in runs:
        ckpt = C.load(run)
        assert not (ckpt.path / "config.json").exists()  # format 1: config only at the top
        assert ckpt.config == json.loads((run / "config.json").read_text())
        assert len(ckpt.records) == ckpt.meta["iteration"] and ckpt.arrays
        info = C.inspect(run)
        assert info.ok and info.iterations_done == len(ckpt.records) and info.label != run.name
    # a copy has the current layout, and loads the same
    C.copy_run(SHIPPED / "cartpole-bc", tmp_path / "copy")
    old, new = C.load(SHIPPED / "cartpole-bc"), C.load(tmp_path / "copy")
    assert (new.path / "config.json").exists() and new.config == old.config and new.records == old.records
    assert all(np.array_equal(old.arrays[k], new.arrays[k]) for k in old.arrays)
    assert C.read_label(tmp_path / "copy") == C.read_label(SHIPPED / "cartpole-bc")
    assert not [n for n in os.listdir(tmp_path) if n.startswith(".")]
    with pytest.raises(C.CheckpointError, match="already exists"):
        C.copy_run(SHIPPED / "cartpole-bc", tmp_path / "copy")


# ----------------------------------------------------------------------------- the lock
def test_the_lock_excludes_another_thread_of_the_same_process(tmp_path):
    """filelock 4.3.1, a new FileLock per operation: a second thread waits like a second process."""
    run = tmp_path / "run"
    a = save(run, 1)
    held, release = threading.Event(), threading.Event()

    def hold():
        with FileLock(run / ".lock", timeout=1):
            held.set()
            release.wait(10)

    t = threading.Thread(target=hold)
    t.start()
    held.wait(5)
    try:
        with pytest.raises(Timeout):
            FileLock(run / ".lock", timeout=0.1).acquire()
        start = time.monotonic()
        with pytest.raises(C.RunBusy, match=r"another session is saving this run \(waited 0.3 s\)"):
            save(run, 2, parent=a, lock_timeout=0.3)
        assert time.monotonic() - start >= 0.3
        with pytest.raises(C.RunBusy):
            C.remove(run, lock_timeout=0.1)
        with pytest.raises(C.RunBusy):
            C.write_label(run, "x", lock_timeout=0.1)
    finally:
        release.set()
        t.join()
    assert C.latest(run) == a and save(run, 2, parent=a)


def _thread_writers(run: Path, saves: int, overwrite: bool, counts: dict, worker: int) -> None:
    parent, i = None, 0
    for _ in range(saves):
        i += 1
        try:
            parent = save(run, i, parent=parent, overwrite=overwrite, lock_timeout=5)
            counts["ok"] += 1
        except C.RunChanged:
            counts["changed"] += 1
            ckpt = C.load(run, with_arrays=False)
            parent, i = ckpt.name, len(ckpt.records)
        except C.RunBusy:
            counts["busy"] += 1


def test_two_writer_threads_per_folder_lose_nothing(tmp_path):
    pairs, saves = 20, 6
    counts = [{"ok": 0, "changed": 0, "busy": 0} for _ in range(2)]
    lost = 0
    for k in range(pairs):
        run = tmp_path / f"run{k}"
        threads = [threading.Thread(target=_thread_writers, args=(run, saves, False, counts[w], w)) for w in (0, 1)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        try:
            assert_sound(run)
            assert not leftovers(run)
        except (C.CheckpointError, AssertionError):
            lost += 1
    total = {k: counts[0][k] + counts[1][k] for k in counts[0]}
    print(f"\n{pairs} thread pairs x {saves} saves each: {total}; lost runs: {lost}")
    assert lost == 0 and sum(total.values()) == 2 * pairs * saves and total["changed"] > 0


def test_a_reader_during_many_saves_never_sees_a_bad_latest_or_a_missing_checkpoint(tmp_path):
    """Two threads save with overwrite (every save succeeds, and deletes what is older than the
    previous one) while a third reads LATEST and loads the run as fast as it can."""
    run = tmp_path / "run"
    save(run, 1)
    stop, problems, reads = threading.Event(), [], [0, 0]
    counts = [{"ok": 0, "changed": 0, "busy": 0} for _ in range(2)]

    def reader():
        while not stop.is_set():
            try:
                name = C.latest(run)
                reads[0] += 1
                ckpt = C.load(run)
                if not consistent(ckpt):
                    problems.append(f"mixed checkpoint {ckpt.name}")
                reads[1] += 1
                assert C.CKPT_RE.fullmatch(name)
            except Exception as e:  # noqa: BLE001 - any failure is what we count
                problems.append(repr(e))

    r = threading.Thread(target=reader)
    r.start()
    writers = [threading.Thread(target=_thread_writers, args=(run, 60, True, counts[w], w)) for w in (0, 1)]
    for t in writers:
        t.start()
    for t in writers:
        t.join()
    stop.set()
    r.join()
    print(f"\nreader during {counts[0]['ok'] + counts[1]['ok']} overwriting saves: {reads[0]} LATEST reads, "
          f"{reads[1]} full loads, {len(problems)} problems")
    assert not problems, problems[:3]
    assert counts[0]["ok"] + counts[1]["ok"] == 120 and reads[1] > 20
    assert_sound(run)


def test_two_writer_processes_per_folder_lose_nothing(tmp_path):
    folders, saves = 40, 6
    procs = [subprocess.Popen([sys.executable, str(WORKER), "pairs", str(tmp_path), str(folders), str(saves), str(w), "0"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for w in (0, 1)]
    outs = [p.communicate(timeout=180) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], [o[1][-2000:] for o in outs]
    counts = [json.loads(o[0]) for o in outs]
    total = {k: counts[0][k] + counts[1][k] for k in counts[0]}
    lost = 0
    for k in range(folders):
        run = tmp_path / f"run{k:03d}"
        try:
            assert_sound(run)
            assert not leftovers(run)
        except (C.CheckpointError, AssertionError):
            lost += 1
    print(f"\n{folders} process pairs x {saves} saves each: {total}; lost runs: {lost}")
    assert lost == 0 and sum(total.values()) == 2 * folders * saves and total["changed"] > 0


def test_kill_9_in_the_middle_of_saves_never_breaks_the_run(tmp_path):
    run = tmp_path / "run"
    save(run, 1)
    rng = random.Random(0)
    kills, seen_leftovers, extra, saves_between = 20, 0, 0, []
    for _ in range(kills):
        before = C.load(run, with_arrays=False).meta["iteration"]
        p = subprocess.Popen([sys.executable, str(WORKER), "loop", str(run)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
        assert p.stdout.readline().strip() == "go", p.stderr.read()
        time.sleep(rng.uniform(0.0, 0.25))
        p.send_signal(signal.SIGKILL)
        p.wait(10)
        p.stdout.close()
        p.stderr.close()
        ckpt = assert_sound(run, most=3)  # loads, LATEST valid, nothing mixed (killed before its tidy-up: 3)
        saves_between.append(ckpt.meta["iteration"] - before)
        seen_leftovers += bool(leftovers(run))
        extra += len(checkpoints(run)) > 2
        name = C.save(run, **payload(ckpt.meta["iteration"] + 1), parent=ckpt.name, lock_timeout=2)
        assert not leftovers(run), leftovers(run)  # the next save cleans what the kill left
        assert C.latest(run) == name and len(checkpoints(run)) == 2
    print(f"\n{kills} kill -9 during saves ({sum(saves_between)} saves completed in between): the run loaded "
          f"every time; {seen_leftovers} kills left a .partial/.tmp and {extra} a third checkpoint, "
          "all removed by the next save")
    assert_sound(run)


# ----------------------------------------------------------------------------- damaged runs
def _other_run(tmp_path: Path) -> str:
    return save(tmp_path / "other", 1)


def _state_claiming_huge_array(path: Path) -> None:
    header = np.lib.format.header_data_from_array_1_0(np.zeros(1))
    header["shape"] = (10**12,)
    import io
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, header)
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("w.npy", buf.getvalue() + b"\0" * 64)


DAMAGE = {
    "latest-parent": (lambda run, n, o: (run / "LATEST").write_text(f"../other/{o}"), "LATEST does not name"),
    "latest-absolute": (lambda run, n, o: (run / "LATEST").write_text(str(run.parent / "other" / o)),
                        "LATEST does not name"),
    "latest-slash": (lambda run, n, o: (run / "LATEST").write_text(f"{n}/../../other/{o}"), "LATEST does not name"),
    "latest-binary": (lambda run, n, o: (run / "LATEST").write_bytes(b"\xff\xfe\0garbage"), "LATEST does not name"),
    "latest-empty": (lambda run, n, o: (run / "LATEST").write_text(""), "LATEST does not name"),
    "latest-huge": (lambda run, n, o: (run / "LATEST").write_text("x" * 5000), "LATEST is 5,000 bytes, over"),
    "latest-missing-ckpt": (lambda run, n, o: (run / "LATEST").write_text("ckpt-00009-00000000"),
                            "LATEST names ckpt-00009-00000000, which is missing"),
    "latest-link": (lambda run, n, o: ((run / "LATEST").write_text("ckpt-00009-00000000"),
                                       (run / "ckpt-00009-00000000").symlink_to(run.parent / "other" / o)),
                    "which is a link"),
    "records-json": (lambda run, n, o: (run / n / "records.json").write_text("[{not json"),
                     "records.json is not valid JSON"),
    "records-kind": (lambda run, n, o: (run / n / "records.json").write_text('{"a": 1}'),
                     "records.json holds a dict, not a list"),
    "records-items": (lambda run, n, o: (run / n / "records.json").write_text("[1, 2]"), "is not a list of records"),
    "records-link": (lambda run, n, o: ((run / n / "records.json").unlink(),
                                        (run / n / "records.json").symlink_to("/etc/hostname")),
                     "records.json is a link"),
    "records-missing": (lambda run, n, o: (run / n / "records.json").unlink(), "records.json is missing"),
    "meta-json": (lambda run, n, o: (run / n / "meta.json").write_text("nope"), "meta.json is not valid JSON"),
    "config-json": (lambda run, n, o: (run / n / "config.json").write_text("{"), "config.json is not valid JSON"),
    "config-missing": (lambda run, n, o: (run / n / "config.json").unlink(), "config.json is missing"),
    "state-truncated": (lambda run, n, o: (run / n / "state.npz").write_bytes((run / n / "state.npz").read_bytes()[:100]),
                        "state.npz is not a readable array archive"),
    "state-bomb": (lambda run, n, o: _state_claiming_huge_array(run / n / "state.npz"), "once decompressed"),
}


@pytest.mark.parametrize("case", list(DAMAGE))
def test_damaged_runs_give_clear_errors_are_listed_damaged_and_can_be_removed(tmp_path, case):
    damage, message = DAMAGE[case]
    other = _other_run(tmp_path)
    run = tmp_path / "run"
    name = save(run, 2)
    C.write_label(run, "My run")
    damage(run, name, other)
    with pytest.raises(C.DamagedRun) as err:
        C.load(run)
    assert message in str(err.value) and message in err.value.reason
    assert "\n" not in str(err.value) and str(run) in str(err.value) and str(run) not in err.value.reason
    info = C.inspect(run)
    if case != "state-bomb":  # listings check the ZIP directory only; the per-array header check is load's
        assert not info.ok and message in info.damaged, info
    assert info.label == "My run" and info.config.get("env") == "cartpole"
    C.remove(run)
    assert not run.exists() and not [n for n in os.listdir(tmp_path) if n.startswith(".")]
    assert C.load(tmp_path / "other").name == other  # never touched


def test_oversize_files_are_refused_before_they_are_read(tmp_path, monkeypatch):
    run = tmp_path / "run"
    save(run, 50)
    size = (run / C.latest(run) / "records.json").stat().st_size
    monkeypatch.setattr(C, "MAX_RECORDS_BYTES", size - 1)
    with pytest.raises(C.DamagedRun, match=rf"records.json is {size:,} bytes, over the {size - 1:,} bytes limit"):
        C.read_records(run)
    assert "over the" in C.inspect(run).damaged
    monkeypatch.setattr(C, "MAX_RECORDS_BYTES", 1 << 20)
    monkeypatch.setattr(C, "MAX_STATE_BYTES", 1000)
    with pytest.raises(C.DamagedRun, match="state.npz is .* over the 1,000 bytes limit"):
        C.load(run)


def test_a_corrupt_label_shows_the_folder_name_and_a_missing_latest_is_damaged(tmp_path):
    run = tmp_path / "run"
    save(run, 1)
    (run / "label.json").write_text("{broken")
    with pytest.raises(C.DamagedRun, match="label.json is not valid JSON"):
        C.read_label(run)
    info = C.inspect(run)
    assert info.ok and info.label == "run"
    C.write_label(run, "kept", replace=False)  # a damaged label is replaced even then
    assert C.read_label(run) == "kept"
    C.write_label(run, "other", replace=False)
    assert C.read_label(run) == "kept"
    (run / "LATEST").unlink()
    with pytest.raises(C.NoRun):
        C.load(run)
    assert C.inspect(run).damaged == "LATEST is missing: no checkpoint is marked as the current one"
    with pytest.raises(FileNotFoundError):  # NoRun is one
        C.latest(tmp_path / "nothing")
    with pytest.raises(C.NoRun):
        C.inspect(tmp_path / "nothing")
    C.remove(run)
    assert not run.exists()


def test_remove_refuses_folders_that_hold_no_run(tmp_path):
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine" / "notes.txt").write_text("keep me")
    with pytest.raises(C.NoRun):
        C.remove(tmp_path / "mine")
    with pytest.raises(C.NoRun):
        C.remove(tmp_path / "missing")
    assert (tmp_path / "mine" / "notes.txt").read_text() == "keep me"


# ----------------------------------------------------------------------------- leftovers and user folders
def test_the_next_save_removes_what_crashes_left_and_nothing_else(tmp_path):
    run = tmp_path / "run"
    a = save(run, 1)
    (run / ".ckpt-00003-abcdef12.partial").mkdir()
    (run / ".ckpt-00003-abcdef12.partial" / "state.npz").write_bytes(b"half")
    (run / ".ckpt-00001-0badc0de.removing").mkdir()
    (run / ".LATEST.abcd1234.tmp").write_text("ckpt-")
    (run / ".demos.npz.x_y1.tmp").write_bytes(b"half")
    (run / ".my-notes").write_text("mine")
    save(run, 2, parent=a)
    assert leftovers(run) == [] and (run / ".my-notes").read_text() == "mine"


def test_a_users_own_folders_inside_a_run_are_never_deleted(tmp_path):
    run = tmp_path / "run"
    parent = save(run, 1)
    (run / "ckpt-mine").mkdir()
    (run / "ckpt-mine" / "notes.txt").write_text("mine")
    (run / "ckpt-00001-deadbeef").mkdir()  # our name, not our meta.json
    (run / "ckpt-00001-deadbeef" / "data.csv").write_text("1,2")
    (run / "ckpt-00002-cafebabe").mkdir()
    (run / "ckpt-00002-cafebabe" / "meta.json").write_text('["not ours"]')
    for i in range(2, 6):
        parent = save(run, i, parent=parent)
    assert (run / "ckpt-mine" / "notes.txt").read_text() == "mine"
    assert (run / "ckpt-00001-deadbeef" / "data.csv").read_text() == "1,2"
    assert (run / "ckpt-00002-cafebabe" / "meta.json").exists()
    assert len([n for n in checkpoints(run) if C._is_ours(run / n)]) == 2


# ----------------------------------------------------------------------------- demonstrations
def test_demos_are_copied_atomically_and_a_cut_short_copy_is_repaired(tmp_path, monkeypatch):
    source = tmp_path / "upload.npz"
    source.write_bytes(os.urandom(300_000))
    run = tmp_path / "run"
    config = {**payload(1)["config"], "demos": str(source)}

    def save_demos(i, parent):
        return C.save(run, **{**payload(i), "config": config}, parent=parent, demos_source=source)

    a = save_demos(1, None)
    assert (run / "demos.npz").read_bytes() == source.read_bytes()
    ckpt = C.load(run)
    assert ckpt.demos == run / "demos.npz" and ckpt.meta["checkpoint"]["demos"]["size"] == 300_000

    # the disk fills up in the middle of copying new demonstrations: the save fails, the run still loads
    source.write_bytes(os.urandom(400_000))
    real = C._hash_copy

    def disk_full(src, dst=None):
        if dst is not None:
            dst.write(src.read(100_000))
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(src, dst)

    monkeypatch.setattr(C, "_hash_copy", disk_full)
    with pytest.raises(OSError, match="No space left"):
        save_demos(2, a)
    assert C.latest(run) == a and C.load(run).name == a and leftovers(run) == []
    assert (run / "demos.npz").stat().st_size == 300_000  # the old copy, whole
    monkeypatch.setattr(C, "_hash_copy", real)

    # a copy cut short by an older version (not atomic): the run says so; the next save repairs it
    (run / "demos.npz").write_bytes(source.read_bytes()[:1000])
    with pytest.raises(C.DamagedRun, match="demos.npz is 1,000 bytes, not the 300,000 its checkpoint recorded"):
        C.load(run)
    assert "demos.npz is 1,000 bytes" in C.inspect(run).damaged
    b = save_demos(2, a)
    assert (run / "demos.npz").read_bytes() == source.read_bytes() and C.load(run).name == b

    # the upload is deleted meanwhile: the run's own intact copy is enough
    source.unlink()
    c = save_demos(3, b)
    assert C.load(run).name == c
    # a loaded run's demos are the run's own copy: saving copies nothing
    C.save(run, **{**payload(4), "config": config}, parent=c, demos_source=run / "demos.npz")
    assert C.load(run).meta["checkpoint"]["demos"] == C.load(run, with_arrays=False).meta["checkpoint"]["demos"]
    (run / "demos.npz").unlink()
    with pytest.raises(C.DamagedRun, match="demos.npz is missing"):
        C.load(run)


# ----------------------------------------------------------------------------- train --out
def test_prepare_out_dir(tmp_path):
    (tmp_path / "a-file").write_text("x")
    with pytest.raises(C.CheckpointError, match="a-file is a file, not a folder"):
        C.prepare_out_dir(tmp_path / "a-file", overwrite=True)
    with pytest.raises(C.CheckpointError, match=r"lies under .*a-file, which is a file"):
        C.prepare_out_dir(tmp_path / "a-file" / "run", overwrite=True)

    foreign = tmp_path / "foreign"
    foreign.mkdir()
    for name in ("notes.txt", "demos.npz", "ckpt-mine"):
        (foreign / name).write_text("mine")
    with pytest.raises(C.CheckpointError, match=r"holds files that are not a saved run \(ckpt-mine, demos.npz, notes"):
        C.prepare_out_dir(foreign)
    C.prepare_out_dir(foreign, overwrite=True)
    a = save(foreign, 1, overwrite=True)
    save(foreign, 2, parent=a)
    save(foreign, 3, parent=C.latest(foreign))
    assert all((foreign / n).read_text() == "mine" for n in ("notes.txt", "ckpt-mine"))

    run = tmp_path / "run"
    a = save(run, 1)
    (run / "label.json").write_text('{"label": "x"}')
    with pytest.raises(C.CheckpointError, match="already holds a saved run: .* --overwrite"):
        C.prepare_out_dir(run)
    C.prepare_out_dir(run, overwrite=True)
    with pytest.raises(C.RunChanged):
        save(run, 1)  # what cmd_train's first save would hit without overwrite
    save(run, 1, overwrite=True)

    empty = tmp_path / "empty"
    empty.mkdir()
    C.prepare_out_dir(empty)
    (empty / ".lock").touch()  # the lock file of a save that never finished
    (empty / ".ckpt-00001-abcdef12.partial").mkdir()
    C.prepare_out_dir(empty)
    C.prepare_out_dir(tmp_path / "new" / "deeper")
    assert (tmp_path / "new" / "deeper").is_dir()


def test_state_arrays_are_written_as_a_plain_npz_that_numpy_reads_back_exactly():
    """Weights are stored (deflate costs seven times the time for a fifth of their size), images and
    counters deflated; numpy and the safe reader read every array back as it was, and the same arrays
    give the same bytes."""
    import io

    from ifo.data.npz import read_npz
    from ifo.io import npz_bytes

    rng = np.random.default_rng(0)
    arrays = {"policy.w": rng.normal(size=(32, 4)).astype(np.float32), "images": np.zeros((50, 8, 8), np.uint8),
              "actions": rng.integers(0, 3, 100), "counters.steps": np.array(7), "empty": np.zeros((0, 3))}
    data = npz_bytes(arrays)
    assert data == npz_bytes(dict(arrays))
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        kinds = {info.filename: info.compress_type for info in zf.infolist()}
    assert kinds["policy.w.npy"] == zipfile.ZIP_STORED and kinds["images.npy"] == zipfile.ZIP_DEFLATED
    with np.load(io.BytesIO(data), allow_pickle=False) as loaded:
        for name, a in arrays.items():
            np.testing.assert_array_equal(loaded[name], a)
            assert loaded[name].dtype == a.dtype
    back = read_npz(data, max_array_bytes=1 << 20, max_total_bytes=1 << 20)
    assert set(back) == set(arrays) and all(np.array_equal(back[k], v) for k, v in arrays.items())


def test_images_are_deflated_fast_when_saved_and_read_back_bit_for_bit(tmp_path):
    """A Step's autosave of a maze run deflates its images at zlib's fastest level (the wait of a student
    taking a ready iteration was this compression); the shipped files keep the default level."""
    import io

    from ifo.io import FAST_DEFLATE, npz_bytes

    rng = np.random.default_rng(0)
    frames = rng.integers(0, 255, (40, 32, 32, 3), dtype=np.uint8)  # few distinct frames, as a maze has
    images = frames[rng.integers(0, 40, 2_000)]
    arrays = {"train_set.states": images, "weights": rng.normal(size=(64, 64)).astype(np.float32)}
    fast, small = npz_bytes(arrays, FAST_DEFLATE), npz_bytes(arrays)
    assert len(fast) != len(small)  # the level is honoured (it is set on each entry, not on the archive)
    assert npz_bytes(arrays, FAST_DEFLATE) == fast  # same arrays, same bytes
    C.save(tmp_path / "run", config={"env": "maze3"}, records=[{"iteration": 1}], arrays=arrays, meta={}, parent=None)
    back = C.load(tmp_path / "run").arrays
    assert all(np.array_equal(back[k], v) and back[k].dtype == v.dtype for k, v in arrays.items())
    with zipfile.ZipFile(io.BytesIO(fast)) as zf:
        assert zf.getinfo("train_set.states.npy").compress_type == zipfile.ZIP_DEFLATED
        assert zf.getinfo("weights.npy").compress_type == zipfile.ZIP_STORED
