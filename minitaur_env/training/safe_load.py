"""Loading models and their statistics without running code from the files.

A pickle runs code when it is loaded; SB3's ``load`` cloudpickles entries of a zip's
``data``, and VecNormalize statistics and replay buffers are pickles. A model downloaded
from the Hub could therefore run anything when it is evaluated. By default:

- a model zip loads with ``custom_objects`` for every cloudpickled entry of its ``data``:
  the policy and replay-buffer classes resolved by name among SB3's, sb3-contrib's and
  this package's own, the spaces rebuilt from the readable fields beside the pickle,
  schedules and training-only state replaced; its tensors load weights-only (SB3 does);
  an entry this module does not know is refused;
- normalization statistics are read from their pickle-free JSON sibling
  (``vecnormalize.json`` beside ``vecnormalize.pkl``), which every run folder, shipped
  folder and Hub folder written here carries;
- an SBX zip's flax objects (its networks, train states and PRNG keys, which SBX only
  pickles) are built anew by the algorithm and their values restored from the msgpack
  member that every zip saved here carries (plain arrays; ``embed_jax_state``);
- a pickle with no such sibling, an unknown entry or an SBX zip without that member
  loads only with ``trust_pickle`` (``--trust-pickle``).

``--resume`` goes the same way: a checkpoint's zip through the safe loader with the
run's own hyperparameters, its statistics from their JSON and its replay buffer from
plain arrays (``replay_buffer.py``); older runs' pickled buffers and SBX checkpoints
saved before the msgpack member load only with ``--trust-pickle``.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import re
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces

from minitaur_env.training import UsageError
from minitaur_env.training.files import load_pickle
from minitaur_env.training.run_folder import (
    EMBEDDED_EVALUATION,
    EMBEDDED_JAX_STATE,
    EMBEDDED_STATISTICS,
    normalizer_json,
)

TRUST_FLAG = "--trust-pickle"
# Modules whose classes a zip may name as its policy or replay buffer.
TRUSTED_MODULES = (
    "stable_baselines3.",
    "sb3_contrib.",
    "minitaur_env.training.policies",
    "minitaur_env.training.replay_buffer",  # MirroredReplayBuffer
    "sbx.",
    "minitaur_env.training.sbx_policies",
)
# Entries of an SBX zip's data that are flax objects its ``_setup_model`` builds anew (the
# values come from EMBEDDED_JAX_STATE), and its PRNG key, which that member restores too.
SBX_REBUILT = ("policy", "actor", "qf", "vf", "ent_coef", "ent_coef_state")
SBX_KEY = "key"
_CLASS_NAME = re.compile(r"<function (\w+)\.__init__ at ")


class UntrustedPickle(UsageError):
    """Loading would unpickle a file the user has not vouched for."""

    def __init__(self, path: Path, what: str) -> None:
        super().__init__(
            f"{path}: loading {what} would unpickle it, and a pickle can run code from the "
            f"file; pass {TRUST_FLAG} if you trust where it came from"
        )


@dataclasses.dataclass
class ObservationNormalizer:
    """VecNormalize's observation statistics, as evaluation applies them (frozen)."""

    mean: np.ndarray
    var: np.ndarray
    epsilon: float
    clip_obs: float
    norm_obs: bool = True

    def normalize_obs(self, obs: np.ndarray) -> np.ndarray:
        """Exactly VecNormalize's ``normalize_obs``: float64 arithmetic, float32 result."""
        if not self.norm_obs:
            return obs
        scaled = (obs - self.mean) / np.sqrt(self.var + self.epsilon)
        return np.clip(scaled, -self.clip_obs, self.clip_obs).astype(np.float32)


def save_normalizer(normalizer: Any, pickle_path: Path) -> None:
    """VecNormalize's pickle (the zoo's scripts and ``--resume`` read it) and its JSON."""
    from minitaur_env.training.files import atomic_path

    with atomic_path(pickle_path) as temp:
        normalizer.save(str(temp))
    write_normalizer_json(normalizer, normalizer_json(pickle_path))


