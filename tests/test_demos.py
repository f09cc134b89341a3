"""Demonstration files: every kind of bad file gets its own clear message, never a traceback."""
import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import ifo.data.demos as demos_mod
from ifo.data.demos import DemoError, load_demonstrations
from ifo.envs import get_env

CARTPOLE = get_env("cartpole")


def good_arrays(episodes=3, length=5, actions=True):
    rng = np.random.default_rng(0)
    n = episodes * length
    data = {"obs": rng.normal(size=(n, 4)).astype(np.float32), "rewards": np.ones(n, dtype=np.float32),
            "episode_starts": np.tile(np.eye(1, length, dtype=np.int8)[0], episodes)}
    if actions:
        data["actions"] = rng.integers(0, 2, size=n)
    return data


def write(tmp_path, arrays, name="demos.npz"):
    path = tmp_path / name
    np.savez(path, **arrays)
    return path


def load(path, **kw):
    return load_demonstrations(path, CARTPOLE, (4,), **kw)


def test_a_valid_sb3_style_file_gives_state_pairs_within_episodes(tmp_path):
    data = good_arrays()
    d = load(write(tmp_path, data))
    # 3 episodes of 5 states -> 4 pairs each: the last state of an episode has no successor
    assert len(d.transitions) == 12 and d.n_episodes == 3
    np.testing.assert_array_equal(d.transitions.states[0], data["obs"][0])
    np.testing.assert_array_equal(d.transitions.next_states[0], data["obs"][1])
    np.testing.assert_array_equal(d.transitions.next_states[3], data["obs"][4])
    np.testing.assert_array_equal(d.transitions.states[4], data["obs"][5])
    assert d.hidden_actions is not None and len(d.hidden_actions) == 12
    np.testing.assert_allclose(d.episode_returns, [5, 5, 5])


def test_next_obs_keeps_every_transition(tmp_path):
    data = good_arrays()
    data["next_obs"] = data["obs"] + 1
    d = load(write(tmp_path, data))
    assert len(d.transitions) == 15


def test_actions_are_optional_for_ifo_but_required_for_bc(tmp_path):
    path = write(tmp_path, good_arrays(actions=False))
    assert load(path).hidden_actions is None
    with pytest.raises(DemoError, match="no 'actions' key: BC"):
        load(path, require_actions=True)


def test_column_shaped_fields_are_accepted(tmp_path):
    data = good_arrays()
    data["rewards"] = data["rewards"][:, None]
    data["actions"] = data["actions"][:, None]
    assert len(load(write(tmp_path, data)).transitions) == 12


BAD_FILES = [
    (lambda d: d.pop("obs"), "missing key\\(s\\) 'obs'"),
    (lambda d: d.pop("episode_starts"), "missing key\\(s\\) 'episode_starts'"),
    (lambda d: d.update(obs=d["obs"][:, :3]), "states have shape \\(3,\\) but cartpole states have shape \\(4,\\)"),
    (lambda d: d.update(obs=d["obs"][:, 0]), "'obs' has shape \\(15,\\); expected \\(N, 4\\)"),
    (lambda d: d["obs"].__setitem__((2, 1), np.nan), "'obs' has 1 non-finite values"),
    (lambda d: d.update(obs=d["obs"].astype(str)), "'obs' has dtype <U"),
    (lambda d: d.update(rewards=d["rewards"][:-1]), "'rewards' has shape \\(14,\\); expected \\(15,\\)"),
    (lambda d: d["rewards"].__setitem__(0, np.inf), "'rewards' has 1 non-finite"),
    (lambda d: d["episode_starts"].__setitem__(0, 0), "must be 1 at index 0"),
    (lambda d: d["episode_starts"].__setitem__(3, 2), "only 0 and 1"),
    (lambda d: d["actions"].__setitem__(4, 7), "'actions' range from 0 to 7; cartpole has actions 0..1"),
    (lambda d: d.update(actions=d["actions"] + 0.5), "whole numbers"),
    (lambda d: d.update(episode_starts=np.ones(15, dtype=np.int8)), "single state"),
    (lambda d: d.update(obs=d["obs"][:1], rewards=d["rewards"][:1], episode_starts=d["episode_starts"][:1],
                        actions=d["actions"][:1]), "at least 2"),
    (lambda d: d.update(next_obs=d["obs"][:3]), "'next_obs' has shape \\(3, 4\\)"),
]


