"""The shared-iteration cache: a class on one lesson computes each iteration once."""
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import torch

from conftest import make_tiny_config
from ifo.iteration_cache import IterationCache
from ifo.run import Run

ROOT = Path(__file__).resolve().parents[1]


def strip(records):
    return [{k: v for k, v in r.items() if k != "seconds"} for r in records]


def weights(run):
    return {k: v.clone() for k, v in run.policy.state_dict().items()}


def test_a_cached_iteration_is_the_iteration_computed_afresh(tmp_path):
    cache = IterationCache(tmp_path / "cache")
    cfg = make_tiny_config(method="iupe", iterations=3)
    fresh = Run(cfg)
    fresh.run()

    teacher = Run(cfg, cache=cache)
    teacher.run(2)
    assert not teacher.last_step_cached  # computed and stored
    student = Run(cfg, cache=cache)
    student.run(2)
    assert student.last_step_cached  # loaded: nothing trained
    assert student.records == teacher.records and strip(student.records) == strip(fresh.records[:2])
    for k, v in weights(teacher).items():
        torch.testing.assert_close(weights(student)[k], v)
    student.step()  # the third iteration, trained from the loaded state, is the fresh run's third
    assert not student.last_step_cached
    assert strip(student.records) == strip(fresh.records)
    assert sorted(student.policy_history) == [1, 2, 3]


def test_a_branch_or_other_settings_never_take_another_lineage(tmp_path):
    cache = IterationCache(tmp_path / "cache")
    a = Run(make_tiny_config(iterations=3), cache=cache)
    a.run(2)
    other_seed = Run(make_tiny_config(iterations=3, seed=1), cache=cache)
    other_seed.step()
    assert not other_seed.last_step_cached
    branch = a.branch(sampling="iupe")
    branch.step()
    assert not branch.last_step_cached and branch.lineage != a.lineage
    again = Run(make_tiny_config(iterations=3), cache=cache).branch(sampling="iupe")
    assert again.lineage != branch.lineage  # (its past is shorter: nothing to share yet)


def test_two_processes_computing_the_same_iteration_at_once_compute_it_once(tmp_path):
    script = textwrap.dedent(f"""
        import json, sys
        sys.path[:0] = [{str(ROOT)!r}, {str(ROOT / 'tests')!r}]
        from conftest import make_tiny_config
        from ifo.iteration_cache import IterationCache
        from ifo.run import Run
        run = Run(make_tiny_config(method="iupe", iterations=1), cache=IterationCache({str(tmp_path / 'cache')!r}))
        record = run.step()
        print(json.dumps({{"cached": run.last_step_cached,
                          "record": {{k: v for k, v in record.items() if k != "seconds"}}}}))
    """)
    procs = [subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                              text=True) for _ in range(2)]
    outs = [p.communicate(timeout=300) for p in procs]
    assert [p.returncode for p in procs] == [0, 0], [o[1][-2000:] for o in outs]
    results = [json.loads(o[0].strip().splitlines()[-1]) for o in outs]
    assert sorted(r["cached"] for r in results) == [False, True]  # one computed, the other waited and loaded
    assert results[0]["record"] == results[1]["record"]


def test_the_cache_evicts_by_size_without_breaking_a_run_in_use(tmp_path):
    cache = IterationCache(tmp_path / "cache", max_bytes=1)  # every entry is over budget
    run = Run(make_tiny_config(iterations=3), cache=cache)
    run.run(2)
    assert cache.size() == 0  # evicted as soon as stored
    run.step()  # the run in use goes on: its state is its own, in memory
    assert run.iteration == 3
    cache.max_bytes = 10**9
    other = Run(make_tiny_config(iterations=3), cache=cache)
    other.run()
    assert cache.size() > 0
    assert strip(other.records) == strip(run.records)


def test_a_damaged_entry_is_recomputed(tmp_path):
    cache = IterationCache(tmp_path / "cache")
    Run(make_tiny_config(iterations=1), cache=cache).step()
    for f in (tmp_path / "cache").glob("??/*/entry.npz"):
        f.write_bytes(b"not an npz")
    run = Run(make_tiny_config(iterations=1), cache=cache)
    run.step()
    assert not run.last_step_cached and run.iteration == 1
    again = Run(make_tiny_config(iterations=1), cache=cache)
    again.step()
    assert again.last_step_cached  # the recomputed entry replaced the damaged one


def test_a_run_trained_without_the_cache_then_opened_with_it_keeps_its_own_past(tmp_path):
    """`python -m ifo train --out` trains without a cache; the app opens that run with one. Its next Step
    must continue its own iterations, not take the cache's iteration 1 of the same configuration."""
    cache = IterationCache(tmp_path / "cache")
    cfg = make_tiny_config(method="iupe", iterations=3)
    Run(cfg, cache=cache).step()  # iteration 1 of this configuration is in the cache
    mine = Run(cfg)
    mine.run(2)
    mine.save(tmp_path / "mine")
    again = Run.load(tmp_path / "mine", cache=cache)
    again.step()
    fresh = Run(cfg)
    fresh.run()
    assert [r["iteration"] for r in again.records] == [1, 2, 3]
    assert strip(again.records) == strip(fresh.records)


