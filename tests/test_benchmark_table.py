"""benchmarks/keep_runs.py and benchmarks/minitaur_table.py on a tiny real run."""

from __future__ import annotations

import argparse
import importlib
import json
import re
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from minitaur_env.ship import main as ship_main
from minitaur_env.training import UsageError, shipping
from minitaur_env.training.aggregate import GroupSummary, RunCurve, iqm_with_ci
from minitaur_env.training.run_folder import RunFolder
from tests.scripts import REPO, TINY, error_lines, run_main, run_script

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(900)]

FAST_SAC = ["--hyperparams", "learning_starts=50", "buffer_size=5000", "batch_size=32"]


@pytest.fixture(scope="module")
def finished_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    result = run_script(
        "train.py",
        "-n",
        "160",
        *FAST_SAC,
        "--seed",
        "3",
        "--eval-freq",
        "80",
        "--eval-episodes",
        "1",
        "--save-freq",
        "80",
        *TINY,
        cwd=root,
    )
    assert result.returncode == 0, result.stderr
    return root / "logs" / "sac" / "MinitaurBulletEnv-v0_1"


def benchmark_script(name: str) -> Any:
    """benchmarks/<name>.py as a module, to run in this process: a script's start-up costs
    seconds, and each script's use as a script is tested once."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    try:
        return importlib.import_module(name)
    finally:
        sys.path.remove(str(REPO / "benchmarks"))


def keep_runs(run: Path, into: Path, *flags: str) -> None:
    """benchmarks/keep_runs.py in this process (its refusal and its use as a script are
    tested below)."""
    benchmark_script("keep_runs").main([str(run), "--into", str(into), *flags])


def test_keep_runs_keeps_what_judging_again_needs_and_nothing_bulky(finished_run, tmp_path):
    kept = run_script(
        "benchmarks/keep_runs.py", str(finished_run), "--into", "results/tiny", cwd=tmp_path
    )
    assert kept.returncode == 0, kept.stderr
    folder = tmp_path / "results" / "tiny" / "seed3"
    names = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())
    assert "MinitaurBulletEnv-v0.zip" in names
    assert "MinitaurBulletEnv-v0/vecnormalize.pkl" in names
    assert {"config.yml", "command.txt", "evaluations.npz"} <= set(names)
    assert any(n.startswith("monitor/") for n in names)
    assert not any(n.startswith("checkpoints/") or n == "best_model.zip" for n in names)
    run = RunFolder(folder)  # renamed, it still finds its model by the env in config.yml
    assert run.final_model == folder / "MinitaurBulletEnv-v0.zip"


def test_keep_runs_refuses_an_unfinished_run_in_one_line(finished_run, tmp_path):
    unfinished = tmp_path / "logs" / "MinitaurBulletEnv-v0_1"
    unfinished.mkdir(parents=True)
    (unfinished / "config.yml").write_text((finished_run / "config.yml").read_text())
    refused = run_script(
        "benchmarks/keep_runs.py", str(unfinished), "--into", "results/x", cwd=tmp_path
    )
    assert refused.returncode == 1
    assert error_lines(refused) == [
        f"keep_runs.py: {unfinished} has no final model MinitaurBulletEnv-v0.zip; unfinished? "
        "(--curves-only keeps a stopped run's evaluations)"
    ]
    assert not (tmp_path / "results").exists()


def test_keep_runs_keeps_a_stopped_runs_curves_without_a_model(finished_run, tmp_path):
    stopped = tmp_path / "logs" / "MinitaurBulletEnv-v0_1"
    shutil.copytree(finished_run, stopped, ignore=shutil.ignore_patterns("MinitaurBulletEnv-v0*"))
    keep_runs(stopped, tmp_path / "kept", "--curves-only")
    folder = tmp_path / "kept" / "seed3"
    names = sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())
    assert {"config.yml", "command.txt", "evaluations.npz"} <= set(names)
    assert any(n.startswith("monitor/") for n in names)
    assert not any(n.startswith(("checkpoints/", "MinitaurBulletEnv-v0")) for n in names)
    with (
        np.load(folder / "evaluations.npz") as kept,
        np.load(finished_run / "evaluations.npz") as run,
    ):
        assert kept["timesteps"].tolist() == run["timesteps"].tolist() == [80, 160]
    (stopped / "evaluations.npz").unlink()  # stopped before its first evaluation
    with pytest.raises(SystemExit, match=re.escape("has no evaluations.npz: nothing to keep")):
        keep_runs(stopped, tmp_path / "again", "--curves-only")
    assert not (tmp_path / "again").exists()


def test_a_kept_runs_final_model_ships_with_its_curve_and_provenance(finished_run, tmp_path):
    # Issue 22 ships SAC from a kept default run's final model: no checkpoints, no figure.
    keep_runs(finished_run, tmp_path / "kept")
    kept = tmp_path / "kept" / "seed3"
    assert not RunFolder(kept).learning_curve.exists()
    shipped = tmp_path / "pretrained" / "sac" / "MinitaurBulletEnv-v0_1"
    # In-process: the command's own start-up is tested where train.py and evaluate.py run.
    result = run_main(
        ship_main,
        str(kept),
        "--final-only",
        "--episodes",
        "1",
        "--ship",
        str(shipped),
        cwd=tmp_path,
    )
    assert result.returncode == 0, result.stderr
    assert RunFolder(shipped).learning_curve.read_bytes().startswith(b"\x89PNG")
    provenance = yaml.safe_load(RunFolder(shipped).provenance.read_text())
    assert "final models (no checkpoint picking)" in provenance["selection"]["rule"]
    assert provenance["training"]["seed"] == 3 and provenance["training"]["model_steps"] == 160
    assert provenance["training"]["model"] == f"MinitaurBulletEnv-v0.zip of {kept}"
    # Training ended inside an unlogged episode: the final model's time was NaN here.
    assert provenance["training"]["wall_clock_min_to_model"] > 0
    # A shipped folder may be the only copy of an agent: shipping over it must be asked for.
    before = {p: p.read_bytes() for p in shipped.rglob("*") if p.is_file()}
    again = ("--final-only", "--episodes", "1", "--report-seed", "777", "--ship", str(shipped))
    refused = run_main(ship_main, str(kept), *again, cwd=tmp_path)
    assert refused.returncode == 2
    assert error_lines(refused.stderr) == [
        f"python -m minitaur_env.ship: error: --ship: {shipped} is already there; "
        "add --replace to replace it"
    ]
    assert {p: p.read_bytes() for p in shipped.rglob("*") if p.is_file()} == before
    replaced = run_main(ship_main, str(kept), *again, "--replace", cwd=tmp_path)  # control
    assert replaced.returncode == 0, replaced.stderr
    assert yaml.safe_load(RunFolder(shipped).provenance.read_text())["eval_seeds"] == "777..777"


def test_keeping_a_run_again_or_failing_part_way_loses_nothing_kept(
    finished_run, tmp_path, monkeypatch
):
    def files(folder: Path) -> dict[Path, bytes]:
        return {p.relative_to(folder): p.read_bytes() for p in folder.rglob("*") if p.is_file()}

    keep_runs(finished_run, tmp_path / "kept")
    folder = tmp_path / "kept" / "seed3"
    before = files(folder)
    assert Path("MinitaurBulletEnv-v0.zip") in before
    keep_runs(folder, tmp_path / "kept")  # a kept run kept again into its own folder
    assert files(folder) == before

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(shutil, "copytree", full_disk)  # after the model is copied
    with pytest.raises(OSError, match="No space left"):
        keep_runs(finished_run, tmp_path / "kept")
    assert files(folder) == before
    assert [p.name for p in folder.parent.iterdir()] == ["seed3"]  # nothing left aside
    monkeypatch.undo()  # control: the same keep, succeeding, replaces the folder whole
    keep_runs(finished_run, tmp_path / "kept", "--curves-only")
    assert Path("MinitaurBulletEnv-v0.zip") not in files(folder)
    assert files(folder)[Path("evaluations.npz")] == before[Path("evaluations.npz")]


def test_a_ship_that_fails_part_way_leaves_the_earlier_shipped_folder_whole(
    finished_run, tmp_path, monkeypatch
):
    keep_runs(finished_run, tmp_path / "kept")
    kept = RunFolder(tmp_path / "kept" / "seed3")
    report = shipping.select([kept], episodes=1, final_only=True)
    shipped = RunFolder(tmp_path / "pretrained" / "sac" / "MinitaurBulletEnv-v0_1")
    shipping.ship(report, shipped.path)
    before = {
        p.relative_to(shipped.path): p.read_bytes() for p in shipped.path.rglob("*") if p.is_file()
    }
    assert shipped.zoo_model.relative_to(shipped.path) in before

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(shipping, "export_onnx", full_disk)  # after the zip is written
    # Another report to ship over it: the same one relabelled, as what ship() writes is
    # the question here, not another minute of playing the Minitaur.
    other = {**report, "report_seed": 777}
    with pytest.raises(OSError, match="No space left"):
        shipping.ship(other, shipped.path)
    after = {
        p.relative_to(shipped.path): p.read_bytes() for p in shipped.path.rglob("*") if p.is_file()
    }
    assert after == before  # the old model, its provenance and statistics, as they were
    assert sorted(p.name for p in shipped.path.parent.iterdir()) == [shipped.path.name]
    monkeypatch.undo()  # control: the same ship, succeeding, does replace the folder
    shipping.ship(other, shipped.path)
    assert yaml.safe_load(shipped.provenance.read_text())["eval_seeds"] == "777..777"


def test_a_model_trained_on_from_a_kept_run_names_that_runs_command(finished_run, tmp_path):
    # The shipped PPO came from a kept default run; a model trained on from one (-i) must
    # ship with the kept run's own command and seed (ship() writes origin_of() as its
    # provenance's started_from), not just the path it started from.
    keep_runs(finished_run, tmp_path / "kept")
    kept = RunFolder(tmp_path / "kept" / "seed3")
    origin = shipping.origin_of(str(kept.zoo_model))
    assert origin["trained_agent"] == str(kept.zoo_model)
    assert origin["commands"] == kept.command.read_text().strip().splitlines()
    assert origin["commands"][0].startswith("python train.py -n 160")
    assert origin["seed"] == 3 and origin["model_steps"] == 160
    # A shipped model's own provenance still wins: its training as it was shipped.
    kept.provenance.write_text("training: {commands: [python train.py --seed 9], seed: 9}\n")
    assert shipping.origin_of(str(kept.zoo_model)) == {
        "trained_agent": str(kept.zoo_model),
        "commands": ["python train.py --seed 9"],
        "seed": 9,
    }


@pytest.fixture
def table(monkeypatch, capsys):
    """minitaur_table.py's main() in this process (its refusals run as a user runs the
    script, below): what it printed."""
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))  # as when the script runs
    main = importlib.import_module("minitaur_table").main

    def run(*argv: str) -> str:
        capsys.readouterr()
        main(list(argv))
        return capsys.readouterr().out

    return run


def test_the_table_judges_final_models_once_and_again_when_asked(finished_run, tmp_path, table):
    keep_runs(finished_run, tmp_path / "r/tiny")
    report = RunFolder(tmp_path / "r" / "tiny" / "seed3").final_model_report()
    row = ["--row", f"tiny={tmp_path}/r/tiny/seed*", "--episodes", "1"]

    first = table(*row)
    line = next(line for line in first.splitlines() if line.startswith("| tiny"))
    judged = json.loads(report.read_text())
    assert judged["episodes"] == 1 and judged["report_seed"] == 12345
    assert f"| {judged['mean']:.2f} |" in line  # median of one seed
    # The stored result is reused while the model is the same file...
    report.write_text(json.dumps({**judged, "mean": 123.0}))
    assert "| 123.00 |" in table(*row)
    # ...and played again for --rejudge (or another model, seed or episode count).
    assert "123.00" not in table(*row, "--rejudge")
    assert json.loads(report.read_text())["mean"] == pytest.approx(judged["mean"])


def test_a_run_judged_in_place_keeps_its_figures_without_its_model(finished_run, tmp_path, table):
    # An SBX model (9.5 MB) is judged in its run folder, then kept without the model.
    run = tmp_path / "logs" / "MinitaurBulletEnv-v0_1"
    shutil.copytree(finished_run, run)
    table("--row", f"live={run}", "--episodes", "1")
    judged = json.loads(RunFolder(run).final_model_report().read_text())
    keep_runs(run, tmp_path / "r" / "judged", "--curves-only")
    unjudged = tmp_path / "logs2" / "MinitaurBulletEnv-v0_1"
    shutil.copytree(finished_run, unjudged)
    keep_runs(unjudged, tmp_path / "r" / "unjudged", "--curves-only")  # the control

    assert not RunFolder(tmp_path / "r" / "judged" / "seed3").final_model.exists()
    out = table("--row", f"j={tmp_path}/r/judged/seed*", "--row", f"u={tmp_path}/r/unjudged/seed*")
    lines = {line.split(" | ")[0]: line for line in out.splitlines() if line.startswith("| ")}
    assert f"| {judged['mean']:.2f} |" in lines["| j (final models judged earlier, not kept)"]
    assert lines["| u"].split(" | ")[3] == "-"  # nothing judged: no figure, none invented


def test_a_run_without_evaluations_is_one_line(finished_run, tmp_path):
    (tmp_path / "r" / "seed0").mkdir(parents=True)
    (tmp_path / "r" / "seed0" / "config.yml").write_text((finished_run / "config.yml").read_text())
    refused = run_script(
        "benchmarks/minitaur_table.py", "--row", f"x={tmp_path}/r/seed*", cwd=tmp_path
    )
    assert refused.returncode == 2
    assert error_lines(refused) == [
        f"minitaur_table.py: error: {tmp_path}/r/seed0 has no evaluations.npz; not a finished run"
    ]


def test_the_docs_tables_are_their_kept_runs_tables(table):
    assert table("--check-docs").strip() == "every table matches its runs"


def test_a_page_that_disagrees_with_its_runs_is_found_and_rewritten(table, tmp_path):
    module = importlib.import_module("minitaur_table")
    args = argparse.Namespace(
        episodes=20, report_seed=12345, rejudge=False, trust_pickle=False, stored_only=True
    )
    (tmp_path / "docs").mkdir()
    for table in module.TABLES.values():  # every page that holds a table
        (tmp_path / table["page"]).write_text((REPO / table["page"]).read_text())
    page = REPO / "docs" / "results.md"
    copy = tmp_path / "docs" / "results.md"
    assert module.docs_tables(args, tmp_path, write=False) == []  # control: a true copy
    row = next(
        line for line in page.read_text().splitlines() if line.startswith("| PPO, `minitaur` entry")
    )
    copy.write_text(page.read_text().replace(row, row.replace("| 3 |", "| 4 |", 1)))
    assert module.docs_tables(args, tmp_path, write=False) == ["benchmark (docs/results.md)"]
    assert module.docs_tables(args, tmp_path, write=True) == ["benchmark (docs/results.md)"]
    assert copy.read_text() == page.read_text()  # rewritten from the runs
    copy.write_text(page.read_text().replace("<!-- table: ablation -->", ""))
    with pytest.raises(UsageError, match=re.escape("no <!-- table: ablation --> ... <!-- /")):
        module.docs_tables(args, tmp_path, write=False)
    # A table whose end marker is mistyped would swallow the page up to the next table's
    # end: refused, and no page written, the tables before it in the file included.
    broken = page.read_text().replace("<!-- /table -->", "<!-- end table -->", 2)
    copy.write_text(broken.replace(row, row.replace("| 3 |", "| 4 |", 1)))
    with pytest.raises(UsageError, match=r"has no <!-- /table --> before the next table"):
        module.docs_tables(args, tmp_path, write=True)
    assert copy.read_text() == broken.replace(row, row.replace("| 3 |", "| 4 |", 1))


def test_a_row_needs_label_and_folders(tmp_path):
    refused = run_script("benchmarks/minitaur_table.py", "--row", "no-glob", cwd=tmp_path)
    assert refused.returncode == 2
    assert error_lines(refused) == [
        "minitaur_table.py: error: --row expects LABEL=GLOB, got 'no-glob' (see --help)"
    ]


def test_how_far_a_run_falls_back_after_first_reaching_a_return():
    curve = RunCurve(
        RunFolder("unused"),
        steps=np.array([10, 20, 30, 40, 50, 60]),
        returns=np.array([1.0, 16.0, 12.0, 18.0, 9.0, 17.0]),
        seconds=np.array([5.0, 10.0, 15.0, 20.0, 25.0, np.nan]),
    )
    assert curve.after_reaching(15.0) == (9.0, 9.0)  # lowest 9; 18 -> 9 the largest drop
    assert curve.after_reaching(17.5) == (9.0, 9.0)
    assert curve.after_reaching(20.0) is None
    assert curve.steps_per_second == 50 / 25.0  # the last evaluation the clock covers


def test_the_confidence_interval_is_the_same_on_every_call_and_leaves_numpy_alone():
    # rliable 1.2 draws its resamples from the global np.random whatever random_state it
    # is given: unpinned, these scores gave 16.56 and 16.74 as the low end on two calls.
    scores = [19.62, 17.50, 18.04, 18.46, 16.09]
    first = iqm_with_ci(scores, reps=300)
    np.random.seed(123)
    caller_next = np.random.random(3)
    np.random.seed(123)
    assert iqm_with_ci(scores, reps=300) == first
    assert (np.random.random(3) == caller_next).all()  # the caller's stream untouched
    others = {iqm_with_ci(scores, reps=300, seed=seed)[1:] for seed in range(1, 6)}
    assert len(others) > 1  # the seed still decides the resamples


def test_a_live_actor_row_judges_the_run_without_its_average(tmp_path, finished_run, table):
    trained = run_script(
        "train.py",
        "-n",
        "160",
        *FAST_SAC,
        "policy=StabilizedMlpPolicy",
        "policy_kwargs={net_arch: [64, 64], actor_ema: 0.999}",
        "--seed",
        "3",
        "--eval-freq",
        "80",
        "--eval-episodes",
        "1",
        *TINY,
        cwd=tmp_path,
    )
    assert trained.returncode == 0, trained.stderr
    run = tmp_path / "logs" / "sac" / "MinitaurBulletEnv-v0_1"
    keep_runs(run, tmp_path / "r/ema")
    kept = tmp_path / "r" / "ema" / "seed3"
    args = ["--episodes", "1"]
    average = table("--row", f"a={kept}", *args)
    live = table("--row", f"l={kept}#live-actor", *args)
    assert "averaged actor's" in live and "averaged actor's" not in average
    reports = [RunFolder(kept).final_model_report(live_actor) for live_actor in (False, True)]
    judged = [json.loads(report.read_text()) for report in reports]
    # The same file, judged with two different actors (0.999 after ~100 updates keeps the
    # average near the initial weights, far from the live actor).
    assert len({r["model_sha256"] for r in judged}) == 1
    assert len({r["mean"] for r in judged}) == 2

    # A run trained without the average has no live actor to tell apart: one line.
    keep_runs(finished_run, tmp_path / "r/plain")
    refused = run_script(
        "benchmarks/minitaur_table.py",
        "--row",
        f"p={tmp_path}/r/plain/seed3#live-actor",
        *args,
        cwd=tmp_path,
    )
    assert refused.returncode == 2
    assert error_lines(refused)[-1].endswith("has no averaged actor (actor_ema) to leave out")


def test_the_share_of_exploring_episodes_that_fell(tmp_path, finished_run, monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))  # as when the script runs
    training_fall_share = importlib.import_module("minitaur_table").training_fall_share

    run = RunFolder(tmp_path / "run")
    run.monitor_dir.mkdir(parents=True)
    config = yaml.safe_load((finished_run / "config.yml").read_text())
    config["env_kwargs"] = {}  # the registered episodes, 1000 steps
    (run.path / "config.yml").write_text(yaml.safe_dump(config))
    # Episodes end at env steps 1000, 1300, 2300, 2800, 3800, 3900; the time limit is 1000.
    lengths = [1000, 300, 1000, 500, 1000, 100]
    rows = [f"0.0,{length},{second}.0" for second, length in enumerate(lengths, start=1)]
    (run.monitor_dir / "0.monitor.csv").write_text('#{"t_start": 0}\nr,l,t\n' + "\n".join(rows))
    assert training_fall_share(run, 1000, 2800) == pytest.approx(2 / 3)  # 300 and 500 fell
    assert training_fall_share(run, 0, 3900) == pytest.approx(3 / 6)
    assert training_fall_share(run, 2800, 3800) == 0.0  # the one episode ran to the limit
    assert np.isnan(training_fall_share(run, 4000, 5000))  # no episode ended there

    # Trained on shorter episodes, an episode that ran to that limit did not fall.
    for shorter in (
        {"env_kwargs": {"max_episode_steps": 300}},
        {"hyperparams": {"training_episode_steps": 300}},
    ):
        (run.path / "config.yml").write_text(yaml.safe_dump({**config, **shorter}))
        rows = [f"0.0,{length},{second}.0" for second, length in enumerate([300, 100, 300], 1)]
        (run.monitor_dir / "0.monitor.csv").write_text('#{"t_start": 0}\nr,l,t\n' + "\n".join(rows))
        assert training_fall_share(run, 0, 700) == pytest.approx(1 / 3)


def fake_run(folder: Path, seed: int, returns: list[float], lengths: list[int]) -> None:
    """A run folder holding only a config and periodic evaluations (2 episodes each)."""
    folder.mkdir(parents=True)
    (folder / "config.yml").write_text(
        f"algo: sac\nenv: MinitaurBulletEnv-v0\nseed: {seed}\nn_timesteps: 40000\n"
    )
    steps = 10_000 * np.arange(1, len(returns) + 1)
    np.savez(
        folder / "evaluations.npz",
        timesteps=steps,
        results=np.repeat(np.array(returns)[:, None], 2, axis=1),
        ep_lengths=np.array([[length, 1000] for length in lengths]),
    )


def test_a_curves_table_gives_each_run_its_evaluations_and_a_median_row(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))
    module = importlib.import_module("minitaur_table")
    monkeypatch.setattr(module, "RESULTS", tmp_path)
    fake_run(tmp_path / "row" / "seed0", 0, [1.0, 5.0, 3.0], [1000, 40, 1000])
    fake_run(tmp_path / "row" / "seed1", 1, [2.0, 9.0], [1000, 1000])
    table = {
        "label": "config",
        "at": [10_000, 30_000],
        "columns": ["best", "last evaluation", "evaluations with a fall"],
        "rows": {"mine": "row/seed*", "both": {"median": "row/seed*"}},
    }
    assert module.render_curves(table).splitlines() == [
        "| config | seed | @10k | @30k | best | last evaluation | evaluations with a fall |",
        "|---|---|---|---|---|---|---|",
        "| mine | 0 | 1.00 | 3.00 | 5.00 @20k | 30k | 1 of 3 |",
        "| the same | 1 | 2.00 |  | 9.00 @20k | 20k | 0 of 2 |",  # stopped before 30k
        "| both | 0 1 (medians) | 1.50 | 3.00 | 7.00 | 25k |  |",
    ]
    # After half the budget (20k of 40k): seed 0's fall at 20k does not count, seed 1
    # has no evaluation there; a fall at 30k does.
    fake_run(tmp_path / "late" / "seed2", 2, [1.0, 5.0, 3.0], [1000, 1000, 40])
    late = {**table, "columns": ["most falls in an evaluation, second half"]}
    assert [line.split(" | ")[-1] for line in module.render_curves(late).splitlines()[2:]] == [
        "0 of 2 |",
        " |",
        " |",
    ]
    late["rows"] = {"late": "late/seed*"}
    assert module.render_curves(late).splitlines()[2].endswith("| 1 of 2 |")
    each = {**table, "columns": ["falls in each evaluation"]}
    assert [line.split(" | ")[-1] for line in module.render_curves(each).splitlines()[2:]] == [
        "0 1 0 of 2 |",
        "0 0 of 2 |",
        " |",  # no median of a sequence
    ]
    # The final model's stored report, where one was kept; none is played for the table.
    final = {**table, "columns": ["final model"]}
    report = {"episodes": 20, "report_seed": 12345, "mean": 21.5, "std": 1.0, "falls": 2}
    (tmp_path / "row" / "seed0" / "final_model_report.json").write_text(json.dumps(report))
    assert [line.split(" | ")[-1] for line in module.render_curves(final).splitlines()[2:]] == [
        "21.50 (2) |",
        " |",  # seed 1 kept no final model
        " |",
    ]
    with pytest.raises(UsageError, match=r"no run folders for the row 'gone' \(nothing/\*\)"):
        module.render_curves({**table, "rows": {"gone": "nothing/*"}})
    with pytest.raises(UsageError, match="no column 'speed' in a curves table"):
        module.render_curves({**table, "columns": ["speed"]})


def test_a_robustness_table_merges_each_rows_sources(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))
    module = importlib.import_module("minitaur_table")
    monkeypatch.setattr(module, "RESULTS", tmp_path)
    cell = {"mean": 12.345, "std": 1.0, "falls": 2, "speed": 1.0}
    (tmp_path / "a.json").write_text(json.dumps({"mine": {"nominal": cell}}))
    (tmp_path / "b.json").write_text(json.dumps({"me too": {"pushes": {**cell, "falls": 20}}}))
    table = {
        "columns": ["nominal", "pushes", "latency"],
        "rows": {"policy": ["a.json#mine", "b.json#me too"], "alone": "a.json#mine"},
    }
    assert module.render_robustness(table).splitlines() == [
        "| policy | nominal | pushes | latency |",
        "|---|---|---|---|",
        "| policy | 12.35 ± 1.00 (2) | 12.35 ± 1.00 (20) | - |",
        "| alone | 12.35 ± 1.00 (2) | - | - |",
    ]
    with pytest.raises(UsageError, match=re.escape("tables.yml: a.json has no policy 'yours'")):
        module.render_robustness({**table, "rows": {"x": "a.json#yours"}})


def test_figure_one_draws_the_tables_figure_rows_in_their_order(monkeypatch):
    monkeypatch.syspath_prepend(str(REPO / "benchmarks"))
    module = importlib.import_module("minitaur_table")
    groups = [GroupSummary(name, [], []) for name in ("screen", "sac", "ppo")]
    monkeypatch.setitem(module.TABLES, "t", {"figure": ["ppo", "sac"], "rows": {}})
    args = argparse.Namespace(table="t", row=None)

    assert [group.name for group in module.figure_groups(groups, args)] == ["ppo", "sac"]
    # --row draws what it was given; a table without a figure list, every row.
    assert module.figure_groups(groups, argparse.Namespace(table="t", row=["x=y"])) == groups
    monkeypatch.setitem(module.TABLES, "t", {"rows": {}})
    assert module.figure_groups(groups, args) == groups
    monkeypatch.setitem(module.TABLES, "t", {"figure": ["sac", "gone"], "rows": {}})
    with pytest.raises(UsageError, match=r"tables\.yml: figure of 't' names no row 'gone'"):
        module.figure_groups(groups, args)


def test_keep_runs_resumable_keeps_what_a_resume_needs_and_it_goes_on(finished_run, tmp_path):
    stopped = tmp_path / "logs" / "MinitaurBulletEnv-v0_1"
    shutil.copytree(finished_run, stopped, ignore=shutil.ignore_patterns("MinitaurBulletEnv-v0*"))
    keep_runs(stopped, tmp_path / "kept", "--resumable")
    folder = tmp_path / "kept" / "seed3"
    names = {p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file()}
    assert {
        "checkpoints/rl_model_160_steps.zip",
        "checkpoints/rl_model_vecnormalize_160_steps.json",
        "checkpoints/rl_model_replay_buffer_160_steps.npz",
        "best_model.zip",
    } <= names
    assert "checkpoints/rl_model_80_steps.zip" not in names  # the newest only
    # Another session, another machine: a copy of the kept folder goes on from 160.
    clone = tmp_path / "clone" / "MinitaurBulletEnv-v0_1"
    shutil.copytree(folder, clone)
    resumed = run_script("train.py", "--resume", str(clone), "-n", "240", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert "(from 160)" in resumed.stdout
    with np.load(clone / "evaluations.npz") as logged:
        assert logged["timesteps"].tolist() == [80, 160, 240]
    # Kept again, the resumed copy keeps the sweep's record it carries inside.
    (clone / "trial.yml").write_text("group: default\nseed: 3\n")
    keep_runs(clone, tmp_path / "kept-again", "--curves-only")
    assert (
        tmp_path / "kept-again" / "seed3" / "trial.yml"
    ).read_text() == "group: default\nseed: 3\n"
    shutil.rmtree(stopped / "checkpoints")  # control: nothing to resume from, refused
    with pytest.raises(SystemExit, match="has no checkpoint to resume from"):
        keep_runs(stopped, tmp_path / "again", "--resumable")
    assert not (tmp_path / "again").exists()


def test_a_branch_goes_on_from_its_checkpoint_with_the_changed_settings(
    finished_run, tmp_path, capsys
):
    branch_run = benchmark_script("branch_run")
    branch = tmp_path / "branch" / "MinitaurBulletEnv-v0_1"
    change = ["--hyperparams", "target_entropy=-1", "mirror=null"]
    branch_run.main([str(finished_run), "--at", "80", "--into", str(branch), *change])
    config = yaml.safe_load((branch / "config.yml").read_text())
    original = yaml.safe_load((finished_run / "config.yml").read_text())
    assert original["hyperparams"]["target_entropy"] == 0 and original["hyperparams"]["mirror"]
    assert config["hyperparams"]["target_entropy"] == -1 and "mirror" not in config["hyperparams"]
    zoo = yaml.safe_load((branch / "MinitaurBulletEnv-v0" / "config.yml").read_text())
    assert zoo["target_entropy"] == -1 and "mirror" not in zoo
    names = {p.relative_to(branch).as_posix() for p in branch.rglob("*") if p.is_file()}
    assert "checkpoints/rl_model_replay_buffer_80_steps.npz" in names
    # Nothing of what the run saved after 80 steps, nor its final model and verdicts.
    assert not [name for name in names if "160" in name]
    assert "MinitaurBulletEnv-v0.zip" not in names
    recorded = (branch / "command.txt").read_text().splitlines()[-1]
    assert recorded == (
        f"# branched at 80 steps from {finished_run}: python benchmarks/branch_run.py "
        f"{finished_run} --at 80 --into {branch} --hyperparams target_entropy=-1 mirror=null"
    )
    resumed = run_script("train.py", "--resume", str(branch), cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert "(from 80)" in resumed.stdout
    with np.load(branch / "evaluations.npz") as logged:
        assert logged["timesteps"].tolist() == [80, 160]  # the original's 160 rewound
    assert (branch / "MinitaurBulletEnv-v0.zip").is_file()
    # Refusals, each in one line, each leaving nothing behind.
    refused = tmp_path / "refused"
    for argv, message in [
        (["--at", "120", "--into", str(refused)], "has no checkpoint at 120 steps (kept: 80, 160)"),
        (
            ["--at", "80", "--into", str(refused), "--hyperparams", "n_envs=2"],
            "--hyperparams n_envs: a branch keeps the run's",
        ),
        (["--at", "80", "--into", str(branch)], "already exists; name a new folder"),
    ]:
        with pytest.raises(SystemExit):
            branch_run.main([str(finished_run), *argv])
        (line,) = error_lines(capsys.readouterr().err)
        assert message in line
        assert not refused.exists()
    # A copy that fails part-way leaves no half branch that a resume could take for whole.
    copy = shutil.copytree

    def copy_then_fail(*args, **kwargs):
        copy(*args, **kwargs)
        raise OSError("disk full")

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(branch_run.shutil, "copytree", copy_then_fail)
        with pytest.raises(OSError, match="disk full"):
            branch_run.main([str(finished_run), "--at", "80", "--into", str(refused)])
    assert not refused.exists()
    script = run_script(
        "benchmarks/branch_run.py", str(tmp_path), "--at", "80", "--into", "x", cwd=tmp_path
    )
    assert script.returncode == 2
    assert error_lines(script) == [
        f"branch_run.py: error: {tmp_path} is not a run folder (no config.yml) (see --help)"
    ]