def normalizer_content(normalizer: Any) -> dict[str, Any]:
    """VecNormalize's settings and statistics as plain JSON data (no pickle)."""

    def stats(rms: Any) -> dict[str, Any]:
        return {
            "mean": np.asarray(rms.mean).tolist(),
            "var": np.asarray(rms.var).tolist(),
            "count": float(rms.count),
        }

    return {
        "format": "minitaur_env VecNormalize statistics 1",
        "norm_obs": bool(normalizer.norm_obs),
        "norm_reward": bool(normalizer.norm_reward),
        "clip_obs": float(normalizer.clip_obs),
        "clip_reward": float(normalizer.clip_reward),
        "gamma": float(normalizer.gamma),
        "epsilon": float(normalizer.epsilon),
        "obs_rms": stats(normalizer.obs_rms),
        "ret_rms": stats(normalizer.ret_rms),
    }


def write_normalizer_json(normalizer: Any, path: Path) -> None:
    from minitaur_env.training.files import atomic_path

    with atomic_path(path) as temp:
        temp.write_text(json.dumps(normalizer_content(normalizer)))


def embed_statistics(model_zip: Path, normalizer: Any) -> None:
    """Add the statistics to a model zip (SB3 ignores members it does not know), so that the
    model and the statistics it was trained with travel, and are replaced, as one file."""
    with zipfile.ZipFile(model_zip, "a") as archive:
        archive.writestr(EMBEDDED_STATISTICS, json.dumps(normalizer_content(normalizer)))


def embedded_statistics(model_zip: Path) -> dict[str, Any] | None:
    """The statistics embedded in a model zip, or None (a model trained without them, or
    saved by SB3 itself)."""
    try:
        with zipfile.ZipFile(model_zip) as archive:
            if EMBEDDED_STATISTICS not in archive.namelist():
                return None
            return _checked(json.loads(archive.read(EMBEDDED_STATISTICS)), model_zip)
    except (zipfile.BadZipFile, OSError, ValueError) as error:
        raise UsageError(f"{model_zip}: not a readable model file ({error})") from error


def embed_evaluation(model_zip: Path, steps: int, mean_reward: float) -> None:
    """Record in a best model's zip the evaluation that made it the best."""
    with zipfile.ZipFile(model_zip, "a") as archive:
        record = {"timesteps": int(steps), "mean_reward": float(mean_reward)}
        archive.writestr(EMBEDDED_EVALUATION, json.dumps(record))


def embedded_evaluation(model_zip: Path) -> tuple[int, float] | None:
    """(steps, mean return) of the evaluation recorded in a best model's zip, or None
    where the zip records none (saved before 0.3, or not a best model)."""
    try:
        with zipfile.ZipFile(model_zip) as archive:
            if EMBEDDED_EVALUATION not in archive.namelist():
                return None
            record = json.loads(archive.read(EMBEDDED_EVALUATION))
        return int(record["timesteps"]), float(record["mean_reward"])
    except (zipfile.BadZipFile, OSError, ValueError, KeyError, TypeError) as error:
        raise UsageError(f"{model_zip}: not a readable best model ({error})") from error


def embed_jax_state(model_zip: Path, model: Any) -> None:
    """Add an SBX model's train states and PRNG keys to its zip as msgpack (plain arrays),
    so that it loads without unpickling what SBX pickles in ``data``. SB3 models: nothing."""
    states = _jax_state(model)
    if states:
        from flax import serialization

        with zipfile.ZipFile(model_zip, "a") as archive:
            archive.writestr(EMBEDDED_JAX_STATE, serialization.msgpack_serialize(states))


def _jax_holders(model: Any) -> dict[str, Any]:
    return {"model": model, "policy": model.policy}


def _jax_state(model: Any) -> dict[str, Any]:
    """``{"policy.actor_state": state dict, "model.key": array, ...}``: every flax train
    state and JAX array an SBX model or its policy holds; {} for an SB3 model."""
    from minitaur_env.training.algorithms import saved_backend

    if saved_backend(type(model.policy).__module__) != "sbx":
        return {}
    import jax
    from flax import serialization
    from flax.training.train_state import TrainState

    return {
        f"{owner}.{name}": serialization.to_state_dict(value)
        for owner, holder in _jax_holders(model).items()
        for name, value in vars(holder).items()
        if isinstance(value, (TrainState, jax.Array))
    }


