"""A kill at any write leaves a run folder that resumes, and a model that plays with its own
statistics: every file is replaced atomically, the statistics travel inside the model zip."""

from __future__ import annotations

import multiprocessing
import os
import random
import shutil
import signal
import time
import zipfile

import gymnasium as gym
import numpy as np
import pytest

from minitaur_env.training import Experiment, ExperimentConfig, UsageError
from minitaur_env.training.evaluation import load_policy
from minitaur_env.training.run_folder import EMBEDDED_STATISTICS, RunFolder
from minitaur_env.training.safe_load import embedded_evaluation
from tests.scripts import REPO, error_lines, run_script

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

NORMALIZED_SAC = {
    "learning_starts": 50,
    "batch_size": 16,
    "buffer_size": 2000,
    "normalize": True,
    "policy_kwargs": {"net_arch": [8]},
}


def pendulum_run(tmp_path, n_timesteps=300) -> RunFolder:
    config = ExperimentConfig.resolve(
        "sac",
        "Pendulum-v1",
        hyperparams=NORMALIZED_SAC,
        n_timesteps=n_timesteps,
        eval_freq=100,
        eval_episodes=1,
        save_freq=100,
        vec_env="dummy",
        device="cpu",
    )
    result = Experiment.create(config, tmp_path / "logs").run()
    assert result.status == "completed"
    return result.run


def test_every_model_zip_carries_the_statistics_it_acts_with(tmp_path):
    run = pendulum_run(tmp_path)
    for model in (run.zoo_model, run.best_model, run.checkpoint(300)):
        with zipfile.ZipFile(model) as archive:
            assert EMBEDDED_STATISTICS in archive.namelist(), model
    final = load_policy(run.zoo_model, device="cpu")
    beside = load_policy(run.checkpoint(300), device="cpu")  # the same step, saved twice
    np.testing.assert_array_equal(final.normalizer.mean, beside.normalizer.mean)
    # A copy of the zip alone, in a folder of another name, plays as the run does.
    elsewhere = tmp_path / "my-walker" / "model.zip"
    elsewhere.parent.mkdir()
    shutil.copyfile(run.zoo_model, elsewhere)
    copied = load_policy(elsewhere, device="cpu")
    np.testing.assert_array_equal(copied.normalizer.mean, final.normalizer.mean)
    obs = np.ones(3, dtype=np.float32)
    np.testing.assert_array_equal(copied.act(obs), final.act(obs))


def test_a_normalized_model_without_its_statistics_is_refused(tmp_path):
    run = pendulum_run(tmp_path, n_timesteps=200)
    bare = run.path / "bare.zip"
    with zipfile.ZipFile(run.zoo_model) as source, zipfile.ZipFile(bare, "w") as target:
        for name in source.namelist():
            if name != EMBEDDED_STATISTICS:  # as SB3 itself, or an older version, saved it
                target.writestr(name, source.read(name))
    with pytest.raises(UsageError, match=r"trained with VecNormalize .* neither in the zip"):
        load_policy(bare, device="cpu")


def test_a_zip_alone_without_statistics_is_played_raw_and_evaluate_says_so(tmp_path):
    run = pendulum_run(tmp_path, n_timesteps=200)
    alone = tmp_path / "downloads" / "model.zip"  # no config.yml to say how it was trained
    alone.parent.mkdir()
    with zipfile.ZipFile(run.zoo_model) as source, zipfile.ZipFile(alone, "w") as target:
        for name in source.namelist():
            if name != EMBEDDED_STATISTICS:
                target.writestr(name, source.read(name))
    loaded = load_policy(alone, device="cpu")
    assert loaded.normalizer is None and loaded.normalization_unknown
    played = run_script(
        "evaluate.py",
        "--model",
        str(alone),
        "--env",
        "Pendulum-v1",
        "--episodes",
        "1",
        cwd=tmp_path,
    )
    assert played.returncode == 0, played.stderr
    assert (
        f"policy: {alone} (sac, raw observations: no VecNormalize statistics in the zip and "
        "no config.yml beside it to say it was trained without them) on Pendulum-v1"
    ) in played.stdout
    shutil.copyfile(run.zoo_model, alone)  # control: the zip carries its statistics
    loaded = load_policy(alone, device="cpu")
    assert loaded.normalizer is not None and not loaded.normalization_unknown


def test_algo_that_contradicts_the_zip_is_one_line(tmp_path):
    shipped = REPO / "pretrained" / "ppo" / "MinitaurBulletEnv-v0_1" / "MinitaurBulletEnv-v0.zip"
    played = run_script(
        "evaluate.py", "--model", str(shipped), "--algo", "a2c", "--episodes", "1", cwd=tmp_path
    )
    assert error_lines(played) == [
        f"evaluate.py: error: {shipped} holds a ppo model, not a2c; drop --algo"
    ]


