"""StabilizedMlpPolicy: LayerNorm critics, gradient clipping, the averaged actor, held
noise and the action gain."""

from __future__ import annotations

import importlib.util

import gymnasium as gym
import numpy as np
import pytest
import torch
from stable_baselines3 import SAC

from minitaur_env.training import Experiment, ExperimentConfig, UsageError
from minitaur_env.training.algorithms import infer_algo, load_model
from minitaur_env.training.onnx_export import export_onnx
from minitaur_env.training.policies import POLICY_NAME, StabilizedSACPolicy
from tests.scripts import needs

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

SMALL = {"learning_starts": 30, "batch_size": 16, "buffer_size": 1000}


def sac(**policy_kwargs) -> SAC:
    kwargs = {"net_arch": [32, 32], **policy_kwargs}
    return SAC(
        StabilizedSACPolicy,
        gym.make("Pendulum-v1"),
        seed=0,
        device="cpu",
        policy_kwargs=kwargs,
        **SMALL,
    )


def critic_output(model: SAC) -> torch.Tensor:
    obs = torch.ones(4, 3)
    actions = torch.zeros(4, 1)
    return model.policy.critic(obs, actions)[0]


@pytest.mark.parametrize("layer_norm", [True, False])
def test_layer_norm_critics_ignore_the_scale_of_a_hidden_layer(layer_norm):
    model = sac(critic_layer_norm=layer_norm)
    norms = [m for m in model.policy.critic.modules() if isinstance(m, torch.nn.LayerNorm)]
    assert len(norms) == (4 if layer_norm else 0)  # two hidden layers, two critics
    assert len(list(model.policy.critic_target.modules())) == len(
        list(model.policy.critic.modules())
    )
    before = critic_output(model)
    with torch.no_grad():
        first = next(m for m in model.policy.critic.qf0 if isinstance(m, torch.nn.Linear))
        first.weight.mul_(10.0)
        first.bias.mul_(10.0)
    after = critic_output(model)
    # LayerNorm undoes the scale; a plain MLP passes it on (the negative control).
    assert torch.allclose(before, after, atol=1e-5) == layer_norm


def test_gradients_are_clipped_before_every_step():
    seen: list[float] = []

    def record(optimizer, *_):
        grads = [p.grad for g in optimizer.param_groups for p in g["params"] if p.grad is not None]
        seen.append(float(torch.linalg.vector_norm(torch.stack([g.norm() for g in grads]))))

    for clip in (1e-3, None):
        model = sac(max_grad_norm=clip)
        for optimizer in (model.policy.actor.optimizer, model.policy.critic.optimizer):
            optimizer.register_step_pre_hook(record)  # runs after the policy's own hook
        seen.clear()
        model.learn(60)
        assert len(seen) == 2 * 30  # one actor and one critic step per update
        if clip:
            assert max(seen) <= clip * 1.001
        else:
            assert max(seen) > 1e-2  # without clipping the same run has larger gradients


def test_the_averaged_actor_acts_deterministically_and_survives_saving(tmp_path):
    decay = 0.9
    model = sac(actor_ema=decay)
    live = model.policy.actor
    expected = [p.detach().clone() for p in live.parameters()]

    def follow(*_):
        for average, param in zip(expected, live.parameters(), strict=True):
            average.mul_(decay).add_(param.detach(), alpha=1 - decay)

    live.optimizer.register_step_post_hook(follow)
    model.learn(80)
    averaged = list(model.policy.averaged_actor.parameters())
    for mine, theirs in zip(expected, averaged, strict=True):
        torch.testing.assert_close(theirs, mine)

    obs = np.array([0.3, -0.2, 0.5], np.float32)
    with torch.no_grad():
        tensor = torch.as_tensor(obs[None])
        from_average = model.policy.averaged_actor(tensor, deterministic=True).numpy()
        from_live = live(tensor, deterministic=True).numpy()
    action = model.predict(obs, deterministic=True)[0]
    np.testing.assert_allclose(action, model.policy.unscale_action(from_average)[0], rtol=1e-6)
    assert not np.allclose(from_average, from_live)  # the average is not the live actor

    model.save(tmp_path / "model.zip")
    loaded = load_model(SAC, tmp_path / "model.zip", device="cpu")
    assert isinstance(loaded.policy, StabilizedSACPolicy) and loaded.policy.actor_ema == decay
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], action)
    assert infer_algo(tmp_path / "model.zip") == ("sac", "sb3")  # evaluate.py without --algo


