"""One seed plan: no episode serves two purposes, before or after any resume."""

from __future__ import annotations

import itertools
import random

import pytest
from gymnasium.envs.classic_control import pendulum

from minitaur_env.training import Experiment, ExperimentConfig
from minitaur_env.training.seeds import (
    FALLS_SEED,
    REPORT_SEED,
    SELECTION_SEED,
    SeedPlan,
    judging_block,
)

JUDGING = [
    judging_block(SELECTION_SEED, 1000),
    judging_block(REPORT_SEED, 1000),
    judging_block(FALLS_SEED, 1000),
]


def overlapping(blocks: list[range]) -> list[tuple[range, range]]:
    return [(a, b) for a, b in itertools.combinations(blocks, 2) if set(a) & set(b)]


def test_no_two_purposes_share_a_seed_after_resumes_at_any_step():
    rng = random.Random(0)
    run_seeds = [0, 1, SELECTION_SEED, REPORT_SEED, 2**32 - 1, *rng.sample(range(2**32), 5)]
    for run_seed, n_envs in itertools.product(run_seeds, (1, 8)):
        plan = SeedPlan(run_seed, n_envs)
        starts = [0, 1, 8, 5000, 10_000, 12_345, *rng.sample(range(10**9), 20)]
        blocks = [plan.video(), *JUDGING]
        for started_at in starts:
            blocks += [plan.training(started_at), plan.evaluation(started_at)]
        assert not overlapping(blocks), (run_seed, n_envs)
    # and two runs of different seeds share none either
    assert not overlapping([SeedPlan(0, 8).training(0), SeedPlan(1, 8).training(0)])


def test_the_old_seeding_is_what_the_plan_prevents():
    # negative control: seed + steps for a resumed session, seed + 10000 for evaluation
    def old(run_seed: int, started_at: int, n_envs: int) -> list[range]:
        return [
            range(run_seed + started_at, run_seed + started_at + n_envs),
            range(run_seed + 10_000, run_seed + 10_001),
        ]

    assert overlapping([*old(0, 10_000, 1), *old(0, 0, 1)])  # trains on its eval episodes
    assert overlapping([*old(0, 5000, 8), *JUDGING])  # and on the selection seeds


def test_judging_blocks_stay_below_the_runs_seeds():
    assert judging_block(REPORT_SEED, 20) == range(12345, 12365)
    with pytest.raises(ValueError, match=r"must lie in 0\.\.4294967295"):
        judging_block(2**32 - 5, 20)
    with pytest.raises(ValueError, match=r"outside 0\.\.2\*\*32-1"):
        SeedPlan(-1)


def test_a_run_and_its_resume_reset_on_the_plans_seeds(tmp_path, monkeypatch):
    seen: list[int] = []
    reset = pendulum.PendulumEnv.reset

    def recording_reset(self, *, seed=None, options=None):
        if seed is not None:
            seen.append(seed)
        return reset(self, seed=seed, options=options)

    monkeypatch.setattr(pendulum.PendulumEnv, "reset", recording_reset)
    config = ExperimentConfig.resolve(
        "sac",
        "Pendulum-v1",
        seed=3,
        n_timesteps=200,
        eval_freq=100,
        eval_episodes=1,
        save_freq=100,
        vec_env="dummy",
        device="cpu",
        hyperparams={"learning_starts": 50, "batch_size": 16, "policy_kwargs": {"net_arch": [8]}},
    )
    plan = SeedPlan(3)
    result = Experiment.create(config, tmp_path, verbose=0, progress="none").run()
    # SB3 would have seeded the training env with the model's seed 3
    assert seen == [plan.training(0)[0], plan.evaluation(0)[0]]
    seen.clear()
    Experiment.resume(result.run.path, n_timesteps=300, verbose=0, progress="none").run()
    assert seen == [plan.training(200)[0], plan.evaluation(200)[0]]
