"""Rollout videos: frames -> H.264 MP4 that browsers play, and the frames of a rollout."""
import numpy as np
import pytest

from ifo.video import expert_rollout_frames, frames_to_mp4, policy_rollout_frames


def decode(data: bytes, tmp_path):
    import imageio_ffmpeg

    path = tmp_path / "clip.mp4"
    path.write_bytes(data)
    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    frames = list(reader)
    return meta, frames


def test_mp4_is_h264_yuv420p_with_every_frame(tmp_path):
    frames = [np.full((63, 95, 3), 8 * i, np.uint8) for i in range(12)]  # odd sizes: padded to even
    data = frames_to_mp4(frames, fps=10)
    assert data[4:8] == b"ftyp"  # an MP4 starts with its ftyp box
    assert b"avc1" in data[:64]  # the H.264 brand
    meta, decoded = decode(data, tmp_path)
    assert meta["codec"] == "h264" and meta["pix_fmt"].startswith("yuv420p")
    assert meta["size"] == (96, 64) and meta["fps"] == 10
    assert len(decoded) == 12
    assert data.find(b"moov") < data.find(b"mdat")  # faststart: plays while it downloads


def test_bad_frames_are_refused():
    with pytest.raises(ValueError):
        frames_to_mp4([])
    with pytest.raises(ValueError):
        frames_to_mp4([np.zeros((8, 8, 3), np.uint8), np.zeros((8, 10, 3), np.uint8)])


def test_maze_expert_rollout_is_drawn_readably_and_reaches_the_goal(tmp_path):
    frames, ret = expert_rollout_frames("maze3", seed=0)
    assert frames[0].shape == (320, 320, 3) and frames[0].dtype == np.uint8
    assert ret > 0.9  # the shortest path reaches the goal
    assert not np.array_equal(frames[0], frames[-1])  # the agent moved
    meta, decoded = decode(frames_to_mp4(frames, fps=6), tmp_path)
    assert len(decoded) == len(frames) and meta["size"] == (320, 320)


def test_policy_rollout_of_a_run_uses_the_gym_renderer(tiny_config):
    from ifo.run import Run

    run = Run(tiny_config())
    run.step()
    frames, ret = policy_rollout_frames(run, seed=0, max_frames=40)
    assert 2 <= len(frames) <= 40 and frames[0].shape == (400, 600, 3)
    assert ret == len(frames) - 1 or len(frames) == 40  # CartPole: +1 per step


@pytest.mark.parametrize("env", ["cartpole", "maze5"])
def test_sessions_drawing_their_first_frames_at_once_all_get_their_video(env):
    """A class opening the rollout video at once on a fresh server draws the first frames in several threads;
    a student once got "module 'pygame.surfarray' has no attribute 'pixels3d'" (a half-loaded lazy module)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[1])
    script = f"""
import threading
import numpy as np
from ifo.video import expert_rollout_frames
start, videos, errors = threading.Barrier(8), {{}}, []
def draw(k):
    start.wait()
    try:
        videos[k] = expert_rollout_frames({env!r}, seed=k, max_frames=3)[0]
    except Exception as e:
        errors.append(repr(e))
threads = [threading.Thread(target=draw, args=(k,)) for k in range(8)]
for t in threads: t.start()
for t in threads: t.join()
assert not errors, errors
for k, frames in videos.items():  # the frames one thread alone draws
    assert all(np.array_equal(a, b) for a, b in zip(frames, expert_rollout_frames({env!r}, seed=k, max_frames=3)[0]))
print(len(videos))
"""
    for _ in range(3):  # a fresh interpreter each time: the race is on the first frame only
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, cwd=root,
                              env={**os.environ, "SDL_VIDEODRIVER": "dummy", "PYTHONPATH": root})
        assert done.returncode == 0 and done.stdout.strip() == "8", done.stderr[-800:]


@pytest.mark.parametrize("env", ["cartpole", "acrobot", "mountaincar"])
def test_videos_drawn_at_once_are_the_videos_drawn_alone(env):
    """Students opening their rollout videos at the same moment each get their own episode, frame for frame as it
    draws alone: gymnasium draws these with pygame.gfxdraw, whose polygon fill shares one buffer between threads
    (CI once saw a CartPole frame drawn beside seven others differ from the same frame drawn alone)."""
    import threading

    n_threads, n_frames = 6, 60
    alone = {k: expert_rollout_frames(env, seed=k, max_frames=n_frames)[0] for k in range(n_threads)}
    start, together, errors = threading.Barrier(n_threads), {}, []

    def draw(k):
        start.wait()
        try:
            together[k] = expert_rollout_frames(env, seed=k, max_frames=n_frames)[0]
        except Exception as e:  # noqa: BLE001  (reported below)
            errors.append(repr(e))

    threads = [threading.Thread(target=draw, args=(k,)) for k in range(n_threads)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors
    for k in range(n_threads):
        assert len(together[k]) == len(alone[k])
        smudged = [i for i, (a, b) in enumerate(zip(together[k], alone[k])) if not np.array_equal(a, b)]
        assert not smudged, f"seed {k}: frames {smudged[:10]} differ when drawn beside other sessions"
