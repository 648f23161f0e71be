"""Finding, loading and judging a trained policy (used by evaluate.py and benchmarks).

Importing it needs neither torch nor SB3: an exported ``.onnx`` policy plays with
onnxruntime alone; SB3 is imported when a model zip is loaded.
"""

from __future__ import annotations

import dataclasses
import pickle
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np

from minitaur_env.onnx_policy import OnnxPolicy
from minitaur_env.realism import RealismProbe
from minitaur_env.training import ALGORITHM_NAMES, UsageError, env_name, missing_dependency
from minitaur_env.training.files import read_yaml
from minitaur_env.training.run_folder import PROVENANCE_FILE, RunFolder

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

    from minitaur_env.training.safe_load import ObservationNormalizer

REWARD_TERMS = ("reward_forward", "reward_energy", "reward_drift", "reward_shake")
# The shipped policies live in the repository, not in the wheel: the checkout this package
# was installed from (pip install -e), else a pretrained/ in the working directory.
PRETRAINED_DIR = Path(__file__).resolve().parents[2] / "pretrained"
NO_MODEL_HINT = (
    "no model given, and no shipped policy (pretrained/) or run (logs/) is here: pass "
    "--model MODEL.zip, train one with `minitaur train`, or run from a clone of the "
    "minitaur-env repository, whose pretrained/ folder holds the shipped policies"
)


