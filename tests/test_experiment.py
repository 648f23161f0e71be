"""The training API in process: Experiment, ExperimentConfig, RunFolder, checked checkpoints."""

from __future__ import annotations

import copy
import re

import gymnasium as gym
import numpy as np
import pytest
import torch
import yaml
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback

from minitaur_env.settings import Uniform
from minitaur_env.training import (
    Experiment,
    ExperimentConfig,
    RunFolder,
    TrainingDiverged,
    UsageError,
)
from minitaur_env.training import experiment as experiment_module
from minitaur_env.training.aggregate import wall_clock_at
from minitaur_env.training.algorithms import algorithm_class, load_model
from minitaur_env.training.checkpoints import save_checked_checkpoint
from minitaur_env.training.envs import RewardPerTime
from minitaur_env.training.files import load_pickle
from minitaur_env.training.hyperparams import load_hyperparams
from minitaur_env.training.policies import GainActor
from minitaur_env.training.replay_buffer import load_replay_buffer
from tests.scripts import REPO, needs

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

SMALL_SAC = {
    "learning_starts": 20,
    "buffer_size": 2000,
    "batch_size": 16,
    "train_freq": 1,
    "gradient_steps": 1,
    "policy_kwargs": {"net_arch": [16]},
}


class RaisesValueErrorAt(gym.Wrapper):
    """Pendulum whose step raises a ValueError with ``message`` at step 25 (a bug, not a NaN)."""

    def __init__(self, message: str = "bad information in the info dict") -> None:
        super().__init__(gym.make("Pendulum-v1"))
        self.message, self.steps = message, 0

    def step(self, action):
        self.steps += 1
        if self.steps == 25:
            raise ValueError(self.message)
        return super().step(action)


class NanObservationAt(gym.Wrapper):
    def __init__(self) -> None:
        super().__init__(gym.make("Pendulum-v1"))
        self.steps = 0

    def step(self, action):
        obs, *rest = super().step(action)
        self.steps += 1
        return (obs * np.nan if self.steps == 25 else obs), *rest


for _name, _cls in (("RaisesValueError-v0", RaisesValueErrorAt), ("NanObs-v0", NanObservationAt)):
    if _name not in gym.registry:
        gym.register(_name, entry_point=_cls, max_episode_steps=200)
if "ShortPendulum-v0" not in gym.registry:
    gym.register(
        "ShortPendulum-v0",
        entry_point="gymnasium.envs.classic_control:PendulumEnv",
        max_episode_steps=25,
    )


def pendulum(tmp_path, callbacks=(), **settings) -> Experiment:
    config = ExperimentConfig.resolve(
        "sac",
        settings.pop("env", "Pendulum-v1"),
        hyperparams={**SMALL_SAC, **settings.pop("hyperparams", {})},
        n_timesteps=settings.pop("n_timesteps", 200),
        eval_freq=settings.pop("eval_freq", 0),
        save_freq=settings.pop("save_freq", 50),
        vec_env="dummy",
        device="cpu",
        **settings,
    )
    return Experiment.create(config, tmp_path / "logs", verbose=0, callbacks=callbacks)


def test_a_run_from_python_writes_its_folder(tmp_path):
    result = pendulum(tmp_path, eval_freq=100, eval_episodes=2).run()
    run = result.run
    assert result.status == "completed" and result.exit_code == 0
    assert result.num_timesteps == 200 and run.path.name == "Pendulum-v1_1"
    assert ExperimentConfig.from_dict(run.read_config()).hyperparams["batch_size"] == 16
    assert [steps for steps, _ in run.checkpoints()] == [200, 150, 100, 50]
    assert [steps for steps, _ in run.replay_buffers()] == [200, 150]  # two newest kept
    assert load_model(SAC, run.final_model).num_timesteps == 200
    assert run.best_model.is_file() and run.learning_curve.is_file()
    assert result.last_eval[0] == 200 and "last eval" in result.summary()


def test_resume_extends_a_run_to_n_steps_and_keeps_its_checkpoints_aligned(tmp_path):
    first = pendulum(tmp_path, n_timesteps=120, save_freq=50, n_envs=3).run()
    # The first step past each multiple of save_freq, and the last step.
    assert [s for s, _ in first.run.checkpoints()] == [120, 102, 51]
    resumed = Experiment.resume(first.run.path, n_timesteps=260, verbose=0)
    result = resumed.run()
    assert result.status == "completed" and resumed.resumed_at == 120
    assert result.num_timesteps >= 260 and result.trained_steps == result.num_timesteps - 120
    assert first.run.read_config()["n_timesteps"] == 260
    # Checkpoints keep landing on the first step past each multiple of save_freq.
    assert [s for s, _ in first.run.checkpoints()] == [261, 252, 201, 150, 120, 102, 51]
    assert first.run.progress(120).is_file()


def test_resume_forgets_what_the_killed_session_logged_after_its_checkpoint(tmp_path):
    # A kill after step 260 whose newest readable checkpoint is 220: the episodes and
    # evaluations of steps 221-260 belong to a branch the resume does not continue.
    run = (
        pendulum(
            tmp_path,
            env="ShortPendulum-v0",
            n_timesteps=260,
            save_freq=110,
            eval_freq=50,
            eval_episodes=1,
        )
        .run()
        .run
    )
    run.checkpoint(260).unlink()
    result = Experiment.resume(run.path, n_timesteps=340, verbose=0).run()
    assert result.status == "completed"
    with np.load(run.evaluations) as data:
        # On multiples of eval_freq after the resume too (not at 270, 320).
        assert data["timesteps"].tolist() == [50, 100, 150, 200, 250, 300]
    monitor = next(run.monitor_dir.glob("*.monitor.csv")).read_text().splitlines()[2:]
    # 8 episodes of 25 steps before the checkpoint, 4 after: 350 if the lost ones were kept.
    assert sum(int(line.split(",")[1]) for line in monitor) == 300


def test_wall_clock_continues_across_resumed_sessions(tmp_path):
    run = RunFolder(tmp_path)
    run.monitor_dir.mkdir()
    episodes = [(10.0, 100), (20.0, 100), (5.0, 100), (10.0, 100)]  # clock restarts at 5.0
    (run.monitor_dir / "0.monitor.csv").write_text(
        '#{"t_start": 0}\nr,l,t\n' + "".join(f"0,{n},{t}\n" for t, n in episodes)
    )
    seconds = wall_clock_at(run, np.array([100, 200, 300, 400]))
    assert seconds.tolist() == [10.0, 20.0, 25.0, 30.0]


def test_the_final_steps_after_the_last_logged_episode_have_a_wall_clock(tmp_path):
    # Training ends inside an episode that no monitor logs: the final model (here at step
    # 450, 50 steps past the last logged episode) got a NaN wall-clock, and the shipped
    # SAC's provenance said wall_clock_min_to_model: .nan.
    run = RunFolder(tmp_path)
    run.monitor_dir.mkdir()
    episodes = [(10.0, 100), (20.0, 100), (30.0, 100), (40.0, 100)]  # 1 s per 10 steps
    (run.monitor_dir / "0.monitor.csv").write_text(
        '#{"t_start": 0}\nr,l,t\n' + "".join(f"0,{n},{t}\n" for t, n in episodes)
    )
    at_final, beyond = wall_clock_at(run, np.array([450, 600]))
    assert at_final == pytest.approx(45.0)
    # More than one episode past the logs is not the unlogged end of this run: unknown.
    assert np.isnan(beyond)


