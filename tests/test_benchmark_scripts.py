"""The speed and robustness benchmark scripts, each on the smallest budget that still runs
every code path they time, judged by what they print: the figures parse, they agree with
the baselines and commands they name, and a setting that would skew a figure is caught.
(keep_runs.py, minitaur_table.py: test_benchmark_table.py.)"""

from __future__ import annotations

import importlib.util
import inspect
import json
import os
import re
import shlex
import subprocess
import sys
from typing import Any

import pytest

from minitaur_env.gait import make_trotting_env
from minitaur_env.training.evaluation import pretrained_models
from tests.scripts import REPO, error_lines, needs, run_main, run_script

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(1200)]

NUMBER = r"([0-9.]+)"


def benchmark_module(name: str) -> Any:
    """benchmarks/<name>.py imported as a module (benchmarks/ is not a package)."""
    spec = importlib.util.spec_from_file_location(name, REPO / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def figure(pattern: str, text: str) -> list[float]:
    found = re.search(pattern, text)
    assert found, f"{pattern!r} not in:\n{text}"
    return [float(group) for group in found.groups()]


def test_env_speed_measures_the_step_against_the_physics_in_the_same_rollout(tmp_path):
    result = run_script(
        "benchmarks/env_speed.py", "--steps", "60", "--only", "step", "reset", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    ours, bound, ratio = figure(
        rf"step: ours {NUMBER} steps/s; physics-only bound {NUMBER} steps/s; ratio {NUMBER}",
        result.stdout,
    )
    assert 0 < ours <= bound  # the bound is a part of the same steps' time
    assert ratio == pytest.approx(ours / bound, abs=0.02)
    # The classic env is either measured or the reason it was not is named, with its fix.
    assert re.search(
        r"step: classic env ([0-9]+ steps/s|not measured \(.*pip install)", result.stdout
    )
    hard, fixed, restored = figure(
        rf"reset: ours hard {NUMBER} ms \(randomized\), {NUMBER} ms \(fixed dynamics\); "
        rf"hard_reset=False {NUMBER} ms",
        result.stdout,
    )
    assert restored < min(hard, fixed)  # restoring a saved state skips rebuilding the world
    assert "render:" not in result.stdout and "vectorized:" not in result.stdout  # --only


def test_onnx_speed_times_every_shipped_policy_on_three_paths(tmp_path):
    needs("onnxruntime")
    result = run_script(
        "benchmarks/onnx_speed.py", "--actions", "20", "--rounds", "1", cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    shipped = {model.parents[1].name for _, model in pretrained_models()}
    rows = {
        line.split()[0]: line.split()[1:]
        for line in result.stdout.splitlines()
        if line.split() and line.split()[0] in shipped
    }
    assert set(rows) == shipped
    for onnx, predict, torch_forward, ratio, size, unit in rows.values():
        assert float(onnx) > 0 and float(torch_forward) > 0
        assert float(ratio.rstrip("x")) == pytest.approx(float(predict) / float(onnx), rel=0.05)
        assert float(size) > 0 and unit == "KiB"


def evaluated_return(model, seed: int, *args: str, cwd) -> float:
    """The mean return ``evaluate.py`` reports for one episode of ``model`` from ``seed``."""
    statistics = cwd / "evaluate.json"
    result = run_script(
        "evaluate.py",
        *("--model", str(model), "--episodes", "1", "--seed", str(seed)),
        *args,
        *("--json", str(statistics)),
        cwd=cwd,
    )
    assert result.returncode == 0, result.stderr
    return json.loads(statistics.read_text())["summary"]["return"]["mean"]


def test_robustness_cells_are_what_evaluate_py_reports_with_the_printed_flags(tmp_path):
    model = next(model for _, model in pretrained_models() if model.parents[1].name == "sac")
    cells = tmp_path / "cells.json"
    result = run_script(
        "benchmarks/robustness.py",
        "--policy",
        f"sac={model}",
        "--episodes",
        "1",
        "--conditions",
        "pushes",
        "--json",
        str(cells),
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    cell = json.loads(cells.read_text())["sac"]["pushes"]
    assert "| sac | " in result.stdout
    flags = shlex.split(figure_line(r"^pushes: --env-kwargs (.*)$", result.stdout))
    mean = evaluated_return(
        model, 12345, "--env", "MinitaurBulletEnv-v0", "--env-kwargs", *flags, cwd=tmp_path
    )
    assert mean == pytest.approx(cell["mean"], abs=1e-6)


def test_robustness_plays_a_gait_policy_on_the_observation_it_was_trained_on(tmp_path):
    """A policy that observes its control step (a 2-frame history of 31 values) gets that
    observation under every column, as evaluate.py gives it on the gait prior's env."""
    trained = run_script(
        "train.py",
        "--algo",
        "ppo",
        "--env",
        "MinitaurBulletTrot-v0",
        "-n",
        "64",
        "--hyperparams",
        "n_envs=1",
        "n_steps=64",
        "batch_size=32",
        "--eval-freq",
        "0",
        "--save-freq",
        "0",
        "--env-kwargs",
        "history=2",
        "observe_control_step=true",
        "-v",
        "0",
        cwd=tmp_path,
    )
    assert trained.returncode == 0, trained.stderr
    model = tmp_path / "logs" / "ppo" / "MinitaurBulletTrot-v0_1" / "MinitaurBulletTrot-v0.zip"
    cells = tmp_path / "cells.json"
    judged = run_script(
        "benchmarks/robustness.py",
        *("--policy", f"clock={model}", "--episodes", "1", "--conditions", "latency 20 ms"),
        *("--json", str(cells)),
        cwd=tmp_path,
    )
    assert judged.returncode == 0, judged.stderr
    cell = json.loads(cells.read_text())["clock"]["latency 20 ms"]
    flags = shlex.split(figure_line(r"^latency 20 ms: --env-kwargs (.*)$", judged.stdout))
    mean = evaluated_return(
        model, 12345, "--env", "MinitaurBulletTrot-v0", "--env-kwargs", *flags, cwd=tmp_path
    )
    assert mean == pytest.approx(cell["mean"], abs=1e-6)


def test_robustness_keeps_every_option_the_gait_prior_adds_to_the_env():
    """The gait prior's own keywords shape what its policies observe and do; a world
    column that dropped one would hand a policy observations of another size."""
    robustness = benchmark_module("robustness")
    added = set(inspect.signature(make_trotting_env).parameters) - {"render_mode", "kwargs"}
    assert added == {"gait", "history", "observe_control_step"}
    assert added <= set(robustness.INTERFACE)
    assert not {"realism", "dynamics_ranges", "preset"} & set(robustness.INTERFACE)


def test_robustness_loads_no_pickle_unless_trusted_and_says_which_flag(tmp_path):
    import shutil
    import zipfile

    from minitaur_env.training.run_folder import EMBEDDED_STATISTICS

    shipped = next(model for _, model in pretrained_models() if model.parents[1].name == "sac")
    run = tmp_path / "downloaded" / shipped.parent.name
    shutil.copytree(shipped.parent, run)
    model = run / shipped.name
    with zipfile.ZipFile(shipped) as source, zipfile.ZipFile(model, "w") as target:
        for name in source.namelist():
            if name != EMBEDDED_STATISTICS:  # statistics only as the pickle beside it
                target.writestr(name, source.read(name))
    for statistics in run.rglob("*vecnormalize*.json"):
        statistics.unlink()
    args = [
        "benchmarks/robustness.py",
        "--policy",
        f"sac={model}",
        "--episodes",
        "1",
        "--conditions",
        "pushes",
    ]
    refused = run_script(*args, cwd=tmp_path)
    assert refused.returncode == 2 and len(error_lines(refused)) == 1, refused.stderr
    assert error_lines(refused)[0].startswith("robustness.py: error: ")
    assert error_lines(refused)[0].endswith("pass --trust-pickle if you trust where it came from")
    trusted = run_script(*args, "--trust-pickle", cwd=tmp_path)
    assert trusted.returncode == 0, trusted.stderr


def test_robustness_judges_every_shipped_policy_and_refuses_a_label_twice(capsys):
    robustness = benchmark_module("robustness")
    shipped = robustness.shipped_policies()
    assert sorted(shipped.values()) == sorted(model for _, model in pretrained_models())
    assert sum(model.parents[1].name == "ppo" for model in shipped.values()) >= 2  # two PPOs
    model = next(iter(shipped.values()))
    refused = robustness.main(
        ["--policy", f"a={model}", "--policy", f"a={model}", "--episodes", "1"]
    )
    assert refused == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.endswith(": error: --policy label 'a' is given twice; each needs its own")


def figure_line(pattern: str, text: str) -> str:
    found = re.search(pattern, text, re.MULTILINE)
    assert found, f"{pattern!r} not in:\n{text}"
    return found.group(1)


def torchs_default_threads() -> int:
    """What torch.get_num_threads() gives a process with no *_NUM_THREADS set."""
    clean = {k: v for k, v in os.environ.items() if not k.endswith("_NUM_THREADS")}
    return int(
        subprocess.run(
            [sys.executable, "-c", "import torch; print(torch.get_num_threads())"],
            capture_output=True,
            text=True,
            env=clean,
            check=True,
        ).stdout
    )


def test_threads_under_load_gives_the_default_variant_torchs_real_default(monkeypatch):
    # Our own runs export OMP_NUM_THREADS=1; the "torch's default" variant must not inherit
    # it, or both rows of the table would be one thread.
    default = torchs_default_threads()
    benchmark = benchmark_module("threads_under_load")
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    rate, threads = benchmark.measure(0, steps=16, warmup=64, untimed=8)
    assert rate > 0 and threads == default


def assert_ratio_of_rounded(ratio: float, rate: float, baseline: float, rate_step: float) -> None:
    """The printed ratio (2 decimals) is rate / baseline for some true rates that round to
    the printed ones: under load a baseline of a few steps/s makes that rounding alone
    worth several percent of the ratio."""
    half = rate_step / 2
    low = (rate - half) / (baseline + half)
    high = (rate + half) / max(baseline - half, 1e-9)
    assert low - 0.005 <= ratio <= high + 0.005, (ratio, rate, baseline)


def test_training_speed_times_every_variant_and_its_baseline_at_torchs_default(tmp_path):
    needs("sbx")
    default = torchs_default_threads()
    result = subprocess.run(
        [
            sys.executable,
            str(REPO / "benchmarks/training_speed.py"),
            "--steps",
            "16",
            "--warmup",
            "32",
            "--untimed",
            "8",
            "--ppo-steps",
            "16",
            "--ppo-rollout",
            "8",
        ],
        capture_output=True,
        text=True,
        env={**os.environ, "OMP_NUM_THREADS": "1"},
        timeout=900,
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    (baseline,) = figure(rf"SB3 SAC defaults \({default} torch threads\): {NUMBER}", result.stdout)
    variants = re.findall(r"^(.*): ([0-9.]+) env steps/s; ratio ([0-9.]+)x", result.stdout, re.M)
    assert len(variants) == 6
    for _, rate, ratio in variants:
        # A timed window left empty would print 0.0 steps/s and a ratio of 1.00.
        assert float(rate) > 0
        assert_ratio_of_rounded(float(ratio), float(rate), baseline, rate_step=0.1)
    dummy, grouped, ratio = figure(
        rf"DummyVecEnv {NUMBER} env steps/s; GroupedSubprocVecEnv .* {NUMBER}; ratio {NUMBER}x",
        result.stdout,
    )
    assert dummy > 0
    assert_ratio_of_rounded(ratio, grouped, dummy, rate_step=1.0)
    assert "(8 envs, 8-step rollouts, 10 epochs)" in result.stdout  # --ppo-rollout took
    # 1M transitions of 28 floats (observation and next observation), 8 actions, and
    # reward, done and timeout as float32: 260 MB.
    (mib,) = figure(rf"replay buffer of 1M transitions .*: {NUMBER} MiB", result.stdout)
    assert mib == pytest.approx(1e6 * (28 + 28 + 8 + 3) * 4 / 2**20, abs=1)


def test_sweep_overhead_runs_the_same_trials_both_ways(tmp_path):
    needs("ray")
    result = run_script(
        "benchmarks/sweep_overhead.py", "-n", "200", "--seeds", "1", cwd=tmp_path, timeout=600
    )
    assert result.returncode == 0, result.stderr
    (scripts,) = figure(rf"train.py, one after the other: {NUMBER} s", result.stdout)
    sweep, overhead = figure(rf"sweep: {NUMBER} s; overhead \+?(-?[0-9.]+) s", result.stdout)
    (startup,) = figure(rf"start-up to the first trial's run folder: {NUMBER} s", result.stdout)
    assert overhead == pytest.approx(sweep - scripts, abs=0.11)
    assert 0 < startup < sweep  # the run folder appeared while the sweep ran
    assert not list(tmp_path.iterdir())  # its runs went to a temporary folder, not the cwd


def test_gait_prior_plays_the_generator_alone_against_the_legs_at_rest(tmp_path):
    result = run_script(
        "benchmarks/gait_prior.py",
        "--episodes",
        "1",
        "--conditions",
        "classic",  # the randomized worlds are the same loop on other kwargs
        "--frequency",
        "4",
        "0.01",
        "--push-forces",
        "0.001",
        "300",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    cell = r"(-?[0-9.]+) at (-?[0-9.]+) m/s, ([0-9]+) falls"
    rest, rest_speed, _ = figure(rf"baseline, no generator, classic: +{cell}", result.stdout)
    trot, speed, falls = figure(
        rf"trot 4 Hz, extension 0.7, swing 0.3, classic: +{cell}", result.stdout
    )
    # The legs at rest make no distance; the trot walks the whole episode.
    assert abs(rest) < 0.5 and abs(rest_speed) < 0.05
    assert trot > 5 and speed > 0.5 and falls == 0
    # A generator 400 times slower barely moves the legs: the distance is the trot's.
    (slow,) = figure(
        r"trot 0.01 Hz, extension 0.7, swing 0.3, classic: +(-?[0-9.]+)", result.stdout
    )
    assert abs(slow) < 1
    assert len(re.findall(r"^trot ", result.stdout, re.M)) == 2  # 2 settings x 1 condition
    assert "tan2018" not in result.stdout  # the worlds not asked for are not played
    # A push of 1 mN is nothing; 300 N topples a robot standing still at the first push.
    taken = r"([0-9]+) pushes, ([0-9]+) falls"
    pushes = rf"legs at rest {taken}; default trot {taken}"
    assert figure(rf"pushes of 0.001 N, random directions: {pushes}", result.stdout) == [8, 0, 8, 0]
    assert figure(rf"pushes of 300 N, random directions: {pushes}", result.stdout) == [1, 1, 1, 1]


def test_push_bound_trains_for_survival_and_counts_the_pushes_it_survived(tmp_path):
    result = run_script(
        "benchmarks/push_bound.py",
        "-n",
        "2048",
        "--eval-freq",
        "1000",
        "--eval-episodes",
        "1",
        "--env-kwargs",
        "realism={pushes: {direction: 90}}",
        "--forces",
        "400",
        "--report-episodes",
        "4",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    row = r"falls ([0-9]+)/([0-9]+)  pushes begun ([0-9.]+)/episode  survived ([0-9.]+)%"
    # Legs at rest fall at the first full-force push or soon after: the bound's baseline.
    falls, episodes, pushes, survived = figure(rf"baseline, zero action.*: {row}", result.stdout)
    assert episodes == 4 and falls >= 3 and pushes >= 1
    assert survived / 100 == pytest.approx(1 - falls / (pushes * episodes), abs=0.001)
    assert len(re.findall(rf"^ +[0-9,]+  {row}", result.stdout, re.M)) == 2  # at 1000, 2000
    falls, episodes, pushes, survived = figure(rf"report seeds \(4\)  {row}", result.stdout)
    assert episodes == 4 and pushes >= 1 and 0 <= survived <= 100
    # A 400 N push from the side, the force given and not drawn, topples both at the first.
    for name in ("zero action", "trained"):
        falls, episodes, pushes, survived = figure(rf"400 N  {name} +{row}", result.stdout)
        assert (falls, episodes, pushes, survived) == (4, 4, 1.0, 0.0)
    assert not list(tmp_path.iterdir())  # nothing written: it only prints


def test_push_bound_without_training_maps_the_zero_action_by_force_and_direction(tmp_path):
    result = run_script(
        "benchmarks/push_bound.py",
        "-n",
        "0",
        "--forces",
        "400",
        "--directions",
        "90",
        "-90",
        "--report-episodes",
        "4",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    row = r"falls ([0-9]+)/4  pushes begun ([0-9.]+)/episode  survived ([0-9.]+)%"
    for direction in ("90", "-90"):
        falls, pushes, survived = figure(
            rf"400 N +{direction} deg  zero action +{row}", result.stdout
        )
        assert (falls, pushes, survived) == (4, 1.0, 0.0)  # from either side, at the first
    assert "trained" not in result.stdout and "report seeds (" not in result.stdout


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["-n", "-5"], "-n must be 0 or more"),
        (["--directions", "90"], "--directions needs"),
        (["--report-episodes", "0"], "--report-episodes must be 1 or more, got 0"),
    ],
)
def test_push_bound_refuses_a_negative_budget_and_directions_without_forces(
    tmp_path, arguments, message
):
    # In-process: the script's own start-up is tested where it trains (above).
    result = run_main(benchmark_module("push_bound").main, *arguments, cwd=tmp_path)
    assert result.returncode == 2
    assert message in result.stderr.strip().splitlines()[-1]
    assert not list(tmp_path.iterdir())


class ScriptedPushes:
    """Steps whose info says whether a push is on; the episode ends (fall) where told."""

    def __init__(self, episodes: list[tuple[list[bool], bool]]) -> None:
        self.episodes, self.episode = episodes, -1
        self.unwrapped = self  # as a gymnasium Env has

    def reset(self, seed: int) -> tuple[int, dict]:
        self.episode, self.t = self.episode + 1, 0
        return 0, {}

    def step(self, action: int) -> tuple[int, float, bool, bool, dict]:
        pushes, fell = self.episodes[self.episode]
        on, self.t = pushes[self.t], self.t + 1
        last = self.t == len(pushes)
        return 0, 1.0, fell and last, not fell and last, {"push_force": [float(on), 0, 0]}


def test_push_bound_blames_a_fall_on_the_pushes_only_after_one_began():
    push_bound = benchmark_module("push_bound")
    episodes = [
        ([False, True, True, False, True], True),  # two pushes, then a fall: one survived
        ([False, False], True),  # a fall with no push: the policy's own
        ([True, False], False),  # a push survived to the end
    ]
    tally = push_bound.play(lambda _: 0, ScriptedPushes(episodes), range(3))
    assert tally == (2, 1.0, pytest.approx(2 / 3), 1)  # 3 pushes, 1 fell under one
    assert "(1 before any push)" in tally.line(3)
    only_pushed = push_bound.play(lambda _: 0, ScriptedPushes(episodes[::2]), range(2))
    assert only_pushed == (1, 1.5, pytest.approx(2 / 3), 0)
    assert "before any push" not in only_pushed.line(2)


def test_learning_prints_each_groups_steps_and_minutes_as_a_ratio_to_the_baseline(tmp_path):
    kept = REPO / "benchmarks" / "results"
    result = run_script(
        "benchmarks/learning.py",
        "--group",
        "sac",
        *(str(kept / "sac-default" / f"seed{s}") for s in range(5)),
        "--group",
        "ppo",
        *(str(kept / "ppo-default" / f"seed{s}") for s in range(3)),
        "--at",
        "150000",
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stdout.splitlines() if line.startswith("sac to 15: ")]
    (line,) = lines
    found = re.fullmatch(
        r"sac to 15: ([0-9,]+) steps = ([0-9.]+)x ppo's ([0-9,]+) steps; "
        r"([0-9.]+) min = ([0-9.]+)x ppo's ([0-9.]+) min",
        line,
    )
    assert found, line
    steps, steps_ratio, ppo_steps, minutes, minutes_ratio, ppo_minutes = found.groups()
    number = lambda text: float(text.replace(",", ""))  # noqa: E731
    assert number(steps_ratio) == pytest.approx(number(steps) / number(ppo_steps), abs=0.01)
    assert number(minutes_ratio) == pytest.approx(number(minutes) / number(ppo_minutes), abs=0.01)
    assert not [line for line in result.stdout.splitlines() if line.startswith("ppo to ")]


def test_default_minutes_prices_evaluations_and_the_wait_for_a_walking_minitaur(
    tmp_path, monkeypatch
):
    needs("sbx")
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))  # it imports training_speed
    result = run_script(
        "benchmarks/default_minutes.py",
        *("--episodes", "1", "--sac-steps", "16", "--ppo-steps", "16"),
        *("--settings", "10000:20", "50000:5"),
        cwd=tmp_path,
        timeout=900,
    )
    assert result.returncode == 0, result.stderr
    evaluation = {
        algo: figure(
            rf"shipped {algo} \(1 episodes, 0 fell\): {NUMBER} env steps/s", result.stdout
        )[0]
        for algo in ("SAC", "PPO")
    }
    commands = (
        "python train.py",
        "python train.py --hyperparams gradient_steps=8",
        "python train.py --backend sbx --hyperparams gradient_steps=8",
        "python train.py --n-envs 8 --hyperparams train_freq=1",
        "python train.py --algo ppo",
    )
    rows = re.findall(
        r"^\| `(.*)` \| (\d+)k \| ([0-9.]+) \| (\d+)k x (\d+) \| ([0-9.]+) \| (\d+)% \|$",
        result.stdout,
        re.M,
    )
    assert [(row[0], row[3], row[4]) for row in rows] == [
        (command, freq, episodes)
        for command in commands
        for freq, episodes in (("10", "20"), ("50", "5"))
    ]
    for command, budget, training, freq, episodes, minutes, share in rows:
        rate = evaluation["PPO" if "ppo" in command else "SAC"]
        steps = int(budget) // int(freq) * int(episodes) * 1000
        # The rate is printed to the step/s and the minutes to 0.1: on a slow machine the
        # rate's rounding alone moves the minutes by more than a fixed tolerance.
        fastest, slowest = steps / (rate + 0.5) / 60, steps / max(rate - 0.5, 0.5) / 60
        assert fastest - 0.051 <= float(minutes) <= slowest + 0.051, (command, rate)
        whole = float(training) + float(minutes)
        assert int(share) == pytest.approx(100 * float(minutes) / whole, abs=1.5)
    budgets = {row[0]: int(row[1]) for row in rows}
    assert budgets["python train.py"] == 300 and budgets["python train.py --algo ppo"] == 1000
    # Fewer episodes, less often: the same training, a smaller share spent evaluating.
    assert rows[0][2] == rows[1][2] and int(rows[1][6]) < int(rows[0][6])

    # The wait: each command at its entry's own evaluations, its kept runs' median steps.
    waits = re.findall(
        r"^\| `(.*)` \| (\d+)k x (\d+) \| (\d+) \| (\d+)k \| ([0-9.]+) \| ([0-9.]+) \| "
        r"([0-9.]+) \| ([0-9.]+) \|$",
        result.stdout,
        re.M,
    )
    assert [wait[0] for wait in waits] == list(commands)
    assert [(wait[1], wait[2]) for wait in waits] == [("10", "10")] * 4 + [("25", "10")]
    module = benchmark_module("default_minutes")
    # A candidate is priced with its own settings, the default with the entry's.
    updates = {
        command: module.Pricing(command, 1.0, 1.0).config.hyperparams["gradient_steps"]
        for command in commands[:4]
    }
    assert updates == dict(zip(commands[:4], (4, 8, 8, 4), strict=True))
    envs = [module.Pricing(command, 1.0, 1.0).config.n_envs for command in commands[:4]]
    assert envs == [1, 1, 1, 8]
    ppo = waits[-1]
    assert float(ppo[6]) == 1.0 and float(ppo[8]) == 1.0
    for command, _, _, runs, steps, to_walk, ratio, whole, whole_ratio in waits:
        median, kept = module.median_steps_to(15.0, module.COMMANDS[command].kept_runs)
        assert int(runs) == kept >= 3 and int(steps) == round(median / 1000)
        assert 0 < float(to_walk) < float(whole)
        assert float(ratio) == pytest.approx(float(to_walk) / float(ppo[5]), rel=0.03)
        assert float(whole_ratio) == pytest.approx(float(whole) / float(ppo[7]), rel=0.03)

    refused = run_script("benchmarks/default_minutes.py", "--settings", "10000", cwd=tmp_path)
    assert refused.returncode == 2
    assert "'10000': expected FREQ:EPISODES" in error_lines(refused.stderr)[-1]


def test_falls_by_draw_plays_evaluate_pys_episodes_and_gives_each_policy_the_same_draws(
    tmp_path,
):
    import csv

    robust = next(
        model
        for _, model in pretrained_models()
        if model.parent.name.startswith("MinitaurBulletTrotRandomized")
    )
    table = tmp_path / "falls.csv"
    result = run_script(
        "benchmarks/falls_by_draw.py",
        *("--policy", f"base={robust}", "--policy", f"again={robust}"),
        *("--episodes", "1", "--seed", "20001", "--csv", str(table)),
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    rows = list(csv.DictReader(table.open()))
    assert [(row["policy"], row["episode_seed"]) for row in rows] == [
        ("base", "20001"),
        ("again", "20001"),
    ]
    base, again = rows
    assert base == {**again, "policy": "base"}  # the same draws, the same play
    # The drawn realism of the Tan 2018 preset: control step 3-20 ms, latency 0-40 ms.
    assert 0.003 <= float(base["control_time_step"]) <= 0.02
    assert 0 < float(base["control_latency"]) <= 0.04
    # Each table ends with both policies' totals.
    totals = [line for line in result.stdout.splitlines() if line.startswith("| all |")]
    assert len(totals) == 2 and all(line.count(" / 1 (") == 2 for line in totals)
    mean = evaluated_return(robust, 20001, cwd=tmp_path)
    assert mean == pytest.approx(float(base["return"]), abs=1e-6)

    # A policy's episodes from that table stand in for playing it again.
    table_again = tmp_path / "falls-again.csv"
    reread = run_script(
        "benchmarks/falls_by_draw.py",
        *("--policy", f"base={table}", "--policy", f"played={robust}"),
        *("--episodes", "1", "--seed", "20001", "--csv", str(table_again)),
        cwd=tmp_path,
    )
    assert reread.returncode == 0, reread.stderr
    recorded, played = list(csv.DictReader(table_again.open()))
    assert recorded == base and played == {**base, "policy": "played"}
    assert [line for line in reread.stdout.splitlines() if line.startswith("| ")] == [
        line.replace("again:", "played:")
        for line in result.stdout.splitlines()
        if line.startswith("| ")
    ]
    # Refused before any episode: other seeds than the table's, another env's episodes.
    other_seeds = run_script(
        "benchmarks/falls_by_draw.py", "--policy", f"base={table}", "--episodes", "2", cwd=tmp_path
    )
    assert other_seeds.returncode == 2 and len(error_lines(other_seeds)) == 1
    assert (
        "holds 'base' on seeds 20001..20001 (1 episodes), not the 20000..20001 asked"
        in (error_lines(other_seeds)[0])
    )
    garbled = tmp_path / "garbled.csv"
    garbled.write_text(table.read_text().replace(f",20001,{base['return']},", ",20001,abc,"))
    unreadable = run_script(
        "benchmarks/falls_by_draw.py",
        *("--policy", f"base={garbled}", "--episodes", "1", "--seed", "20001"),
        cwd=tmp_path,
    )
    assert unreadable.returncode == 2 and error_lines(unreadable) == [
        f"falls_by_draw.py: error: {garbled}: 'base' episode 20001 has return 'abc', not a number"
    ]
    elsewhere = tmp_path / "elsewhere.csv"
    elsewhere.write_text(
        table.read_text().replace(",MinitaurBulletTrotRandomized-v0,", ",Other-v0,")
    )
    mixed = run_script(
        "benchmarks/falls_by_draw.py",
        *("--policy", f"base={elsewhere}", "--policy", f"played={robust}"),
        *("--episodes", "1", "--seed", "20001"),
        cwd=tmp_path,
    )
    assert mixed.returncode == 2 and error_lines(mixed) == [
        "falls_by_draw.py: error: the policies' episodes come from different envs "
        "(base: Other-v0, played: MinitaurBulletTrotRandomized-v0)"
    ]


def test_falls_by_draw_refuses_a_policy_whose_env_draws_no_control_step(tmp_path):
    sac = next(model for _, model in pretrained_models() if model.parents[1].name == "sac")
    result = run_script("benchmarks/falls_by_draw.py", "--policy", f"sac={sac}", cwd=tmp_path)
    assert result.returncode == 2 and len(error_lines(result)) == 1, result.stderr
    assert error_lines(result)[0].endswith("so there is nothing to group its falls by")
    twice = run_script(
        "benchmarks/falls_by_draw.py",
        *("--policy", f"sac={sac}", "--policy", f"sac={sac}"),
        cwd=tmp_path,
    )
    assert twice.returncode == 2 and error_lines(twice) == [
        "falls_by_draw.py: error: --policy label 'sac' is given twice; each needs its own"
    ]


def test_falls_by_draw_bins_hold_their_upper_edge_and_the_first_its_lower():
    falls = benchmark_module("falls_by_draw")
    edges = (3.0, 8.0, 12.0, 16.0, 20.0)
    values = (2.9, 3.0, 7.99, 8.0, 8.01, 20.0, 20.5)
    labels = [falls.bin_label(value, edges) for value in values]
    assert labels == ["< 3 ms", "3-8 ms", "3-8 ms", "3-8 ms", "8-12 ms", "16-20 ms", "> 20 ms"]
    low, high = falls.wilson_interval(4, 150)
    assert low < 4 / 150 < high and high - low < 0.06
    assert falls.wilson_interval(0, 150)[0] == 0 < falls.wilson_interval(0, 150)[1] < 0.03
