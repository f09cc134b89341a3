"""Per-user storage (ifo.ui.storage): ids, half-written runs, rename/delete/zip, shipped runs, uploads."""
import io
import json
import zipfile

import numpy as np
import pytest

from conftest import make_tiny_config
from ifo import checkpoint
from ifo.data.demos import DemoError
from ifo.run import Run
from ifo.ui import storage

USER = "tester01"


@pytest.fixture(autouse=True)
def runs_root(tmp_path, monkeypatch):
    monkeypatch.setenv("IFO_LAB_RUNS", str(tmp_path / "runs"))
    return tmp_path / "runs"


@pytest.fixture(scope="module")
def tiny_run():
    run = Run(make_tiny_config())
    run.step()
    return run


def cartpole_demos(episodes: int = 2) -> dict:
    with np.load(storage.PROJECT / "assets" / "demos" / "cartpole.npz") as d:
        data = {k: d[k] for k in ("obs", "next_obs", "rewards", "episode_starts")}
    starts = np.flatnonzero(data["episode_starts"])
    end = starts[episodes] if episodes < len(starts) else len(data["obs"])
    return {k: v[:end] for k, v in data.items()}


def npz(arrays: dict) -> bytes:
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


@pytest.mark.parametrize("user", ["../x", "..", "a/b", "", None, "UPPER123", "short", "x" * 40, "abc def12"])
def test_bad_user_ids_are_refused(user):
    assert not storage.valid_user(user)
    with pytest.raises(ValueError):
        storage.user_dir(user)
    with pytest.raises(ValueError):
        storage.list_runs(user)


@pytest.mark.parametrize("run_id", ["../other", "..", ".hidden", "a/b", "", "x" * 200])
def test_bad_run_ids_are_refused(run_id):
    with pytest.raises(ValueError):
        storage.run_path(USER, run_id)
    with pytest.raises(ValueError):
        storage.delete_run(USER, run_id)


def test_new_users_are_valid_and_distinct():
    a, b = storage.new_user(), storage.new_user()
    assert storage.valid_user(a) and storage.valid_user(b) and a != b


def test_save_list_rename_zip_delete(tiny_run):
    storage.save_run(tiny_run, USER, "run-one", label="First run")
    [saved] = storage.list_runs(USER)
    assert (saved.run_id, saved.label, saved.iterations_done, saved.iterations_total) == ("run-one", "First run", 1, 2)
    assert saved.last["aer"] == tiny_run.records[-1]["evaluation"]["aer"]
    storage.rename_run(USER, "run-one", "  Renamed  ")
    assert storage.list_runs(USER)[0].label == "Renamed"
    with pytest.raises(ValueError):
        storage.rename_run(USER, "run-one", "   ")
    assert storage.list_runs(USER)[0].label == "Renamed"
    with zipfile.ZipFile(io.BytesIO(storage.zip_run(USER, "run-one"))) as zf:
        names = zf.namelist()
    assert "run-one/config.json" in names and "run-one/label.json" in names and "run-one/LATEST" in names
    assert any(n.endswith("state.npz") for n in names) and not any("/." in n for n in names)
    assert len({n.split("/")[1] for n in names if "/ckpt-" in n}) == 1  # the latest checkpoint only
    storage.delete_run(USER, "run-one")
    assert storage.list_runs(USER) == []
    with pytest.raises(FileNotFoundError):
        storage.rename_run(USER, "run-one", "gone")
    with pytest.raises(FileNotFoundError):
        storage.get_run(USER, "run-one")


def test_damaged_runs_are_listed_with_the_reason_and_half_written_ones_skipped(tiny_run, runs_root):
    storage.save_run(tiny_run, USER, "complete")
    user = runs_root / USER
    (user / "no-latest").mkdir()
    (user / "no-latest" / "config.json").write_text("{}")
    broken = user / "dangling"
    broken.mkdir()
    (broken / "config.json").write_text(json.dumps(tiny_run.config.to_dict()))
    (broken / "LATEST").write_text("ckpt-missing")
    storage.save_run(tiny_run, USER, "corrupt", label="Corrupt one")
    corrupt = storage.run_path(USER, "corrupt")
    (corrupt / checkpoint.latest(corrupt) / "records.json").write_text("[{")
    storage.save_run(tiny_run, USER, "bad-label")
    (user / "bad-label" / "label.json").write_text("{no")
    (user / ".complete.partial").mkdir()
    (user / "first-save").mkdir()  # a first save in progress (or killed): not a run yet
    (user / "first-save" / ".lock").touch()
    (user / "first-save" / ".ckpt-00001-abcdef12.partial").mkdir()

    runs = {r.run_id: r for r in storage.list_runs(USER)}
    assert set(runs) == {"complete", "no-latest", "dangling", "corrupt", "bad-label"}
    assert runs["complete"].damaged is None and runs["complete"].iterations_done == 1
    assert runs["dangling"].damaged == "LATEST does not name a checkpoint of this folder ('ckpt-missing')"
    assert runs["dangling"].config["env"] == "cartpole"
    assert runs["no-latest"].damaged.startswith("LATEST is missing")
    assert "records.json is not valid JSON" in runs["corrupt"].damaged and runs["corrupt"].label == "Corrupt one"
    assert runs["bad-label"].damaged is None and runs["bad-label"].label == "bad-label"  # shown by folder name
    with pytest.raises(ValueError, match=r"the run 'corrupt' is damaged: .*records.json is not valid JSON"):
        storage.get_run(USER, "corrupt")
    with pytest.raises(ValueError, match="damaged"):
        storage.zip_run(USER, "corrupt")
    assert storage.last_records(runs["corrupt"]) == []
    storage.rename_run(USER, "bad-label", "Fixed")
    assert storage.get_run(USER, "bad-label").label == "Fixed"
    for rid in ("no-latest", "dangling", "corrupt"):
        storage.delete_run(USER, rid)
    assert sorted(r.run_id for r in storage.list_runs(USER)) == ["bad-label", "complete"]
    with pytest.raises(ValueError):
        storage.delete_run(USER, storage.DEMOS_FOLDER)