def test_resume_refuses_settings_that_contradict_the_run(tmp_path):
    run = pendulum(tmp_path, n_timesteps=60).run().run
    with pytest.raises(UsageError, match="seed 3 contradicts the run's saved seed 0"):
        Experiment.resume(run.path, overrides={"seed": 3})
    with pytest.raises(UsageError, match=r"hyperparams\.batch_size 64 contradicts"):
        Experiment.resume(run.path, overrides={"hyperparams.batch_size": 64})
    Experiment.resume(run.path, overrides={"seed": 0, "hyperparams.batch_size": 16})  # agrees


def test_a_checkpoint_is_never_written_from_diverged_weights(tmp_path):
    experiment = pendulum(tmp_path, n_timesteps=60)
    experiment.run()
    model, run = load_model(SAC, experiment.run_folder.final_model), experiment.run_folder
    model.num_timesteps = 999
    assert save_checked_checkpoint(model, run) == run.checkpoint(999)  # negative control
    with torch.no_grad():
        next(model.policy.parameters())[0] = float("nan")
    model.num_timesteps = 1000
    with pytest.raises(TrainingDiverged, match="became non-finite at step 1000"):
        save_checked_checkpoint(model, run)
    assert not run.checkpoint(1000).exists()


class InterruptAt(BaseCallback):
    """Ctrl-C at a given step, optionally after poisoning a weight."""

    def __init__(self, step: int, poison: bool) -> None:
        super().__init__()
        self.step, self.poison = step, poison

    def _on_step(self) -> bool:
        if self.num_timesteps == self.step:
            if self.poison:
                with torch.no_grad():
                    next(self.model.policy.parameters())[0] = float("nan")
            raise KeyboardInterrupt
        return True


@pytest.mark.parametrize("poison", [False, True], ids=["healthy", "diverged"])
def test_the_ctrl_c_checkpoint_is_checked_too(tmp_path, poison):
    config = pendulum(tmp_path).config
    run = Experiment.create(
        config, tmp_path / "other", verbose=0, callbacks=[InterruptAt(77, poison)]
    ).run()
    if poison:
        assert run.status == "diverged" and run.exit_code == 1 and run.checkpoint is None
        assert "last good checkpoint" in run.message
        assert not run.run.checkpoint(77).exists()
    else:
        assert run.status == "interrupted" and run.exit_code == 130
        assert run.checkpoint == run.run.checkpoint(77) and run.checkpoint.is_file()
        assert run.run.replay_buffer(77).is_file()


def test_divergence_is_told_by_type_not_by_words_in_the_message(tmp_path):
    # The old check matched r"\b(nan|inf)" in any ValueError: "information" read as divergence.
    failed = pendulum(tmp_path, env="RaisesValueError-v0").run()
    assert failed.status == "failed" and "ValueError: bad information" in failed.message
    result = pendulum(tmp_path, env="NanObs-v0").run()
    assert result.status == "diverged" and "found nan in observations" in result.message


def test_resume_skips_torn_checkpoints_without_building_envs_for_them(tmp_path, monkeypatch):
    run = pendulum(tmp_path, n_timesteps=150, save_freq=50).run().run
    run.checkpoint(150).write_bytes(b"torn")
    built = []
    original = experiment_module.make_training_env
    monkeypatch.setattr(
        experiment_module,
        "make_training_env",
        lambda *args, **kwargs: built.append(1) or original(*args, **kwargs),
    )
    resumed = Experiment.resume(run.path, n_timesteps=160, verbose=0, log=lambda *a, **k: None)
    result = resumed.run()
    assert resumed.resumed_at == 100 and result.num_timesteps == 160
    assert len(built) == 1


def test_resume_never_goes_on_with_an_empty_replay_buffer(tmp_path):
    run = pendulum(tmp_path, n_timesteps=150, save_freq=50).run().run
    run.replay_buffer(150).unlink()  # a kill between the model and its buffer
    said = []
    resumed = Experiment.resume(run.path, n_timesteps=160, log=lambda *a, **k: said.append(a[0]))
    resumed.run()
    assert resumed.resumed_at == 100  # the newest checkpoint that has its buffer
    assert resumed.model.replay_buffer.size() > 0
    assert any("rl_model_150_steps.zip: its replay buffer is missing" in line for line in said)
    # with no complete checkpoint left, one line, not an empty buffer
    for _, buffer in run.replay_buffers():
        buffer.unlink()
    with pytest.raises(UsageError, match=r"no complete checkpoint .*replay buffer"):
        Experiment.resume(run.path, n_timesteps=170, log=lambda *a, **k: None).build()


def test_config_resolves_entries_and_rejects_bad_values():
    tuned = ExperimentConfig.resolve("sac", "MinitaurBulletEnv-v0")
    assert tuned.hyperparams["n_steps"] == 10 and tuned.normalize is True
    tutorial = ExperimentConfig.resolve("sac", "MinitaurBulletEnv-v0", entry="tutorial")
    assert tutorial.n_timesteps == 100_000 and tutorial.hyperparams["buffer_size"] == 10_000
    assert ExperimentConfig.from_dict({**tuned.to_dict(), "overlap_updates": False}) == tuned
    with pytest.raises(UsageError, match="--eval-freq must be >= 0"):
        ExperimentConfig.resolve("sac", "Pendulum-v1", eval_freq=-1)
    with pytest.raises(UsageError, match="unknown env id"):
        ExperimentConfig.resolve("sac", "NoSuchEnv-v3")


def test_run_folder_names_every_file_in_one_place(tmp_path):
    run = RunFolder.create(tmp_path, "sac", "minitaur_env:MinitaurBulletEnv-v0")
    assert run.path == tmp_path / "sac" / "MinitaurBulletEnv-v0_1" and run.number == 1
    assert run.checkpoint(5).name == "rl_model_5_steps.zip"
    assert run.replay_buffer(5).name == "rl_model_replay_buffer_5_steps.npz"
    assert run.vecnormalize(5).name == "rl_model_vecnormalize_5_steps.pkl"
    assert run.vecnormalize_beside(run.best_model).name == "best_model_vecnormalize.pkl"
    assert RunFolder.create(tmp_path, "sac", "MinitaurBulletEnv-v0").number == 2
    config = ExperimentConfig.resolve(
        "sac", "MinitaurBulletEnv-v0", seed=3, env_kwargs={"max_episode_steps": 40}
    ).to_dict()
    run.write_config(config)
    assert yaml.safe_load(run.config.read_text()) == config
    # The same settings where rl-baselines3-zoo looks for them, beside <env>.zip.
    assert run.final_model == run.path / "MinitaurBulletEnv-v0.zip"
    zoo = yaml.safe_load((run.zoo_dir / "config.yml").read_text())
    assert zoo["normalize"] is True and zoo["n_steps"] == 10 and zoo["policy"] == "MlpPolicy"
    zoo_args = yaml.safe_load((run.zoo_dir / "args.yml").read_text())
    # The entry's own env kwargs (the default sees three observations) and the run's.
    assert zoo_args["seed"] == 3
    assert zoo_args["env_kwargs"] == {"history": 3, "max_episode_steps": 40}
    with pytest.raises(UsageError, match=r"no config\.yml"):
        RunFolder.existing(tmp_path / "sac" / "MinitaurBulletEnv-v0_2")