@pytest.mark.parametrize("use_sde", [False, True])
def test_the_average_leaves_training_unchanged(use_sde):
    # The SAC ablation judges an actor_ema run's live actor as the run without the
    # average: that holds only if averaging draws nothing from the random stream.
    def trained(**policy_kwargs) -> SAC:
        model = SAC(
            StabilizedSACPolicy,
            gym.make("Pendulum-v1"),
            seed=0,
            device="cpu",
            use_sde=use_sde,
            policy_kwargs={"net_arch": [32, 32], **policy_kwargs},
            **SMALL,
        )
        model.learn(80)
        return model

    plain, averaged = trained(), trained(actor_ema=0.9)
    for mine, theirs in zip(
        plain.policy.actor.parameters(), averaged.policy.actor.parameters(), strict=True
    ):
        torch.testing.assert_close(theirs, mine, rtol=0, atol=0)
    # The negative control: another seed's live actor differs.
    other = SAC(
        StabilizedSACPolicy,
        gym.make("Pendulum-v1"),
        seed=1,
        device="cpu",
        use_sde=use_sde,
        policy_kwargs={"net_arch": [32, 32]},
        **SMALL,
    )
    other.learn(80)
    first = next(other.policy.actor.parameters())
    assert not torch.equal(first, next(plain.policy.actor.parameters()))


def test_held_noise_repeats_the_exploring_draw_for_its_steps_and_no_longer(tmp_path):
    def policy(hold: int) -> SAC:
        return SAC(
            StabilizedSACPolicy,
            gym.make("Pendulum-v1"),
            seed=0,
            device="cpu",
            policy_kwargs={"net_arch": [32, 32], "noise_hold": hold},
            **SMALL,
        )

    obs = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.5]], dtype=np.float32)  # two envs
    held = policy(4)
    actions = [held.predict(obs, deterministic=False)[0] for _ in range(9)]
    for first, later in ((0, [1, 2, 3]), (4, [5, 6, 7])):
        for step in later:
            np.testing.assert_array_equal(actions[step], actions[first])
    assert not np.allclose(actions[4], actions[0]) and not np.allclose(actions[8], actions[4])
    assert not np.allclose(actions[0][0], actions[0][1])  # each env its own draw
    white = policy(1)  # the control: SAC's white noise draws at every step
    drawn = [white.predict(obs, deterministic=False)[0] for _ in range(3)]
    assert not np.allclose(drawn[0], drawn[1]) and not np.allclose(drawn[1], drawn[2])
    deterministic = held.predict(obs, deterministic=True)[0]  # no noise, held or not
    np.testing.assert_array_equal(deterministic, white.predict(obs, deterministic=True)[0])
    held.save(tmp_path / "held.zip")
    assert load_model(SAC, tmp_path / "held.zip", device="cpu").policy.noise_hold == 4
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match="noise_hold must be a whole number of steps >= 1"):
            policy(bad)
    with pytest.raises(ValueError, match="does not combine with use_sde"):
        SAC(
            StabilizedSACPolicy,
            gym.make("Pendulum-v1"),
            use_sde=True,
            device="cpu",
            policy_kwargs={"noise_hold": 8},
            **SMALL,
        )


