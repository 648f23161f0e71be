"""Env throughput: step, reset, render and vectorized, against named baselines.

Baselines, measured in this same run:
- the physics-only bound: the time of the bare ``stepSimulation`` calls of each env step
  (5 per step at the default settings), timed inside the very same rollout;
- the classic ``pybullet_envs`` MinitaurBulletEnv from the pybullet wheel, when it can be
  imported (it needs ``pip install gym==0.26.2 'setuptools>=77.0.3,<81'``);
- for the vectorized figures, one env stepped in the main process (the same monitored
  env that SB3's ``make_vec_env`` builds), and two bare physics loops in two processes
  (how far two cores scale at all).

    python benchmarks/env_speed.py [--steps 3000] [--only step reset render vectorized] [--video]
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import io
import os
import sys
import time
import types

import gymnasium as gym
import numpy as np

from minitaur_env import MinitaurBulletEnv

STEP_ATTEMPTS = 3


def random_actions(n: int, seed: int = 0, size: int = 8) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-1, 1, (n, size)).astype(np.float32)


# Timed beside the nominal env, as randomization must not cost the nominal env speed and
# its own cost should be known. The Tan 2018 preset draws a control step of 3-20 ms per
# episode (1.5-10 physics steps per env step), so these are also given in simulated
# seconds per wall-clock second.
PRESETS = {
    "preset (MinitaurBulletRandomized-v0)": ("MinitaurBulletRandomized-v0", {}),
    "preset + trot prior, pushes, history 4": (
        "MinitaurBulletTrotRandomized-v0",
        {"realism": {"pushes": True}, "history": 4},
    ),
}


def time_our_steps(steps: int, env: gym.Env | None = None) -> tuple[float, float, float]:
    """(env steps/s, physics-only steps/s, simulated s per wall s) from one rollout, the
    physics timed inside it; the nominal env unless ``env`` is given."""
    env = env or MinitaurBulletEnv()
    sim = env.unwrapped.sim
    bare_step = sim.step
    physics = 0.0

    def timed_step() -> None:
        nonlocal physics
        start = time.perf_counter()
        bare_step()
        physics += time.perf_counter() - start

    sim.step = timed_step  # instrument this instance only
    actions = random_actions(steps, size=env.action_space.shape[0])
    env.reset(seed=0)
    physics = 0.0
    total = 0.0
    simulated = 0.0
    for action in actions:
        start = time.perf_counter()
        _, _, terminated, truncated, _ = env.step(action)
        total += time.perf_counter() - start
        simulated += env.unwrapped.dt  # the episode's drawn control step
        if terminated or truncated:
            settling = physics
            env.reset()
            physics = settling  # a reset's settling steps are not part of the steps' time
    env.close()
    return steps / total, steps / physics, simulated / total


@functools.cache  # a second import would find the bare stub module below and fail
def load_classic_env_class():
    """The classic env class from the pybullet wheel, or None with the reason."""
    import importlib.util

    spec = importlib.util.find_spec("pybullet_envs")
    if spec is None or not spec.submodule_search_locations:
        return None, "pybullet_envs not found"
    # pybullet_envs/__init__.py registers with the gym API of 2019 and fails today: load
    # the package as a bare module so only the bullet submodule is executed.
    package = types.ModuleType("pybullet_envs")
    package.__path__ = list(spec.submodule_search_locations)
    sys.modules.setdefault("pybullet_envs", package)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            from pybullet_envs.bullet.minitaur_gym_env import MinitaurBulletEnv as Classic
    except Exception as error:  # gym or pkg_resources missing
        return (
            None,
            f"{type(error).__name__}: {error} (pip install gym==0.26.2 'setuptools>=77.0.3,<81')",
        )
    return Classic, ""


def time_classic_steps(classic, steps: int) -> float:
    with contextlib.redirect_stdout(io.StringIO()):
        env = classic()
    env.reset()
    actions = random_actions(steps)
    total = 0.0
    for action in actions:
        start = time.perf_counter()
        _, _, done, _ = env.step(action)
        total += time.perf_counter() - start
        if done:
            env.reset()
    return steps / total


def time_resets(make, n: int) -> float:
    """Mean ms per reset (after a first one that builds the world)."""
    env = make()
    env.reset()
    start = time.perf_counter()
    for _ in range(n):
        env.reset()
    elapsed = (time.perf_counter() - start) / n * 1000
    return elapsed


def time_render(width: int, height: int, frames: int = 30) -> float:
    env = MinitaurBulletEnv(render_mode="rgb_array", width=width, height=height)
    env.reset(seed=0)
    env.render()
    start = time.perf_counter()
    for _ in range(frames):
        env.step(np.zeros(8, np.float32))
        env.render()
    elapsed = (time.perf_counter() - start) / frames * 1000
    env.close()
    return elapsed


def time_vectorized(n_envs: int, steps: int, vec_env_cls: type | None) -> float:
    """Env steps/s of ``n_envs`` envs in ``vec_env_cls``; None: one plain env in-process."""
    from stable_baselines3.common.env_util import make_vec_env

    actions = random_actions(steps)
    if vec_env_cls is None:
        env = make_vec_env("minitaur_env:MinitaurBulletEnv-v0", n_envs=1, seed=0).envs[0]
        env.reset(seed=0)
        start = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        elapsed = time.perf_counter() - start
        env.close()
        return steps / elapsed
    vec = make_vec_env(
        "minitaur_env:MinitaurBulletEnv-v0", n_envs=n_envs, seed=0, vec_env_cls=vec_env_cls
    )
    vec.reset()
    start = time.perf_counter()
    for action in actions:
        vec.step(np.tile(action, (n_envs, 1)))
    elapsed = time.perf_counter() - start
    vec.close()
    return n_envs * steps / elapsed


def _bare_physics(steps: int, results) -> None:
    env = MinitaurBulletEnv(randomize_dynamics=False)
    env.reset(seed=0)
    sim = env.sim
    start = time.perf_counter()
    for _ in range(steps * 5):  # 5 physics steps per env step
        sim.step()
    results.put(steps / (time.perf_counter() - start))
    env.close()


def time_bare_physics_processes(n_processes: int, steps: int) -> float:
    """Summed physics-only steps/s of ``n_processes`` concurrent bare physics loops."""
    import multiprocessing as mp

    context = mp.get_context("forkserver")
    results = context.Queue()
    processes = [
        context.Process(target=_bare_physics, args=(steps, results)) for _ in range(n_processes)
    ]
    for process in processes:
        process.start()
    rates = [results.get() for _ in processes]
    for process in processes:
        process.join()
    return sum(rates)


def time_video_episode() -> float:
    from minitaur_env.training.video import record_video

    env = MinitaurBulletEnv(render_mode="rgb_array")
    with contextlib.suppress(FileNotFoundError):
        os.remove("/tmp/minitaur-benchmark.mp4")
    start = time.perf_counter()
    record_video(env, lambda obs: np.zeros(8, np.float32), "/tmp/minitaur-benchmark.mp4", seed=0)
    env.close()
    return time.perf_counter() - start


SECTIONS = ("step", "reset", "render", "vectorized")


def step_figures(steps: int) -> None:
    # The presets are timed interleaved with the nominal env, so a slow spell of a shared
    # machine hits all of them alike; the best of the attempts counts for each.
    rounds = [
        [time_our_steps(steps)]
        + [time_our_steps(steps, gym.make(i, **k)) for i, k in PRESETS.values()]
        for _ in range(STEP_ATTEMPTS)
    ]
    best = [max(attempts, key=lambda r: r[0]) for attempts in zip(*rounds, strict=True)]
    (ours, physics, realtime), presets = best[0], best[1:]
    print(
        f"step: ours {ours:.0f} steps/s; physics-only bound {physics:.0f} steps/s; "
        f"ratio {ours / physics:.2f} of the bound"
    )
    for name, (rate, _, preset_realtime) in zip(PRESETS, presets, strict=True):
        print(
            f"step: {name} {rate:.0f} steps/s, {preset_realtime:.1f} simulated s/s; "
            f"nominal {ours:.0f} steps/s, {realtime:.1f} simulated s/s, same run"
        )
    classic, reason = load_classic_env_class()
    if classic is not None:
        classic_rate = max(time_classic_steps(classic, steps) for _ in range(STEP_ATTEMPTS))
        print(
            f"step: classic env {classic_rate:.0f} steps/s; ours/classic {ours / classic_rate:.2f}x"
        )
    else:
        print(f"step: classic env not measured ({reason})")


def reset_figures() -> None:
    hard = time_resets(lambda: MinitaurBulletEnv(), 20)
    fixed = time_resets(lambda: MinitaurBulletEnv(randomize_dynamics=False), 20)
    restored = time_resets(
        lambda: MinitaurBulletEnv(randomize_dynamics=False, hard_reset=False), 20
    )
    print(
        f"reset: ours hard {hard:.1f} ms (randomized), {fixed:.1f} ms (fixed dynamics); "
        f"hard_reset=False {restored:.2f} ms (fixed dynamics)"
    )
    classic, _ = load_classic_env_class()
    if classic is not None:
        with contextlib.redirect_stdout(io.StringIO()):
            classic_reset = time_resets(lambda: classic(env_randomizer=None), 20)
        print(
            f"reset: classic hard {classic_reset:.1f} ms; ratios classic/ours: hard "
            f"{classic_reset / fixed:.2f}x, hard_reset=False {classic_reset / restored:.0f}x"
        )


def render_figures() -> None:
    for width, height in ((640, 480), (960, 720), (320, 240)):
        print(f"render: {width}x{height} {time_render(width, height):.0f} ms/frame")


def vectorized_figures(steps: int) -> None:
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    from minitaur_env.training.vec_env import GroupedSubprocVecEnv

    half = steps // 2
    one = max(time_vectorized(1, half, None) for _ in range(2))
    physics_one = time_bare_physics_processes(1, half)
    physics_two = time_bare_physics_processes(2, half)
    print(
        f"vectorized: one env in-process {one:.0f} steps/s; bare physics in 2 processes "
        f"{physics_two / physics_one:.2f}x one process"
    )
    for name, cls, n_envs in (
        ("SubprocVecEnv, 1 worker", SubprocVecEnv, 1),
        ("SubprocVecEnv, 2 workers", SubprocVecEnv, 2),
        ("GroupedSubprocVecEnv, 2 envs in 2 processes", GroupedSubprocVecEnv, 2),
        ("GroupedSubprocVecEnv, 8 envs in 2 processes", GroupedSubprocVecEnv, 8),
        ("DummyVecEnv, 8 envs", DummyVecEnv, 8),
    ):
        rate = time_vectorized(n_envs, half if n_envs <= 2 else half // 4, cls)
        print(f"vectorized: {name}: {rate:.0f} steps/s; {rate / one:.2f}x one env in-process")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=3000, help="env steps per measurement")
    parser.add_argument(
        "--only",
        nargs="+",
        choices=SECTIONS,
        default=SECTIONS,
        metavar="PART",
        help=f"measure only these parts: {' '.join(SECTIONS)} (default: all)",
    )
    parser.add_argument("--video", action="store_true", help="also time a 1000-step video")
    args = parser.parse_args()
    print(f"env speed, {args.steps} random-action steps per figure, pid {os.getpid()}")
    if "step" in args.only:
        step_figures(args.steps)
    if "reset" in args.only:
        reset_figures()
    if "render" in args.only:
        render_figures()
    if "vectorized" in args.only:
        vectorized_figures(args.steps)
    if args.video:
        print(f"video: one 1000-step episode at 640x480, 50 fps: {time_video_episode():.1f} s")


if __name__ == "__main__":
    main()
