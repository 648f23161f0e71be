"""No loader runs code from a model file, its statistics or its replay buffer by default.

Each booby-trapped file writes a marker file when it is unpickled and then behaves like
the real thing, so that only the marker tells whether its code ran.
"""

from __future__ import annotations

import base64
import json
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

import evaluate as evaluate_script
import train
from minitaur_env.training import UsageError
from minitaur_env.training.evaluation import load_policy
from minitaur_env.training.run_folder import EMBEDDED_STATISTICS
from minitaur_env.training.safe_load import UntrustedPickle, safe_custom_objects
from tests.scripts import TINY, error_lines, needs, run_main, run_script

# Trains, plays episodes or starts processes: the full suite's, not the edit loop's.
pytestmark = [pytest.mark.slow, pytest.mark.timeout(600)]

FAST_SAC = ["--hyperparams", "learning_starts=50", "buffer_size=5000", "batch_size=32"]


class Trap:
    """Unpickles by writing ``marker``, then evaluating to ``then`` (Python source)."""

    def __init__(self, marker: Path, then: str) -> None:
        self.code = f"(__import__('pathlib').Path({str(marker)!r}).write_text('ran'), {then})[1]"

    def __reduce__(self):
        return (eval, (self.code,))


def trap_zip(model: Path, marker: Path, key: str = "lr_schedule") -> None:
    """Replace (or add) the cloudpickled ``key`` of the zip's data by a trap."""
    then = "(lambda _: 0.0)" if key == "lr_schedule" else "0"
    payload = base64.b64encode(pickle.dumps(Trap(marker, then))).decode()
    with zipfile.ZipFile(model) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(members["data"])
    data[key] = {":type:": "<class 'function'>", ":serialized:": payload}
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(model, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)


def trap_pickle(path: Path, marker: Path) -> None:
    """Replace a pickle by one that writes the marker and then returns the original."""
    original = path.read_bytes()
    path.write_bytes(pickle.dumps(Trap(marker, f"__import__('pickle').loads({original!r})")))


@pytest.fixture(scope="module")
def checkpointed(tmp_path_factory) -> Path:
    """A run with checkpoints at 60 and 120 steps, to resume (one 28-number observation:
    the tests build observations and statistics of that shape)."""
    root = tmp_path_factory.mktemp("checkpointed")
    result = run_script(
        "train.py",
        "--config",
        "minitaur-mirror",
        "-n",
        "120",
        *FAST_SAC,
        "--eval-freq",
        "0",
        "--save-freq",
        "60",
        *TINY,
        cwd=root,
    )
    assert result.returncode == 0, result.stderr
    return root / "logs" / "sac" / "MinitaurBulletEnv-v0_1"


@pytest.fixture
def run(checkpointed: Path, tmp_path: Path) -> Path:
    """A fresh copy of the run folder, to booby-trap."""
    copy = tmp_path / "downloaded" / "MinitaurBulletEnv-v0_1"
    shutil.copytree(checkpointed, copy)
    return copy


def strip_embedded_statistics(model: Path) -> None:
    """Make ``model`` a zip as SB3 or the zoo save it: without the statistics ours carry."""
    with zipfile.ZipFile(model) as source:
        members = {n: source.read(n) for n in source.namelist() if n != EMBEDDED_STATISTICS}
    with zipfile.ZipFile(model, "w") as target:
        for name, data in members.items():
            target.writestr(name, data)


def evaluate(*args: str, cwd: Path):
    # In this process: a pickle that ran would write its marker here as well, and the
    # seven plays skip an interpreter's start each.
    return run_main(
        evaluate_script.main,
        *args,
        "--episodes",
        "1",
        "--env-kwargs",
        "max_episode_steps=20",
        cwd=cwd,
    )