def has_jax_state(model_zip: Path) -> bool:
    try:
        with zipfile.ZipFile(model_zip) as archive:
            return EMBEDDED_JAX_STATE in archive.namelist()
    except (zipfile.BadZipFile, OSError):
        return False


def restore_jax_state(model: Any, model_zip: Path) -> None:
    """Put the zip's saved train states and keys into ``model`` (an SBX model freshly built
    with the zip's spaces and policy_kwargs). Refused in one line where they do not match
    the fresh model's, entry for entry and shape for shape: a state left out would leave
    freshly initialized weights in its place, silently."""
    import jax
    import jax.numpy as jnp
    from flax import serialization

    try:
        with zipfile.ZipFile(model_zip) as archive:
            saved = serialization.msgpack_restore(archive.read(EMBEDDED_JAX_STATE))
    except (zipfile.BadZipFile, KeyError, OSError, ValueError) as error:
        raise UsageError(f"{model_zip}: its JAX state is not readable ({error})") from error
    fresh = _jax_state(model)
    if not isinstance(saved, dict) or set(saved) != set(fresh):
        names = sorted(saved) if isinstance(saved, dict) else saved
        raise UsageError(
            f"{model_zip}: its JAX state holds {names}, a {type(model).__name__} here "
            f"{sorted(fresh)} (saved by another SBX version?)"
        )
    holders = _jax_holders(model)
    for name, state in saved.items():
        owner, attribute = name.split(".", 1)
        target = getattr(holders[owner], attribute)
        try:
            restored = serialization.from_state_dict(target, state)
        except (ValueError, KeyError, TypeError) as error:
            raise UsageError(f"{model_zip}: its {name} does not fit ({error})") from error
        mine, theirs = jax.tree_util.tree_leaves(target), jax.tree_util.tree_leaves(restored)
        shapes = [(np.shape(a), np.shape(b)) for a, b in zip(mine, theirs, strict=False)]
        if len(mine) != len(theirs) or any(a != b for a, b in shapes):
            raise UsageError(f"{model_zip}: its {name} has arrays of other shapes than the model's")
        setattr(holders[owner], attribute, jax.tree_util.tree_map(jnp.asarray, restored))


def copy_statistics(source: Path, target: Path, trust_pickle: bool = False) -> None:
    """Publish VecNormalize statistics as ``target`` (the pickle the zoo's scripts read)
    and its JSON sibling, both written from the statistics' values: the source pickle's
    bytes are never copied, so that a pickle that would run code is not handed on to
    whoever loads the published folder. A pickle without JSON is read only if trusted."""
    if normalizer_json(source).is_file():
        content = read_normalizer_json(normalizer_json(source))
    elif not trust_pickle:
        raise UntrustedPickle(
            source, f"the VecNormalize statistics (no {normalizer_json(source).name})"
        )
    else:
        content = normalizer_content(load_pickle(source))
    target.parent.mkdir(parents=True, exist_ok=True)
    save_normalizer(adapting_normalizer(content, source)(_SpacesOnly.vec_env(content)), target)


class _SpacesOnly:
    """A VecEnv stand-in with the statistics' observation shape: VecNormalize needs one to
    exist, and its pickle leaves it out."""

    @staticmethod
    def vec_env(content: dict[str, Any]) -> Any:
        import gymnasium as gym
        from stable_baselines3.common.vec_env import DummyVecEnv

        shape = np.asarray(content["obs_rms"]["mean"]).shape

        class Placeholder(gym.Env):
            observation_space = spaces.Box(-np.inf, np.inf, shape, np.float32)
            action_space = spaces.Box(-1.0, 1.0, (1,), np.float32)

        return DummyVecEnv([Placeholder])


def read_normalizer_json(path: Path) -> dict[str, Any]:
    try:
        content = json.loads(path.read_text())
    except (OSError, ValueError) as error:
        raise UsageError(f"{path}: not readable VecNormalize statistics ({error})") from error
    return _checked(content, path)


