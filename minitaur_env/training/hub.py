"""A trained agent as a Hugging Face Hub model folder, in the layout of the zoo's push_to_hub.

Written offline: the model evaluated on unseen seeds, its deterministic actor as
``policy.onnx`` (normalization folded in; plays with onnxruntime alone), a replay video
and a model card whose ``model-index`` the Hub reads (huggingface_hub's
``metadata_eval_result``). Pushing is the user's step, e.g. ``huggingface-cli upload
<user>/<folder name> <folder>``.
"""

from __future__ import annotations

import json
import shutil
from datetime import datetime
from pathlib import Path
from pprint import pformat
from typing import Any

import yaml

from minitaur_env.gait import has_gait_prior
from minitaur_env.training import UsageError, env_name
from minitaur_env.training.evaluation import (
    LoadedPolicy,
    load_policy,
    play,
    playing_kwargs,
    summarize,
)
from minitaur_env.training.files import (
    ensure_writable,
    read_yaml,
    refuse_to_replace,
    replaced_folder,
)
from minitaur_env.training.run_folder import (
    HUB_VECNORMALIZE,
    ONNX_POLICY,
    RunFolder,
    zoo_hyperparams,
)
from minitaur_env.training.safe_load import copy_statistics
from minitaur_env.training.seeds import REPORT_SEED


def package_for_hub(
    run_or_model: Path,
    out_dir: Path,
    env_id: str | None = None,
    episodes: int = 20,
    seed: int = REPORT_SEED,
    video_steps: int = 1000,
    trust_pickle: bool = False,
    replace: bool = False,
) -> Path:
    """Write ``<out_dir>/<algo>-<env>/`` and return it; an existing one only if ``replace``."""
    if episodes < 1:
        raise UsageError("--episodes must be >= 1: the model card reports an evaluation")
    if video_steps < 1:
        raise UsageError("--video-steps must be >= 1: the folder's replay.mp4 shows them")
    try:  # the model card needs it: say so before the evaluation and the video
        import huggingface_hub  # noqa: F401
    except ImportError as error:
        raise UsageError(
            "packaging needs huggingface_hub: pip install 'minitaur-env[zoo]'"
        ) from error
    ensure_writable(out_dir)  # before the episodes and the video
    policy = load_policy(RunFolder.model_of(run_or_model), trust_pickle=trust_pickle)
    env_id = env_id or policy.env_id
    if not env_id:
        raise UsageError(f"{policy.path}: no run config names its env; pass --env")
    name = f"{policy.algo}-{env_name(env_id)}"
    refuse_to_replace(out_dir / name, replace, "-o")
    # Written aside, swapped in whole: a failure leaves an earlier folder as it was.
    with replaced_folder(out_dir / name) as staged:
        _write_hub_folder(policy, env_id, staged, name, episodes, seed, video_steps, trust_pickle)
    return out_dir / name


def _write_hub_folder(
    policy: LoadedPolicy,
    env_id: str,
    folder: Path,
    name: str,
    episodes: int,
    seed: int,
    video_steps: int,
    trust_pickle: bool,
) -> None:
    from minitaur_env.training.envs import make_env
    from minitaur_env.training.onnx_export import export_onnx
    from minitaur_env.training.video import record_video

    shutil.copyfile(policy.path, folder / f"{name}.zip")
    stats = RunFolder.of_model(policy.path).vecnormalize_for(policy.path)
    if stats is not None:  # the pickle for the zoo and SB3, the JSON for safe loading
        copy_statistics(stats, folder / HUB_VECNORMALIZE, trust_pickle)
    config = RunFolder.of_model(policy.path).settings()
    (folder / "config.yml").write_text(yaml.safe_dump(zoo_hyperparams(config)))
    (folder / "env_kwargs.yml").write_text(yaml.safe_dump(policy.env_kwargs))
    export_onnx(policy.path, folder / ONNX_POLICY, trust_pickle)

    env_kwargs = playing_kwargs(policy, {})
    summary = summarize(play(policy, env_id, env_kwargs, episodes, seed))
    results = {
        "mean_reward": summary["return"]["mean"],
        "std_reward": summary["return"]["std"],
        "is_deterministic": True,
        "n_eval_episodes": episodes,
        "eval_datetime": datetime.now().isoformat(),
        "eval_seeds": f"{seed}..{seed + episodes - 1}",
        "falls": int(summary["fell"]["count"]),
    }
    (folder / "results.json").write_text(json.dumps(results, indent=2))

    # Small enough to commit beside the model: 480x360 at 25 fps.
    env = make_env(env_id, env_kwargs, render_mode="rgb_array", width=480, height=360)
    try:
        record_video(
            env, policy.act, folder / "replay.mp4", max_steps=video_steps, fps=25, seed=seed
        )
    finally:
        env.close()
    _model_card(policy, env_id, folder, config, results, env_kwargs).save(folder / "README.md")


def _commands(training: dict) -> list[str]:
    """A provenance's training commands: one ``command`` or a list of ``commands``."""
    found = training.get("commands") or [training.get("command")]
    return [
        command if command.startswith("python") else f"python {command}"
        for command in found
        if command
    ]