def test_run_folders_carry_pickle_free_statistics_that_act_as_the_pickle(checkpointed):
    stats = checkpointed / "MinitaurBulletEnv-v0" / "vecnormalize.pkl"
    assert stats.with_suffix(".json").is_file()
    safe = load_policy(checkpointed / "MinitaurBulletEnv-v0.zip", device="cpu")
    trusted = load_policy(
        checkpointed / "MinitaurBulletEnv-v0.zip", device="cpu", trust_pickle=True
    )
    obs = np.random.default_rng(0).normal(scale=5, size=(20, 28)).astype(np.float32)
    for o in obs:
        np.testing.assert_array_equal(safe.act(o), trusted.act(o))


def test_evaluate_runs_no_code_from_a_zip_entry_without_the_flag(run, tmp_path):
    marker = tmp_path / "ran-zip"
    model = run / "MinitaurBulletEnv-v0.zip"
    trap_zip(model, marker)  # an entry evaluation replaces anyway: it loads, safely
    played = evaluate("--model", str(model), cwd=tmp_path)
    assert played.returncode == 0, played.stderr
    assert not marker.exists()
    trap_zip(model, marker, key="booby")  # an entry nobody knows: refused in one line
    refused = evaluate("--model", str(model), cwd=tmp_path)
    assert refused.returncode == 2 and not marker.exists()
    assert error_lines(refused) == [
        f"evaluate.py: error: {model}: loading its data entry 'booby' would unpickle it, and "
        "a pickle can run code from the file; pass --trust-pickle if you trust where it came "
        "from"
    ]
    trusted = evaluate("--model", str(model), "--trust-pickle", cwd=tmp_path)
    assert trusted.returncode == 0, trusted.stderr
    assert marker.read_text() == "ran"  # the flag is what lets it run


def test_evaluate_needs_the_flag_for_statistics_without_their_json(run, tmp_path):
    strip_embedded_statistics(run / "MinitaurBulletEnv-v0.zip")
    marker = tmp_path / "ran-stats"
    stats = run / "MinitaurBulletEnv-v0" / "vecnormalize.pkl"
    stats.with_suffix(".json").unlink()
    trap_pickle(stats, marker)
    refused = evaluate("--model", str(run / "MinitaurBulletEnv-v0.zip"), cwd=tmp_path)
    assert refused.returncode == 2 and not marker.exists()
    (line,) = error_lines(refused)
    assert str(stats) in line and "--trust-pickle" in line
    trusted = evaluate(
        "--model", str(run / "MinitaurBulletEnv-v0.zip"), "--trust-pickle", cwd=tmp_path
    )
    assert trusted.returncode == 0, trusted.stderr
    assert marker.read_text() == "ran"


def test_training_from_a_model_starts_an_empty_buffer_and_loads_no_pickle(run, tmp_path):
    marker = tmp_path / "ran-train"
    model = run / "MinitaurBulletEnv-v0.zip"
    trap_zip(model, marker)
    buffer = run / "replay_buffer.pkl"  # where the zoo keeps one beside a model
    buffer.write_bytes(pickle.dumps(Trap(marker, "None")))
    args = ["-i", str(model), "--config", "minitaur-mirror", "-n", "60", *FAST_SAC]
    args += ["--eval-freq", "0", "--save-freq", "0"]
    started = run_script("train.py", *args, *TINY, cwd=tmp_path)
    assert started.returncode == 0, started.stderr
    assert not marker.exists()
    assert f"{buffer} is a pickle (it can run code): starting with an empty replay buffer" in (
        started.stdout + started.stderr
    )
    # The statistics without their JSON: refused in one line, then loaded with the flag.
    strip_embedded_statistics(model)
    stats = run / "MinitaurBulletEnv-v0" / "vecnormalize.pkl"
    stats.with_suffix(".json").unlink()
    refused = run_main(train.main, *args, *TINY, cwd=tmp_path)
    assert refused.returncode == 2 and not marker.exists()
    assert "--trust-pickle" in error_lines(refused)[-1] and str(stats) in refused.stderr
    buffer.unlink()
    trap_pickle(stats, marker)
    trusted = run_script("train.py", *args, "--trust-pickle", *TINY, cwd=tmp_path)
    assert trusted.returncode == 0, trusted.stderr
    assert marker.read_text() == "ran"  # the flag is what lets it run