def _policy_weights(model) -> np.ndarray:
    if hasattr(model.policy, "actor_state"):  # SBX
        import jax

        leaves = jax.tree_util.tree_leaves(model.policy.actor_state.params)
        return np.concatenate([np.ravel(leaf) for leaf in leaves])
    return torch.cat([p.detach().ravel() for p in model.policy.parameters()]).numpy()


@pytest.mark.parametrize(("algo", "backend"), [("sac", "sb3"), ("sac", "sbx"), ("tqc", "sbx")])
def test_the_seed_decides_the_run_on_every_backend(tmp_path, algo, backend):
    if backend == "sbx":
        needs("sbx")

    def trained(seed):
        config = ExperimentConfig.resolve(
            algo,
            "Pendulum-v1",
            hyperparams=SMALL_SAC,
            n_timesteps=120,
            backend=backend,
            seed=seed,
            eval_freq=0,
            save_freq=0,
            vec_env="dummy",
            device="cpu",
        )
        experiment = Experiment.create(config, tmp_path, verbose=0)
        experiment.run()
        return _policy_weights(experiment.model), experiment.model.replay_buffer.actions[:100]

    before = copy.deepcopy(SMALL_SAC)
    first, again, other = trained(0), trained(0), trained(1)
    assert before == SMALL_SAC  # the algorithm did not write into the caller's settings
    np.testing.assert_array_equal(first[1], again[1])  # the same exploration
    np.testing.assert_allclose(first[0], again[0], rtol=0, atol=1e-6)  # and updates
    assert not np.allclose(first[1], other[1]) and not np.allclose(first[0], other[0])


def test_sbx_weights_are_checked_too():
    sbx = needs("sbx")
    from minitaur_env.training.checkpoints import check_weights, weights_finite

    model = sbx.SAC("MlpPolicy", "Pendulum-v1", policy_kwargs={"net_arch": [8]}, seed=0)
    assert weights_finite(model)
    state = model.policy.actor_state
    params = __import__("jax").tree_util.tree_map(lambda leaf: leaf * np.nan, state.params)
    model.policy.actor_state = state.replace(params=params)
    assert not weights_finite(model)
    with pytest.raises(TrainingDiverged, match="actor_state"):
        check_weights(model)


def test_a_trained_agent_starts_a_new_run_with_its_weights_statistics_and_buffer(tmp_path):
    first = pendulum(tmp_path, hyperparams={"normalize": True}).run().run
    trained = load_model(SAC, first.zoo_model)
    load_replay_buffer(trained.replay_buffer, first.replay_buffer(200))
    stored = trained.replay_buffer.size()
    trained.save_replay_buffer(first.zoo_model.with_name("replay_buffer.pkl"))  # the zoo's

    def started(**settings) -> Experiment:
        experiment = pendulum(tmp_path, hyperparams={"normalize": True}, seed=5, **settings)
        experiment.build()
        experiment.close()
        return experiment

    fine_tuned, fresh = started(trained_agent=str(first.zoo_model), trust_pickle=True), started()
    without_buffer = started(trained_agent=str(first.zoo_model))  # the buffer is a pickle
    weights = _policy_weights(trained)
    np.testing.assert_array_equal(_policy_weights(fine_tuned.model), weights)
    assert not np.allclose(_policy_weights(fresh.model), weights)  # control: a fresh start
    saved = load_pickle(first.zoo_vecnormalize)
    np.testing.assert_array_equal(fine_tuned.env.obs_rms.mean, saved.obs_rms.mean)
    assert fresh.env.obs_rms.count < 1  # a fresh run's statistics are empty
    assert stored > 100 and fine_tuned.model.replay_buffer.size() == stored
    assert fresh.model.replay_buffer.size() == 0
    # Without --trust-pickle: the same weights and statistics (from the JSON), no buffer.
    np.testing.assert_array_equal(_policy_weights(without_buffer.model), weights)
    np.testing.assert_array_equal(without_buffer.env.obs_rms.mean, saved.obs_rms.mean)
    assert without_buffer.env.obs_rms.count == saved.obs_rms.count
    assert without_buffer.model.replay_buffer.size() == 0
    # It trains on, counting its own steps, into its own folder.
    result = pendulum(
        tmp_path, hyperparams={"normalize": True}, trained_agent=str(first.zoo_model)
    ).run()
    assert result.status == "completed" and result.trained_steps == result.num_timesteps == 200
    assert result.run.path != first.path
    assert result.run.read_config()["trained_agent"] == str(first.zoo_model)


def test_a_trained_agent_that_does_not_fit_is_one_line(tmp_path):
    run = pendulum(tmp_path).run().run  # raw observations
    with pytest.raises(UsageError, match="no model file at"):
        pendulum(tmp_path, trained_agent=str(tmp_path / "missing.zip"))
    with pytest.raises(UsageError, match=r"trained without VecNormalize.*normalize=false"):
        pendulum(tmp_path, hyperparams={"normalize": True}, trained_agent=str(run.zoo_model)).run()
    with pytest.raises(UsageError, match=r"is a sb3 sac model .* pass --algo sac --backend sb3"):
        ExperimentConfig.resolve(
            "td3",
            "Pendulum-v1",
            n_timesteps=50,
            trained_agent=str(run.zoo_model),
            eval_freq=0,
            save_freq=0,
            vec_env="dummy",
            device="cpu",
        )
    with pytest.raises(UsageError, match=r"does not fit MountainCarContinuous-v0: .*space"):
        pendulum(tmp_path, env="MountainCarContinuous-v0", trained_agent=str(run.zoo_model)).run()


class RecordsSchedules(BaseCallback):
    """The actor's learning rate and the entropy target at every env step, and a Ctrl-C at
    ``interrupt_at``."""

    def __init__(self, interrupt_at: int | None = None) -> None:
        super().__init__()
        self.interrupt_at = interrupt_at
        self.rates: dict[int, float] = {}
        self.targets: dict[int, float] = {}

    def _on_step(self) -> bool:
        self.rates[self.num_timesteps] = self.model.actor.optimizer.param_groups[0]["lr"]
        self.targets[self.num_timesteps] = self.model.target_entropy
        if self.num_timesteps == self.interrupt_at:
            raise KeyboardInterrupt
        return True