def test_sessions_of_one_process_read_an_entry_once_and_each_trains_on_alone(tmp_path, monkeypatch):
    """A class's students take the teacher's iterations from one read of each entry (kept in memory,
    read-only); one student training on from it changes nothing the others take."""
    import ifo.iteration_cache as iteration_cache

    cache = IterationCache(tmp_path / "cache")
    cfg = make_tiny_config(method="iupe", iterations=3)
    fresh = Run(cfg)
    fresh.run()
    Run(cfg, cache=cache).run(2)  # the teacher
    reads = []
    real = iteration_cache.read_npz
    monkeypatch.setattr(iteration_cache, "read_npz", lambda *a, **k: reads.append(1) or real(*a, **k))
    first, second = Run(cfg, cache=cache), Run(cfg, cache=cache)
    first.run(2)
    second.run(2)
    assert len(reads) == 2 and first.last_step_cached and second.last_step_cached  # two entries, read once each
    first.step()  # trains iteration 3 from the shared state
    assert not first.last_step_cached and strip(first.records) == strip(fresh.records)
    second.cache = None  # trains its own iteration 3 from the same shared state, after the first did
    second.step()
    assert strip(second.records) == strip(fresh.records)
    for k, v in weights(fresh).items():
        torch.testing.assert_close(weights(second)[k], v, rtol=0, atol=0)


def test_what_a_process_keeps_stays_under_its_bound_oldest_used_out_first():
    from ifo.runtime import BoundedCache
    kept = BoundedCache(100, size=len)
    kept.put("a", b"x" * 40)
    kept.put("b", b"x" * 40)
    assert kept.get("a") == b"x" * 40  # "a" is now the most recently used
    kept.put("b", b"x" * 50)  # a new value for a key replaces its size, it does not add to it
    assert kept.get("a") is not None and kept.get("b") == b"x" * 50
    kept.put("c", b"x" * 30)  # 120 bytes: the least recently used ("a") goes
    assert kept.get("a") is None and kept.get("b") is not None and kept.get("c") is not None
    kept.put("huge", b"x" * 500)  # larger than the bound: kept alone, since the newest always stays
    assert kept.get("huge") is not None and kept.get("b") is None and kept.get("c") is None
    kept.put("d", b"x" * 10)
    assert kept.get("huge") is None and kept.get("d") is not None


def test_a_cache_bounded_by_count_builds_each_value_once_and_keeps_a_none():
    from ifo.runtime import BoundedCache
    kept, built = BoundedCache(2), []

    def build(key):
        built.append(key)
        return None if key == "empty" else key.upper()  # a figure that does not apply is None, and kept

    assert [kept.get_or_build(k, lambda k=k: build(k)) for k in ("a", "empty", "a", "empty")] == ["A", None, "A", None]
    assert built == ["a", "empty"]
    kept.get_or_build("b", lambda: build("b"))  # a third entry: the least recently used ("a") goes
    assert len(kept) == 2 and kept.get("a") is None and kept.get("empty", "gone") is None


def test_sessions_asking_for_the_same_missing_value_at_once_build_it_once():
    import threading

    from ifo.runtime import BoundedCache
    kept, built, release = BoundedCache(16), [], threading.Event()

    def slow_build(key):
        built.append(key)
        if key == "fig":
            release.wait(10)  # the figure takes a while: every other session asks meanwhile
        return key.upper()

    got, start = [], threading.Barrier(9)

    def session(key):
        start.wait()
        got.append(kept.get_or_build(key, lambda: slow_build(key)))

    threads = [threading.Thread(target=session, args=("fig",)) for _ in range(8)]
    other = threading.Thread(target=session, args=("other",))
    for t in threads + [other]:
        t.start()
    other.join(5)
    assert not other.is_alive() and got == ["OTHER"]  # another key is not held up by the slow one
    release.set()
    for t in threads + [other]:
        t.join(10)
    assert sorted(got) == ["FIG"] * 8 + ["OTHER"]
    assert sorted(built) == ["fig", "other"]  # once each, not once per session


def test_a_build_that_fails_leaves_the_next_caller_to_build():
    import pytest

    from ifo.runtime import BoundedCache
    kept = BoundedCache(4)

    def broken():
        raise OSError("disk gone")

    with pytest.raises(OSError):
        kept.get_or_build("k", broken)
    assert kept.get_or_build("k", lambda: "fine") == "fine"
