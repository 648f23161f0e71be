"""Choosing the policy to ship: the rule, and which models are candidates."""

from __future__ import annotations

import shlex
from pathlib import Path
from types import SimpleNamespace

import pytest

from minitaur_env.training import UsageError, shipping
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.seeds import REPORT_SEED


def fake_run(root: Path) -> RunFolder:
    run = RunFolder(root / "sac" / "MinitaurBulletEnv-v0_1")
    run.checkpoint_dir.mkdir(parents=True)
    run.config.write_text("env: MinitaurBulletEnv-v0\n")
    for path in (run.best_model, run.zoo_model, run.checkpoint(100), run.checkpoint(300)):
        path.write_bytes(b"")
    return run


@pytest.fixture
def judged(monkeypatch):
    """judge() replaced by a table: model file name -> (mean, falls) on selection seeds;
    (name, condition label) -> (mean, falls) under ``also_on`` conditions."""
    table: dict[str | tuple[str, str], tuple[float, int]] = {}
    calls: list[tuple[str, int]] = []

    def judge(model, episodes, seed, overrides=None, **_):
        calls.append((Path(model).name, seed))
        key = (Path(model).name, shipping.condition_label(overrides)) if overrides else None
        mean, falls = table.get(key or Path(model).name, (0.0, 0))
        return {"mean": mean, "std": 0.0, "falls": falls, "speed": 1.0}

    monkeypatch.setattr(shipping, "judge", judge)
    return table, calls


def test_fewest_falls_wins_over_a_higher_mean(tmp_path, judged):
    table, _ = judged
    run = fake_run(tmp_path)
    table.update(
        {
            "best_model.zip": (25.0, 2),  # the highest mean, but it falls
            "MinitaurBulletEnv-v0.zip": (18.0, 0),
            "rl_model_300_steps.zip": (19.0, 0),  # no falls and the best mean of those
            "rl_model_100_steps.zip": (30.0, 1),
        }
    )
    report = shipping.select([run], episodes=2, from_steps=0, log=lambda _: None)
    assert Path(report["chosen"]["model"]).name == "rl_model_300_steps.zip"


def test_final_only_considers_the_final_models_alone(tmp_path, judged):
    table, calls = judged
    run = fake_run(tmp_path)
    table.update({"best_model.zip": (30.0, 0), "MinitaurBulletEnv-v0.zip": (12.0, 3)})
    report = shipping.select([run], episodes=2, final_only=True, log=lambda _: None)
    assert list(report["selection"]) == [str(run.zoo_model)]
    assert Path(report["chosen"]["model"]).name == "MinitaurBulletEnv-v0.zip"
    # only the chosen model and each run's best and final are played on the report seeds
    played_on_report = {name for name, seed in calls if seed == REPORT_SEED}
    assert played_on_report == {"best_model.zip", "MinitaurBulletEnv-v0.zip"}
    # ...each once: the chosen final model's report is the one its run already has
    assert len(calls) == len(set(calls)) == 3, calls
    assert report["chosen"]["report"] == report["runs"][str(run)]["final"]
    assert report["chosen"]["report"] is not report["runs"][str(run)]["final"]  # no YAML alias


def test_checkpoints_before_from_steps_are_not_candidates(tmp_path, judged):
    run = fake_run(tmp_path)
    report = shipping.select([run], episodes=1, from_steps=200, log=lambda _: None)
    names = {Path(model).name for model in report["selection"]}
    assert names == {"best_model.zip", "MinitaurBulletEnv-v0.zip", "rl_model_300_steps.zip"}


def test_no_candidate_is_one_line(tmp_path, judged):
    run = RunFolder(tmp_path / "empty_1")
    run.path.mkdir()
    with pytest.raises(UsageError, match="no candidate model"):
        shipping.select([run], episodes=1, log=lambda _: None)


CLASSIC = {"dynamics_ranges": "classic", "realism": "classic"}


def test_also_on_sums_falls_over_the_conditions_and_reports_each(tmp_path, judged):
    table, _ = judged
    run = fake_run(tmp_path)
    table.update(
        {
            "best_model.zip": (25.0, 3),
            "MinitaurBulletEnv-v0.zip": (25.0, 3),
            "rl_model_300_steps.zip": (20.0, 0),  # the best on its own env...
            ("rl_model_300_steps.zip", "dynamics_ranges=classic realism=classic"): (14.0, 2),
            "rl_model_100_steps.zip": (16.0, 1),  # ...but this one falls less in all
            ("rl_model_100_steps.zip", "dynamics_ranges=classic realism=classic"): (15.0, 0),
        }
    )
    report = shipping.select([run], episodes=2, from_steps=0, also_on=[CLASSIC], log=lambda _: None)
    assert Path(report["chosen"]["model"]).name == "rl_model_100_steps.zip"
    assert report["selection"][str(run.checkpoint(100))]["falls"] == 1
    assert report["selection"][str(run.checkpoint(100))]["mean"] == pytest.approx(15.5)
    assert report["chosen"]["also_on"]["dynamics_ranges=classic realism=classic"]["mean"] == 15.0
    assert report["also_on"] == {"dynamics_ranges=classic realism=classic": CLASSIC}
    # negative control: judged on its own env alone, the other checkpoint wins
    report = shipping.select([run], episodes=2, from_steps=0, log=lambda _: None)
    assert Path(report["chosen"]["model"]).name == "rl_model_300_steps.zip"
    assert "also_on" not in report["chosen"]


def test_a_condition_that_changes_nothing_or_repeats_is_refused(tmp_path, judged):
    run = fake_run(tmp_path)
    for also_on in ([{}], [CLASSIC, dict(CLASSIC)]):
        with pytest.raises(UsageError, match="--also-on"):
            shipping.select([run], episodes=1, also_on=also_on, log=lambda _: None)


def test_condition_labels_are_env_kwargs_flags_a_shell_reads_back():
    label = shipping.condition_label(
        {"realism": {"pushes": {"direction": 90}}, "dynamics_ranges": "classic"}
    )
    assert shlex.split(label) == ['realism={"pushes":{"direction":90}}', "dynamics_ranges=classic"]


def test_judge_plays_on_the_policys_own_kwargs_with_the_overrides(monkeypatch):
    """A policy trained with env kwargs (an observation history, a randomization) is judged
    on them, as evaluate.py plays it, not on the bare registered env."""
    policy = SimpleNamespace(
        env_id="MinitaurBulletTrotRandomized-v0",
        env_kwargs={"history": 4, "realism": {"pd_latency": 0.003}, "max_episode_steps": 50},
    )
    played = []
    monkeypatch.setattr(shipping, "load_policy", lambda *a, **k: policy)

    def play(policy, env_id, env_kwargs, episodes, seed):
        played.append((env_id, env_kwargs))
        return [{"return": 1.0, "fell": 0.0, "speed": 1.0}]

    monkeypatch.setattr(shipping, "play", play)
    shipping.judge(Path("m.zip"), 1, 0, {"realism": "classic"})
    shipping.judge(Path("m.zip"), 1, 0)
    shipping.judge(Path("m.zip"), 1, 0, env=("MinitaurBulletTrot-v0", {"history": 4}))
    assert played == [
        ("MinitaurBulletTrotRandomized-v0", {"history": 4, "realism": "classic"}),
        ("MinitaurBulletTrotRandomized-v0", {"history": 4, "realism": {"pd_latency": 0.003}}),
        ("MinitaurBulletTrot-v0", {"history": 4}),
    ]
