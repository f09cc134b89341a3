"""Rollouts as videos: RGB frames -> MP4 bytes (H.264, yuv420p) that every browser plays.

    frames = policy_rollout_frames(run, seed=0)     # the learner, one episode
    frames = expert_rollout_frames("cartpole", 0)   # the expert on the same episode
    data = frames_to_mp4(frames, fps=30)            # bytes for st.video / a file

Control tasks are drawn by their gymnasium `rgb_array` renderer; the maze by
`ifo.envs.maze.render_maze` at a readable size (observations are only 32 px). Encoding
uses the ffmpeg binary shipped with imageio-ffmpeg; no streamlit here.
"""
from __future__ import annotations

import os
import tempfile
from typing import Sequence

import numpy as np

from ifo.envs import get_env

MAZE_VIDEO_SIZE = 320  # px: readable on a projector
MAX_FRAMES = 600  # a lost maze agent would otherwise wander for 1,000 steps


def _even(frame: np.ndarray) -> np.ndarray:
    """yuv420p needs even width and height: pad one white row/column where needed."""
    h, w = frame.shape[:2]
    if h % 2 == 0 and w % 2 == 0:
        return frame
    return np.pad(frame, ((0, h % 2), (0, w % 2), (0, 0)), constant_values=255)


def frames_to_mp4(frames: Sequence[np.ndarray], fps: int = 30, quality_crf: int = 23) -> bytes:
    """Encode uint8 RGB frames (all the same size, H x W x 3) as an H.264 MP4 (yuv420p, faststart)."""
    import imageio_ffmpeg

    frames = [np.asarray(f) for f in frames]
    if not frames:
        raise ValueError("no frames to encode")
    shape = frames[0].shape
    if len(shape) != 3 or shape[2] != 3 or any(f.shape != shape for f in frames):
        raise ValueError(f"frames must all be H x W x 3 RGB images of one size, got {shape} first")
    first = _even(frames[0])
    h, w = first.shape[:2]
    fd, path = tempfile.mkstemp(suffix=".mp4")
    os.close(fd)
    try:
        writer = imageio_ffmpeg.write_frames(
            path, (w, h), fps=fps, codec="libx264", pix_fmt_in="rgb24", pix_fmt_out="yuv420p",
            macro_block_size=1, quality=None, ffmpeg_log_level="error",
            output_params=["-crf", str(quality_crf), "-preset", "veryfast", "-movflags", "+faststart",
                           "-threads", "1"])
        writer.send(None)  # start ffmpeg
        for f in frames:
            writer.send(np.ascontiguousarray(_even(f.astype(np.uint8, copy=False))))
        writer.close()
        with open(path, "rb") as fh:
            return fh.read()
    finally:
        os.unlink(path)


# --------------------------------------------------------------------------- rollouts
def _maze_episode(spec, act, seed: int, obs_mode: str, image_size: int, max_frames: int,
                  size: int) -> tuple[list[np.ndarray], float]:
    from ifo.envs.maze import render_maze

    env = spec.make(split="eval", obs_mode=obs_mode, image_size=image_size, max_steps=max_frames)
    obs, _ = env.reset(seed=int(seed))
    frames = [render_maze(env.layout, env.position, size)]
    ret, done = 0.0, False
    while not done and len(frames) < max_frames:
        obs, r, term, trunc, _ = env.step(int(act(obs)))
        ret += r
        done = term or trunc
        frames.append(render_maze(env.layout, env.position, size))
    return frames, ret


def _control_episode(spec, act, seed: int, max_frames: int) -> tuple[list[np.ndarray], float]:
    from ifo.envs.drawing import close_env, render_frame

    env = spec.make(render_mode="rgb_array")
    try:
        obs, _ = env.reset(seed=int(seed))
        try:
            first = render_frame(env)
        except NotImplementedError:  # gymnasium's own render(): a researcher's environment may not draw itself
            first = None
        if first is None:
            raise ValueError(f"{spec.thesis_name or spec.name} draws no pictures (its render() gives none in "
                             "render_mode='rgb_array')")
        frames = [first]
        ret, done = 0.0, False
        while not done and len(frames) < max_frames:
            obs, r, term, trunc, _ = env.step(int(act(obs)))
            ret += float(r)
            done = term or trunc
            frames.append(render_frame(env))
        return frames, ret
    finally:
        close_env(env)


def policy_rollout_frames(run, seed: int = 0, max_frames: int | None = None, size: int = MAZE_VIDEO_SIZE,
                          iteration: int | None = None) -> tuple[list[np.ndarray], float]:
    """One evaluation-style episode of the run's policy (MAP actions, or sampled when the run measures
    AER with sampled actions), as it is now or as it was after `iteration`: (RGB frames, return)."""
    from contextlib import nullcontext

    cfg, max_frames = run.config, max_frames or MAX_FRAMES
    rng = run.ctx.seeds.rng("video", seed)
    act = lambda obs: run.act(np.asarray(obs)[None], sample=cfg.eval_explore, rng=rng)[0]  # noqa: E731
    with run.policy_at(iteration) if iteration not in (None, run.iteration) else nullcontext():
        if run.spec.is_maze:
            return _maze_episode(run.spec, act, seed, cfg.obs_mode, cfg.image_size, max_frames, size)
        return _control_episode(run.spec, act, _control_seed(seed), max_frames)


def expert_rollout_frames(env: str, seed: int = 0, max_frames: int | None = None,
                          size: int = MAZE_VIDEO_SIZE) -> tuple[list[np.ndarray], float]:
    """The expert on the same episode as `policy_rollout_frames(..., seed)`: (RGB frames, return)."""
    from ifo.experts import load_expert

    spec, max_frames = get_env(env), max_frames or MAX_FRAMES
    expert = load_expert(spec)
    act = lambda obs: expert.act(np.asarray(obs)[None])[0]  # noqa: E731
    if spec.is_maze:  # the shortest-path expert reads vector observations
        return _maze_episode(spec, act, seed, "vector", 32, max_frames, size)
    return _control_episode(spec, act, _control_seed(seed), max_frames)


def _control_seed(seed: int) -> int:
    from ifo.seeds import evaluation_seeds

    return int(evaluation_seeds(int(seed) + 1, maze=False)[-1])  # the first evaluation episode's start, as Run.evaluate uses
