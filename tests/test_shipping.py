"""Choosing the policy to ship: the rule, and which models are candidates."""

from __future__ import annotations

from pathlib import Path

import pytest

from minitaur_env.training import UsageError, shipping
from minitaur_env.training.run_folder import RunFolder


def fake_run(root: Path) -> RunFolder:
    run = RunFolder(root / "sac" / "MinitaurBulletEnv-v0_1")
    run.checkpoint_dir.mkdir(parents=True)
    run.config.write_text("env: MinitaurBulletEnv-v0\n")
    for path in (run.best_model, run.zoo_model, run.checkpoint(100), run.checkpoint(300)):
        path.write_bytes(b"")
    return run


@pytest.fixture
def judged(monkeypatch):
    """judge() replaced by a table: model file name -> (mean, falls) on selection seeds."""
    table: dict[str, tuple[float, int]] = {}
    calls: list[tuple[str, int]] = []

    def judge(model, episodes, seed, **_):
        calls.append((Path(model).name, seed))
        mean, falls = table.get(Path(model).name, (0.0, 0))
        return {"mean": mean, "std": 0.0, "falls": falls, "speed": 1.0}

    monkeypatch.setattr(shipping, "judge", judge)
    return table, calls


def test_fewest_falls_wins_over_a_higher_mean(tmp_path, judged):
    table, _ = judged
    run = fake_run(tmp_path)
    table.update({
        "best_model.zip": (25.0, 2),  # the highest mean, but it falls
        "MinitaurBulletEnv-v0.zip": (18.0, 0),
        "rl_model_300_steps.zip": (19.0, 0),  # no falls and the best mean of those
        "rl_model_100_steps.zip": (30.0, 1),
    })  # fmt: skip
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
    played_on_report = {name for name, seed in calls if seed == shipping.REPORT_SEED}
    assert played_on_report == {"best_model.zip", "MinitaurBulletEnv-v0.zip"}


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
