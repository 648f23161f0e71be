"""Sweeps on Ray Tune: seeds, a search with a failing trial, Ctrl-C then --resume."""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from minitaur_env.training import Experiment, ExperimentConfig, RunFolder, UsageError
from minitaur_env.training.aggregate import default_milestones
from minitaur_env.training.evaluation import load_policy
from minitaur_env.training.search_space import load_search_space
from minitaur_env.training.sweep_summary import summarize
from minitaur_env.training.sweeps import Sweep
from tests.scripts import REPO, error_lines, needs

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1500)]

needs("ray")
needs("rliable")

TINY_SAC = {"learning_starts": 100, "batch_size": 32, "policy_kwargs": {"net_arch": [32]}}
SWEEP_ARGS = [
    "--env",
    "Pendulum-v1",
    "--eval-freq",
    "500",
    "--eval-episodes",
    "2",
    "--save-freq",
    "500",
    "--hyperparams",
    "learning_starts=100",
    "batch_size=32",
    "policy_kwargs={net_arch: [32]}",
]


def base(n_timesteps: int = 400) -> ExperimentConfig:
    return ExperimentConfig.resolve(
        "sac",
        "Pendulum-v1",
        hyperparams=TINY_SAC,
        n_timesteps=n_timesteps,
        eval_freq=200,
        eval_episodes=2,
        save_freq=200,
        vec_env="dummy",
        device="cpu",
    )