@dataclasses.dataclass
class LoadedPolicy:
    """A model, the observation statistics it was trained with, and where it came from."""

    model: BaseAlgorithm
    algo: str
    backend: str
    path: Path
    env_id: str | None
    env_kwargs: dict[str, Any]
    normalizer: ObservationNormalizer | None
    # A zip alone: no statistics in it, no config.yml beside it to say it was trained
    # without them. It plays raw observations, and evaluate.py says so.
    normalization_unknown: bool = False

    def act(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        if self.normalizer is not None:
            obs = self.normalizer.normalize_obs(obs)
        action, _ = self.model.predict(obs, deterministic=deterministic)
        return action

    def check_spaces(self, observation_space: gym.Space, action_space: gym.Space) -> None:
        model = self.model
        if model.observation_space.shape != observation_space.shape:
            raise UsageError(
                f"{self.path.name} expects observations of shape "
                f"{model.observation_space.shape}, the env gives {observation_space.shape}"
            )
        if model.action_space != action_space:
            raise UsageError(
                f"{self.path.name} acts in {model.action_space}, the env needs {action_space}"
            )


def _env_kwargs_of(model_path: Path, config: dict[str, Any]) -> dict[str, Any]:
    """The run's env kwargs; for a zip without a run's config (a Hub folder), those of the
    zoo's ``env_kwargs.yml`` beside it, so a policy that sees three observations gets them."""
    if "env_kwargs" in config:
        return dict(config["env_kwargs"] or {})
    beside = model_path.parent / "env_kwargs.yml"
    kwargs = read_yaml(beside, "env kwargs") if beside.is_file() else {}
    if not isinstance(kwargs, dict):
        raise UsageError(f"{beside} does not hold env kwargs (a mapping)")
    return kwargs


def load_policy(
    model_path: str | Path,
    algo: str | None = None,
    device: str = "auto",
    trust_pickle: bool = False,
) -> LoadedPolicy | OnnxPolicy:
    """A model zip with its VecNormalize statistics, or an exported ``.onnx`` policy.

    Runs no code from the files unless ``trust_pickle`` (see ``safe_load``).
    """
    model_path = Path(model_path)
    if model_path.suffix == ".onnx":
        policy = OnnxPolicy(model_path)
        if algo is not None and algo != policy.algo:
            raise UsageError(f"{model_path} holds a {policy.algo} policy, not {algo}")
        return policy
    if not model_path.is_file():
        raise UsageError(f"model file not found: {model_path}")
    try:
        from minitaur_env.training.algorithms import algorithm_class, infer_algo
        from minitaur_env.training.safe_load import check_statistics_fit, load_sb3_model
    except ModuleNotFoundError as error:
        exported = RunFolder(model_path.parent).onnx_policy
        alternative = (
            f"or play its ONNX export without them: --model {exported}"
            if exported.is_file()
            else "or export it where they are (python -m minitaur_env.onnx) and play the .onnx"
        )
        needs = missing_dependency("a model zip", error).split(": error: ", 1)[1]
        raise UsageError(f"{needs}; {alternative}") from error
    run = RunFolder.of_model(model_path)
    config = run.settings()
    try:
        inferred_algo, backend = infer_algo(model_path)
    except UsageError:
        if algo is None:
            raise
        inferred_algo, backend = algo, config.get("backend", "sb3")
    if algo is not None and algo != inferred_algo:
        raise UsageError(f"{model_path} holds a {inferred_algo} model, not {algo}; drop --algo")
    algo = inferred_algo
    backend = config.get("backend", backend)
    cls = algorithm_class(algo, backend)
    try:
        model = load_sb3_model(cls, model_path, trust_pickle, device=device)
    except (zipfile.BadZipFile, ValueError, KeyError, EOFError, pickle.PickleError) as error:
        raise UsageError(f"cannot load {model_path} as a {algo} model: {error}") from error
    normalizer = _normalizer_of(model_path, run, config, trust_pickle)
    if normalizer is not None:
        check_statistics_fit(normalizer, model.observation_space.shape, model_path)
    return LoadedPolicy(
        model=model,
        algo=algo,
        backend=backend,
        path=model_path,
        env_id=config.get("env"),
        env_kwargs=_env_kwargs_of(model_path, config),
        normalizer=normalizer,
        normalization_unknown=normalizer is None and not config,
    )


def playing_kwargs(policy: LoadedPolicy | OnnxPolicy, overrides: dict[str, Any]) -> dict[str, Any]:
    """The env kwargs a policy is judged with: those it was trained with, on the registered
    episode length whatever the training run used, updated by ``overrides``."""
    kwargs = {k: v for k, v in policy.env_kwargs.items() if k != "max_episode_steps"}
    return {**kwargs, **overrides}


def _normalizer_of(
    model_path: Path, run: RunFolder, config: dict[str, Any], trust_pickle: bool
) -> ObservationNormalizer | None:
    """The statistics inside the zip, else those saved beside it; None only where the run
    did not normalize: playing a normalized model without its statistics would be a silent
    wrong answer."""
    from minitaur_env.training.safe_load import (
        embedded_statistics,
        frozen_normalizer,
        observation_normalizer,
    )

    content = embedded_statistics(model_path)
    if content is not None:
        return frozen_normalizer(content)
    stats = run.vecnormalize_for(model_path)
    if stats is not None:
        return observation_normalizer(stats, trust_pickle)
    if config.get("normalize"):
        raise UsageError(
            f"{model_path} was trained with VecNormalize ({run.config} says normalize: "
            f"{config['normalize']}) but its statistics are neither in the zip nor beside it"
        )
    return None


def pretrained_models(folder: Path | None = None) -> list[tuple[float, Path]]:
    """(eval mean return, model zip) of the shipped policies, best first.

    Each lives in a zoo-style run folder, ``pretrained/<algo>/<env>_<N>/``, whose
    ``<env>.zip`` is the shipped model and ``provenance.yml`` says how it was made.
    """
    folder = PRETRAINED_DIR if folder is None else folder
    found = []
    for provenance in folder.glob(f"*/*/{PROVENANCE_FILE}"):
        run = RunFolder(provenance.parent)
        info = read_yaml(provenance) or {}
        if run.zoo_model.is_file():
            found.append((float(info.get("eval_mean_return", -np.inf)), run.zoo_model))
    return sorted(found, key=lambda item: item[0], reverse=True)


def find_model(
    log_folder: str | None,
    algo: str | None,
    env_id: str | None,
    exp_id: int = 0,
    load_best: bool = False,
    load_checkpoint: int | None = None,
    load_last_checkpoint: bool = False,
) -> Path:
    """The model file a user means, rl-baselines3-zoo style.

    With no log folder: the best shipped policy, else the best model of the most
    recent run under ``logs/``.
    """
    implicit = log_folder is None
    if implicit:
        shipped = pretrained_models() or pretrained_models(Path("pretrained"))
        if shipped and not (algo or env_id or load_checkpoint or load_last_checkpoint):
            return shipped[0][1]
        log_folder = "logs"
        load_best = load_best or not (load_checkpoint or load_last_checkpoint)
    root = Path(log_folder)
    runs = []
    for algo_name in [algo] if algo else list(ALGORITHM_NAMES):
        if env_id:
            runs += [run.path for run in RunFolder.all(root, algo_name, env_id)]
        elif (root / algo_name).is_dir():
            runs += [run.path for run in RunFolder.found_under(root / algo_name, "*")]
    if not runs:
        if implicit and not (algo or env_id):
            raise UsageError(NO_MODEL_HINT)
        raise UsageError(
            f"no trained model found under {root}/ (train one with train.py, or pass --model)"
        )
    if exp_id:
        if not env_id:
            raise UsageError("--exp-id needs --env to name the run")
        name = f"{env_name(env_id or '')}_{exp_id}"
        matches = [r for r in runs if r.name == name]
        if not matches:
            raise UsageError(f"no run {name} under {root}/{algo or '*'}/")
        run = matches[0]
    else:
        run = max(runs, key=lambda r: RunFolder(r).config.stat().st_mtime)
    if load_checkpoint is not None:
        path = RunFolder(run).checkpoint(load_checkpoint)
    elif load_last_checkpoint:
        # The newest whole one: a kill (in versions that wrote in place) could tear the last.
        found = [p for _, p in RunFolder(run).checkpoints() if _whole_zip(p)]
        if not found:
            raise UsageError(f"{run} has no readable checkpoint")
        path = found[0]
    elif load_best:
        path = RunFolder(run).best_model
    else:
        path = RunFolder(run).final_model
    if not path.is_file():
        raise UsageError(f"model file not found: {path}")
    return path


def _whole_zip(path: Path) -> bool:
    try:
        with zipfile.ZipFile(path) as archive:
            return "data" in archive.namelist() and archive.testzip() is None
    except (zipfile.BadZipFile, OSError):
        return False


def run_episodes(
    policy: LoadedPolicy | OnnxPolicy | Callable[[np.ndarray], np.ndarray],
    env: gym.Env,
    episodes: int,
    seed: int | None,
    deterministic: bool = True,
    from_reset: Callable[[dict[str, Any]], dict[str, float]] | None = None,
    max_steps: int | None = None,
) -> list[dict[str, float]]:
    """One record per episode: return, length, distance, speed, fall, reward terms, and
    under pushes the pushes begun. The one loop that plays episodes: evaluation, shipping,
    packaging, videos and the benchmarks all call it. ``policy`` is a loaded policy, or
    any function of the observation (a benchmark's zero action, a video's filming one).
    ``seed``: episode ``i`` resets with ``seed + i`` (None: unseeded). ``from_reset`` adds
    fields read from each reset's info (a benchmark's drawn dynamics); ``max_steps`` cuts
    episodes shorter than the env's own limit (a short video)."""
    if hasattr(policy, "act"):  # a LoadedPolicy, an OnnxPolicy or one like them
        policy.check_spaces(env.observation_space, env.action_space)
        loaded = policy

        def policy(obs: np.ndarray) -> np.ndarray:
            return loaded.act(obs, deterministic=deterministic)

    records = []
    for episode in range(episodes):
        obs, info = env.reset(seed=None if seed is None else seed + episode)
        drawn = from_reset(info) if from_reset is not None else {}
        # Read after the reset: a randomized control step is drawn per episode.
        dt = float(getattr(env.unwrapped, "dt", 0.0) or 0.0)
        start = np.asarray(info.get("base_position", np.zeros(3)), dtype=float)
        totals = dict.fromkeys(REWARD_TERMS, 0.0)
        limits = {"at_torque_limit": 0, "at_velocity_limit": 0}
        slips: list[float] = []
        actions_at_limit = 0.0
        episode_return, length, pushes, pushing = 0.0, 0, 0, False
        terminated = truncated = False
        while not (terminated or truncated or length == max_steps):
            obs, reward, terminated, truncated, info = env.step(policy(obs))
            episode_return += float(reward)
            length += 1
            if "push_force" in info:  # count a push when it begins
                pushed = bool(np.any(info["push_force"]))
                pushes += int(pushed and not pushing)
                pushing = pushed
            for term in REWARD_TERMS:
                totals[term] += float(info.get(term, 0.0))
            if "foot_slip" in info:  # a RealismProbe (play(..., realism=True))
                limits["at_torque_limit"] += info["motors_at_torque_limit"] > 0
                limits["at_velocity_limit"] += info["motors_at_velocity_limit"] > 0
                if not np.isnan(info["foot_slip"]):
                    slips.append(info["foot_slip"])
                actions_at_limit += info["actions_at_limit"]
        record = {"return": episode_return, "length": float(length), "fell": float(terminated)}
        record.update(drawn)
        if "push_force" in info:
            record["pushes"] = float(pushes)
        if "base_position" in info:
            distance = float(np.asarray(info["base_position"])[0] - start[0])
            record["distance"] = distance
            record["speed"] = distance / (length * dt) if dt else float("nan")
            record.update(totals)
        if "foot_slip" in info:
            # Shares of the episode's steps with at least one motor at the limit.
            record.update({key: count / length for key, count in limits.items()})
            record["foot_slip"] = float(np.mean(slips)) if slips else float("nan")
            record["actions_at_limit"] = actions_at_limit / length
        records.append(record)
    return records


def play(
    policy: LoadedPolicy | OnnxPolicy,
    env_id: str,
    env_kwargs: dict[str, Any],
    episodes: int,
    seed: int,
    deterministic: bool = True,
    realism: bool = False,
) -> list[dict[str, float]]:
    """:func:`run_episodes` in a fresh env of ``env_id``, closed afterwards.

    ``realism``: also the shares of steps with a motor at its torque or velocity limit,
    the foot slip and the share of actions at their range's ends
    (:mod:`minitaur_env.realism`).
    """
    from minitaur_env.training.single_env import make_env

    env = make_env(env_id, env_kwargs)
    if realism:
        try:
            env = RealismProbe(env)
        except ValueError as error:
            env.close()
            raise UsageError(f"--realism on {env_id}: {error}") from error
    try:
        return run_episodes(policy, env, episodes, seed, deterministic)
    finally:
        env.close()


def summarize(records: list[dict[str, float]]) -> dict[str, dict[str, float]]:
    """mean, std, min, max of every statistic; ``fell`` also as a count."""
    summary = {}
    for key in records[0]:
        values = np.array([r[key] for r in records])
        summary[key] = {
            "mean": float(values.mean()),
            "std": float(values.std()),
            "min": float(values.min()),
            "max": float(values.max()),
        }
    summary["fell"]["count"] = float(sum(r["fell"] for r in records))
    return summary


LABELS = {
    "return": "return",
    "length": "episode length (steps)",
    "distance": "forward distance (m)",
    "speed": "average forward speed (m/s)",
    "reward_forward": "reward: forward",
    "reward_energy": "reward: energy",
    "reward_drift": "reward: drift",
    "reward_shake": "reward: shake",
    "at_torque_limit": "steps at a torque limit",
    "at_velocity_limit": "steps at a velocity limit",
    "foot_slip": "foot slip in contact (m/s)",
    "actions_at_limit": "actions at a range's end",
}


def format_table(summary: dict[str, dict[str, float]], episodes: int) -> str:
    rows = [f"{'statistic':<30}{'mean':>10}{'std':>10}{'min':>10}{'max':>10}"]
    for key, label in LABELS.items():
        if key in summary:
            s = summary[key]
            rows.append(
                f"{label:<30}{s['mean']:>10.3f}{s['std']:>10.3f}{s['min']:>10.3f}{s['max']:>10.3f}"
            )
    rows.append(f"{'falls':<30}{int(summary['fell']['count']):>10d} of {episodes}")
    return "\n".join(rows)
