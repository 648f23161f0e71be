"""train.py end to end, in subprocesses with tiny budgets."""

from __future__ import annotations

import fcntl
import os
import pty
import signal
import struct
import subprocess
import sys
import termios
import time
import zipfile

import numpy as np
import pytest
import yaml
from stable_baselines3 import PPO, SAC

import evaluate
import train
from minitaur_env.training import UsageError
from minitaur_env.training.algorithms import load_model
from minitaur_env.training.replay_buffer import load_replay_buffer
from minitaur_env.training.video import read_video
from tests.scripts import REPO, TINY, error_lines, needs, run_main, run_script, start_script

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

FAST_SAC = [
    "--hyperparams",
    "learning_starts=50",
    "buffer_size=5000",
    "batch_size=32",
    "train_freq=1",
    "gradient_steps=1",
]


def run_dir_of(root, algo="sac", env="MinitaurBulletEnv-v0", n=1):
    return root / "logs" / algo / f"{env}_{n}"


def test_default_run_leaves_everything_behind(tmp_path):
    result = run_script(
        "train.py",
        "-n",
        "240",
        *FAST_SAC,
        "--eval-freq",
        "120",
        "--eval-episodes",
        "2",
        "--save-freq",
        "80",
        "--video-freq",
        "200",
        "--video-length",
        "30",
        *TINY,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    run = run_dir_of(tmp_path)
    config = yaml.safe_load((run / "config.yml").read_text())
    assert config["algo"] == "sac" and config["n_timesteps"] == 240
    assert config["hyperparams"]["policy_kwargs"] == {"net_arch": [256, 256]}
    assert config["hyperparams"]["learning_starts"] == 50
    assert config["hyperparams"]["n_steps"] == 10  # the default Minitaur entry
    assert config["normalize"] is True  # observations and rewards
    assert "train.py" in (run / "command.txt").read_text()

    with np.load(run / "evaluations.npz") as evaluations:
        np.testing.assert_array_equal(evaluations["timesteps"], [120, 240])
        assert evaluations["results"].shape == (2, 2)
        np.testing.assert_array_equal(evaluations["ep_lengths"], 40)

    model = load_model(SAC, run / "best_model.zip")
    observation = np.zeros(model.observation_space.shape, np.float32)  # the default: 3 x 28
    action, _ = model.predict(observation, deterministic=True)
    assert action.shape == (8,) and np.all(np.abs(action) <= 1)
    assert load_model(SAC, run / "MinitaurBulletEnv-v0.zip").num_timesteps == 240

    checkpoints = sorted(p.name for p in (run / "checkpoints").iterdir())
    assert checkpoints == [
        "rl_model_160_steps.zip",
        "rl_model_240_steps.zip",
        "rl_model_80_steps.zip",
        "rl_model_replay_buffer_160_steps.npz",  # plain arrays: resuming unpickles nothing
        "rl_model_replay_buffer_240_steps.npz",
        "rl_model_vecnormalize_160_steps.json",  # pickle-free, for loaders that trust none
        "rl_model_vecnormalize_160_steps.pkl",
        "rl_model_vecnormalize_240_steps.json",
        "rl_model_vecnormalize_240_steps.pkl",
        "rl_model_vecnormalize_80_steps.json",
        "rl_model_vecnormalize_80_steps.pkl",
    ]
    assert (run / "MinitaurBulletEnv-v0" / "vecnormalize.json").is_file()
    assert (run / "best_model_vecnormalize.json").is_file()
    assert (run / "monitor" / "0.monitor.csv").read_text().count("\n") > 2
    assert "train/critic_loss" in (run / "progress.csv").read_text()
    assert (run / "learning_curve.png").read_bytes().startswith(b"\x89PNG")

    video = run / "videos" / "sac-MinitaurBulletEnv-v0_1-step-200.mp4"
    frames, fps = read_video(video)
    assert fps == 50 and frames.shape == (15, 480, 640, 3)  # 30 steps at 100 Hz, every 2nd
    assert frames.std() > 10
    assert (tmp_path / "videos" / video.name).read_bytes() == video.read_bytes()
    assert "last eval" in result.stdout and "steps/s" in result.stdout
    # Not a terminal: one line per evaluation, and no SB3 logger table.
    lines = [line for line in result.stderr.splitlines() if "  step " in line]
    assert [line.split("  ")[1] for line in lines] == ["step 120/240", "step 240/240"]
    assert all(" eval " in line and "ETA" in line for line in lines)
    assert "total_timesteps" not in result.stdout


def run_in_terminal(args: list[str], cwd) -> str:
    """Run train.py with a pseudo-terminal as its stdout and stderr; its output."""
    main, child = pty.openpty()
    fcntl.ioctl(child, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))
    process = subprocess.Popen(
        [sys.executable, str(REPO / "train.py"), *args],
        cwd=cwd,
        stdin=subprocess.DEVNULL,
        stdout=child,
        stderr=child,
    )
    os.close(child)
    output = b""
    while True:
        try:
            chunk = os.read(main, 4096)
        except OSError:  # EIO: the child closed the terminal
            break
        if not chunk:
            break
        output += chunk
    os.close(main)
    assert process.wait(timeout=300) == 0, output.decode(errors="replace")[-2000:]
    return output.decode(errors="replace")