def test_resume_continues_a_decaying_learning_rate_instead_of_restarting_it(tmp_path):
    decaying = {"hyperparams": {"learning_rate": "lin_1e-3"}, "n_timesteps": 200}
    whole = RecordsSchedules()
    pendulum(tmp_path / "whole", **decaying, callbacks=[whole]).run()

    first = RecordsSchedules(interrupt_at=100)
    interrupted = pendulum(tmp_path / "cut", **decaying, callbacks=[first]).run()
    assert interrupted.status == "interrupted" and interrupted.num_timesteps == 100
    second = RecordsSchedules()
    Experiment.resume(interrupted.run.path, verbose=0, callbacks=[second]).run()
    after = sorted(s for s in second.rates if s > 101)  # the first step's lr is set by train()
    assert after and after[-1] == 200
    np.testing.assert_allclose([second.rates[s] for s in after], [whole.rates[s] for s in after])
    assert second.rates[after[0]] < 0.5e-3  # a restarted schedule would be back near 1e-3

    # -n extends the schedule to the new length: at step s of 300, 1e-3 * (1 - s / 300).
    extended = RecordsSchedules()
    Experiment.resume(interrupted.run.path, n_timesteps=300, verbose=0, callbacks=[extended]).run()
    steps = sorted(s for s in extended.rates if s > 201)
    expected = [1e-3 * (1 - (s - 1) / 300) for s in steps]  # set after step s - 1
    np.testing.assert_allclose([extended.rates[s] for s in steps], expected, rtol=1e-6)


def test_a_decaying_entropy_target_steers_alpha_and_continues_after_a_resume(tmp_path):
    # Rising to +50 (not falling) makes the effect visible past Adam's sign-like steps:
    # a target above the policy's entropy pushes alpha up, the control's 0 pushes it down.
    decay = {"target_entropy": 0, "target_entropy_decay": {"final": 50, "start": 0.5}}
    whole = RecordsSchedules()
    decayed = pendulum(tmp_path / "whole", hyperparams=decay, callbacks=[whole]).run()
    assert [whole.targets[s] for s in (1, 100, 150, 200)] == [0, 0, 25, 50]
    control = pendulum(tmp_path / "control", hyperparams={"target_entropy": 0}).run()

    def alpha(result) -> float:
        return float(load_model(SAC, result.run.final_model).log_ent_coef.exp())

    assert alpha(decayed) > alpha(control)

    first = RecordsSchedules(interrupt_at=120)
    interrupted = pendulum(tmp_path / "cut", hyperparams=decay, callbacks=[first]).run()
    second = RecordsSchedules()
    Experiment.resume(interrupted.run.path, verbose=0, callbacks=[second]).run()
    assert min(second.targets) == 121
    assert second.targets == {s: whole.targets[s] for s in range(121, 201)}

    # -n stretches the decay to the new length, from 150 (0.5 of 300) to 50 at 300; the
    # 200-step decay would already be at 50 by step 225.
    extended = RecordsSchedules()
    Experiment.resume(interrupted.run.path, n_timesteps=300, verbose=0, callbacks=[extended]).run()
    assert min(extended.targets) == 201  # from the finished run's 200-step checkpoint
    assert [extended.targets[s] for s in (225, 300)] == [25, 50]


@pytest.mark.parametrize("algo", ["sac", "tqc"])
def test_a_decaying_entropy_target_steers_alpha_on_sbx_too(tmp_path, algo):
    # SBX compiles its update: the target must reach it as a value, not be frozen at the
    # first call. A rising target pushes alpha up where the constant control lets it fall.
    needs("sbx")
    decay = {"target_entropy": 0, "target_entropy_decay": {"final": 50, "start": 0.5}}

    def alpha(name: str, hyperparams: dict) -> float:
        config = ExperimentConfig.resolve(
            algo,
            "Pendulum-v1",
            hyperparams={**SMALL_SAC, **hyperparams},
            n_timesteps=200,
            backend="sbx",
            eval_freq=0,
            save_freq=0,
            vec_env="dummy",
            device="cpu",
        )
        experiment = Experiment.create(config, tmp_path / name, verbose=0)
        experiment.run()
        assert experiment.model.target_entropy == hyperparams.get("target_entropy_decay", {}).get(
            "final", 0
        )
        params = experiment.model.ent_coef_state.params
        return float(np.exp(np.asarray(params["log_ent_coef"])))

    assert alpha("decayed", decay) > alpha("control", {"target_entropy": 0})


class RecordsPushScale(BaseCallback):
    """The training envs' push scale at every env step, and a Ctrl-C at ``interrupt_at``."""

    def __init__(self, interrupt_at: int | None = None) -> None:
        super().__init__()
        self.interrupt_at = interrupt_at
        self.scales: dict[int, float] = {}

    def _on_step(self) -> bool:
        (scale,) = set(self.training_env.get_attr("push_scale"))
        self.scales[self.num_timesteps] = scale
        if self.num_timesteps == self.interrupt_at:
            raise KeyboardInterrupt
        return True


def test_a_push_curriculum_grows_the_training_pushes_only_and_continues_after_a_resume(
    tmp_path,
):
    def pushed(name: str, callback: BaseCallback, **settings) -> Experiment:
        return pendulum(
            tmp_path / name,
            env="MinitaurBulletEnv-v0",
            n_envs=2,
            eval_freq=100,
            eval_episodes=1,
            env_kwargs={"realism": {"pushes": True}, "max_episode_steps": 30},
            hyperparams={"push_curriculum": {"start": 0.2, "full_at": 0.5}},
            callbacks=[callback],
            **settings,
        )

    whole = RecordsPushScale()
    experiment = pushed("whole", whole)
    experiment.run()
    expected = {s: min(0.2 + 0.8 * s / 100, 1.0) for s in whole.scales}  # full at 100 of 200
    assert whole.scales[2] == pytest.approx(0.2, abs=0.02)
    for step, scale in whole.scales.items():  # set when it has moved by a hundredth
        assert scale == pytest.approx(expected[step], abs=0.02)
    assert all(whole.scales[s] == 1.0 for s in whole.scales if s >= 102)
    assert experiment.eval_env.get_attr("push_scale") == [1.0]  # evaluations: full force

    control = RecordsPushScale()
    pendulum(
        tmp_path / "control",
        env="MinitaurBulletEnv-v0",
        env_kwargs={"realism": {"pushes": True}, "max_episode_steps": 30},
        callbacks=[control],
    ).run()
    assert set(control.scales.values()) == {1.0}

    first = RecordsPushScale(interrupt_at=60)
    interrupted = pushed("cut", first).run()
    assert interrupted.status == "interrupted"
    second = RecordsPushScale()
    Experiment.resume(interrupted.run.path, verbose=0, callbacks=[second]).run()
    resumed_at = min(second.scales)
    assert resumed_at > 50  # from the 50-step checkpoint, not from step 0 and scale 0.2
    assert second.scales[resumed_at] == pytest.approx(expected[resumed_at], abs=0.02)


class RecordsControlSteps(BaseCallback):
    """Each training env's control step at every env step, and a Ctrl-C at ``interrupt_at``."""

    def __init__(self, interrupt_at: int | None = None) -> None:
        super().__init__()
        self.interrupt_at = interrupt_at
        self.steps: list[list[float]] = []

    def _on_step(self) -> bool:
        self.steps.append([float(dt) for dt in self.training_env.get_attr("dt")])
        if self.num_timesteps == self.interrupt_at:
            raise KeyboardInterrupt
        return True