def test_two_tabs_on_one_run_the_later_save_is_refused_and_nothing_is_lost(tiny_run):
    storage.save_run(tiny_run, USER, "shared")
    path = storage.run_path(USER, "shared")
    first, second = Run.load(path), Run.load(path)
    first.step()
    storage.save_run(first, USER, "shared")
    with pytest.raises(checkpoint.RunChanged, match="another session saved this run"):
        storage.save_run(second, USER, "shared")
    assert storage.get_run(USER, "shared").iterations_done == 2
    assert [r["evaluation"] for r in Run.load(path).records] == json.loads(json.dumps(
        [r["evaluation"] for r in first.records]))


def test_shipped_runs_copy_into_the_users_folder(tiny_run, tmp_path, monkeypatch):
    shipped = tmp_path / "shipped"
    tiny_run.save(shipped / "cartpole-example")
    (shipped / "cartpole-example" / "label.json").write_text(json.dumps({"label": "Example"}))
    monkeypatch.setenv("IFO_LAB_SHIPPED_RUNS", str(shipped))
    [ex] = storage.list_shipped_runs()
    assert ex.label == "Example"
    run_id = storage.copy_shipped_run(USER, "cartpole-example")
    [mine] = storage.list_runs(USER)
    assert mine.run_id == run_id and mine.label == "Example"
    assert Run.load(mine.path).records == json.loads(json.dumps(tiny_run.records))
    with pytest.raises(ValueError):
        storage.copy_shipped_run(USER, "../cartpole-example")
    with pytest.raises(FileNotFoundError):
        storage.copy_shipped_run(USER, "nothing-here")


def test_the_real_shipped_runs_load():
    shipped = storage.list_shipped_runs()
    names = {r.run_id for r in shipped}
    assert {"cartpole-iupe", "cartpole-bco-alpha", "cartpole-bc", "acrobot-iupe", "mountaincar-iupe",
            "maze3-iupe", "maze5-iupe-thesis"} <= names
    for saved in shipped:
        assert saved.iterations_done == saved.iterations_total >= 1
        assert storage.folder_bytes(saved.path) < 4 * 2**20
        if not saved.config["env"].startswith("maze"):  # the maze one loads in ~2 s; covered by the script
            run = Run.load(saved.path)
            assert run.iteration == saved.iterations_done and run.finished


def test_uploaded_demos_are_validated_and_a_bad_upload_keeps_the_good_file():
    good = storage.save_demos(USER, "cartpole", "my expert.npz", npz(cartpole_demos(2)))
    assert good.name == "cartpole-my-expert" and good.env == "cartpole"
    assert good.summary["episodes"] == 2 and not good.summary["has_actions"]
    before = good.path.read_bytes()

    broken = cartpole_demos(2)
    del broken["episode_starts"]
    with pytest.raises(DemoError) as err:
        storage.save_demos(USER, "cartpole", "my expert.npz", npz(broken))
    assert str(err.value).startswith("my expert.npz: missing key(s) 'episode_starts'")
    with pytest.raises(DemoError, match="not an .npz archive"):
        storage.save_demos(USER, "cartpole", "my expert.npz", b"this is not a zip file")
    wrong_shape = cartpole_demos(2)
    wrong_shape["obs"] = wrong_shape["obs"][:, :3]
    wrong_shape["next_obs"] = wrong_shape["next_obs"][:, :3]
    with pytest.raises(DemoError, match=r"states have shape \(3,\) but cartpole states have shape \(4,\)"):
        storage.save_demos(USER, "cartpole", "my expert.npz", npz(wrong_shape))
    pickled = io.BytesIO()
    np.savez(pickled, obs=np.array([{"a": 1}, {"b": 2}], dtype=object))
    with pytest.raises(DemoError, match="pickled"):
        storage.save_demos(USER, "cartpole", "my expert.npz", pickled.getvalue())

    [kept] = storage.list_demos(USER)
    assert kept.path.read_bytes() == before
    assert not [p for p in kept.path.parent.iterdir() if p.name.startswith(".")]  # no temporary file left behind


def test_a_run_trains_on_uploaded_demos():
    saved = storage.save_demos(USER, "cartpole", "two.npz", npz(cartpole_demos(2)))
    run = Run(make_tiny_config(demos=str(saved.path), iterations=1))
    assert run.demos.n_episodes == 2