def test_colored_noise_is_correlated_in_time_seeded_and_leaves_the_deterministic_policy(tmp_path):
    def policy(color: float, seed: int = 0) -> SAC:
        return SAC(
            StabilizedSACPolicy,
            gym.make("Pendulum-v1"),
            seed=seed,
            device="cpu",
            policy_kwargs={"net_arch": [32, 32], "noise_color": color},
            **SMALL,
        )

    obs = np.zeros((2, 3), dtype=np.float32)  # two envs, the same observation every step

    def exploring(model: SAC, steps: int = 400) -> np.ndarray:
        with torch.no_grad():  # the pre-squash noise: atanh of the action over its mean
            mean, log_std, _ = model.policy.actor.get_action_dist_params(torch.as_tensor(obs))
        actions = np.array([model.predict(obs, deterministic=False)[0] for _ in range(steps)])
        gaussian = np.arctanh(np.clip(actions / 2.0, -0.999999, 0.999999))  # bounds ±2
        return (gaussian - mean.numpy()) / log_std.exp().numpy()

    def lag_one_correlation(noise: np.ndarray) -> float:
        series = noise[:, 0, 0]
        return float(np.corrcoef(series[:-1], series[1:])[0, 1])

    pink, white = exploring(policy(1.0)), exploring(policy(0.0))
    assert lag_one_correlation(pink) > 0.3  # pink noise: neighbouring steps alike
    assert abs(lag_one_correlation(white)) < 0.15  # the control: SAC's white noise is not
    assert 0.5 < pink.std() < 1.5  # unit variance, as SAC's own draw
    assert not np.allclose(pink[:, 0], pink[:, 1])  # each env its own sequence
    np.testing.assert_allclose(exploring(policy(1.0)), pink, atol=1e-5)  # the seed fixes it
    assert not np.allclose(exploring(policy(1.0, seed=1)), pink, atol=1e-3)
    colored = policy(1.0)
    np.testing.assert_array_equal(  # no noise when deterministic, colored or not
        colored.predict(obs, deterministic=True)[0], policy(0.0).predict(obs, deterministic=True)[0]
    )
    colored.save(tmp_path / "pink.zip")
    assert load_model(SAC, tmp_path / "pink.zip", device="cpu").policy.noise_color == 1.0
    for bad in (-0.5, 2.5, True, "1"):
        with pytest.raises(ValueError, match=r"noise_color must be a number in \[0, 2\]"):
            policy(bad)
    with pytest.raises(ValueError, match="two kinds of exploring noise; pick one"):
        SAC(
            StabilizedSACPolicy,
            gym.make("Pendulum-v1"),
            device="cpu",
            policy_kwargs={"noise_color": 1.0, "noise_hold": 4},
            **SMALL,
        )


def test_action_gain_multiplies_and_clips_the_action_and_counts_the_gain_in_its_log_prob(
    tmp_path,
):
    plain, gained = sac(), sac(action_gain=2)
    gained.policy.actor.load_state_dict(plain.policy.actor.state_dict())  # the same actor
    with torch.no_grad():  # means spread over tanh's range: some beyond ±0.5, some not
        for actor in (plain.policy.actor, gained.policy.actor):
            actor.mu.weight.mul_(50.0)
    obs = torch.tensor(np.random.default_rng(0).normal(size=(64, 3)), dtype=torch.float32)
    with torch.no_grad():
        squashed = plain.policy.actor(obs, deterministic=True)
        acted = gained.policy.actor(obs, deterministic=True)
        torch.manual_seed(1)
        sampled, log_prob = plain.policy.actor.action_log_prob(obs)
        torch.manual_seed(1)
        gained_sample, gained_log_prob = gained.policy.actor.action_log_prob(obs)
    assert (squashed.abs() > 0.5).any() and (squashed.abs() < 0.4).any()
    torch.testing.assert_close(acted, torch.clamp(2 * squashed, -1, 1))
    torch.testing.assert_close(gained_sample, torch.clamp(2 * sampled, -1, 1))
    torch.testing.assert_close(gained_log_prob, log_prob - np.log(2.0))  # 1 action dim
    # The control: without the gain, actions beyond ±0.5 are not at the limit.
    assert not torch.allclose(squashed, acted)
    # The held noise goes through the gain too, and every action stays within the bounds.
    held = sac(action_gain=2, noise_hold=4)
    held.policy.actor.load_state_dict(gained.policy.actor.state_dict())
    held_plain = sac(noise_hold=4)
    held_plain.policy.actor.load_state_dict(gained.policy.actor.state_dict())
    torch.manual_seed(2)
    exploring = held.predict(obs.numpy(), deterministic=False)[0]
    torch.manual_seed(2)
    exploring_plain = held_plain.predict(obs.numpy(), deterministic=False)[0]
    np.testing.assert_allclose(exploring, np.clip(2 * exploring_plain, -2, 2), atol=1e-5)
    assert np.abs(exploring).max() <= 2.0  # Pendulum's bounds
    gained.save(tmp_path / "gained.zip")
    loaded = load_model(SAC, tmp_path / "gained.zip", device="cpu")
    assert loaded.policy.action_gain == 2.0
    np.testing.assert_array_equal(
        loaded.predict(obs.numpy(), deterministic=True)[0],
        gained.predict(obs.numpy(), deterministic=True)[0],
    )
    for bad in (0.5, True, "2", float("inf")):
        with pytest.raises(ValueError, match="action_gain must be a number >= 1"):
            sac(action_gain=bad)