def test_hard_draws_narrow_the_first_training_envs_only_and_again_after_a_resume(tmp_path):
    def trained(name: str, callback: BaseCallback, hard: bool = True) -> Experiment:
        draws = {"envs": 1, "realism": {"control_time_step": [0.016, 0.02]}}
        return pendulum(
            tmp_path / name,
            env="MinitaurBulletRandomized-v0",
            n_envs=2,
            n_timesteps=240,
            env_kwargs={"max_episode_steps": 10},  # many resets: many draws
            hyperparams={"hard_draws": draws} if hard else {},
            callbacks=[callback],
        )

    seen = RecordsControlSteps()
    experiment = trained("hard", seen)
    experiment.run()
    narrowed = [steps[0] for steps in seen.steps[20:]]  # past the first (unnarrowed) episode
    own = [steps[1] for steps in seen.steps]
    assert min(narrowed) >= 0.016 - 1e-9
    assert min(own) < 0.016  # the second training env keeps the preset's 3-20 ms
    eval_realism = experiment.eval_env.get_attr("realism")[0]
    assert eval_realism.control_time_step == Uniform(0.003, 0.02)  # evaluations: the env's own
    control = RecordsControlSteps()
    trained("control", control, hard=False).run()
    assert (
        min(steps[0] for steps in control.steps) < 0.016
    )  # without the key, env 0 is not narrowed

    first = RecordsControlSteps(interrupt_at=120)
    interrupted = trained("cut", first).run()
    assert interrupted.status == "interrupted"
    second = RecordsControlSteps()
    Experiment.resume(interrupted.run.path, verbose=0, callbacks=[second]).run()
    assert min(steps[0] for steps in second.steps[20:]) >= 0.016 - 1e-9


def test_hard_draws_groups_narrow_their_own_envs(tmp_path):
    # Two groups on consecutive envs, each inside the env's own ranges (the second's is
    # not inside the first's: each narrows the env's own), the last env on the preset.
    groups = [
        {"envs": 1, "realism": {"control_time_step": [0.016, 0.02]}},
        {"envs": 1, "realism": {"control_time_step": [0.008, 0.012]}},
    ]
    seen = RecordsControlSteps()
    pendulum(
        tmp_path / "groups",
        env="MinitaurBulletRandomized-v0",
        n_envs=3,
        n_timesteps=300,
        env_kwargs={"max_episode_steps": 10},
        hyperparams={"hard_draws": groups},
        callbacks=[seen],
    ).run()
    later = seen.steps[20:]  # past each env's first (unnarrowed) episode
    assert min(steps[0] for steps in later) >= 0.016 - 1e-9
    assert all(0.008 - 1e-9 <= steps[1] <= 0.012 + 1e-9 for steps in later)
    own = [steps[2] for steps in seen.steps]
    assert min(own) < 0.008 and max(own) > 0.012  # the third env keeps the preset's 3-20 ms


@pytest.mark.parametrize(
    ("draws", "message"),
    [
        ({"envs": 1}, "hard_draws: expected {envs: <how many training envs>"),
        (
            {"envs": 2, "realism": {"control_latency": [0.02, 0.04]}},
            "hard_draws narrows 2 training envs; at most 1 (n_envs is 2",
        ),
        (
            [{"envs": 1, "realism": {"control_latency": [0.02, 0.04]}}, {"envs": 1}],
            "hard_draws[1]: expected {envs: <how many training envs>",
        ),
        (
            [
                {"envs": 1, "realism": {"control_latency": [0.02, 0.04]}},
                {"envs": 1, "realism": {"control_latency": [0.0, 0.01]}},
            ],
            "hard_draws narrows 2 training envs; at most 1",
        ),
        ({"envs": 0, "realism": {"control_latency": [0.02, 0.04]}}, "hard_draws.envs must be"),
        (
            {"envs": 1, "realism": {"control_latency": [0.02, 0.06]}},
            "is not inside the env's own (0.0, 0.04)",
        ),
        ({"envs": 1, "realism": {"pushes": True}}, "takes a mapping of drawn realism fields"),
    ],
)
def test_hard_draws_that_cannot_be_drawn_are_one_line(draws, message):
    with pytest.raises(UsageError, match=re.escape(message)):
        ExperimentConfig.resolve(
            "ppo", "MinitaurBulletRandomized-v0", n_envs=2, hyperparams={"hard_draws": draws}
        )


@pytest.mark.parametrize(
    ("hyperparams", "env_kwargs", "message"),
    [
        ({"start": 0.2, "full_at": 0.5}, {}, "the env has no pushes to scale; add --env-kwargs"),
        (
            {"start": 0.2},
            {"realism": {"pushes": True}},
            "expected {start: <fraction of the force>, full_at",
        ),
        (
            {"start": 2, "full_at": 0.5},
            {"realism": {"pushes": True}},
            "start must be a number in [0, 1], got 2",
        ),
        (
            {"start": 0, "full_at": 0},
            {"realism": {"pushes": True}},
            "full_at must be a number in (0, 1], got 0",
        ),
    ],
)
def test_a_push_curriculum_that_would_do_nothing_is_refused(hyperparams, env_kwargs, message):
    with pytest.raises(UsageError, match=re.escape(message)):
        ExperimentConfig.resolve(
            "sac",
            "MinitaurBulletEnv-v0",
            hyperparams={"push_curriculum": hyperparams},
            env_kwargs=env_kwargs,
        )


@pytest.mark.parametrize(
    "env_kwargs",
    [{"realism": {"pushes": True}}, {"pushes": True}, {"realism": {"pushes": {"force": [9, 9]}}}],
)
def test_a_push_curriculum_finds_the_pushes_in_realism_or_the_old_keyword(env_kwargs):
    curriculum = {"push_curriculum": {"start": 0.0, "full_at": 0.5}}
    config = ExperimentConfig.resolve(
        "sac", "MinitaurBulletEnv-v0", hyperparams=curriculum, env_kwargs=env_kwargs
    )
    assert config.env_pushes not in (None, False)
    with pytest.raises(UsageError, match="no pushes to scale"):  # control: pushes off
        ExperimentConfig.resolve(
            "sac",
            "MinitaurBulletEnv-v0",
            hyperparams=curriculum,
            env_kwargs={"realism": {"pushes": False}},
        )


@pytest.mark.parametrize(("time_step", "factor"), [(None, 1.0), (0.1, 2.0), (0.025, 0.5)])
def test_reward_time_step_scales_what_the_learner_is_paid_and_not_the_monitor(
    tmp_path, time_step, factor
):
    # Pendulum's dt is 0.05 s: a 0.1 s time step pays the learner twice the env's reward.
    hyperparams = {} if time_step is None else {"reward_time_step": time_step}
    experiment = pendulum(tmp_path, hyperparams=hyperparams)
    experiment.run()
    learned = experiment.model.replay_buffer.rewards[:200, 0]
    monitor = experiment.run_folder.monitor_dir / "0.monitor.csv"
    logged = float(monitor.read_text().splitlines()[2].split(",")[0])
    assert logged < -1  # the control's sum is not trivially 0
    assert learned.sum() == pytest.approx(factor * logged, rel=1e-4)
    assert experiment.eval_env.env_is_wrapped(RewardPerTime) == [False]

    resumed = Experiment.resume(experiment.run_folder.path, n_timesteps=250, verbose=0)
    resumed.build()
    assert resumed.env.env_is_wrapped(RewardPerTime) == [time_step is not None]
    resumed.close()


