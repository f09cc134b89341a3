"""The run list page (views/runs.py) through AppTest: list, rename, delete, bad input, uploads, examples.

Runs live in a temporary IFO_LAB_RUNS; the user id comes from `?user=` like in a browser.
"""
import io
from pathlib import Path

import numpy as np
import pytest
from streamlit.testing.v1 import AppTest

from conftest import make_tiny_config
from ifo.run import Run
from ifo.ui import storage

ROOT = Path(__file__).resolve().parents[1]
USER = "pagetest01"


@pytest.fixture(autouse=True)
def env(tmp_path, monkeypatch):
    monkeypatch.setenv("IFO_LAB_FAST", "1")
    monkeypatch.setenv("IFO_LAB_RUNS", str(tmp_path / "runs"))


@pytest.fixture(scope="module")
def tiny_run():
    run = Run(make_tiny_config(iterations=3))
    run.step()
    return run


def open_runs_page(user: str | None = USER) -> AppTest:
    at = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    if user:
        at.query_params["user"] = user
    at.run()
    at.switch_page("views/runs.py").run()
    assert not at.exception, at.exception
    return at


def texts(at: AppTest) -> str:
    return " ".join([m.value for m in at.markdown] + [c.value for c in at.caption])


def test_lists_a_saved_run_with_its_numbers(tiny_run):
    storage.save_run(tiny_run, USER, "run-a", label="My first run")
    at = open_runs_page()
    assert at.title[0].value == "Your runs"
    shown = texts(at)
    assert "My first run" in shown
    assert "BCO(α) on CartPole, seed 0 · 1 of 3 iterations" in shown
    assert f"AER {tiny_run.records[-1]['evaluation']['aer']:.2f}" in shown
    assert {"runs.open.run-a", "runs.rename.run-a", "runs.delete.run-a"} <= {b.key for b in at.button}
    assert not at.error


def test_a_missing_user_gets_a_new_id_in_the_url():
    at = open_runs_page(user=None)
    user = at.query_params["user"]
    user = user[0] if isinstance(user, list) else user
    assert storage.valid_user(user)
    assert "No saved runs yet" in " ".join(i.value for i in at.info)


def test_rename_changes_the_label_and_a_bad_name_shows_an_error(tiny_run):
    storage.save_run(tiny_run, USER, "run-a", label="Old name")
    at = open_runs_page()
    at.text_input(key="runs.name.run-a").set_value("New name")
    at.button(key="runs.rename.run-a").click().run()
    assert not at.exception and not at.error
    assert storage.list_runs(USER)[0].label == "New name"
    assert "New name" in texts(at)

    at.text_input(key="runs.name.run-a").set_value("   ")
    at.button(key="runs.rename.run-a").click().run()
    assert [e.value for e in at.error] == ["Could not rename the run: a run needs a name"]
    assert storage.list_runs(USER)[0].label == "New name"  # nothing lost


def test_delete_removes_the_run_and_a_run_deleted_meanwhile_is_an_error(tiny_run):
    storage.save_run(tiny_run, USER, "run-a", label="Doomed")
    storage.save_run(tiny_run, USER, "run-b", label="Survivor")
    at = open_runs_page()
    at.button(key="runs.delete.run-a").click().run()
    assert not at.exception and not at.error
    assert [r.run_id for r in storage.list_runs(USER)] == ["run-b"]
    assert "Doomed" not in " ".join(m.value for m in at.markdown if m.value.startswith("**"))

    storage.delete_run(USER, "run-b")  # deleted in another tab
    at.text_input(key="runs.name.run-b").set_value("Too late")
    at.button(key="runs.rename.run-b").click().run()
    assert len(at.error) == 1 and "no saved run 'run-b'" in at.error[0].value


def test_a_damaged_run_is_listed_with_its_reason_and_can_be_deleted(tiny_run):
    storage.save_run(tiny_run, USER, "run-ok", label="Healthy")
    path = storage.save_run(tiny_run, USER, "run-bad", label="Broken run")
    (path / "LATEST").write_text("../someone-else/ckpt-00001-abcdef12")
    at = open_runs_page()
    assert not at.exception and not at.error
    shown = texts(at)
    assert "Broken run" in shown and "Healthy" in shown
    assert ("This run is damaged and cannot be opened: LATEST does not name a checkpoint of this folder "
            "('../someone-else/ckpt-00001-abcdef12')") in shown
    keys = {b.key for b in at.button}
    assert "runs.delete.run-bad" in keys and "runs.open.run-bad" not in keys and "runs.rename.run-bad" not in keys
    assert "runs.open.run-ok" in keys
    at.button(key="runs.delete.run-bad").click().run()
    assert not at.exception and not at.error
    assert [s.value for s in at.success] == ["Deleted Broken run."]
    assert [r.run_id for r in storage.list_runs(USER)] == ["run-ok"] and not path.exists()