@pytest.mark.parametrize("spoil,message", BAD_FILES)
def test_each_kind_of_bad_file_says_what_is_wrong(tmp_path, spoil, message):
    data = good_arrays()
    spoil(data)
    path = write(tmp_path, data)
    with pytest.raises(DemoError, match=message):
        load(path)


def test_missing_file_folder_and_non_npz(tmp_path):
    with pytest.raises(DemoError, match="no such file"):
        load(tmp_path / "nope.npz")
    with pytest.raises(DemoError, match="is a folder"):
        load(tmp_path)
    text = tmp_path / "notes.npz"
    text.write_text("obs,rewards\n1,2\n")
    with pytest.raises(DemoError, match="not an .npz archive"):
        load(text)


def test_pickled_content_is_refused_without_unpickling(tmp_path):
    marker = tmp_path / "unpickled"

    class Boom:
        def __reduce__(self):
            return (Path.touch, (marker,))

    data = good_arrays()
    path = tmp_path / "evil.npz"
    np.savez(path, obs=data["obs"], rewards=data["rewards"], episode_starts=data["episode_starts"],
             actions=np.array([Boom()], dtype=object))
    with pytest.raises(DemoError, match="Python objects"):
        load(path)
    assert not marker.exists()


def test_truncated_archive_is_reported_as_damaged(tmp_path):
    path = write(tmp_path, good_arrays())
    blob = path.read_bytes()
    path.write_bytes(blob[: len(blob) // 2])
    with pytest.raises(DemoError):
        load(path)


def test_size_limit(tmp_path, monkeypatch):
    path = write(tmp_path, good_arrays())
    monkeypatch.setattr(demos_mod, "MAX_DEMO_BYTES", 100)
    with pytest.raises(DemoError, match="over the"):
        load(path)


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "ifo", *args], capture_output=True, text=True, timeout=120)


def test_cli_demos_check(tmp_path):
    good = write(tmp_path, good_arrays(), "good.npz")
    res = run_cli("demos", "check", str(good), "--env", "cartpole")
    assert res.returncode == 0, res.stderr
    assert "3 episodes" in res.stdout and "12 transitions" in res.stdout

    data = good_arrays()
    data["obs"] = data["obs"][:, :2]
    bad = write(tmp_path, data, "bad.npz")
    res = run_cli("demos", "check", str(bad), "--env", "CartPole-v1")
    assert res.returncode == 2
    assert "states have shape (2,) but cartpole states have shape (4,)" in res.stderr
    assert "Traceback" not in res.stderr

    res = run_cli("demos", "check", str(good), "--env", "pong")
    assert res.returncode == 2 and "unknown environment 'pong'" in res.stderr


def test_shipped_demonstrations_are_read_once_and_shared_read_only(tmp_path, monkeypatch, tiny_config):
    """Thirty students opening the step page build thirty runs on the same shipped file: it is read once per
    process, its arrays cannot be written by one session for the others, each run gets its own copy, and a
    remade file is read again."""
    import shutil

    import ifo.data.shipped as shipped
    from ifo.run import Run

    spec = get_env("cartpole")
    shipped._loaded.clear()
    first = shipped.load_shipped_demonstrations(spec)
    second = shipped.load_shipped_demonstrations(spec)
    assert np.shares_memory(second.transitions.states, first.transitions.states)  # read once
    second.hidden_actions = None  # a caller's own object: the next caller still gets the actions
    assert shipped.load_shipped_demonstrations(spec).hidden_actions is not None
    with pytest.raises(ValueError):
        first.transitions.states[0, 0] = 1.0
    run = Run(tiny_config())
    run.demos.transitions.states[0, 0] += 1.0  # the run's own copy
    assert not np.shares_memory(run.demos.transitions.states, first.transitions.states)

    # a remade file (another inode, size or time) is read again
    moved = tmp_path / "demos"
    shutil.copytree(demos_mod.shipped_demos_path(spec).parent, moved)
    original = demos_mod.shipped_demos_path(spec)
    with np.load(original, allow_pickle=False) as data:
        arrays = {k: data[k] for k in data.files}
    arrays["obs"] = arrays["obs"] + 1.0
    copy = moved / original.name
    np.savez(copy, **arrays)
    monkeypatch.setattr(shipped, "level_demos_path", lambda s, level=1: copy)
    again = shipped.load_shipped_demonstrations(spec)
    assert not np.shares_memory(again.transitions.states, first.transitions.states)
    np.testing.assert_allclose(again.transitions.states, first.transitions.states + 1.0)