def test_reward_per_time_follows_each_episodes_drawn_control_step():
    env_id = "MinitaurBulletTrotRandomized-v0"
    plain, scaled = gym.make(env_id), RewardPerTime(gym.make(env_id), time_step=0.01)
    actions = np.zeros((5, *plain.action_space.shape), dtype=np.float32)
    steps_seen, largest = set(), 0.0
    try:
        for seed in range(4):
            plain.reset(seed=seed)
            scaled.reset(seed=seed)
            dt = float(scaled.unwrapped.dt)
            steps_seen.add(round(dt, 4))
            for action in actions:
                reward = plain.step(action)[1]
                largest = max(largest, abs(reward))
                assert scaled.step(action)[1] == pytest.approx(reward * 0.01 / dt, abs=1e-9)
    finally:
        plain.close()
        scaled.close()
    assert len(steps_seen) > 1  # the draws moved the step, so the factor moved with it
    assert largest > 1e-4  # and the rewards it scaled were not all zero


def test_reward_time_step_refuses_an_env_without_a_control_step():
    message = "reward_time_step: CartPole-v1 has no control step to scale by"
    with pytest.raises(UsageError, match=re.escape(message)):
        ExperimentConfig.resolve("ppo", "CartPole-v1", hyperparams={"reward_time_step": 0.01})
    # control: the same key on an env with a dt resolves
    ExperimentConfig.resolve("ppo", "Pendulum-v1", hyperparams={"reward_time_step": 0.01})


@pytest.mark.parametrize("time_step", [0, -0.01, "10ms", True, float("inf")])
def test_a_bad_reward_time_step_is_one_line(time_step):
    message = f"reward_time_step must be a control step in seconds above 0, got {time_step!r}"
    with pytest.raises(UsageError, match=re.escape(message)):
        ExperimentConfig.resolve("ppo", "Pendulum-v1", hyperparams={"reward_time_step": time_step})


@pytest.mark.parametrize(
    ("algo", "hyperparams", "message"),
    [
        ("ppo", {}, "only for sac, tqc, crossq, not ppo"),
        ("sac", {"ent_coef": 0.1}, "needs ent_coef: auto"),
        ("sac", {"target_entropy": "auto"}, "target_entropy must be a number, got 'auto'"),
        ("sac", {"target_entropy_decay": {"final": -4, "start": 1}}, "start must be a"),
        ("sac", {"target_entropy_decay": {"to": -4}}, "expected {final: <number>, start"),
    ],
)
def test_an_entropy_decay_that_would_do_nothing_is_refused(algo, hyperparams, message):
    settings = {"target_entropy": 0, "target_entropy_decay": {"final": -4}, **hyperparams}
    with pytest.raises(UsageError, match=re.escape(message)):
        ExperimentConfig.resolve(algo, "Pendulum-v1", hyperparams=settings)


@pytest.mark.parametrize(
    ("algo", "name"),
    [
        ("sac", None),
        ("sac", "minitaur-gain"),
        ("sac", "minitaur-mirror"),
        ("sac", "minitaur-pink"),
        ("sac", "minitaur-history"),
        ("sac", "minitaur-history-nstep"),
        ("sac", "minitaur-half-updates"),
        ("tqc", None),
        ("crossq", None),
    ],
)
def test_the_minitaur_entries_build_and_train(tmp_path, algo, name):
    config = ExperimentConfig.resolve(
        algo,
        "MinitaurBulletEnv-v0",
        entry=name,
        hyperparams={"learning_starts": 32},
        n_timesteps=64,
        env_kwargs={"max_episode_steps": 40},
        eval_freq=0,
        save_freq=0,
        vec_env="dummy",
        device="cpu",
    )
    entry = load_hyperparams(algo, "MinitaurBulletEnv-v0", entry=name)
    assert entry["normalize"] is True and entry["n_timesteps"] <= 300_000
    experiment = Experiment.create(config, tmp_path, verbose=0)
    result = experiment.run()
    assert result.status == "completed" and result.num_timesteps == 64
    actor = load_model(algorithm_class(algo), result.run.final_model, device="cpu").policy.actor
    assert isinstance(actor, GainActor) == (name == "minitaur-gain")
    colored = getattr(experiment.model.policy, "noise_color", 0.0)
    assert colored == (1.0 if name == "minitaur-pink" else 0.0)
    buffer = type(experiment.model.replay_buffer).__name__
    assert (buffer == "MirroredReplayBuffer") == bool(entry.get("mirror"))
    # None: the env's own entry, minitaur-half-updates
    nstep_entries = [
        ("sac", None),
        ("sac", "minitaur-history-nstep"),
        ("sac", "minitaur-half-updates"),
    ]
    history_entries = [("sac", "minitaur-history"), *nstep_entries]
    mirror_entries = [("sac", "minitaur-mirror"), ("sac", "minitaur-pink"), *history_entries]
    assert bool(entry.get("mirror")) == ((algo, name) in mirror_entries)
    # the entry's history reaches the env, beside the env settings given here
    frames = 3 if (algo, name) in history_entries else 1
    assert experiment.model.observation_space.shape == (28 * frames,)
    assert config.env_kwargs == {"max_episode_steps": 40, **({"history": 3} if frames > 1 else {})}
    if (algo, name) in nstep_entries:
        # 10-step returns handed over to 5 at step 32, half the run
        assert entry["n_steps"] == 10 and experiment.model.replay_buffer.n_steps == 5
    # half the updates: 4 gradient steps every 8 env steps; the entry before it, 8
    half = (algo, name) in [("sac", None), ("sac", "minitaur-half-updates")]
    if algo == "sac":
        assert experiment.model.gradient_steps == (4 if half else 8) == entry["gradient_steps"]


@pytest.mark.parametrize(
    ("hyperparams", "message"),
    [
        ({"batch_size": -5}, "batch_size=-5: must be an integer >= 1"),
        ({"batch_size": 0}, "batch_size=0: must be an integer >= 1"),
        ({"gamma": 2}, "gamma=2: must be a number in (0, 1]"),
        ({"tau": 0}, "tau=0: must be a number in (0, 1]"),
        ({"buffer_size": 0}, "buffer_size=0: must be an integer >= batch_size (256)"),
        ({"buffer_size": 100, "batch_size": 256}, "must be an integer >= batch_size (256)"),
    ],
)
def test_hyperparameters_sb3_accepts_but_fails_on_later_are_refused_first(hyperparams, message):
    with pytest.raises(UsageError) as refused:
        ExperimentConfig.resolve(
            "sac", "Pendulum-v1", hyperparams={"batch_size": 256, **hyperparams}
        )
    assert str(refused.value).endswith(message)


def test_hyperparameters_in_range_pass():  # the control: the edges are allowed
    config = ExperimentConfig.resolve(
        "sac", "Pendulum-v1", hyperparams={"gamma": 1, "tau": 1, "batch_size": 1, "buffer_size": 1}
    )
    assert config.hyperparams["gamma"] == 1