def training_command(model: Path) -> str:
    """The command that trained ``model``: a shipped agent's provenance, or its run's."""
    for folder in (model.parent, model.parent.parent):
        run = RunFolder(folder)
        if run.provenance.is_file():
            training = read_yaml(run.provenance).get("training") or {}
            stages = []  # a model trained on from another (train.py -i): oldest run first
            while training:
                stages.insert(0, _commands(training))
                training = training.get("started_from") or {}
            return "\n".join(command for stage in stages for command in stage)
        if run.command.is_file():
            return run.command.read_text().strip()
    return ""


def _model_card(
    policy: LoadedPolicy,
    env_id: str,
    folder: Path,
    config: dict[str, Any],
    results: dict[str, Any],
    env_kwargs: dict[str, Any],
) -> Any:
    from huggingface_hub import ModelCard, ModelCardData
    from huggingface_hub.repocard import metadata_eval_result

    algo_class = type(policy.model).__name__
    mean, std = results["mean_reward"], results["std_reward"]
    metadata = metadata_eval_result(
        model_pretty_name=algo_class,
        task_pretty_name="reinforcement-learning",
        task_id="reinforcement-learning",
        metrics_pretty_name="mean_reward",
        metrics_id="mean_reward",
        metrics_value=f"{mean:.2f} +/- {std:.2f}",
        dataset_pretty_name=env_id,
        dataset_id=env_id,
    )
    data = ModelCardData(
        library_name="stable-baselines3",
        tags=[
            env_id,
            "deep-reinforcement-learning",
            "reinforcement-learning",
            "stable-baselines3",
            "pybullet",
            "minitaur",
        ],
        **metadata,
    )
    module = type(policy.model).__module__.split(".")[0]  # stable_baselines3, sb3_contrib, sbx
    obs_dim = policy.model.observation_space.shape[0]
    name = folder.name
    if policy.normalizer is not None:
        normalization = (
            f'env = VecNormalize.load(load_from_hub("<user>/{name}", "vec_normalize.pkl"), env)\n'
            "env.training, env.norm_reward = False, False\n"
        )
    else:
        normalization = ""
    # The env the policy was trained on: its id and the keyword arguments of its run.
    arguments = "".join(f", {key}={value!r}" for key, value in (env_kwargs or {}).items())
    make = f'gym.make("{env_id}"{arguments})'
    actions = "actions in env units out"
    if has_gait_prior(env_id):
        actions += (
            f" (the gait prior's {policy.model.action_space.shape[0]} entries: step "
            f"`{make}` with them, whose `TrottingGait` runs the trotting generator)"
        )
    body = f"""
# **{algo_class}** agent playing **{env_id}**

A {algo_class} policy trained with [Stable-Baselines3](https://github.com/DLR-RM/stable-baselines3)
on minitaur-env, a gymnasium port of PyBullet's Minitaur. Evaluated on
{results["n_eval_episodes"]} deterministic episodes whose seeds ({results["eval_seeds"]})
training never used, with the env's raw classic return: **{mean:.2f} ± {std:.2f}**,
{results["falls"]} falls.

## Usage

```python
import gymnasium as gym
import minitaur_env  # registers {env_id}
from huggingface_sb3 import load_from_hub
from {module} import {algo_class}
from stable_baselines3.common.vec_env import DummyVecEnv, VecNormalize

model = {algo_class}.load(load_from_hub("<user>/{name}", "{name}.zip"))
env = DummyVecEnv([lambda: {make}])
{normalization}obs = env.reset()
for _ in range(1000):
    action, _ = model.predict(obs, deterministic=True)
    obs, reward, done, info = env.step(action)
```

With minitaur-env's scripts: `python evaluate.py --model {name}.zip --episodes 20`
(it finds `vec_normalize.pkl` beside the zip).

## Without torch: `{ONNX_POLICY}`

The deterministic actor with the observation normalization folded in: raw float32
observations in (`obs`, shape (batch, {obs_dim})), {actions}.
`pip install onnxruntime`, then:

```python
import onnxruntime as ort
session = ort.InferenceSession("{ONNX_POLICY}")
action = session.run(None, {{"obs": obs[None].astype("float32")}})[0][0]
```

or `python evaluate.py --model {ONNX_POLICY}` with `pip install 'minitaur-env[onnx]'`.

## Loading models safely

A pickle can run code when it is loaded. SB3's `load` unpickles entries of
`{name}.zip`, and `VecNormalize.load` unpickles `vec_normalize.pkl`: do that only with
files from a source you trust. minitaur-env's own loaders (`evaluate.py`,
`python -m minitaur_env.package`, `train.py -i`) unpickle nothing by default: they
rebuild the zip's entries from their readable copies, load its tensors weights-only and
read the statistics from `vec_normalize.json`; `--trust-pickle` is the opt-in for files
without such a copy. `{ONNX_POLICY}` holds weights and operators and runs no code of its own.

## Training

```
{training_command(policy.path)}
```

## Hyperparameters

```python
{pformat(zoo_hyperparams(config))}
```
"""
    return ModelCard(f"---\n{data.to_yaml()}\n---\n{body}")