def tiny_run(policy_kwargs: dict, backend: str = "sb3", **hyperparams) -> ExperimentConfig:
    """A 60-step Pendulum run of the policy, checkpointed at 30."""
    return ExperimentConfig.resolve(
        "sac",
        "Pendulum-v1",
        n_timesteps=60,
        eval_freq=0,
        save_freq=30,
        vec_env="dummy",
        device="cpu",
        backend=backend,
        hyperparams={
            **SMALL,
            "policy": POLICY_NAME,
            "policy_kwargs": {"net_arch": [8], **policy_kwargs},
            **hyperparams,
        },
    )


def test_the_policy_and_its_held_noise_train_resume_export_and_bad_values_are_one_line(tmp_path):
    def config(**policy_kwargs):
        # target_entropy auto, as the held-noise entry: its resume once failed
        return tiny_run(policy_kwargs, target_entropy="auto")

    settings = {"critic_layer_norm": True, "noise_hold": 8, "action_gain": 2}
    run = Experiment.create(config(**settings), tmp_path, verbose=0)
    result = run.run()
    assert result.status == "completed"
    resumed = Experiment.resume(result.run.path, n_timesteps=90, verbose=0)
    assert resumed.run().status == "completed" and resumed.resumed_at == 60
    model = load_model(SAC, result.run.final_model, device="cpu")
    assert isinstance(model.policy, StabilizedSACPolicy) and model.policy.noise_hold == 8
    assert model.policy.action_gain == 2
    if importlib.util.find_spec("onnxruntime"):  # the held noise leaves, the gain stays
        exported = export_onnx(result.run.path, tmp_path / "policy.onnx")
        assert exported["max_abs_difference"] < 1e-5
    with pytest.raises(UsageError, match=r"actor_ema is a decay in \(0, 1\), got 1.5"):
        Experiment.create(config(actor_ema=1.5), tmp_path, verbose=0).run()


def test_the_torch_only_keys_on_sbx_are_one_line_not_a_traceback(tmp_path):
    needs("sbx")
    config = tiny_run({"noise_color": 1.0, "critic_layer_norm": True}, "sbx")
    with pytest.raises(UsageError, match="takes noise_color, not critic_layer_norm"):
        Experiment.create(config, tmp_path, verbose=0).run()
    assert not any(tmp_path.rglob("config.yml"))  # the run that never started is gone


def test_colored_noise_on_sbx_explores_as_on_torch_trains_saves_and_resumes(tmp_path):
    needs("sbx")
    from sbx import SAC as SbxSAC

    from minitaur_env.training.algorithms import infer_algo
    from minitaur_env.training.safe_load import load_sb3_model
    from minitaur_env.training.sbx_policies import ColoredNoiseSACPolicy

    def policy(color: float, seed: int = 0) -> SbxSAC:
        kwargs = {"net_arch": [32, 32], "noise_color": color}
        return SbxSAC(
            ColoredNoiseSACPolicy, gym.make("Pendulum-v1"), seed=seed, policy_kwargs=kwargs
        )

    obs = np.zeros((2, 3), dtype=np.float32)

    def lag_one_correlation(model: SbxSAC) -> float:
        actions = np.array([model.predict(obs, deterministic=False)[0] for _ in range(300)])
        series = np.arctanh(np.clip(actions[:, 0, 0] / 2.0, -0.999999, 0.999999))
        return float(np.corrcoef(series[:-1], series[1:])[0, 1])

    assert lag_one_correlation(policy(1.0)) > 0.3
    assert abs(lag_one_correlation(policy(0.0))) < 0.15  # the control: SBX's white noise
    first = [policy(1.0).predict(obs, deterministic=False)[0] for _ in range(2)]
    np.testing.assert_allclose(first[0], first[1])  # the seed fixes the noise
    assert not np.allclose(policy(1.0, seed=1).predict(obs, deterministic=False)[0], first[0])
    np.testing.assert_array_equal(
        policy(1.0).predict(obs, deterministic=True)[0],
        policy(0.0).predict(obs, deterministic=True)[0],
    )

    result = Experiment.create(tiny_run({"noise_color": 1.0}, "sbx"), tmp_path, verbose=0).run()
    assert result.status == "completed"
    assert infer_algo(result.run.final_model) == ("sac", "sbx")
    resumed = Experiment.resume(result.run.path, n_timesteps=90, verbose=0)  # no pickle
    assert resumed.run().status == "completed" and resumed.resumed_at == 60
    loaded = SbxSAC.load(result.run.final_model)
    assert isinstance(loaded.policy, ColoredNoiseSACPolicy) and loaded.policy.noise_color == 1.0
    safe = load_sb3_model(SbxSAC, result.run.final_model)  # from readable entries and msgpack
    assert isinstance(safe.policy, ColoredNoiseSACPolicy) and safe.policy.noise_color == 1.0
    np.testing.assert_array_equal(
        safe.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0]
    )