class RaisesAt(BaseCallback):
    """A callback that raises ``error`` at env step ``at``: a video, TensorBoard or disk
    failure in the middle of training."""

    def __init__(self, error: Exception, at: int) -> None:
        super().__init__()
        self.error, self.at = error, at

    def _on_step(self) -> bool:
        if self.num_timesteps == self.at:
            raise self.error
        return True


@pytest.mark.parametrize(
    ("error", "exit_code"),
    [
        (OSError(28, "No space left on device"), 1),
        (PermissionError(13, "Permission denied: 'videos'"), 1),
        (ValueError("Expected parameter loc of shape (16, 1)"), 2),  # a setting SB3 rejected
    ],
)
def test_an_error_after_training_starts_keeps_the_run_and_says_how_to_resume(
    tmp_path, error, exit_code
):
    result = pendulum(tmp_path, callbacks=[RaisesAt(error, 77)], save_freq=50).run()
    run = result.run
    assert result.status == "failed" and result.exit_code == exit_code
    assert "\n" not in result.message and f"--resume {run.path}" in result.message
    assert type(error).__name__ in result.message and str(error.args[-1]) in result.message
    # The weights of step 77 are kept whole, with the buffer SAC needs to go on exactly.
    assert result.checkpoint == run.checkpoint(77) and run.replay_buffer(77).is_file()
    assert "Traceback" in run.failure_log.read_text()
    resumed = Experiment.resume(run.path, verbose=0).run()
    assert resumed.status == "completed" and resumed.num_timesteps == 200


def test_a_failure_whose_checkpoint_cannot_be_written_names_the_last_good_one(
    tmp_path, monkeypatch
):
    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    experiment = pendulum(tmp_path, callbacks=[RaisesAt(OSError(28, "disk full"), 77)])
    from minitaur_env.training import checkpoints

    monkeypatch.setattr(checkpoints, "save_checked_checkpoint", disk_full)
    result = experiment.run()
    assert result.status == "failed" and result.exit_code == 1 and result.checkpoint is None
    assert "no new checkpoint (OSError" in result.message
    assert f"last one {result.run.checkpoint(50)}" in result.message  # from before the failure
    assert not result.run.checkpoint(77).exists()
    assert f"(resume with --resume {result.run.path})" in result.message


def test_a_failure_that_leaves_no_checkpoint_does_not_promise_a_resume(tmp_path, monkeypatch):
    def disk_full(*args, **kwargs):
        raise OSError(28, "No space left on device")

    experiment = pendulum(tmp_path, callbacks=[RaisesAt(OSError(28, "disk full"), 77)], save_freq=0)
    from minitaur_env.training import checkpoints

    monkeypatch.setattr(checkpoints, "save_checked_checkpoint", disk_full)
    result = experiment.run()
    assert result.status == "failed" and not result.run.checkpoints()
    assert "--resume" not in result.message
    assert "no checkpoint to resume from: start the run again" in result.message


def test_a_run_folder_stands_for_its_final_model_in_every_command(tmp_path):
    run = pendulum(tmp_path, eval_freq=100, n_timesteps=200).run().run
    assert RunFolder.model_of(run.path) == run.zoo_model  # package and onnx alike
    assert RunFolder.model_of(run.best_model) == run.best_model  # a zip as given
    run.zoo_model.unlink()  # stopped before its end: say so rather than pick another model
    with pytest.raises(UsageError, match=r"has no final model .* pass its best_model\.zip"):
        RunFolder.model_of(run.path)


def test_the_robust_ppos_env_runs_the_shipped_recipe_and_the_robust_entry_adds_pushes():
    import yaml

    shipped = yaml.safe_load(
        (REPO / "pretrained/ppo/MinitaurBulletTrotRandomized-v0_1/config.yml").read_text()
    )
    for how in ({}, {"entry": "trot-history-decay"}):
        recipe = ExperimentConfig.resolve("ppo", "MinitaurBulletTrotRandomized-v0", **how)
        assert recipe.env_kwargs == shipped["env_kwargs"] == {"history": 4}
        assert recipe.hyperparams == shipped["hyperparams"]
        assert (recipe.n_timesteps, recipe.n_envs) == (shipped["n_timesteps"], shipped["n_envs"])
    before = ExperimentConfig.resolve(
        "ppo", "MinitaurBulletTrotRandomized-v0", entry="trot-history"
    )
    assert recipe.hyperparams == {**before.hyperparams, "learning_rate": "lin_2.5e-4"}
    config = ExperimentConfig.resolve("ppo", "MinitaurBulletTrotRandomized-v0", entry="robust")
    assert config.env_kwargs == {"history": 4, "realism": {"pushes": "sagittal"}}
    assert config.env_pushes == "sagittal"
    changed = {"learning_rate": "lin_2.5e-4", "push_curriculum": {"start": 0.0, "full_at": 0.5}}
    assert config.hyperparams == {**before.hyperparams, **changed}
    assert (config.n_timesteps, config.n_envs) == (before.n_timesteps, before.n_envs)
    config.validate()
    # --env-kwargs still decide over the entry's
    mine = ExperimentConfig.resolve(
        "ppo",
        "MinitaurBulletTrotRandomized-v0",
        env_kwargs={"history": 2, "realism": {"pushes": True}},
    )
    assert mine.env_kwargs == {"history": 2, "realism": {"pushes": True}}
    # and the classic entry has none
    assert ExperimentConfig.resolve("ppo", "MinitaurBulletEnv-v0").env_kwargs == {}


def test_mirror_stores_each_transition_and_its_mirror_image_and_resumes_without_pickles(tmp_path):
    from minitaur_env.robot import mirror_leg_action, mirror_observation
    from minitaur_env.training.replay_buffer import MirroredReplayBuffer

    def minitaur(name: str, **hyperparams) -> Experiment:
        config = ExperimentConfig.resolve(
            "sac",
            "MinitaurBulletEnv-v0",
            entry="minitaur-mirror",  # one observation, fixed 3-step returns
            hyperparams={**SMALL_SAC, "n_steps": 3, **hyperparams},
            n_timesteps=120,
            eval_freq=0,
            save_freq=60,
            vec_env="dummy",
            device="cpu",
        )
        return Experiment.create(config, tmp_path / name, verbose=0)

    experiment = minitaur("mirror", mirror=True)
    run = experiment.run().run
    buffer = experiment.model.replay_buffer
    assert isinstance(buffer, MirroredReplayBuffer) and buffer.n_steps == 3
    stored = np.s_[: buffer.pos]
    assert buffer.observations.shape[1] == 2 and buffer.pos == 120
    assert np.array_equal(
        buffer.observations[stored, 1], mirror_observation(buffer.observations[stored, 0])
    )
    assert np.array_equal(buffer.actions[stored, 1], mirror_leg_action(buffer.actions[stored, 0]))
    assert np.array_equal(buffer.rewards[stored, 1], buffer.rewards[stored, 0])
    assert not np.array_equal(buffer.observations[stored, 1], buffer.observations[stored, 0])
    assert 0 < buffer.sample(4000).discounts.mean() < 0.99  # 3-step returns: 0.99**3 mostly

    control = minitaur("control", mirror=False)  # the classic id's default has mirror: true
    control.run()
    assert type(control.model.replay_buffer).__name__ == "NStepReplayBuffer"
    assert control.model.replay_buffer.observations.shape[1] == 1

    resumed = Experiment.resume(run.path, n_timesteps=160, verbose=0)  # no --trust-pickle
    assert resumed.run().status == "completed" and resumed.resumed_at == 120
    buffer = resumed.model.replay_buffer
    assert isinstance(buffer, MirroredReplayBuffer) and buffer.n_steps == 3
    stored = np.s_[: buffer.pos]
    assert buffer.pos > 150
    assert np.array_equal(
        buffer.observations[stored, 1], mirror_observation(buffer.observations[stored, 0])
    )