def _checked(content: Any, source: Path) -> dict[str, Any]:
    """The statistics as read, refused in one line where they could not be VecNormalize's:
    a mean and variance of different shapes, a negative or non-finite variance, a count
    or epsilon that is not positive (each would normalize silently wrong)."""
    missing = [
        k
        for k in ("norm_obs", "clip_obs", "epsilon", "obs_rms", "ret_rms")
        if not isinstance(content, dict) or k not in content
    ]
    if missing:
        raise UsageError(f"{source}: not VecNormalize statistics (no {', '.join(missing)})")
    for name in ("obs_rms", "ret_rms"):
        problem = _statistics_problem(content[name])
        if problem:
            raise UsageError(f"{source}: not VecNormalize statistics ({name}: {problem})")
    for name in ("epsilon", "clip_obs"):
        if not _positive(content[name]):
            raise UsageError(f"{source}: not VecNormalize statistics ({name} {content[name]!r})")
    return content


def _positive(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and 0 < value < np.inf


def _statistics_problem(rms: Any) -> str:
    """What is wrong with one running mean/variance, or ''."""
    if not isinstance(rms, dict) or not {"mean", "var", "count"} <= set(rms):
        return "needs mean, var and count"
    try:
        mean = np.asarray(rms["mean"], dtype=np.float64)
        var = np.asarray(rms["var"], dtype=np.float64)
    except (TypeError, ValueError):
        return "mean and var must be numbers"
    if mean.shape != var.shape:
        return f"mean has shape {mean.shape} but var {var.shape}"
    if not (np.isfinite(mean).all() and np.isfinite(var).all()):
        return "mean and var must be finite"
    if (var < 0).any():
        return f"var has negative entries ({var.min():g})"
    if not _positive(rms["count"]):
        return f"count {rms['count']!r}"
    return ""


def check_statistics_fit(normalizer: ObservationNormalizer, shape: tuple, source: Path) -> None:
    """Refuse statistics whose mean is not the shape of the observations they normalize."""
    if normalizer.norm_obs and normalizer.mean.shape != tuple(shape):
        raise UsageError(
            f"{source}: its VecNormalize statistics are for observations of shape "
            f"{normalizer.mean.shape}, the model's are {tuple(shape)}"
        )


def frozen_normalizer(content: dict[str, Any]) -> ObservationNormalizer:
    return ObservationNormalizer(
        mean=np.asarray(content["obs_rms"]["mean"], dtype=np.float64),
        var=np.asarray(content["obs_rms"]["var"], dtype=np.float64),
        epsilon=float(content["epsilon"]),
        clip_obs=float(content["clip_obs"]),
        norm_obs=bool(content["norm_obs"]),
    )


def observation_normalizer(pickle_path: Path, trust_pickle: bool = False) -> ObservationNormalizer:
    """The statistics saved as ``pickle_path``: from its JSON sibling, else (trusted) the
    pickle itself."""
    sibling = normalizer_json(pickle_path)
    if sibling.is_file():
        return frozen_normalizer(read_normalizer_json(sibling))
    if not trust_pickle:
        raise UntrustedPickle(pickle_path, f"the VecNormalize statistics (no {sibling.name})")
    loaded = load_pickle(pickle_path)
    return ObservationNormalizer(
        mean=np.asarray(loaded.obs_rms.mean, dtype=np.float64),
        var=np.asarray(loaded.obs_rms.var, dtype=np.float64),
        epsilon=float(loaded.epsilon),
        clip_obs=float(loaded.clip_obs),
        norm_obs=bool(loaded.norm_obs),
    )


def training_normalizer(pickle_path: Path, trust_pickle: bool = False) -> Callable[[Any], Any]:
    """A function that wraps a training VecEnv in a VecNormalize with the saved statistics
    (from the JSON sibling, else the trusted pickle), which goes on adapting from them."""

    sibling = normalizer_json(pickle_path)
    if not sibling.is_file():
        if not trust_pickle:
            raise UntrustedPickle(pickle_path, f"the VecNormalize statistics (no {sibling.name})")
        return attach(load_pickle(pickle_path))
    return adapting_normalizer(read_normalizer_json(sibling), sibling)


def adapting_normalizer(content: dict[str, Any], source: Path) -> Callable[[Any], Any]:
    """``training_normalizer`` from statistics already read from ``source`` (a JSON file,
    a model zip)."""
    from stable_baselines3.common.vec_env import VecNormalize

    def wrap(venv: Any) -> Any:
        normalizer = VecNormalize(
            venv,
            norm_obs=content["norm_obs"],
            norm_reward=content["norm_reward"],
            clip_obs=content["clip_obs"],
            clip_reward=content["clip_reward"],
            gamma=content["gamma"],
            epsilon=content["epsilon"],
        )
        for name in ("obs_rms", "ret_rms"):
            rms, saved = getattr(normalizer, name), content[name]
            if np.shape(saved["mean"]) != rms.mean.shape:
                raise UsageError(
                    f"{source}: its VecNormalize statistics for {name} have shape "
                    f"{np.shape(saved['mean'])}, the env's are {rms.mean.shape}"
                )
            rms.mean = np.asarray(saved["mean"], dtype=np.float64).reshape(rms.mean.shape)
            rms.var = np.asarray(saved["var"], dtype=np.float64).reshape(rms.var.shape)
            rms.count = float(saved["count"])
        return normalizer

    return wrap


def attach(normalizer: Any) -> Callable[[Any], Any]:
    """``training_normalizer``'s form for an unpickled VecNormalize."""

    def wrap(venv: Any) -> Any:
        normalizer.set_venv(venv)
        return normalizer

    return wrap


def _trusted_class(path: Path, key: str, entry: dict[str, Any]) -> type:
    module_name = str(entry.get("__module__", ""))
    match = _CLASS_NAME.match(str(entry.get("__init__", "")))
    if not match or not module_name.startswith(TRUSTED_MODULES):
        raise UntrustedPickle(path, f"its {key} ({module_name or 'an unnamed class'})")
    try:
        found = getattr(importlib.import_module(module_name), match.group(1))
    except (ImportError, AttributeError) as error:
        raise UsageError(
            f"{path}: its {key} {module_name}.{match.group(1)} is not installed here ({error})"
        ) from error
    return found


def _space(path: Path, key: str, entry: dict[str, Any]) -> spaces.Space:
    """A Box or Discrete from the readable fields SB3 writes beside the pickled space."""
    kind = str(entry.get(":type:", ""))
    try:
        if kind.endswith("spaces.discrete.Discrete'>"):
            return spaces.Discrete(int(entry["n"]), start=int(entry.get("start", 0)))
        if kind.endswith("spaces.box.Box'>"):
            stored = entry["_shape"]
            shape = tuple(
                int(n) for n in (json.loads(stored) if isinstance(stored, str) else stored)
            )
            dtype = np.dtype(entry["dtype"])

            def bound(text: str) -> np.ndarray:
                if "..." in text:  # numpy summarized a large array: the values are lost
                    raise ValueError("summarized bounds")
                values = text.replace("[", " ").replace("]", " ").split()
                return np.array(values, dtype=np.float64).astype(dtype).reshape(shape)

            return spaces.Box(bound(entry["low"]), bound(entry["high"]), shape, dtype)
    except (KeyError, ValueError, TypeError):
        pass
    raise UntrustedPickle(path, f"its {key} ({kind or 'an unknown space'})")


_CLASS_REPR = re.compile(r"^<class '([\w.]+)\.(\w+)'>$")
# Modules whose classes policy_kwargs may name (activations, optimizers).
TRUSTED_KWARG_MODULES = ("torch.nn.", "torch.optim.")


def _policy_kwargs(path: Path, entry: dict[str, Any]) -> dict[str, Any]:
    """policy_kwargs from the readable copy SB3 writes beside the pickle: plain values as
    they are, classes (``"<class 'torch.nn...Tanh'>"``) resolved among torch's own."""
    rebuilt: dict[str, Any] = {}
    for name, value in entry.items():
        if name.startswith(":"):
            continue
        match = _CLASS_REPR.match(value) if isinstance(value, str) else None
        if match and match.group(1).startswith(TRUSTED_KWARG_MODULES):
            module = importlib.import_module(match.group(1))
            rebuilt[name] = getattr(module, match.group(2))
        elif isinstance(value, str) and value.startswith("<"):
            raise UntrustedPickle(path, f"its policy_kwargs {name} ({value})")
        else:
            rebuilt[name] = value
    return rebuilt


def _constant_schedule(_: float) -> float:
    return 0.0


# Entries that only training reads: a run that trains from a model must set them itself.
TRAINING_ONLY = ("learning_rate", "clip_range", "clip_range_vf", "train_freq", "action_noise")


def safe_custom_objects(
    path: Path, spaces_from: Any = None, training_kwargs: dict[str, Any] | None = None
) -> dict[str, Any]:
    """``custom_objects`` for ``load`` that leave no cloudpickled entry of ``data`` to unpickle.

    ``spaces_from``: an env (or anything with the two spaces) whose spaces replace the
    saved ones after a shape check, where the caller plays or trains on that env.
    Schedules become a constant 0 and training-only state is dropped, which evaluation
    never reads; ``training_kwargs`` (the hyperparameters of a run that trains from the
    model) must then set every pickled ``TRAINING_ONLY`` entry, or it is refused rather
    than silently trained with a placeholder.
    """
    from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit

    from minitaur_env.training.algorithms import saved_backend

    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
    except (zipfile.BadZipFile, KeyError, ValueError, OSError) as error:
        raise UsageError(f"{path} is not a Stable-Baselines3 model file: {error}") from error
    sbx = saved_backend(str(data.get("policy_class", {}).get("__module__", ""))) == "sbx"
    if sbx and not has_jax_state(path):
        raise UntrustedPickle(path, "an SBX model saved without its JAX state")
    replaced: dict[str, Any] = {}
    for key, entry in data.items():
        if not (isinstance(entry, dict) and ":serialized:" in entry):
            continue
        if key in ("policy_class", "replay_buffer_class", "rollout_buffer_class"):
            replaced[key] = _trusted_class(path, key, entry)
        elif key in ("observation_space", "action_space"):
            replaced[key] = _space(path, key, entry)
        elif key in (
            "lr_schedule",
            "learning_rate",
            "clip_range",
            "clip_range_vf",
            "clip_range_schedule",  # SBX PPO's, made again from clip_range
        ):
            replaced[key] = _constant_schedule
        elif key == "policy_kwargs":
            replaced[key] = _policy_kwargs(path, entry)
        elif sbx and key in SBX_REBUILT:
            replaced[key] = None  # built anew, then restore_jax_state fills in the values
        elif sbx and key == SBX_KEY:
            import jax

            replaced[key] = jax.random.PRNGKey(0)  # a placeholder until restore_jax_state
        elif key == "target_entropy":  # TQC's numpy float: "auto", -dim(actions), below
            replaced[key] = None
        elif key == "train_freq":
            replaced[key] = TrainFreq(1, TrainFrequencyUnit.STEP)
        elif key in (
            "_last_obs",
            "_last_episode_starts",
            "_last_original_obs",
            "action_noise",
            "ep_info_buffer",
            "ep_success_buffer",
            "_last_lstm_states",
        ):
            replaced[key] = None
        else:
            raise UntrustedPickle(path, f"its data entry {key!r}")
        if training_kwargs is not None and key in TRAINING_ONLY and key not in training_kwargs:
            raise UsageError(
                f"{path}: its {key} is a pickle (loading it can run code from the file): set "
                f"it with --hyperparams {key}=..., or pass {TRUST_FLAG} to load it"
            )
    if "target_entropy" in replaced and "action_space" in replaced:
        action_dims = np.prod(replaced["action_space"].shape)
        replaced["target_entropy"] = float(-action_dims.astype(np.float32))
    if spaces_from is not None:
        for key in ("observation_space", "action_space"):
            mine = getattr(spaces_from, key)
            saved = replaced.get(key)
            if saved is not None and saved.shape != mine.shape:  # the caller names the env
                raise ValueError(f"the model's {key} is {saved}, the env's {mine}")
            replaced[key] = mine
    return replaced


def load_sb3_model(
    cls: type, path: Path, trust_pickle: bool = False, training: bool = False, **kwargs: Any
) -> Any:
    """``cls.load`` that runs no code from the zip unless ``trust_pickle``; ``training``:
    the caller trains on, with ``kwargs`` as its hyperparameters."""
    from minitaur_env.training.algorithms import load_model

    if trust_pickle:
        return load_model(cls, path, **kwargs)
    custom = safe_custom_objects(path, kwargs.get("env"), kwargs if training else None)
    kwargs["custom_objects"] = {**custom, **kwargs.get("custom_objects", {})}
    model = load_model(cls, path, **kwargs)
    if has_jax_state(path):
        restore_jax_state(model, path)
    return model
