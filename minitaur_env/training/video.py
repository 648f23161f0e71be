"""Videos of a policy: H.264 mp4 through imageio-ffmpeg, optional GIF, atomic writes."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable
from pathlib import Path

import gymnasium as gym
import imageio.v2 as imageio
import numpy as np

from minitaur_env.training.evaluation import run_episodes
from minitaur_env.training.files import atomic_path

Policy = Callable[[np.ndarray], np.ndarray]


def frame_stride(control_fps: float, video_fps: float) -> int:
    """Render every n-th control step so the video plays back at real time."""
    return max(1, round(control_fps / video_fps))


def record_video(
    env: gym.Env,
    policy: Policy,
    path: str | os.PathLike[str],
    episodes: int = 1,
    max_steps: int = 1000,
    fps: float = 50.0,
    seed: int | None = None,
    gif_path: str | os.PathLike[str] | None = None,
    gif_width: int = 320,
    gif_fps: float = 12.5,
) -> dict[str, float]:
    """Run ``episodes`` episodes of ``policy`` in ``env`` (render_mode="rgb_array").

    Frames are taken every ``frame_stride`` control steps and streamed to an H.264
    mp4 at ``control rate / stride`` fps, i.e. real time. Returns the frame count,
    the fps and each episode's return. The mp4 replaces ``path`` only once it is read
    back with every frame: ffmpeg on a full disk can exit quietly with a truncated file.
    Raises OSError (one line) where it could not be written whole.
    """
    if env.render_mode != "rgb_array":
        raise ValueError(f"record_video needs render_mode='rgb_array', got {env.render_mode!r}")
    control_fps = env.metadata.get("render_fps", fps)
    stride = frame_stride(control_fps, fps)
    video_fps = control_fps / stride
    gif_every = max(1, round(video_fps / gif_fps))
    gif_frames: list[np.ndarray] = []
    frames = 0
    steps_into_episode = 0

    def restart(info: dict) -> dict[str, float]:
        nonlocal steps_into_episode
        steps_into_episode = 0
        return {}

    def filming(obs: np.ndarray) -> np.ndarray:
        """The policy's action, after a frame every ``stride`` steps of each episode."""
        nonlocal frames, steps_into_episode
        if steps_into_episode % stride == 0:
            frame = env.render()
            writer.append_data(frame)
            if gif_path is not None and frames % gif_every == 0:
                gif_frames.append(_shrink(frame, gif_width))
            frames += 1
        steps_into_episode += 1
        return policy(obs)

    with atomic_path(path) as temp:
        writer = imageio.get_writer(
            temp,
            format="FFMPEG",
            mode="I",
            fps=video_fps,
            codec="libx264",
            quality=7,
            pixelformat="yuv420p",
            macro_block_size=8,
        )
        try:
            records = run_episodes(
                filming, env, episodes, seed, from_reset=restart, max_steps=max_steps
            )
        except OSError as error:  # ffmpeg died: a full disk, a file size limit
            raise OSError(
                f"{path}: the video could not be written ({_first_line(error)})"
            ) from error
        finally:
            # A writer whose ffmpeg died raises again on close; the count below tells.
            with contextlib.suppress(OSError):
                writer.close()
        written = _frames_in(temp)
        if written != frames:
            raise OSError(
                f"{path}: the video came out with {written} of {frames} frames; is the disk full?"
            )
    if gif_path is not None:
        write_gif(gif_frames, gif_path, fps=video_fps / gif_every)
    return {"frames": frames, "fps": video_fps, "returns": [r["return"] for r in records]}


def _first_line(error: BaseException) -> str:
    lines = str(error).strip().splitlines()
    return lines[0] if lines else type(error).__name__


def _frames_in(path: Path) -> int:
    """The frames ffmpeg can read back from ``path`` (0 for a file it cannot read)."""
    from imageio_ffmpeg import count_frames_and_secs

    try:
        return count_frames_and_secs(str(path))[0]
    except (OSError, RuntimeError):
        return 0


def _shrink(frame: np.ndarray, width: int) -> np.ndarray:
    step = max(1, frame.shape[1] // width)
    return frame[::step, ::step]


def write_gif(frames: list[np.ndarray], path: str | os.PathLike[str], fps: float) -> None:
    with atomic_path(path) as temp:
        imageio.mimsave(temp, frames, format="GIF", duration=1000.0 / fps, loop=0)


def read_video(path: str | os.PathLike[str]) -> tuple[np.ndarray, float]:
    """All frames of a video and its fps (for tests and checks)."""
    reader = imageio.get_reader(path, format="FFMPEG")
    try:
        fps = float(reader.get_meta_data()["fps"])
        frames = np.stack(list(reader.iter_data()))
    finally:
        reader.close()
    return frames, fps