def test_training_on_needs_the_pickled_schedule_set_not_silently_zero(tmp_path):
    import gymnasium as gym
    from stable_baselines3 import SAC

    model = SAC("MlpPolicy", gym.make("Pendulum-v1"), learning_rate=lambda f: 1e-3 * f)
    model.save(tmp_path / "m.zip")
    # Evaluation never steps an optimizer: the schedule is dropped, nothing is unpickled.
    assert safe_custom_objects(tmp_path / "m.zip")["learning_rate"](1.0) == 0.0
    # A run that trains on must set it rather than train at a placeholder rate.
    with pytest.raises(UsageError, match=r"its learning_rate is a pickle.*--hyperparams "):
        safe_custom_objects(tmp_path / "m.zip", training_kwargs={"train_freq": 1})
    with pytest.raises(UntrustedPickle, match="its policy_class"):  # not a library's class
        data = json.loads(zipfile.ZipFile(tmp_path / "m.zip").read("data"))
        data["policy_class"]["__module__"] = "evil.policies"
        with zipfile.ZipFile(tmp_path / "evil.zip", "w") as archive:
            archive.writestr("data", json.dumps(data))
        safe_custom_objects(tmp_path / "evil.zip")


def test_packaging_runs_no_code_from_the_files(run, tmp_path):
    needs("huggingface_hub")
    marker = tmp_path / "ran-package"
    model = run / "MinitaurBulletEnv-v0.zip"
    trap_zip(model, marker)
    stats = run / "MinitaurBulletEnv-v0" / "vecnormalize.pkl"
    trap_pickle(stats, marker)  # its JSON sibling is what packaging reads
    package = [
        "-m",
        "minitaur_env.package",
        str(model),
        "-o",
        str(tmp_path / "hub"),
        "--episodes",
        "1",
        "--video-steps",
        "10",
    ]
    import subprocess
    import sys

    done = subprocess.run(
        [sys.executable, *package], cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    assert not marker.exists()
    folder = tmp_path / "hub" / "sac-MinitaurBulletEnv-v0"
    assert (folder / "vec_normalize.json").is_file() and (folder / "policy.onnx").is_file()
    card = (folder / "README.md").read_text()
    assert "## Loading models safely" in card and "--trust-pickle" in card
    # The published pickle is written from the statistics, not copied: whoever loads the
    # folder with VecNormalize.load runs nothing from the trapped source.
    published = pickle.loads((folder / "vec_normalize.pkl").read_bytes())
    assert not marker.exists() and type(published).__name__ == "VecNormalize"
    source = json.loads(stats.with_suffix(".json").read_text())
    np.testing.assert_array_equal(published.obs_rms.mean, source["obs_rms"]["mean"])
    pickle.loads(stats.read_bytes())  # control: the source itself would have run the trap
    assert marker.read_text() == "ran"


def resumed_copy(checkpointed: Path, tmp_path: Path) -> Path:
    copy = tmp_path / "elsewhere" / checkpointed.name
    shutil.copytree(checkpointed, copy)
    return copy


def test_resume_runs_no_code_from_the_run_folder(checkpointed, tmp_path):
    run = resumed_copy(checkpointed, tmp_path)
    marker = tmp_path / "ran-resume"
    trap_zip(run / "checkpoints" / "rl_model_120_steps.zip", marker)
    trap_pickle(run / "checkpoints" / "rl_model_vecnormalize_120_steps.pkl", marker)
    buffer = run / "checkpoints" / "rl_model_replay_buffer_120_steps.npz"
    assert buffer.is_file() and not list(run.glob("checkpoints/*replay_buffer*.pkl"))
    resumed = run_script("train.py", "--resume", str(run), "-n", "240", cwd=tmp_path)
    assert resumed.returncode == 0, resumed.stderr
    assert "(from 120)" in resumed.stdout and not marker.exists()
    # The schedule came from the run's config (lin_7.3e-4), not a placeholder: its last
    # update before the checkpoint at 180 (every 8 steps: at 176 of 240) used 64/240 of it.
    import torch

    checkpoint = run / "checkpoints" / "rl_model_180_steps.zip"
    with zipfile.ZipFile(checkpoint) as archive, archive.open("actor.optimizer.pth") as saved:
        state = torch.load(saved, weights_only=True)
    assert state["param_groups"][0]["lr"] == pytest.approx(7.3e-4 * 64 / 240)
    # Control: the same folder, trusted, does unpickle the trapped files.
    run = resumed_copy(checkpointed, tmp_path / "again")
    trap_zip(run / "checkpoints" / "rl_model_120_steps.zip", marker)
    trusted = run_script(
        "train.py", "--resume", str(run), "-n", "180", "--trust-pickle", cwd=tmp_path
    )
    assert trusted.returncode == 0, trusted.stderr
    assert marker.read_text() == "ran"


def test_resume_refuses_a_pickled_replay_buffer_unless_trusted(checkpointed, tmp_path):
    from stable_baselines3.common.buffers import NStepReplayBuffer, ReplayBuffer

    from minitaur_env.training.replay_buffer import MirroredReplayBuffer, load_replay_buffer

    run = resumed_copy(checkpointed, tmp_path)
    marker = tmp_path / "ran-buffer"
    for steps in (60, 120):  # as versions before 0.3 saved them: SB3's pickle
        arrays = run / "checkpoints" / f"rl_model_replay_buffer_{steps}_steps.npz"
        kind = str(np.load(arrays)["kind"])
        kinds = {
            "ReplayBuffer": ReplayBuffer,
            "NStepReplayBuffer": NStepReplayBuffer,
            "MirroredReplayBuffer": MirroredReplayBuffer,  # the default SAC entry
        }
        buffer = kinds[kind](5000, *spaces_of_the_minitaur())
        load_replay_buffer(buffer, arrays)
        pickled = arrays.with_suffix(".pkl")
        pickled.write_bytes(pickle.dumps(buffer))
        trap_pickle(pickled, marker)
        arrays.unlink()
    refused = run_main(train.main, "--resume", str(run), "-n", "180", cwd=tmp_path)
    assert refused.returncode == 2 and not marker.exists()
    assert error_lines(refused)[-1] == (
        f"train.py: error: {run / 'checkpoints' / 'rl_model_replay_buffer_120_steps.pkl'}: "
        "loading this replay buffer would unpickle it, and a pickle can run code from the "
        "file; pass --trust-pickle if you trust where it came from"
    )
    trusted = run_script(
        "train.py", "--resume", str(run), "-n", "180", "--trust-pickle", cwd=tmp_path
    )
    assert trusted.returncode == 0, trusted.stderr
    assert marker.read_text() == "ran" and "(from 120)" in trusted.stdout


def spaces_of_the_minitaur():
    import gymnasium as gym

    import minitaur_env  # noqa: F401

    env = gym.make("MinitaurBulletEnv-v0")
    try:
        return env.observation_space, env.action_space
    finally:
        env.close()


def test_a_replay_buffer_round_trips_as_arrays_and_a_mismatch_is_refused(tmp_path):
    from gymnasium import spaces
    from stable_baselines3.common.buffers import ReplayBuffer

    from minitaur_env.training.replay_buffer import load_replay_buffer, save_replay_buffer

    obs, act = spaces.Box(-1, 1, (3,), np.float32), spaces.Box(-1, 1, (2,), np.float32)
    buffer = ReplayBuffer(7, obs, act)
    rng = np.random.default_rng(0)
    for _ in range(9):  # wraps around: full, position 2
        o = rng.normal(size=(1, 3)).astype(np.float32)
        buffer.add(o, o + 1, rng.normal(size=(1, 2)), rng.normal(size=1), np.array([False]), [{}])
    save_replay_buffer(buffer, tmp_path / "buffer.npz")
    fresh = ReplayBuffer(7, obs, act)
    load_replay_buffer(fresh, tmp_path / "buffer.npz")
    assert (fresh.pos, fresh.full) == (2, True)
    for name in ("observations", "next_observations", "actions", "rewards", "dones"):
        np.testing.assert_array_equal(getattr(fresh, name), getattr(buffer, name))
    other = ReplayBuffer(7, spaces.Box(-1, 1, (4,), np.float32), act)
    with pytest.raises(UsageError, match=r"observations is float32\[7, 1, 3\], the run's"):
        load_replay_buffer(other, tmp_path / "buffer.npz")
    assert other.pos == 0 and not other.observations.any()  # left as it was
    # An array of objects would need a pickle to read: refused, not unpickled.
    np.savez(tmp_path / "objects.npz", format=np.array([Trap(tmp_path / "m", "0")], dtype=object))
    with pytest.raises(UsageError, match="not a readable replay buffer"):
        load_replay_buffer(fresh, tmp_path / "objects.npz")
    assert not (tmp_path / "m").exists()


def valid_statistics() -> dict:
    from minitaur_env.training.safe_load import normalizer_content

    class Stats:  # what normalizer_content reads from a VecNormalize
        def __init__(self, shape):
            self.mean, self.var, self.count = np.zeros(shape), np.ones(shape), 10.0

    class Normalizer:
        norm_obs, norm_reward, clip_obs, clip_reward, gamma, epsilon = (
            True,
            True,
            10.0,
            10.0,
            0.99,
            1e-8,
        )
        obs_rms, ret_rms = Stats((28,)), Stats(())

    return normalizer_content(Normalizer())


@pytest.mark.parametrize(
    ("change", "problem"),
    [
        (lambda c: c["obs_rms"].update(mean=[0.0] * 27), "mean has shape (27,) but var (28,)"),
        (lambda c: c["obs_rms"]["var"].__setitem__(3, -1.0), "var has negative entries (-1)"),
        (lambda c: c["obs_rms"]["mean"].__setitem__(0, float("nan")), "must be finite"),
        (lambda c: c["ret_rms"].update(count=0.0), "ret_rms: count 0.0"),
        (lambda c: c["obs_rms"].pop("count"), "needs mean, var and count"),
        (lambda c: c["obs_rms"].update(var="ones"), "mean and var must be numbers"),
        (lambda c: c.update(epsilon=-1e-8), "epsilon -1e-08"),
    ],
)
def test_statistics_that_would_normalize_wrongly_are_refused_in_one_line(tmp_path, change, problem):
    from minitaur_env.training.safe_load import read_normalizer_json

    path = tmp_path / "vecnormalize.json"
    content = valid_statistics()
    path.write_text(json.dumps(content))
    read_normalizer_json(path)  # control: as written, they load
    change(content)
    path.write_text(json.dumps(content))
    with pytest.raises(UsageError) as refused:
        read_normalizer_json(path)
    assert problem in str(refused.value) and "\n" not in str(refused.value)


def test_statistics_of_another_observation_shape_are_refused_at_load_and_resume(
    checkpointed, run, tmp_path
):
    short = valid_statistics()
    short["obs_rms"].update(mean=[0.0] * 27, var=[1.0] * 27)
    model = run / "MinitaurBulletEnv-v0.zip"
    with zipfile.ZipFile(model) as source:
        members = {n: source.read(n) for n in source.namelist()}
    members[EMBEDDED_STATISTICS] = json.dumps(short).encode()
    with zipfile.ZipFile(model, "w") as target:
        for name, data in members.items():
            target.writestr(name, data)
    played = evaluate("--model", str(model), cwd=tmp_path)
    assert error_lines(played) == [
        f"evaluate.py: error: {model}: its VecNormalize statistics are for observations of "
        "shape (27,), the model's are (28,)"
    ], played.stderr
    resumable = resumed_copy(checkpointed, tmp_path)
    statistics = resumable / "checkpoints" / "rl_model_vecnormalize_120_steps.json"
    statistics.write_text(json.dumps(short))
    resumed = run_main(train.main, "--resume", str(resumable), "-n", "240", cwd=tmp_path)
    assert resumed.returncode == 2 and error_lines(resumed) == [
        f"train.py: error: {statistics}: its VecNormalize statistics for obs_rms have shape "
        "(27,), the env's are (28,)"
    ], resumed.stderr


def test_an_sbx_zip_loads_from_its_msgpack_state_with_nothing_unpickled(tmp_path):
    sbx = needs("sbx")
    import gymnasium as gym
    import jax

    from minitaur_env.training.checkpoints import save_model
    from minitaur_env.training.run_folder import EMBEDDED_JAX_STATE
    from minitaur_env.training.safe_load import _jax_state, load_sb3_model

    def trained(net_arch: list[int], path: Path):
        model = sbx.SAC(
            "MlpPolicy",
            gym.make("Pendulum-v1"),
            learning_starts=20,
            seed=3,
            policy_kwargs={"net_arch": net_arch},
        )
        model.learn(60)  # 40 updates: weights, optimizer moments and targets all moved
        save_model(model, path)
        return model

    model = tmp_path / "sac.zip"
    original = trained([16], model)
    marker = tmp_path / "ran-sbx"
    for key in ("policy", "ent_coef_state"):  # what SBX pickles its networks' state in
        trap_zip(model, marker, key=key)
    loaded = load_sb3_model(sbx.SAC, model)
    assert not marker.exists()
    saved, restored = _jax_state(original), _jax_state(loaded)
    assert set(saved) == set(restored) >= {"policy.actor_state", "policy.qf_state", "model.key"}
    for name in saved:  # values, targets, optimizer state and keys, leaf for leaf
        for mine, theirs in zip(
            jax.tree_util.tree_leaves(saved[name]),
            jax.tree_util.tree_leaves(restored[name]),
            strict=True,
        ):
            np.testing.assert_array_equal(np.asarray(mine), np.asarray(theirs))
    obs = np.random.default_rng(0).normal(size=(8, 3)).astype(np.float32)
    np.testing.assert_array_equal(
        loaded.predict(obs, deterministic=True)[0], original.predict(obs, deterministic=True)[0]
    )
    fresh = sbx.SAC("MlpPolicy", gym.make("Pendulum-v1"), seed=3, policy_kwargs={"net_arch": [16]})
    assert not np.allclose(  # control: the restored weights are not what a build gives
        fresh.predict(obs, deterministic=True)[0], loaded.predict(obs, deterministic=True)[0]
    )

    # Another network's state: refused in one line, not loaded half-way.
    other = tmp_path / "wider.zip"
    trained([32], other)
    with zipfile.ZipFile(other) as archive:
        wider_state = archive.read(EMBEDDED_JAX_STATE)
    members = {}
    with zipfile.ZipFile(model) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    members[EMBEDDED_JAX_STATE] = wider_state
    with zipfile.ZipFile(model, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)
    with pytest.raises(UsageError, match="has arrays of other shapes than the model's"):
        load_sb3_model(sbx.SAC, model)
    # A state left out would leave a freshly built critic in its place: refused too.
    from flax import serialization

    partial = serialization.msgpack_restore(members.pop(EMBEDDED_JAX_STATE))
    del partial["policy.qf_state"]
    with zipfile.ZipFile(model, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)
        archive.writestr(EMBEDDED_JAX_STATE, serialization.msgpack_serialize(partial))
    with pytest.raises(UsageError, match=r"its JAX state holds .* a SAC here"):
        load_sb3_model(sbx.SAC, model)
    # Without the member (SBX's own save) the flax state is only a pickle: the flag decides.
    with zipfile.ZipFile(model, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)
    with pytest.raises(UntrustedPickle, match="an SBX model saved without its JAX state"):
        load_sb3_model(sbx.SAC, model)
    assert not marker.exists()