@pytest.fixture(scope="module")
def caller_ray():
    """One Ray for this module's in-process sweeps, started as a notebook user starts it:
    each Sweep.run uses it and leaves it running (and the module starts Ray once)."""
    ray = needs("ray")
    os.environ.setdefault("RAY_worker_niceness", "0")  # as Sweep.run starts its own
    ray.init(include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()


def test_seeds_of_one_configuration_give_a_table_from_their_run_folders(
    tmp_path, capsys, caller_ray
):
    command = "python -m minitaur_env.sweep --seeds 2"
    sweep = Sweep(base(), storage=str(tmp_path), name="seeds", seeds=[0, 1], command=command)
    assert sweep.run() == []
    assert caller_ray.is_initialized()  # the caller's Ray, left running
    elsewhere = Sweep(base(), storage=str(tmp_path), name="x", address="127.0.0.1:1")
    with pytest.raises(UsageError, match="already connected to Ray"):
        elsewhere.run()
    shown = [line for line in capsys.readouterr().out.splitlines() if "  eval " in line]
    for seed in (0, 1):  # one line per evaluation of each trial, as train.py prints
        steps = [line.split("  ")[1] for line in shown if f"(seed {seed})" in line]
        assert steps == ["step 200/400", "step 400/400"]
    rows = summarize(sweep.folder, milestones=(-3000.0, 0.0))
    assert len(rows) == 1 and rows[0]["config"] == "default"
    row = rows[0]
    assert row["seeds_done"] == 2 and row["seeds_failed"] == 0 and row["steps"] == 400
    runs = sorted(sweep.folder.glob("runs/*/sac/Pendulum-v1_1"))
    finals = []
    for run in runs:
        with np.load(run / "evaluations.npz") as data:
            assert list(data["timesteps"]) == [200, 400]
            finals.append(data["results"][-1].mean())
        load_policy(run / "best_model.zip", device="cpu")  # evaluate.py reads trials too
        # what made the run, for its provenance, with the trial's seed
        (line,) = (run / "command.txt").read_text().splitlines()
        assert line.startswith(command + "  # trial ") and line.endswith(f"seed {len(finals) - 1}")
    assert row["final_per_seed"] == " ".join(f"{v:.2f}" for v in finals)
    # A trial is the run train.py makes with its seed: the benchmark's default-entry rows
    # come from the sweep command and stand for `python train.py --seed S`.
    plain = Experiment.create(dataclasses.replace(base(), seed=1), tmp_path / "plain", verbose=0)
    assert plain.run().status == "completed"
    (plain_run,) = RunFolder.all(tmp_path / "plain", "sac", "Pendulum-v1")

    def evaluations(run: Path) -> np.ndarray:
        with np.load(run / "evaluations.npz") as data:
            return data["results"]

    np.testing.assert_array_equal(evaluations(runs[1]), evaluations(plain_run.path))
    assert not np.array_equal(evaluations(runs[0]), evaluations(plain_run.path))  # can fail
    trial_actor = load_policy(RunFolder(runs[1]).final_model, device="cpu").model.policy
    alone_actor = load_policy(plain_run.final_model, device="cpu").model.policy
    trial_actor, alone_actor = trial_actor.state_dict(), alone_actor.state_dict()
    assert trial_actor.keys() == alone_actor.keys()
    assert all(torch.equal(trial_actor[key], alone_actor[key]) for key in trial_actor)
    assert row["median"] == pytest.approx(np.median(finals))
    assert row["iqm_low"] <= row["iqm"] <= row["iqm_high"]
    with (sweep.folder / "summary.csv").open() as handle:
        written = list(csv.DictReader(handle))
    assert {"iqm", "iqm_low", "iqm_high", "median_minutes_to_0"} <= set(written[0])
    # Pendulum's return is never below -3000 nor above 0.
    assert row["reached_-3000"] == "2/2" and row["steps_to_-3000_per_seed"] == "200 200"
    assert row["reached_0"] == "0/2" and row["steps_to_0_per_seed"] == "- -"
    assert np.isnan(row["median_steps_to_0"])
    assert (sweep.folder / "curves.png").read_bytes().startswith(b"\x89PNG")
    # --summarize prints the same table again from the folder alone
    (sweep.folder / "summary.csv").unlink()
    again = subprocess.run(
        sweep_command("--summarize", str(sweep.folder), "--milestones", "-3000", "0"),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert again.returncode == 0, again.stderr
    assert f"{row['iqm']:.2f}" in again.stdout and (sweep.folder / "summary.csv").is_file()
    # More seeds of the configuration from a later sweep make one table with these...
    later = tmp_path / "later"
    trial = runs[1].parents[1]  # runs/<trial>/sac/Pendulum-v1_1
    shutil.copytree(trial, later / "runs" / trial.name)
    (combined,) = summarize([sweep.folder, later], milestones=(-3000.0, 0.0))
    assert combined["seeds_done"] == 3
    assert combined["final_per_seed"] == row["final_per_seed"] + f" {finals[1]:.2f}"
    # ...but not a run of another config, which would pass for another seed
    config = later / "runs" / trial.name / "sac" / "Pendulum-v1_1" / "config.yml"
    config.write_text(config.read_text().replace("learning_starts: 100", "learning_starts: 99"))
    with pytest.raises(UsageError, match=r"train different configs \(hyperparams\)"):
        summarize([sweep.folder, later])


def test_a_search_repeats_each_configuration_over_the_seeds_and_asha_stops_on_steps(tmp_path):
    from ray.tune.schedulers import ASHAScheduler
    from ray.tune.search import Repeater

    (tmp_path / "space.yml").write_text("learning_rate: {loguniform: [1.0e-4, 1.0e-3]}\n")
    space = load_search_space(tmp_path / "space.yml")
    # Ray writes the Tuner's state into its storage on construction: not into the repo.
    storage = str(tmp_path / "sweeps")
    repeated = Sweep(base(), seeds=[0, 1, 2], search=space, trials=2, storage=storage)._tuner(
        resume=False
    )
    config = repeated._local_tuner._tune_config
    assert isinstance(config.search_alg, Repeater) and config.search_alg.repeat == 3
    assert config.num_samples == 6  # 2 configurations x 3 seeds
    asha = Sweep(base(), seeds=[0], search=space, scheduler="asha", storage=storage)._tuner(
        resume=False
    )
    scheduler = asha._local_tuner._tune_config.scheduler
    assert isinstance(scheduler, ASHAScheduler)
    assert scheduler._time_attr == "timesteps" and scheduler._max_t == 400


def test_gpus_and_cpus_per_trial_are_checked_before_ray_starts():
    for settings in ({"gpus_per_trial": -1.0}, {"cpus_per_trial": 0.0}):
        with pytest.raises(UsageError, match="--cpus-per-trial must be > 0"):
            Sweep(base(), **settings).validate()


@pytest.mark.parametrize(
    ("env_id", "milestones"),
    [
        ("MinitaurBulletEnv-v0", (5.0, 15.0)),
        ("MinitaurBulletDuckEnv-v0", (5.0,)),
        ("CartPole-v1", (475.0,)),
        ("Pendulum-v1", ()),  # gymnasium gives it no reward threshold
    ],
)
def test_default_milestones_follow_the_env(env_id, milestones):
    import minitaur_env  # noqa: F401

    assert default_milestones(env_id) == milestones


def test_a_failing_trial_is_one_line_and_the_others_finish(tmp_path, caller_ray):
    space = tmp_path / "space.yml"
    space.write_text(
        'policy_kwargs: {choice: ["{net_arch: [32]}", "{activation_fn: relu}"]}\n'
        "learning_rate: {loguniform: [1.0e-4, 1.0e-3]}\n"
    )
    sweep = Sweep(
        base(200), storage=str(tmp_path), name="search", search=load_search_space(space), trials=4
    )
    failures = sweep.run()
    rows = summarize(sweep.folder)
    done = sum(row["seeds_done"] for row in rows)
    assert failures and done >= 1 and done + len(failures) == 4
    for line in failures:
        assert "\n" not in line and "invalid hyperparameters for sac" in line
    assert all("activation_fn" in row["config"] for row in rows if row["seeds_failed"])


def test_scientific_notation_without_a_dot_is_a_number_everywhere(tmp_path):
    from ray.tune.search.sample import Float

    space_file = tmp_path / "space.yml"
    space_file.write_text("lr: {loguniform: [1e-4, 1e-3]}\ntau: {uniform: [0.0001, 5e-3]}\n")
    space = load_search_space(space_file)
    assert isinstance(space["lr"], Float) and (space["lr"].lower, space["lr"].upper) == (1e-4, 1e-3)
    assert space["tau"].upper == 5e-3
    (tmp_path / "conf.yml").write_text("Pendulum-v1:\n  tau: 5e-3\n  learning_rate: 1e-4\n")
    config = ExperimentConfig.resolve("sac", "Pendulum-v1", conf_file=str(tmp_path / "conf.yml"))
    assert config.hyperparams["tau"] == 5e-3 and config.hyperparams["learning_rate"] == 1e-4


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("lr: {normal: [0, 1]}", "must be one of {uniform: ...}"),
        ("lr: {loguniform: [0, 1]}", "loguniform needs low > 0"),
        ("lr: {uniform: [1, 0]}", "needs [low, high], low < high"),
        ("lr: {uniform: [1e-3, 1e-4]}", "needs [low, high], low < high"),
        ("lr: {uniform: [a, 1]}", "needs [low, high], low < high"),
        ("net: {choice: [{net_arch: [8]}]}", "write {'net_arch': [8]} as a YAML string"),
        ("[1, 2]", "must map hyperparameter names to ranges"),
    ],
)
def test_bad_search_spaces_are_one_clear_error(tmp_path, text, message):
    path = tmp_path / "space.yml"
    path.write_text(text)
    with pytest.raises(UsageError) as error:
        load_search_space(path)
    assert message in str(error.value)