def test_mirror_with_several_envs_keeps_each_envs_image_in_its_own_column(tmp_path):
    from minitaur_env.robot import mirror_leg_action, mirror_observation
    from minitaur_env.training.replay_buffer import MirroredReplayBuffer

    config = ExperimentConfig.resolve(
        "sac",
        "MinitaurBulletEnv-v0",  # the default entry: three observations, 10-step returns
        hyperparams={**SMALL_SAC, "n_envs": 3},
        n_timesteps=150,
        env_kwargs={"max_episode_steps": 30},
        eval_freq=0,
        save_freq=0,
        vec_env="grouped",
        device="cpu",
    )
    experiment = Experiment.create(config, tmp_path, verbose=0)
    assert experiment.run().status == "completed"
    buffer = experiment.model.replay_buffer
    assert isinstance(buffer, MirroredReplayBuffer) and buffer.observations.shape[1] == 6
    stored = np.s_[: buffer.pos]
    frames = buffer.observations[stored].reshape((buffer.pos, 6, 3, -1))
    for env in range(3):  # env k's images are column 3 + k, nobody else's
        assert np.array_equal(frames[:, 3 + env], mirror_observation(frames[:, env]))
        assert np.array_equal(
            buffer.actions[stored, 3 + env], mirror_leg_action(buffer.actions[stored, env])
        )
        assert np.array_equal(buffer.dones[stored, 3 + env], buffer.dones[stored, env])
    # the control: the envs are seeded apart, so a column paired with another env's
    # images would not match
    assert not np.array_equal(frames[:, 4], mirror_observation(frames[:, 0]))
    assert buffer.dones[stored, :3].any()  # episodes ended inside the run


def test_mirror_images_each_frame_of_a_stack_of_classic_observations():
    from gymnasium import spaces

    from minitaur_env.robot import mirror_leg_action, mirror_observation
    from minitaur_env.sensors import OBSERVATION_BOUND
    from minitaur_env.training.replay_buffer import MirroredReplayBuffer

    bound = np.tile(OBSERVATION_BOUND, 3)
    actions = spaces.Box(-1.0, 1.0, (8,), np.float32)
    buffer = MirroredReplayBuffer(
        10, spaces.Box(-bound, bound, dtype=np.float32), actions, device="cpu"
    )
    rng = np.random.default_rng(0)
    frames = rng.uniform(-1.0, 1.0, (2, 3, 28)).astype(np.float32)  # 3 different frames
    action = rng.uniform(-1.0, 1.0, (1, 8)).astype(np.float32)
    obs, next_obs = frames[0].reshape(1, -1), frames[1].reshape(1, -1)
    buffer.add(obs, next_obs, action, np.ones(1), np.zeros(1), [{}])
    for stored, original in (
        (buffer.observations, frames[0]),
        (buffer.next_observations, frames[1]),
    ):
        image = stored[0, 1].reshape(3, 28)
        assert np.array_equal(image, mirror_observation(original))  # frame by frame, in order
        assert not np.array_equal(image, mirror_observation(original[::-1]))
        assert np.array_equal(stored[0, 0], original.reshape(-1))
    assert np.array_equal(buffer.actions[0, 1], mirror_leg_action(action[0]))

    other = bound.copy()
    other[28 + 5] *= 2  # the second frame is not a classic observation
    with pytest.raises(UsageError, match="a stack of them"):
        MirroredReplayBuffer(10, spaces.Box(-other, other, dtype=np.float32), actions)


@pytest.mark.parametrize(
    ("algo", "env", "hyperparams", "message"),
    [
        ("sac", "Pendulum-v1", {"mirror": "yes"}, "mirror must be true or false, got 'yes'"),
        ("ppo", "MinitaurBulletEnv-v0", {"mirror": True}, "mirror: ppo has no replay buffer"),
        ("sac", "Pendulum-v1", {"mirror": True}, "mirror: needs the classic 28-value observation"),
        (
            "sac",
            "MinitaurBulletTrot-v0",
            {"mirror": True},
            "mirror: needs the classic 28-value observation",
        ),
    ],
)
def test_mirror_where_there_is_no_mirror_image_is_one_line(algo, env, hyperparams, message):
    with pytest.raises(UsageError, match=re.escape(message)):  # before any env or model runs
        config = ExperimentConfig.resolve(algo, env, hyperparams=hyperparams, n_timesteps=100)
        experiment_module.check_buildable(config)


def test_checking_a_many_env_rollout_does_not_warn_with_the_stand_in_env_count(recwarn):
    """A sweep checks its settings with one env standing in for n_envs: SB3's rollout
    warning would then name a buffer of n_steps x 1 that no trial will have."""
    from stable_baselines3.common.vec_env import DummyVecEnv

    hyperparams = {"n_steps": 64, "batch_size": 256}
    config = ExperimentConfig.resolve("ppo", "Pendulum-v1", hyperparams=hyperparams, n_envs=32)
    experiment_module.check_buildable(config)
    assert not [w for w in recwarn if "mini-batch" in str(w.message)]
    # the warning the check keeps quiet: the same settings built on the one stand-in env
    env = DummyVecEnv([lambda: gym.make("Pendulum-v1")])
    with pytest.warns(UserWarning, match="n_steps \\* n_envs = 64"):
        experiment_module.new_model(config, env)
    env.close()


def test_mirror_refuses_an_observation_that_only_has_the_classic_size():
    from gymnasium import spaces

    from minitaur_env.training.replay_buffer import MirroredReplayBuffer

    leg_actions = spaces.Box(-1, 1, (8,))
    with pytest.raises(UsageError, match="mirror: needs the classic 28-value observation"):
        MirroredReplayBuffer(100, spaces.Box(-1, 1, (28,)), leg_actions)
    classic = gym.make("MinitaurBulletEnv-v0")
    assert MirroredReplayBuffer(100, classic.observation_space, leg_actions).n_envs == 2
    classic.close()


@pytest.mark.parametrize("algo", ["sac", "td3", "tqc", "crossq"])
def test_mirror_discounts_its_returns_with_the_algorithms_own_gamma(algo):
    # No gamma in the hyperparameters: the buffer must not guess one the algorithm lacks.
    from stable_baselines3.common.vec_env import DummyVecEnv

    from minitaur_env.training.single_env import make_env

    config = ExperimentConfig.resolve(
        algo, "MinitaurBulletEnv-v0", entry="default", hyperparams={"mirror": True}
    )
    assert "gamma" not in config.hyperparams
    env = DummyVecEnv([lambda: make_env(config.env, config.env_kwargs)])
    model = experiment_module.new_model(config, env)
    assert model.replay_buffer.gamma == model.gamma
    env.close()