@pytest.mark.parametrize("backend", ["sb3", "sbx"])
def test_noise_color_until_turns_the_exploring_noise_white_there_and_after_a_resume(
    tmp_path, backend
):
    if backend == "sbx":
        needs("sbx")
    config = tiny_run({"noise_color": 1.0}, backend, noise_color_until=0.5)
    experiment = Experiment.create(config, tmp_path, verbose=0)
    result = experiment.run()
    assert result.status == "completed"
    assert experiment.model.policy.noise_color == 0.0  # white from step 30 of 60
    control = Experiment.create(tiny_run({"noise_color": 1.0}, backend), tmp_path, verbose=0)
    control.run()
    assert control.model.policy.noise_color == 1.0  # without the key: colored to the end
    # Resumed (its zip's policy_kwargs still say noise_color 1): white again from the start.
    resumed = Experiment.resume(result.run.path, n_timesteps=90, verbose=0)
    assert resumed.run().status == "completed" and resumed.resumed_at == 60
    assert resumed.model.policy.noise_color == 0.0


@pytest.mark.parametrize("backend", ["sb3", "sbx"])
def test_n_steps_after_shortens_the_sampled_returns_there_and_after_a_resume(tmp_path, backend):
    if backend == "sbx":
        needs("sbx")
    shorter = {"at": 0.5, "n_steps": 1}
    config = tiny_run({}, backend, n_steps=3, gamma=0.9, n_steps_after=shorter)
    experiment = Experiment.create(config, tmp_path, verbose=0)
    result = experiment.run()
    assert result.status == "completed"
    # From step 30 of 60 every sampled return is one step long: discounted once.
    sampled = experiment.model.replay_buffer.sample(64).discounts.numpy()
    np.testing.assert_allclose(sampled, 0.9)
    control = Experiment.create(tiny_run({}, backend, n_steps=3, gamma=0.9), tmp_path, verbose=0)
    control.run()
    assert control.model.replay_buffer.n_steps == 3  # without the key: 3 steps to the end
    assert np.isclose(control.model.replay_buffer.sample(64).discounts.numpy(), 0.9**3).any()
    # Resumed (its zip still says n_steps 3): one step again from the start.
    resumed = Experiment.resume(result.run.path, n_timesteps=90, verbose=0)
    assert resumed.run().status == "completed" and resumed.resumed_at == 60
    assert resumed.model.replay_buffer.n_steps == 1


@pytest.mark.parametrize(
    ("algo", "hyperparams", "message"),
    [
        ("sac", {"n_steps": 3, "n_steps_after": {"at": 1.5, "n_steps": 1}}, r"\.at must be"),
        ("sac", {"n_steps": 3, "n_steps_after": {"at": 0.5, "n_steps": 3}}, "below the entry's"),
        ("sac", {"n_steps_after": {"at": 0.5, "n_steps": 1}}, r"below the entry's n_steps \(1\)"),
        ("sac", {"n_steps": 3, "n_steps_after": 0.5}, "expected {at: "),
        ("ppo", {"n_steps_after": {"at": 0.5, "n_steps": 1}}, "ppo has no n-step returns"),
    ],
)
def test_n_steps_after_bad_values_are_one_line(algo, hyperparams, message):
    with pytest.raises(UsageError, match=message):
        ExperimentConfig.resolve(algo, "Pendulum-v1", hyperparams=hyperparams).validate()


@pytest.mark.parametrize(
    ("hyperparams", "message"),
    [
        ({"noise_color_until": 1.5}, "noise_color_until must be a fraction of n_timesteps"),
        ({"noise_color_until": 0.5}, "the policy explores with white noise already"),
    ],
)
def test_noise_color_until_bad_values_are_one_line(tmp_path, hyperparams, message):
    color = {"noise_color": 1.0} if hyperparams["noise_color_until"] > 1 else {}
    with pytest.raises(UsageError, match=message):
        Experiment.create(tiny_run(color, **hyperparams), tmp_path, verbose=0).run()