def sweep_command(*args: str) -> list[str]:
    return [sys.executable, "-m", "minitaur_env.sweep", *args]


def sweep_at_its_first_checkpoint(tmp_path, args: list[str], name: str) -> subprocess.Popen:
    """A sweep process, once one of its trials wrote its 500-step checkpoint."""
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    process = subprocess.Popen(
        sweep_command(*args),
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
        start_new_session=True,
    )
    deadline = time.monotonic() + 900  # generous: a machine 5x slower still gets there
    while not list(tmp_path.glob(f"{name}/runs/*/sac/*/checkpoints/rl_model_500_steps.zip")):
        assert time.monotonic() < deadline and process.poll() is None, process.stderr.read()
        time.sleep(0.5)
    return process


def test_ctrl_c_leaves_a_sweep_that_resume_finishes(tmp_path):
    # Cut at the 500-step checkpoint, with 1000 steps left so the cut lands before the end.
    # One trial's worker dies first, as under the OOM killer: Tune marks that trial errored,
    # and --resume once skipped errored trials, so a crashed seed never finished.
    import psutil

    args = [*SWEEP_ARGS, "-n", "1500", "--seeds", "2", "-f", str(tmp_path), "--name", "cut"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    process = sweep_at_its_first_checkpoint(tmp_path, args, "cut")
    workers = [
        child
        for child in psutil.Process(process.pid).children(recursive=True)
        if "ImplicitFunc" in " ".join(child.cmdline())
    ]
    assert workers, "no trial worker found"
    workers[0].kill()
    workers[0].wait(timeout=60)
    time.sleep(2)  # Tune sees the dead worker (or not yet: --resume must finish it either way)
    os.killpg(process.pid, signal.SIGINT)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 130, stderr
    assert "--resume" in stderr.splitlines()[-1]

    resumed = subprocess.run(
        sweep_command(*args, "--resume"),
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env=env,
        timeout=600,
    )
    assert resumed.returncode == 0, resumed.stderr
    rows = summarize(tmp_path / "cut")
    assert rows[0]["seeds_done"] == 2 and rows[0]["steps"] == 1500
    assert list(tmp_path.glob("cut/runs/*/sac/*/progress-resumed-at-*.csv"))  # not restarted
    commands = [f.read_text().splitlines() for f in tmp_path.glob("cut/runs/*/sac/*/command.txt")]
    assert len(commands) == 2
    resume = f"python -m minitaur_env.sweep -f {tmp_path} --name cut --resume"
    for lines in commands:  # launched by the sweep, then continued by its --resume
        assert lines[0].startswith("python -m minitaur_env.sweep --env Pendulum-v1")
    assert any(len(lines) == 2 and lines[1].startswith(resume) for lines in commands)


def test_sigterm_to_the_sweep_stops_it_as_ctrl_c_does_and_says_how_to_resume(tmp_path):
    # A scheduler's or kill's SIGTERM to the driver: Ray's handler printed a C++ stack dump
    # and no resume hint. Now the trials stop at their checkpoints and the exit is 143.
    args = [*SWEEP_ARGS, "-n", "3000", "--seeds", "1", "-f", str(tmp_path), "--name", "term"]
    process = sweep_at_its_first_checkpoint(tmp_path, args, "term")
    process.send_signal(signal.SIGTERM)  # the driver alone, as `kill PID` sends it
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 143, stderr
    assert stderr.splitlines()[-1] == (
        f"sweep interrupted; continue it with: python -m minitaur_env.sweep -f {tmp_path} "
        "--name term --resume"
    )
    assert "SIGTERM received" not in stderr and "Stack trace" not in stderr


def test_settings_that_cannot_make_the_env_or_model_are_refused_before_ray_starts():
    bad_env = dataclasses.replace(base(), env_kwargs={"not_a_setting": 1})
    with pytest.raises(UsageError, match="cannot make Pendulum-v1 with"):
        Sweep(bad_env).validate()
    bad_model = dataclasses.replace(base(), hyperparams={**TINY_SAC, "policy_kwargs": {"x": 1}})
    with pytest.raises(UsageError, match="invalid hyperparameters for sac"):
        Sweep(bad_model).validate()
    if not torch.cuda.is_available():  # Tune waited forever for a GPU
        with pytest.raises(UsageError, match="--gpus-per-trial 1: this machine has 0 GPU"):
            Sweep(base(), gpus_per_trial=1.0).validate()
    Sweep(base()).validate()  # control


def test_trials_the_cluster_cannot_place_are_refused_not_waited_for():
    sweep = Sweep(base(), cpus_per_trial=4.0)
    with pytest.raises(UsageError, match="--cpus-per-trial 4: the Ray cluster has 2 CPU"):
        sweep._check_cluster({"CPU": 2.0})
    with pytest.raises(UsageError, match="--gpus-per-trial 1: the Ray cluster has 0 GPU"):
        Sweep(base(), gpus_per_trial=1.0)._check_cluster({"CPU": 2.0})
    Sweep(base(), cpus_per_trial=2.0)._check_cluster({"CPU": 2.0})


def test_without_the_ray_extra_the_sweep_says_so_in_one_line():
    hide_ray = "import sys\nsys.modules['ray'] = None\nsys.argv = ['sweep', '--seeds', '1']\n"
    run = hide_ray + "import runpy\nrunpy.run_module('minitaur_env.sweep', run_name='__main__')"
    result = subprocess.run(
        [sys.executable, "-c", run], capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2
    assert error_lines(result) == [
        "python -m minitaur_env.sweep: error: ray is not installed; sweeps need the ray extra: "
        "pip install 'minitaur-env[ray]'"
    ]


def test_a_trial_on_one_cpu_steps_its_envs_in_its_own_process():
    from minitaur_env.training.trial import trial_config

    several = dataclasses.replace(base(), n_envs=4, vec_env="auto").to_dict()
    one_cpu = trial_config({"base": several, "seed": 3, "num_threads": 1})
    assert (one_cpu.vec_env, one_cpu.seed, one_cpu.n_envs) == ("dummy", 3, 4)
    # with more CPUs reserved, or a vec env the user chose, it is left as it was
    assert trial_config({"base": several, "seed": 3, "num_threads": 2}).vec_env == "auto"
    chosen = {**several, "vec_env": "grouped"}
    assert trial_config({"base": chosen, "seed": 3, "num_threads": 1}).vec_env == "grouped"


def test_seeds_are_a_count_from_first_seed_or_a_list():
    from minitaur_env.training.sweeps import seed_list

    assert seed_list([3]) == [0, 1, 2]
    assert seed_list([1], first_seed=2) == [2]  # one seed that is not 0: a row's third seed
    assert seed_list([0, 4, 7]) == [0, 4, 7]
    for values, first, message in (
        ([0, 4], 2, "--first-seed goes with a count"),
        ([0], 0, "a count N >= 1"),
        ([1, 1], 0, "distinct seeds"),
    ):
        with pytest.raises(UsageError, match=message):
            seed_list(values, first)


def test_a_sweep_without_evaluations_is_refused_before_it_trains():
    sweep = Sweep(base=dataclasses.replace(base(), eval_freq=0), seeds=[0])
    with pytest.raises(UsageError, match="--eval-freq > 0"):
        sweep.validate()
    # Ray itself failed at the end with a 40-line traceback: no result held eval_return.
    sweep = Sweep(base=dataclasses.replace(base(), eval_freq=300, n_timesteps=200), seeds=[0])
    with pytest.raises(UsageError, match="--eval-freq 300 is more than -n 200"):
        sweep.validate()
    Sweep(base=dataclasses.replace(base(), eval_freq=200, n_timesteps=200), seeds=[0]).validate()


def test_the_summary_reads_the_trials_newest_run(tmp_path):
    from minitaur_env.training.sweep_summary import _newest_run

    trial = tmp_path / "runs" / "abc"
    for number in (2, 10, 1):  # 10 sorts before 2 as text: the number decides
        run = trial / "sac" / f"Pendulum-v1_{number}"
        run.mkdir(parents=True)
        (run / "config.yml").write_text("env: Pendulum-v1\n")
    assert _newest_run(trial).path.name == "Pendulum-v1_10"


def free_ports(count: int) -> list[int]:
    import socket

    sockets = [socket.socket() for _ in range(count)]
    for sock in sockets:
        sock.bind(("127.0.0.1", 0))
    ports = [sock.getsockname()[1] for sock in sockets]
    for sock in sockets:
        sock.close()
    return ports


def test_address_runs_the_trials_on_the_cluster_it_names(tmp_path):
    # A real one-node cluster, started as a user starts one (`ray start --head`), with its
    # own ports and session folder, so that no other Ray on the machine is touched; it is
    # stopped by signalling its process group, never with `ray stop` (which stops them all).
    import tempfile

    session = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))  # short: Ray's socket paths
    gcs, dashboard, agent, agent_grpc, client, metrics, runtime_env = free_ports(7)
    env = {
        **os.environ,
        "RAY_AUTH_MODE": "token",
        "RAY_USAGE_STATS_ENABLED": "0",
        "OMP_NUM_THREADS": "1",
    }
    head = subprocess.Popen(
        [
            str(Path(sys.executable).parent / "ray"),
            "start",
            "--head",
            "--block",
            "--node-ip-address",
            "127.0.0.1",
            "--port",
            str(gcs),
            "--num-cpus",
            "2",
            "--include-dashboard=false",
            "--dashboard-port",
            str(dashboard),
            "--dashboard-agent-listen-port",
            str(agent),
            "--dashboard-agent-grpc-port",
            str(agent_grpc),
            "--ray-client-server-port",
            str(client),
            "--metrics-export-port",
            str(metrics),
            "--runtime-env-agent-port",
            str(runtime_env),
            "--temp-dir",
            str(session),
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env=env,
        start_new_session=True,
    )
    try:
        deadline = time.monotonic() + 300
        while not list(session.glob("session_*/logs/raylet.out")):
            assert head.poll() is None, "ray start --head failed"
            assert time.monotonic() < deadline, "the Ray head did not come up in 300 s"
            time.sleep(0.5)
        address = f"127.0.0.1:{gcs}"
        args = [*SWEEP_ARGS, "-n", "500", "--seeds", "1", "-f", str(tmp_path), "--name", "c"]
        done = subprocess.run(
            sweep_command(*args, "--address", address),
            cwd=tmp_path,
            capture_output=True,
            text=True,
            timeout=600,
            env=env,
        )
        assert done.returncode == 0, done.stderr[-2000:]
        (trial,) = tmp_path.glob("c/runs/*/trial.yml")
        node = trial.read_text().split("node: ")[1].split()[0]
        # The trial ran on the head's node: its id is in the head's own logs, and the
        # sweep's driver logged into the head's session, not into a local instance.
        logs = next(session.glob("session_*/logs"))
        assert node in (logs / "raylet.out").read_text()
        assert list(logs.glob("python-core-driver-*.log"))
    finally:
        os.killpg(head.pid, signal.SIGTERM)
        with contextlib.suppress(subprocess.TimeoutExpired):
            head.wait(timeout=10)  # its own shutdown; then the whole group, for sure
        with contextlib.suppress(ProcessLookupError):
            os.killpg(head.pid, signal.SIGKILL)
        head.wait(timeout=60)
        shutil.rmtree(session, ignore_errors=True)


def test_a_trial_cut_off_before_its_first_checkpoint_restarts_in_one_run_folder(tmp_path):
    # Ctrl-C before a trial's first checkpoint left a run folder that --resume could not
    # continue; the restart then made a second one beside it (found on a loaded machine).
    from minitaur_env.training.run_folder import RunFolder
    from minitaur_env.training.trial import set_aside_unresumable

    for _ in range(2):
        run = RunFolder.create(tmp_path, "sac", "Pendulum-v1")
        run.write_config(base().to_dict())
        (run.path / "monitor").mkdir()
        (run.path / "monitor" / "0.monitor.csv").write_text("#\nr,l,t\n-1,200,0.1\n")
        moved = set_aside_unresumable(tmp_path, "sac", "Pendulum-v1")
        assert len(moved) == 1 and (moved[0] / "monitor" / "0.monitor.csv").is_file()  # kept
        assert RunFolder.all(tmp_path, "sac", "Pendulum-v1") == []
        assert RunFolder.found_under(tmp_path) == []  # the summary's glob does not see it
    kept = sorted(p.relative_to(tmp_path).as_posix() for p in tmp_path.glob("abandoned/*/*"))
    assert kept == ["abandoned/1/sac-Pendulum-v1_1", "abandoned/2/sac-Pendulum-v1_1"]