def test_open_goes_to_the_step_page_with_the_run_in_the_url(tiny_run):
    storage.save_run(tiny_run, USER, "run-a", label="To open")
    at = open_runs_page()
    at.button(key="runs.open.run-a").click().run()
    assert at.query_params["run"] in ("run-a", ["run-a"])
    assert at.query_params["user"] in (USER, [USER])
    assert not at.title or at.title[0].value != "Your runs"


def test_opening_an_example_copies_it_and_goes_to_the_step_page():
    at = open_runs_page()
    examples = [b.key for b in at.button if b.key and b.key.startswith("runs.example.")]
    assert "runs.example.cartpole-bco-alpha" in examples
    at.button(key="runs.example.cartpole-bco-alpha").click().run()
    [copied] = storage.list_runs(USER)
    assert copied.run_id.startswith("cartpole-bco-alpha-") and copied.iterations_done == copied.iterations_total
    assert at.query_params["run"] in (copied.run_id, [copied.run_id])


def demos_bytes(drop: str | None = None) -> bytes:
    with np.load(ROOT / "assets" / "demos" / "cartpole.npz") as d:
        data = {k: d[k][:1000] for k in ("obs", "next_obs", "rewards", "episode_starts")}
    if drop:
        del data[drop]
    buf = io.BytesIO()
    np.savez(buf, **data)
    return buf.getvalue()


def upload(at: AppTest, name: str, data: bytes) -> AppTest:
    at.selectbox(key="runs.upload_env").set_value("cartpole")
    at.file_uploader(key="runs.upload_file").set_value((name, data, "application/octet-stream"))
    at.button[[b.label for b in at.button].index("Check and save")].click().run()
    assert not at.exception, at.exception
    return at


def test_uploads_a_good_file_then_a_bad_one_keeps_it():
    at = upload(open_runs_page(), "expert.npz", demos_bytes())
    assert not at.error
    assert any("Saved cartpole-expert" in s.value for s in at.success)
    [saved] = storage.list_demos(USER)
    good = saved.path.read_bytes()
    assert "runs.train.cartpole-expert" in {b.key for b in at.button}

    at = upload(at, "expert.npz", demos_bytes(drop="episode_starts"))
    assert [e.value for e in at.error] == [
        "expert.npz: missing key(s) 'episode_starts'; found ['next_obs', 'obs', 'rewards']; "
        "expected ['obs', 'rewards', 'episode_starts'] (+ optional 'actions', 'next_obs')"]
    [kept] = storage.list_demos(USER)
    assert kept.path.read_bytes() == good


def test_train_on_uploaded_demos_queues_a_run():
    from ifo.ui.queue import get_queue

    storage.save_demos(USER, "cartpole", "expert.npz", demos_bytes())
    at = open_runs_page()
    at.button(key="runs.train.cartpole-expert").click().run()
    assert not at.exception and not at.error
    [job] = get_queue().jobs(USER)
    assert job.config.demos.endswith("cartpole-expert.npz") and job.config.method == "iupe"
    get_queue().wait_idle(120)
    assert get_queue().job(USER, job.id).state == "done", get_queue().job(USER, job.id).error
    at.run()
    [saved] = [r for r in storage.list_runs(USER) if r.config.get("demos")]

    # Open, as its button does: the Step page shows that trained run, not a fresh one of the same settings
    # (the upload's obs_mode "vector" used to make the page's settings another run's, on a control task)
    step = AppTest.from_file(str(ROOT / "app.py"), default_timeout=60)
    step.query_params.update({"user": USER, "run": saved.run_id})
    step.run()
    step.switch_page("views/step_through.py").run()
    assert not step.exception and not step.error
    assert step.session_state["ifo.slot.step"].run.iteration == saved.iterations_done > 0
    assert step.query_params["run"] in (saved.run_id, [saved.run_id])