KILL_AT_SECOND_PROMOTION = """
import os, sys
sys.path.insert(0, {repo!r})
from minitaur_env.training import callbacks
calls = []
embed = callbacks.embed_statistics
def dying_embed(path, normalizer):
    calls.append(path)
    if len(calls) == 2:  # the second new best: killed while it is being written
        with open(path, "r+b") as handle:
            handle.truncate(100)
        os._exit(9)
    embed(path, normalizer)
callbacks.embed_statistics = dying_embed
import train
sys.exit(train.main())
"""


def test_a_kill_while_a_new_best_model_is_written_keeps_the_previous_one(tmp_path):
    launcher = tmp_path / "launcher.py"
    launcher.write_text(KILL_AT_SECOND_PROMOTION.format(repo=str(REPO)))
    args = [
        "--env",
        "Pendulum-v1",
        "-n",
        "600",
        "--eval-freq",
        "100",
        "--eval-episodes",
        "1",
        "--save-freq",
        "100",
        "--hyperparams",
        "learning_starts=50",
        "batch_size=16",
        "normalize=true",
        "policy_kwargs={net_arch: [8]}",
    ]
    killed = run_script(str(launcher), *args, cwd=tmp_path)
    assert killed.returncode == 9
    run = RunFolder(tmp_path / "logs" / "sac" / "Pendulum-v1_1")
    best = load_policy(run.best_model, device="cpu")  # the first best, whole
    assert best.normalizer is not None
    with np.load(run.evaluations) as data:  # published whole after each evaluation
        assert len(data["timesteps"]) >= 1
    resumed = run_script("train.py", "--resume", str(run.path), cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    with np.load(run.evaluations) as data:
        steps = list(data["timesteps"])
    assert steps == sorted(set(steps)) and steps[-1] == 600  # no evaluation twice
    load_policy(run.best_model, device="cpu")


def test_resume_repairs_a_torn_monitor_line_and_an_unreadable_evaluations_file(tmp_path):
    run = pendulum_run(tmp_path, n_timesteps=200)
    monitor = next(run.monitor_dir.glob("*.monitor.csv"))
    lines = monitor.read_text().splitlines(True)
    lines.insert(3, "-3.1,2\x00\x00,17\n")  # a line the disk mangled mid-file
    monitor.write_text("".join(lines) + "-12.5,20")  # and a kill mid-line
    best_before = embedded_evaluation(run.best_model)
    run.evaluations.write_bytes(b"PK\x03\x04 torn")
    said = []
    resumed = Experiment.resume(run.path, n_timesteps=300, log=lambda *a, **k: said.append(a[0]))
    result = resumed.run()
    assert result.status == "completed"
    assert any("dropped a partial last line" in line for line in said)
    assert any("dropped 1 malformed line(s), the first at line 4" in line for line in said)
    assert "\x00" not in monitor.read_text()
    assert any("evaluations.npz was unreadable" in line for line in said)
    with np.load(run.evaluations) as data:
        assert list(data["timesteps"]) == [300]
        new_mean = float(data["results"].mean())
    # The best model was not judged against an empty history: it is the better of the two,
    # and the summary names the model best_model.zip holds.
    best_after = embedded_evaluation(run.best_model)
    assert best_after == max(best_before, (300, new_mean), key=lambda record: record[1])
    assert result.best_eval == best_after


def test_a_rewind_keeps_the_monitor_lines_it_keeps_byte_for_byte(tmp_path):
    from stable_baselines3.common.monitor import ResultsWriter

    run = RunFolder(tmp_path / "run")
    run.monitor_dir.mkdir(parents=True)
    monitor = run.monitor_dir / "0.monitor.csv"
    writer = ResultsWriter(str(monitor), header={"t_start": 0.0, "env_id": "Pendulum-v1"})
    for episode in range(5):  # as SB3 writes them: csv's CRLF line ends
        writer.write_row({"r": -1.5 * episode, "l": 100, "t": float(episode + 1)})
    writer.close()
    written = monitor.read_bytes()
    assert written.count(b"\r\n") == 6  # the header's r,l,t and five episodes
    with monitor.open("ab") as handle:
        handle.write(b"-9.0,100,6.0\r")  # killed between the line's \r and its \n
    said = []
    run.rewind_logs(250, log=said.append)
    kept = written.splitlines(True)[:4]  # the JSON line, r,l,t and the two episodes to 200
    assert monitor.read_bytes() == b"".join(kept)
    assert any("dropped a partial last line" in line for line in said)
    assert [episode.length for episode in run.monitor_episodes()] == [100, 100]


def test_two_processes_never_train_one_run_and_a_killed_one_leaves_no_lock(tmp_path):
    import subprocess
    import sys

    from minitaur_env.training.files import exclusive

    run = pendulum_run(tmp_path, n_timesteps=200)
    # held as a second train.py --resume of the same run would hold it
    held = exclusive(run.lock_file, "probe")
    with held, pytest.raises(UsageError, match="is in use by another process"):
        Experiment.resume(run.path, n_timesteps=300).run()
    # a process killed while holding the lock does not leave it stuck
    holder = (
        "import os, sys; sys.path.insert(0, sys.argv[2])\n"
        "from pathlib import Path\nfrom minitaur_env.training.files import exclusive\n"
        "with exclusive(Path(sys.argv[1]), 'x'):\n    os._exit(9)\n"
    )
    killed = subprocess.run(
        [sys.executable, "-c", holder, str(run.lock_file), str(REPO)], timeout=120
    )
    assert killed.returncode == 9
    assert Experiment.resume(run.path, n_timesteps=300).run().status == "completed"


SOAK_STEPS = 3000
if "ShortPendulum-v0" not in gym.registry:  # at import: the soak's children need it too
    gym.register(
        "ShortPendulum-v0",
        max_episode_steps=25,
        entry_point="gymnasium.envs.classic_control:PendulumEnv",
    )


def _resume_in_child(run_path: str) -> None:
    """One session of the soak: resume the run towards SOAK_STEPS until killed."""
    import torch

    torch.set_num_threads(1)
    result = Experiment.resume(run_path, n_timesteps=SOAK_STEPS, verbose=0, progress="none").run()
    os._exit(0 if result.status == "completed" else 3)


def preloaded_forkserver() -> multiprocessing.context.ForkServerContext:
    """Children forked from a server that imported this module and what a run imports
    lazily (plots, videos, torch's compiler via Adam) once. The preload list only counts
    before the server's first start, so every test here asks for it the same way."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload(
        [__name__, "minitaur_env.training.plotting", "minitaur_env.training.video", "torch._dynamo"]
    )
    return context


def _train_until_killed_after_checkpoint(logs: str, step: int) -> None:
    """Train, and die like a kill -9 right after the checkpoint at ``step`` is written."""
    from minitaur_env.training import callbacks

    written = callbacks.save_checked_checkpoint

    def save_then_die(model, run):
        path = written(model, run)
        if model.num_timesteps == step:
            os._exit(9)
        return path

    callbacks.save_checked_checkpoint = save_then_die
    _train_short_run(logs)


def _train_short_run(logs: str) -> None:
    """A 300-step run evaluated and checkpointed every 100 steps (in a child: exits)."""
    config = ExperimentConfig.resolve(
        "sac",
        "ShortPendulum-v0",
        hyperparams=NORMALIZED_SAC,
        n_timesteps=300,
        eval_freq=100,
        eval_episodes=1,
        save_freq=100,
        vec_env="dummy",
        device="cpu",
    )
    Experiment.create(config, logs, verbose=0, progress="none").run()
    os._exit(0)


def killed_run(tmp_path, train_until_killed, step: int) -> RunFolder:
    """The run folder a child left when ``train_until_killed`` killed it at ``step``."""
    child = preloaded_forkserver().Process(
        target=train_until_killed, args=(str(tmp_path / "logs"), step)
    )
    child.start()
    child.join(timeout=600)
    assert child.exitcode == 9
    return RunFolder(tmp_path / "logs" / "sac" / "ShortPendulum-v0_1")


def test_a_kill_after_a_checkpoint_on_an_evaluation_step_loses_no_evaluation(tmp_path):
    # Found by the soak below: the checkpoint at 200 was written before the evaluation at
    # 200, so a kill between them resumed from 200 and never evaluated it. Evaluations
    # now come first: a checkpoint's step has its evaluation on disk.
    run = killed_run(tmp_path, _train_until_killed_after_checkpoint, 200)
    assert max(steps for steps, _ in run.checkpoints()) == 200
    assert Experiment.resume(run.path, verbose=0).run().status == "completed"
    with np.load(run.evaluations) as data:
        assert data["timesteps"].tolist() == [100, 200, 300]


def _train_until_killed_after_evaluation(logs: str, step: int) -> None:
    """Train, and die like a kill -9 right after the evaluation at ``step`` is published,
    before the checkpoint of the same step."""
    from minitaur_env.training import callbacks

    publish = callbacks.PublishEvaluations._on_step

    def publish_then_die(self):
        publish(self)
        if self.model.num_timesteps == step:
            os._exit(9)
        return True

    callbacks.PublishEvaluations._on_step = publish_then_die
    _train_short_run(logs)


def progress_steps(run: RunFolder) -> list[float]:
    """time/total_timesteps of every row of every session's progress CSV, in order."""
    import csv

    steps = []
    for progress in sorted(run.path.glob("progress*.csv"), key=lambda p: p.stat().st_mtime):
        with progress.open() as handle:
            steps += [float(row["time/total_timesteps"]) for row in csv.DictReader(handle)]
    return steps


def test_a_kill_between_an_evaluation_and_its_checkpoint_leaves_one_history(tmp_path):
    run = killed_run(tmp_path, _train_until_killed_after_evaluation, 200)
    assert max(steps for steps, _ in run.checkpoints()) == 100  # the 200 checkpoint never came
    before = progress_steps(run)
    assert max(before) > 100  # the abandoned branch logged rows past the checkpoint
    result = Experiment.resume(run.path, verbose=0).run()
    assert result.status == "completed"
    with np.load(run.evaluations) as data:
        assert data["timesteps"].tolist() == [100, 200, 300]
    after = progress_steps(run)
    assert after == sorted(after)  # the abandoned branch's rows are gone: none repeats a step
    # best_model.zip may be the abandoned branch's 200 model; the summary names what the
    # file holds, and no later, worse evaluation replaced it.
    assert result.best_eval == embedded_evaluation(run.best_model)


def test_a_run_killed_at_random_points_twenty_times_resumes_every_time(tmp_path):
    """Fault injection: SIGKILL at random moments (mid-step, mid-checkpoint, mid-eval),
    then resume, 20 times. Children fork from a forkserver that imported the package
    once, so a cycle costs a fraction of a second rather than an interpreter start."""
    config = ExperimentConfig.resolve(
        "sac",
        "ShortPendulum-v0",
        hyperparams=NORMALIZED_SAC,
        n_timesteps=60,
        eval_freq=100,
        eval_episodes=1,
        save_freq=40,
        vec_env="dummy",
        device="cpu",
    )
    run = Experiment.create(config, tmp_path / "logs", verbose=0).run().run
    context = preloaded_forkserver()
    rng = random.Random(0)
    outcomes, progress = [], []
    while outcomes.count(-signal.SIGKILL) < 20:
        before = max((steps for steps, _ in run.checkpoints()), default=0)
        child = context.Process(target=_resume_in_child, args=(str(run.path),))
        child.start()
        if rng.random() < 0.25:  # a kill while the resume loads the run
            child.join(timeout=rng.uniform(0.0, 0.5))
        else:  # a kill while training: after the session's first checkpoint, wherever
            # the clock then finds it (mid-step, mid-checkpoint, mid-evaluation). Waiting
            # for the checkpoint, not for a fixed time, keeps a slow machine's kills out
            # of the start-up.
            deadline = time.monotonic() + 300
            while child.is_alive() and time.monotonic() < deadline:
                if max((steps for steps, _ in run.checkpoints()), default=0) > before:
                    break
                time.sleep(0.05)
            child.join(timeout=rng.uniform(0.0, 1.0))
        if child.is_alive():
            child.kill()
        child.join(timeout=60)
        outcomes.append(child.exitcode)
        # A resume either was killed or finished; none failed to start (status 3 or a raise).
        assert child.exitcode in (-signal.SIGKILL, 0), outcomes
        progress.append(max((steps for steps, _ in run.checkpoints()), default=0))
        if child.exitcode == 0:
            break
    # The kills landed while training, not only while starting: checkpoints moved on.
    assert len(set(progress)) >= 10, progress
    # The children aim far (SOAK_STEPS) so that no kill finds a finished run; the last
    # session ends two evaluations past the newest checkpoint instead, as the uninterrupted
    # training beyond that checks nothing the kills left (and cost 30-50 s a run).
    end = min(SOAK_STEPS, (max(progress) // 100 + 2) * 100)
    final = Experiment.resume(run.path, n_timesteps=end, verbose=0).run()
    assert final.status == "completed" and final.num_timesteps == end
    with np.load(run.evaluations) as data:
        steps = data["timesteps"].tolist()
    assert steps == list(range(100, end + 1, 100))  # each evaluation once, none lost
    episodes = [
        int(line.split(",")[1])
        for monitor in run.monitor_dir.glob("*.monitor.csv")
        for line in monitor.read_text().splitlines()[2:]
    ]
    # No episode of a killed branch is kept (they would add up to more than the run's
    # steps); a session loses at most the unfinished episode it resumed in.
    sessions = len(outcomes) + 1
    assert set(episodes) == {25}
    assert end - 25 * sessions <= sum(episodes) <= end
    assert load_policy(run.best_model, device="cpu").normalizer is not None
    assert load_policy(run.zoo_model, device="cpu").normalizer is not None
    # Kills between an evaluation and its checkpoint left no abandoned progress row and a best
    # model whose own record is at least every evaluation the history kept.
    rows = progress_steps(run)
    assert rows == sorted(rows)
    best = embedded_evaluation(run.best_model)
    with np.load(run.evaluations) as data:
        assert best[1] >= data["results"].mean(axis=1).max() - 1e-9
    assert final.best_eval == best