def test_a_terminal_gets_a_progress_bar_and_v1_the_logger_tables(tmp_path):
    args = [
        "-n",
        "80",
        *FAST_SAC,
        "--eval-freq",
        "40",
        "--eval-episodes",
        "1",
        "--save-freq",
        "0",
        "--env-kwargs",
        "max_episode_steps=20",
    ]
    shown = run_in_terminal(args, tmp_path)
    assert "80/80" in shown and "step/s" in shown and "eval " in shown  # the bar, at its end
    assert "  step 40/80" not in shown and "total_timesteps" not in shown
    tables = run_script("train.py", *args, "-v", "1", "--tensorboard-log", "tb", cwd=tmp_path)
    assert tables.returncode == 0, tables.stderr
    assert "| time/" in tables.stdout and "total_timesteps |" in tables.stdout
    events = list((tmp_path / "tb").rglob("events.out.tfevents.*"))
    assert len(events) == 1 and events[0].stat().st_size > 0


def test_sbx_backend_trains_checkpoints_resumes_and_evaluates(tmp_path):
    sbx = needs("sbx")
    args = ["--backend", "sbx", "-n", "200", *FAST_SAC, "--eval-freq", "100"]
    result = run_script(
        "train.py", *args, "--eval-episodes", "1", "--save-freq", "50", *TINY, cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    run = run_dir_of(tmp_path)
    model = load_model(sbx.SAC, run / "best_model.zip")
    observation = np.zeros(model.observation_space.shape, np.float32)  # the default: 3 x 28
    action, _ = model.predict(observation, deterministic=True)
    assert action.shape == (8,)
    (run / "checkpoints" / "rl_model_200_steps.zip").unlink()  # as if killed before it
    # No flag: the checkpoint's flax state is read from its msgpack member, not unpickled.
    resumed = run_script("train.py", "--resume", str(run), "-n", "250", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert "for 100 steps (from 150)" in resumed.stdout
    final = load_model(sbx.SAC, run / "MinitaurBulletEnv-v0.zip")
    assert final.num_timesteps == 250
    load_replay_buffer(
        final.replay_buffer, run / "checkpoints" / "rl_model_replay_buffer_250_steps.npz"
    )
    assert final.replay_buffer.size() == 149 + 99  # the 150-step buffer was resumed
    model = str(run / "MinitaurBulletEnv-v0.zip")
    evaluated = run_script("evaluate.py", "--model", model, "--episodes", "1", cwd=tmp_path)
    assert evaluated.returncode == 0, evaluated.stderr
    assert "(sac, sbx, observations normalized)" in evaluated.stdout
    # Control: as SBX itself saves it (no msgpack member), its flax state is only a pickle.
    final.save(model)
    refused = run_main(evaluate.main, "--model", model, "--episodes", "1", cwd=tmp_path)
    assert refused.returncode == 2 and error_lines(refused)[-1].endswith(
        "an SBX model saved without its JAX state would unpickle it, and a pickle can run "
        "code from the file; pass --trust-pickle if you trust where it came from"
    ), refused.stderr
    evaluated = run_script(
        "evaluate.py", "--model", model, "--episodes", "1", "--trust-pickle", cwd=tmp_path
    )
    assert evaluated.returncode == 0, evaluated.stderr


def test_video_recording_does_not_change_training_nor_stop_it_on_a_write_error(tmp_path):
    common = ["-n", "150", *FAST_SAC, "--eval-freq", "0", "--save-freq", "0", *TINY]
    plain = run_main(train.main, *common, cwd=tmp_path)
    # The shared videos/ folder cannot be made (a file has its name): each video's copy
    # there fails, which costs that copy, not the run.
    (tmp_path / "videos").write_text("a file where the shared videos folder would go")
    filmed = run_main(
        train.main, *common, "--video-freq", "60", "--video-length", "10", cwd=tmp_path
    )
    assert plain.returncode == 0 and filmed.returncode == 0, filmed.stderr
    skipped = [line.split(":")[0] for line in filmed.stderr.splitlines() if "skipped" in line]
    assert skipped == ["video at step 60 skipped", "video at step 120 skipped"]
    a = load_model(SAC, run_dir_of(tmp_path, n=1) / "MinitaurBulletEnv-v0.zip")
    b = load_model(SAC, run_dir_of(tmp_path, n=2) / "MinitaurBulletEnv-v0.zip")
    assert len(list((run_dir_of(tmp_path, n=2) / "videos").glob("*.mp4"))) == 2
    for (name, pa), (_, pb) in zip(
        a.policy.state_dict().items(), b.policy.state_dict().items(), strict=True
    ):
        assert np.array_equal(pa.numpy(), pb.numpy()), name


def _wait_for(path_glob, root, timeout=600):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = list(root.glob(path_glob))
        if found:
            return found
        time.sleep(0.2)
    raise TimeoutError(path_glob)


def test_kill_9_then_resume_continues_steps_and_replay_buffer(tmp_path):
    args = ["-n", "600", *FAST_SAC, "--eval-freq", "0", "--save-freq", "100", *TINY]
    process = start_script("train.py", *args, cwd=tmp_path)
    run = run_dir_of(tmp_path)
    # the zip is a checkpoint's last file: once it is there, the buffer is too
    _wait_for("logs/sac/*/checkpoints/rl_model_200_steps.zip", tmp_path)
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=120)
    saved = max(
        int(p.name.split("_")[2]) for p in (run / "checkpoints").glob("rl_model_*_steps.zip")
    )
    assert 200 <= saved < 600

    result = run_main(train.main, "--resume", str(run), cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "(from " in result.stdout
    resumed_from = int(result.stdout.split("(from ")[1].split(")")[0])
    assert resumed_from >= saved - 100  # loses at most --save-freq steps
    final = load_model(SAC, run / "MinitaurBulletEnv-v0.zip")
    assert final.num_timesteps == 600
    load_replay_buffer(
        final.replay_buffer, run / "checkpoints" / "rl_model_replay_buffer_600_steps.npz"
    )
    # The pre-kill transitions were kept. SB3 checkpoints a step before storing its
    # transition, so each checkpoint (the resumed one, the last one) lacks one.
    assert final.replay_buffer.size() == 600 - 2
    assert list(run.glob("progress-resumed-at-*.csv"))


@pytest.mark.parametrize("sigint_ignored", [False, True], ids=["foreground", "background"])
def test_ctrl_c_saves_model_and_replay_buffer(tmp_path, sigint_ignored):
    # "background": started as `train.py &` from a script, SIGINT ignored at start (Python
    # then installs no handler); an explicit `kill -INT` must still checkpoint and stop.
    args = ["-n", "100000", *FAST_SAC, "--eval-freq", "0", "--save-freq", "100", *TINY]
    process = start_script("train.py", *args, cwd=tmp_path, sigint_ignored=sigint_ignored)
    _wait_for("logs/sac/*/checkpoints/rl_model_200_steps.zip", tmp_path)
    process.send_signal(signal.SIGINT)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 130, stderr
    assert "interrupted: saved" in stderr and "--resume" in stderr
    run = run_dir_of(tmp_path)
    steps = int(stderr.split("rl_model_")[1].split("_steps")[0])
    assert steps > 100
    assert (run / "checkpoints" / f"rl_model_replay_buffer_{steps}_steps.npz").exists()
    assert (
        load_model(SAC, run / "checkpoints" / f"rl_model_{steps}_steps.zip").num_timesteps == steps
    )


# PPO's envs in 3 processes, more than this 2-core machine has: the common user machine.
THREE_PROCESSES = [
    "--algo",
    "ppo",
    "--n-envs",
    "6",
    "--vec-env",
    "grouped",
    "--hyperparams",
    "n_steps=32",
    "batch_size=32",
]


BROKEN_IN_WORKERS = """
import multiprocessing
import gymnasium as gym


class BrokenInWorkers(gym.Wrapper):
    def __init__(self):
        super().__init__(gym.make("Pendulum-v1"))
        self.steps = 0

    def step(self, action):
        self.steps += 1
        if self.steps == 30 and multiprocessing.parent_process() is not None:
            raise RuntimeError("motor driver fault")
        return super().step(action)


gym.register("BrokenInWorkers-v0", entry_point=BrokenInWorkers, max_episode_steps=200)
"""


def assert_process_group_ends(group: int, timeout: float = 10) -> None:
    """No worker outlives the trainer (dead ones wait to be reaped by init for a moment)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            os.killpg(group, 0)
        except ProcessLookupError:
            return
        time.sleep(0.2)
    raise AssertionError(f"processes of group {group} still alive after {timeout} s")


def start_with_three_worker_processes(tmp_path, *args, setup=""):
    """train.py with available_cores() forced to 3, so 6 envs get 2 worker processes."""
    launcher = tmp_path / "train_on_3_cores.py"
    launcher.write_text(
        f"import sys\nsys.path.insert(0, {str(REPO)!r})\n{setup}\n"
        "from minitaur_env.training import envs, vec_env\n"
        "envs.available_cores = vec_env.available_cores = lambda: 3\n"
        "import train\n"
        "if __name__ == '__main__':\n"
        "    sys.exit(train.main())\n"
    )
    return start_script(str(launcher), *args, cwd=tmp_path, own_process_group=True)


@pytest.mark.parametrize(
    ("how", "code"),
    [
        ("ctrl-c to the group", 130),
        ("sigterm to the group", 143),
        ("sigterm to the trainer", 143),
    ],
)
def test_ctrl_c_and_sigterm_with_worker_processes_save_a_checkpoint(tmp_path, how, code):
    process = start_with_three_worker_processes(
        tmp_path,
        "-n",
        "100000",
        "--eval-freq",
        "0",
        "--save-freq",
        "96",
        *THREE_PROCESSES,
        *TINY,
    )
    # Training is under way past a checkpoint: the signal lands mid-run, not at the start.
    _wait_for("logs/ppo/*/checkpoints/rl_model_192_steps.zip", tmp_path, timeout=600)
    if how == "ctrl-c to the group":
        os.killpg(process.pid, signal.SIGINT)
    elif how == "sigterm to the group":
        os.killpg(process.pid, signal.SIGTERM)  # Slurm, a container stop
    else:
        process.send_signal(signal.SIGTERM)  # timeout, Ray, kill
    _, stderr = process.communicate(timeout=300)  # it stops, however slow the machine
    assert process.returncode == code, stderr
    assert "interrupted: saved" in stderr and "--resume" in stderr and "Traceback" not in stderr
    assert_process_group_ends(process.pid)
    run = run_dir_of(tmp_path, "ppo")
    steps = int(stderr.split("rl_model_")[1].split("_steps")[0])
    assert PPO.load(run / "checkpoints" / f"rl_model_{steps}_steps.zip").num_timesteps == steps


def test_sigterm_without_workers_saves_model_and_replay_buffer(tmp_path):
    args = ["-n", "100000", *FAST_SAC, "--eval-freq", "0", "--save-freq", "100", *TINY]
    process = start_script("train.py", *args, cwd=tmp_path)
    _wait_for("logs/sac/*/checkpoints/rl_model_200_steps.zip", tmp_path, timeout=600)
    process.send_signal(signal.SIGTERM)
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 143, stderr
    steps = int(stderr.split("rl_model_")[1].split("_steps")[0])
    assert (
        run_dir_of(tmp_path) / "checkpoints" / f"rl_model_replay_buffer_{steps}_steps.npz"
    ).exists()


def test_an_env_failing_in_a_worker_ends_the_run_with_one_line_and_a_checkpoint(tmp_path):
    process = start_with_three_worker_processes(
        tmp_path,
        "--env",
        "BrokenInWorkers-v0",
        "-n",
        "2000",
        "--eval-freq",
        "0",
        "--save-freq",
        "1000",
        *THREE_PROCESSES,
        "-v",
        "0",
        setup=BROKEN_IN_WORKERS,
    )
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 1, stderr
    assert error_lines(stderr) == [
        "train.py: error: env 2 raised RuntimeError: motor driver fault; "
        "saved logs/ppo/BrokenInWorkers-v0_1/checkpoints/rl_model_174_steps.zip "
        "(resume with --resume logs/ppo/BrokenInWorkers-v0_1); "
        "details in logs/ppo/BrokenInWorkers-v0_1/failure.txt"
    ]


def test_resume_extends_with_n_and_refuses_contradicting_flags(tmp_path):
    args = ["-n", "100", *FAST_SAC, "--eval-freq", "0", "--save-freq", "50", *TINY]
    assert run_main(train.main, *args, cwd=tmp_path).returncode == 0
    run = str(run_dir_of(tmp_path))
    written = [
        run_dir_of(tmp_path) / name
        for name in (
            "config.yml",
            "command.txt",
            "MinitaurBulletEnv-v0/args.yml",
            "MinitaurBulletEnv-v0/config.yml",
        )
    ]
    before = [path.read_bytes() for path in written]
    for flags, message in (
        (["--seed", "3"], "seed 3 contradicts the run's saved seed 0"),
        (["--hyperparams", "batch_size=64"], "hyperparams.batch_size 64 contradicts"),
        (["--env-kwargs", "energy_weight=0.1"], "env_kwargs.energy_weight 0.1 contradicts"),
        (["--config", "tutorial"], "--config cannot be combined with --resume"),
        (["-n", "50"], "-n 50: its newest checkpoint is at 100"),
    ):
        refused = run_main(train.main, "--resume", run, *flags, cwd=tmp_path)
        assert refused.returncode == 2 and error_lines(refused) == [
            line for line in error_lines(refused) if message in line
        ], refused.stderr
        # a refused resume leaves the run's settings as they were
        assert [path.read_bytes() for path in written] == before, flags
    extended = run_main(
        train.main,
        "--resume",
        run,
        "-n",
        "150",
        "--seed",
        "0",
        "--num-threads",
        "1",
        "-v",
        "0",
        cwd=tmp_path,
    )
    assert extended.returncode == 0, extended.stderr
    assert "for 50 steps (from 100)" in extended.stdout
    assert load_model(SAC, run_dir_of(tmp_path) / "MinitaurBulletEnv-v0.zip").num_timesteps == 150


def test_nan_stops_the_run_and_keeps_good_checkpoints(tmp_path):
    result = run_main(
        train.main,
        "-n",
        "400",
        "--hyperparams",
        "learning_starts=30",
        "learning_rate=1e12",
        "batch_size=16",
        "--eval-freq",
        "0",
        "--save-freq",
        "10",
        *TINY,
        cwd=tmp_path,
    )
    assert result.returncode == 1
    lines = error_lines(result)
    assert len(lines) == 1 and "training diverged" in lines[0]
    assert "last good checkpoint" in lines[0]
    for checkpoint in (run_dir_of(tmp_path) / "checkpoints").glob("rl_model_*_steps.zip"):
        model = load_model(SAC, checkpoint)
        for parameter in model.policy.parameters():
            assert parameter.isfinite().all(), checkpoint.name
    assert not (run_dir_of(tmp_path) / "MinitaurBulletEnv-v0.zip").exists()


def test_generic_on_cartpole_with_ppo(tmp_path):
    result = run_main(
        train.main,
        "--algo",
        "ppo",
        "--env",
        "CartPole-v1",
        "-n",
        "256",
        "--hyperparams",
        "n_steps=64",
        "batch_size=32",
        "normalize=true",
        "--n-envs",
        "2",
        "--eval-freq",
        "128",
        "--eval-episodes",
        "2",
        "--save-freq",
        "128",
        "-v",
        "0",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    run = run_dir_of(tmp_path, "ppo", "CartPole-v1")
    model = PPO.load(run / "best_model.zip", device="cpu")
    assert model.action_space.n == 2
    with np.load(run / "evaluations.npz") as evaluations:
        assert len(evaluations["timesteps"]) == 2
    assert zipfile.is_zipfile(run / "checkpoints" / "rl_model_128_steps.zip")
    # VecNormalize statistics travel with the final, best and checkpointed models.
    assert (run / "CartPole-v1" / "vecnormalize.pkl").is_file()
    assert (run / "best_model_vecnormalize.pkl").is_file()
    assert (run / "checkpoints" / "rl_model_vecnormalize_128_steps.pkl").is_file()
    evaluated = run_main(
        evaluate.main,
        "--model",
        str(run / "best_model.zip"),
        "--episodes",
        "2",
        "--json",
        "stats.json",
        cwd=tmp_path,
    )
    assert evaluated.returncode == 0, evaluated.stderr
    assert "observations normalized" in evaluated.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--no-such-flag"], "unrecognized arguments: --no-such-flag"),
        (["--algo", "dqn"], "invalid choice: 'dqn'"),
        (["--env", "NoSuchEnv-v9"], "unknown env id 'NoSuchEnv-v9'"),
        (["--eval-freq", "-5"], "--eval-freq must be >= 0"),
        (["-f", "{file}/logs"], "cannot write to"),
        (["--hyperparams", "not_a_param=1"], "invalid hyperparameters for sac"),
        (["--hyperparams", "novalue"], "expects key=value"),
        (["--resume", "{tmp}/missing-run"], "no config.yml"),
        (["--env-kwargs", "energy_weight=-1"], "energy_weight must be in [0, inf), got -1"),
        (["--vec-env", "subproc"], "invalid choice: 'subproc'"),
        (["--vec-env", "threads"], "invalid choice: 'threads'"),
        (["-i", "{tmp}/missing.zip"], "--trained-agent: no model file at"),
        (["-i", "{file}"], "is not a Stable-Baselines3 model file"),
    ],
)
def test_user_errors_give_one_clear_line(tmp_path, args, message):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    args = [a.replace("{file}", str(blocker)).replace("{tmp}", str(tmp_path)) for a in args]
    # Two cases run as a user runs the script; the others through its main() in this process.
    if "NoSuchEnv-v9" in args or "dqn" in args:
        result = run_script("train.py", *args, cwd=tmp_path, timeout=120)
    else:
        result = run_main(train.main, *args, cwd=tmp_path)
    assert result.returncode == 2
    lines = error_lines(result)
    assert len(lines) == 1, result.stderr
    assert message in lines[0]
    assert not (tmp_path / "logs" / "sac").exists() or not any(
        (tmp_path / "logs" / "sac").iterdir()
    )


def test_eval_env_normalizes_observations_as_training_does():
    from minitaur_env.training.envs import make_eval_env

    reward_only = make_eval_env("CartPole-v1", seed=0, normalize={"norm_obs": False})
    assert not reward_only.norm_obs and not reward_only.norm_reward and not reward_only.training
    both = make_eval_env("CartPole-v1", seed=0, normalize=True)
    assert both.norm_obs and not both.norm_reward
    reward_only.close()
    both.close()


def test_evaluations_normalize_observations_with_the_training_statistics(tmp_path):
    from minitaur_env.training import Experiment, ExperimentConfig

    config = ExperimentConfig.resolve(
        "sac",
        "Pendulum-v1",
        n_timesteps=300,
        eval_freq=150,
        eval_episodes=1,
        save_freq=0,
        vec_env="dummy",
        device="cpu",
        hyperparams={
            "learning_starts": 50,
            "batch_size": 16,
            "normalize": True,
            "policy_kwargs": {"net_arch": [8]},
        },
    )
    experiment = Experiment.create(config, tmp_path)
    assert experiment.run().status == "completed"
    trained, evaluated = experiment.env, experiment.eval_env
    assert not evaluated.training  # evaluation never updates the statistics...
    # ...it uses the training env's, synced at each evaluation (the last one at step 300,
    # so they match the statistics the run ended with)
    np.testing.assert_array_equal(evaluated.obs_rms.mean, trained.obs_rms.mean)
    assert trained.obs_rms.count > 300  # and those saw the training observations


def test_hyperparameter_entries_resolve_with_bases_and_named_configs():
    from minitaur_env.training.hyperparams import hard_draws, load_hyperparams

    tuned = load_hyperparams("sac", "MinitaurBulletEnv-v0")
    tutorial = load_hyperparams("sac", "MinitaurBulletEnv-v0", entry="tutorial")
    assert tutorial["buffer_size"] == 10_000 and "n_steps" not in tutorial
    assert tuned["buffer_size"] == 100_000 and tuned["n_steps"] == 10
    assert tuned["policy_kwargs"] == tutorial["policy_kwargs"]  # inherited through `base`
    assert load_hyperparams("sac", "minitaur_env:MinitaurBullet-v0") == tuned
    # The classic ids' default is the half-updates entry (five bases deep); the ids it was
    # not measured on keep the minitaur entry it extends.
    minitaur = load_hyperparams("sac", "MinitaurBulletEnv-v0", entry="minitaur")
    mirror = {**minitaur, "mirror": True, "gamma": 0.98, "tau": 0.02}
    assert load_hyperparams("sac", "MinitaurBulletEnv-v0", entry="minitaur-mirror") == mirror
    n_steps_after = {"at": 0.5, "n_steps": 5}
    history = {"env_kwargs": {"history": 3}, "n_steps": 10, "n_steps_after": n_steps_after}
    nstep = {**mirror, **history}
    assert load_hyperparams("sac", "MinitaurBulletEnv-v0", entry="minitaur-history-nstep") == nstep
    assert tuned == {**nstep, "gradient_steps": 4} and nstep["gradient_steps"] == 8
    assert load_hyperparams("sac", "MinitaurBulletTrot-v0") == minitaur
    assert load_hyperparams("sac", "Acrobot-v1") == {"n_timesteps": 100000, "policy": "MlpPolicy"}
    assert load_hyperparams("sac", "Pendulum-v1")["learning_rate"] == 1e-3  # its own entry
    with pytest.raises(UsageError, match="no entry 'nope'"):
        load_hyperparams("sac", "MinitaurBulletEnv-v0", entry="nope")
    # PPO's classic ids decay the minitaur entry's rate; the other ids keep the entry,
    # and the robust recipe's history entry stays the shipped robust policy's.
    ppo = load_hyperparams("ppo", "MinitaurBulletEnv-v0", entry="minitaur")
    assert ppo["learning_rate"] == 2.5e-4
    for env in ("MinitaurBulletEnv-v0", "MinitaurBullet-v0"):
        assert load_hyperparams("ppo", env) == {**ppo, "learning_rate": "lin_2.5e-4"}
    for env in ("MinitaurBulletDuckEnv-v0", "MinitaurBulletRandomized-v0"):
        assert load_hyperparams("ppo", env) == ppo
    history = load_hyperparams("ppo", "MinitaurBulletTrotRandomized-v0", entry="trot-history")
    assert history["learning_rate"] == 2.5e-4
    decay = load_hyperparams("ppo", "MinitaurBulletTrotRandomized-v0", entry="trot-history-decay")
    assert decay == {**history, "n_timesteps": 1_000_000, "learning_rate": "lin_2.5e-4"}
    assert load_hyperparams("ppo", "MinitaurBulletTrotRandomized-v0") == decay
    # The recipe under test is the decaying one with 2 of its 8 envs near the classic end.
    classic_end = load_hyperparams(
        "ppo", "MinitaurBulletTrotRandomized-v0", entry="trot-classic-draws"
    )
    assert {k: v for k, v in classic_end.items() if k != "hard_draws"} == decay
    [(envs, realism)] = hard_draws(classic_end, classic_end["n_envs"])
    assert (envs, realism["control_time_step"]) == (range(2), [0.008, 0.012])
    # Its successor under test adds 2 envs at the hard corner after the classic end's 2.
    both = load_hyperparams("ppo", "MinitaurBulletTrotRandomized-v0", entry="trot-hard-classic")
    assert {k: v for k, v in both.items() if k != "hard_draws"} == decay
    [(classic_envs, classic), (hard_envs, hard)] = hard_draws(both, both["n_envs"])
    assert (classic_envs, classic) == (envs, realism)
    assert (hard_envs, hard["control_latency"]) == (range(2, 4), [0.02, 0.04])


def test_runs_started_together_get_their_own_folders(tmp_path):
    from concurrent.futures import ThreadPoolExecutor

    from minitaur_env.training.run_folder import RunFolder

    def start(_):
        return RunFolder.create(tmp_path / "logs", "tqc", "MinitaurBulletEnv-v0").path

    for _ in range(5):
        with ThreadPoolExecutor(8) as pool:
            folders = list(pool.map(start, range(8)))
        assert len(set(folders)) == 8 and all(folder.is_dir() for folder in folders)
    assert len(list((tmp_path / "logs" / "tqc").iterdir())) == 40  # no probe left behind


def test_an_unwritable_tensorboard_folder_is_refused_before_training(tmp_path):
    (tmp_path / "a-file").write_text("")
    result = run_main(
        train.main,
        "--env",
        "Pendulum-v1",
        "-n",
        "100",
        "--tensorboard-log",
        str(tmp_path / "a-file" / "tb"),
        "-f",
        str(tmp_path / "logs"),
        "-v",
        "0",
        cwd=tmp_path,
    )
    assert result.returncode == 2
    assert error_lines(result) == [
        f"train.py: error: cannot write to {tmp_path / 'a-file' / 'tb'}: Not a directory"
    ]
    assert not list((tmp_path / "logs").glob("*/*"))  # no half-made run folder


def test_evaluation_settings_come_from_the_entry_and_a_flag_wins():
    from minitaur_env.training.cli import config_from_args

    def config(*argv: str):
        return config_from_args(train.build_parser().parse_args(list(argv)))

    sac, ppo = config(), config("--algo", "ppo")
    assert (sac.eval_freq, sac.eval_episodes) == (10_000, 10)
    assert (ppo.eval_freq, ppo.eval_episodes) == (25_000, 10)  # the PPO entry's
    assert "eval_freq" not in ppo.hyperparams  # a run setting, never PPO's keyword
    given = config("--algo", "ppo", "--eval-freq", "5000", "--eval-episodes", "3")
    assert (given.eval_freq, given.eval_episodes) == (5_000, 3)
    assert config("--algo", "ppo", "--eval-freq", "0").eval_freq == 0  # 0 is given, not unset
    via_hyperparams = config("--hyperparams", "eval_freq=20000")
    assert via_hyperparams.eval_freq == 20_000 and "eval_freq" not in via_hyperparams.hyperparams
    with pytest.raises(UsageError, match="eval_episodes"):
        config("--hyperparams", "eval_episodes=2.5")
