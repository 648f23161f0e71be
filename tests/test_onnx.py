"""python -m minitaur_env.onnx: exported actors act as the models do, without torch."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import evaluate
from minitaur_env.onnx_policy import OnnxPolicy
from minitaur_env.training.evaluation import PRETRAINED_DIR, load_policy
from minitaur_env.training.single_env import make_env
from tests.scripts import REPO, error_lines, needs, run_main

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

onnxruntime = needs("onnxruntime")
SHIPPED = sorted(PRETRAINED_DIR.glob("*/*/MinitaurBulletEnv-v0.zip"))
EXPORT = [sys.executable, "-m", "minitaur_env.onnx"]


def export(source: Path, output: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [*EXPORT, str(source), "-o", str(output)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.mark.parametrize("shipped", SHIPPED, ids=lambda p: p.parents[1].name)
def test_each_shipped_policy_onnx_acts_as_its_zip_over_a_whole_episode(shipped):
    # The shipped file, beside the zip and in the Hub folder (python -m minitaur_env.package
    # wrote both from the zip).
    onnx_file = shipped.parent / "policy.onnx"
    algo = shipped.parents[1].name
    hub_copy = PRETRAINED_DIR / "hub" / f"{algo}-MinitaurBulletEnv-v0" / "policy.onnx"
    assert hub_copy.read_bytes() == onnx_file.read_bytes()
    model, onnx = load_policy(shipped, device="cpu"), OnnxPolicy(onnx_file)
    assert (onnx.algo, onnx.env_id) == (model.algo, "MinitaurBulletEnv-v0")
    # The file names the env it was trained on (the shipped SAC sees three observations).
    assert onnx.env_kwargs == model.env_kwargs
    env = make_env("MinitaurBulletEnv-v0", onnx.env_kwargs)
    obs, _ = env.reset(seed=777)
    differences, steps, done = [], 0, False
    while not done:  # the zip drives; both act on the same observations
        expected = model.act(obs)
        differences.append(np.abs(onnx.act(obs) - expected).max())
        obs, _, terminated, truncated, _ = env.step(expected)
        steps, done = steps + 1, terminated or truncated
    env.close()
    assert steps == 1000
    assert max(differences) <= 1e-5


def tiny_model(tmp_path: Path, algo: str, env_id: str = "Pendulum-v1", **kwargs) -> Path:
    import sb3_contrib
    import stable_baselines3

    cls = getattr(stable_baselines3, algo, None) or getattr(sb3_contrib, algo)
    extra = {"learning_starts": 50} if algo not in ("PPO", "A2C") else {"n_steps": 64}
    model = cls(
        kwargs.pop("policy", "MlpPolicy"), gym.make(env_id), seed=0, device="cpu", **extra, **kwargs
    )
    model.learn(100)
    path = tmp_path / f"{algo.lower()}.zip"
    model.save(path)
    return path


def test_a_run_folder_exports_its_final_model(tmp_path):
    shipped = PRETRAINED_DIR / "sac" / "MinitaurBulletEnv-v0_1"
    written = export(shipped, tmp_path / "policy.onnx")
    assert written.returncode == 0, written.stderr
    assert "observation normalization folded" in written.stdout
    model = load_policy(shipped / "MinitaurBulletEnv-v0.zip", device="cpu")
    shape = (16, *model.model.observation_space.shape)  # 28 per observation in its history
    obs = np.random.default_rng(3).normal(size=shape).astype(np.float32)
    got = OnnxPolicy(tmp_path / "policy.onnx").session.run(None, {"obs": obs})[0]
    np.testing.assert_allclose(got, np.stack([model.act(o) for o in obs]), atol=1e-5)


@pytest.mark.parametrize(
    ("algo", "kwargs"),
    [
        ("TD3", {}),
        ("A2C", {}),
        # Actor and critic with their own extractors: SB3's extract_features gives a pair.
        # Without orthogonal init, whose 0.01 gain on the action layer leaves means ~0.
        (
            "PPO",
            {
                "policy_kwargs": {
                    "net_arch": [32],
                    "share_features_extractor": False,
                    "ortho_init": False,
                }
            },
        ),
        ("CrossQ", {"policy_kwargs": {"net_arch": [32, 32]}}),
        (
            "SAC",
            {
                "use_sde": True,
                "policy": "StabilizedMlpPolicy",
                "policy_kwargs": {"net_arch": [32], "actor_ema": 0.5},
            },
        ),
    ],
)
def test_every_head_exports_and_acts_in_env_units(algo, kwargs, tmp_path):
    if kwargs.get("policy") == "StabilizedMlpPolicy":
        from minitaur_env.training.policies import StabilizedSACPolicy

        kwargs = {**kwargs, "policy": StabilizedSACPolicy}
    model_path = tiny_model(tmp_path, algo, **kwargs)
    if algo == "TD3":  # one head as a user runs the command, the others in this process
        written = export(model_path, tmp_path / "p.onnx")
        assert written.returncode == 0, written.stderr
    else:
        from minitaur_env.training.onnx_export import export_onnx

        export_onnx(model_path, tmp_path / "p.onnx")
    model, onnx = load_policy(model_path, device="cpu"), OnnxPolicy(tmp_path / "p.onnx")
    obs = np.random.default_rng(1).uniform(-1, 1, (64, 3)).astype(np.float32)
    expected = np.stack([model.act(o) for o in obs])
    got = onnx.session.run(None, {"obs": obs})[0]  # a batch of 64 through the dynamic axis
    np.testing.assert_allclose(got, expected, atol=1e-5)
    assert np.abs(expected).max() > 0.05  # Pendulum's torque in [-2, 2], not a trivial zero


def test_an_averaged_actor_is_what_the_graph_holds(tmp_path):
    from minitaur_env.training.policies import StabilizedSACPolicy

    model_path = tiny_model(
        tmp_path,
        "SAC",
        policy=StabilizedSACPolicy,
        policy_kwargs={"net_arch": [32], "actor_ema": 0.99},
    )
    assert export(model_path, tmp_path / "p.onnx").returncode == 0
    model = load_policy(model_path, device="cpu")
    obs = np.random.default_rng(2).uniform(-1, 1, (32, 3)).astype(np.float32)
    got = OnnxPolicy(tmp_path / "p.onnx").session.run(None, {"obs": obs})[0]
    averaged = np.stack([model.act(o) for o in obs])
    model.model.policy.averaged_actor = None  # the negative control: the live actor
    live = np.stack([model.act(o) for o in obs])
    np.testing.assert_allclose(got, averaged, atol=1e-5)
    assert np.abs(got - live).max() > 1e-3


def test_unsupported_policies_and_files_are_one_line(tmp_path):
    discrete = tiny_model(tmp_path, "PPO", "CartPole-v1")
    refused = export(discrete, tmp_path / "p.onnx")
    assert refused.returncode == 2
    assert error_lines(refused) == [
        f"python -m minitaur_env.onnx: error: {discrete}: only continuous (Box) actions export "
        "to ONNX, this policy acts in Discrete(2)"
    ]
    assert not (tmp_path / "p.onnx").exists()
    missing = export(tmp_path / "none.zip", tmp_path / "p.onnx")
    assert error_lines(missing)[-1].endswith(f"model file not found: {tmp_path / 'none.zip'}")

    (tmp_path / "garbage.onnx").write_bytes(b"not a graph")
    for model in ("garbage.onnx", "absent.onnx"):
        played = run_main(evaluate.main, "--model", str(tmp_path / model), cwd=tmp_path)
        assert played.returncode == 2
        (line,) = error_lines(played)
        assert line.startswith("evaluate.py: error: ")
        assert ("cannot load" in line) if model == "garbage.onnx" else ("not found" in line)


# Python as the onnx extra installs it: no torch, SB3, SBX or JAX.
HIDDEN = ("torch", "stable_baselines3", "sb3_contrib", "sbx", "jax", "matplotlib", "tqdm")
WITHOUT_TORCH = "import sys\n" + "".join(f"sys.modules[{m!r}] = None\n" for m in HIDDEN)


def evaluate_without_torch(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    run = f"sys.argv = ['evaluate.py', *{list(args)!r}]\nimport runpy\n"
    run += f"runpy.run_path({str(REPO / 'evaluate.py')!r}, run_name='__main__')\n"
    return subprocess.run(
        [sys.executable, "-c", WITHOUT_TORCH + run],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_evaluate_plays_an_onnx_policy_and_its_video_without_torch(tmp_path):
    shipped = PRETRAINED_DIR / "ppo" / "MinitaurBulletEnv-v0_1"
    # the shipped export (tests above check that exports agree with their zips)
    shutil.copyfile(shipped / "policy.onnx", tmp_path / "policy.onnx")
    # The contacts are chaotic: an action difference of 1e-6 grows to a different gait
    # phase within 50 steps, yet returns stay close over 300 steps (within 1 % measured):
    # a missing or doubled normalization would not walk at all.
    short = ["--episodes", "1", "--env-kwargs", "max_episode_steps=300"]
    played = evaluate_without_torch(
        "--model",
        "policy.onnx",
        *short,
        "--json",
        "onnx.json",
        "--render-video",
        "--video-episodes",
        "1",
        "-o",
        "videos/onnx.mp4",
        cwd=tmp_path,
    )
    assert played.returncode == 0, played.stderr
    assert "onnxruntime" in played.stdout and (tmp_path / "videos" / "onnx.mp4").stat().st_size
    zipped = subprocess.run(
        [
            sys.executable,
            str(REPO / "evaluate.py"),
            "--model",
            str(shipped / "MinitaurBulletEnv-v0.zip"),
            *short,
            "--json",
            "zip.json",
        ],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert zipped.returncode == 0, zipped.stderr
    onnx, zip_ = (
        json.loads((tmp_path / f).read_text())["per_episode"] for f in ("onnx.json", "zip.json")
    )
    for mine, theirs in zip(onnx, zip_, strict=True):
        assert mine["length"] == theirs["length"] == 300
        assert mine["return"] == pytest.approx(theirs["return"], rel=0.05)
        assert theirs["return"] > 5  # it walks

    # Without torch a model zip is one line that points to the export beside it.
    zip_alone = evaluate_without_torch(
        "--model", str(shipped / "MinitaurBulletEnv-v0.zip"), cwd=tmp_path
    )
    assert zip_alone.returncode == 2
    (line,) = error_lines(zip_alone)
    assert "is not installed" in line
    assert line.endswith(f"or play its ONNX export without them: --model {shipped}/policy.onnx")
    stochastic = evaluate_without_torch("--model", "policy.onnx", "--stochastic", cwd=tmp_path)
    assert error_lines(stochastic) == [
        "evaluate.py: error: policy.onnx is the deterministic actor; --stochastic needs the zip"
    ]
