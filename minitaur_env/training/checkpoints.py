"""What a run starts from and saves: checkpoints written only from finite weights and read
back only when every file loads, and a trained agent to go on from (``train.py -i``)."""

from __future__ import annotations

import inspect
import pickle
import sys
import traceback
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecNormalize, unwrap_vec_normalize

from minitaur_env.training import TrainingDiverged, UsageError
from minitaur_env.training.algorithms import OFF_POLICY, algorithm_class
from minitaur_env.training.config import ExperimentConfig
from minitaur_env.training.files import atomic_path, write_text
from minitaur_env.training.hyperparams import algorithm_kwargs
from minitaur_env.training.replay_buffer import load_replay_buffer, save_replay_buffer
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.runtime import ignoring_more_signals
from minitaur_env.training.safe_load import (
    TRAINING_ONLY,
    TRUST_FLAG,
    UntrustedPickle,
    adapting_normalizer,
    embed_jax_state,
    embed_statistics,
    embedded_statistics,
    load_sb3_model,
    save_normalizer,
    training_normalizer,
)
from minitaur_env.training.vec_env import EnvWorkerError

# What a kill -9 during a save leaves behind: a torn zip or pickle.
UNREADABLE = (ValueError, OSError, EOFError, KeyError, zipfile.BadZipFile, pickle.PickleError)


def check_weights(model: BaseAlgorithm) -> None:
    """Raise TrainingDiverged naming the first non-finite weight of the model's policy."""
    for name, finite in _weights_finite(model.policy):
        if not finite:
            raise TrainingDiverged(f"weight {name} became non-finite at step {model.num_timesteps}")


def weights_finite(model: BaseAlgorithm) -> bool:
    return all(finite for _, finite in _weights_finite(model.policy))


def save_model(model: BaseAlgorithm, path: Path) -> None:
    """The model zip, replaced atomically, with its VecNormalize statistics inside: a model
    and the statistics it acts with can never be out of step, wherever the zip goes. An SBX
    model's zip also carries its JAX state as plain arrays, to load without pickles."""
    normalizer = unwrap_vec_normalize(model.get_env()) if model.get_env() is not None else None
    with atomic_path(path) as temp:
        model.save(temp)
        if normalizer is not None:
            embed_statistics(temp, normalizer)
        embed_jax_state(temp, model)


def save_checked_checkpoint(model: BaseAlgorithm, run: RunFolder) -> Path:
    """Check the weights, then save replay buffer, VecNormalize and model at the model's step.

    A diverged model raises TrainingDiverged before anything is written, so the
    checkpoints on disk are always usable. Each file is replaced atomically and the model
    zip comes last: a checkpoint whose zip is there has its other files too.
    """
    check_weights(model)
    steps = model.num_timesteps
    run.checkpoint_dir.mkdir(parents=True, exist_ok=True)
    if isinstance(model, OffPolicyAlgorithm) and model.replay_buffer is not None:
        save_replay_buffer(model.replay_buffer, run.replay_buffer(steps))
    normalizer = unwrap_vec_normalize(model.get_env())
    if normalizer is not None:
        save_normalizer(normalizer, run.vecnormalize(steps))
    path = run.checkpoint(steps)
    save_model(model, path)
    run.prune_replay_buffers()
    return path


def load_newest_checkpoint(
    run: RunFolder,
    config: ExperimentConfig,
    *,
    trust_pickle: bool = False,
    log: Callable[..., Any] = print,
) -> tuple[BaseAlgorithm, Callable[[VecEnv], VecNormalize] | None, int]:
    """(model, VecNormalize to wrap the new env in, steps) of the newest complete
    checkpoint: its model, its statistics (if the run normalizes) and its replay buffer (if
    off-policy) all load. Torn or incomplete ones are skipped with a line that says so:
    going on with an empty buffer or without statistics would silently be another run.

    Nothing is unpickled unless ``trust_pickle``: the zip's entries go through the safe
    loader with the run's own hyperparameters, the statistics come from their JSON and the
    replay buffer from its arrays. A run folder is a file like any other; one from
    elsewhere could hold a pickle that runs code.
    """
    off_policy = config.algo in OFF_POLICY
    algorithm = algorithm_class(config.algo, config.backend)
    for steps, path in run.checkpoints():
        buffer = run.replay_buffer(steps)
        if off_policy and not buffer.is_file():
            if trust_pickle and run.pickled_replay_buffer(steps).is_file():
                buffer = run.pickled_replay_buffer(steps)
            elif run.pickled_replay_buffer(steps).is_file():
                raise UntrustedPickle(run.pickled_replay_buffer(steps), "this replay buffer")
            else:
                log(
                    f"skipping checkpoint {path.name}: its replay buffer is missing",
                    file=sys.stderr,
                )
                continue
        try:
            model = load_sb3_model(
                algorithm,
                path,
                trust_pickle,
                training=True,
                device=config.device,
                **resume_kwargs(config, algorithm),
            )
            normalizer = None
            if config.normalize:
                normalizer = training_normalizer(run.vecnormalize(steps), trust_pickle)
            if off_policy and buffer.suffix == ".npz":
                load_replay_buffer(model.replay_buffer, buffer)
            elif off_policy:
                model.load_replay_buffer(buffer)
            return model, normalizer, steps
        except UntrustedPickle:
            raise
        except (*UNREADABLE, UsageError) as error:
            log(f"skipping unreadable checkpoint {path.name}: {error}", file=sys.stderr)
    raise UsageError(
        f"no complete checkpoint (model{', statistics' if config.normalize else ''}"
        f"{', replay buffer' if off_policy else ''}) in {run.checkpoint_dir}"
    )


def resume_kwargs(config: ExperimentConfig, algorithm: type[BaseAlgorithm]) -> dict[str, Any]:
    """The hyperparameters a checkpoint is loaded with to train on: the run's own, and the
    algorithm's defaults for the training-only ones the run left unset, which the safe
    loader does not take from the zip's pickles."""
    kwargs = algorithm_kwargs(config.hyperparams)
    kwargs.pop("policy_kwargs", None)  # the saved network keeps its shape
    if kwargs.get("target_entropy") == "auto":
        # The zip holds the number "auto" resolved to; the model is loaded without an env,
        # so resolving "auto" again would read the action space of None.
        del kwargs["target_entropy"]
    defaults = inspect.signature(algorithm.__init__).parameters
    for key in TRAINING_ONLY:
        if key not in kwargs and key in defaults:
            kwargs[key] = defaults[key].default
    return kwargs


def load_trained_agent(
    config: ExperimentConfig, env: VecEnv, log: Callable[..., Any] = print
) -> BaseAlgorithm:
    """The model of ``config.trained_agent`` on this run's envs, with the run's
    hyperparameters (network shape aside) and its replay buffer where one lies beside
    it, as the zoo's ``--trained-agent`` does."""
    path = Path(config.trained_agent)
    kwargs = algorithm_kwargs(config.hyperparams)
    kwargs.pop("policy_kwargs", None)  # the saved network decides its own shape
    try:
        model = load_sb3_model(
            algorithm_class(config.algo, config.backend),
            path,
            config.trust_pickle,
            training=True,
            env=env,
            seed=config.seed,
            device=config.device,
            tensorboard_log=config.tensorboard_log,
            **kwargs,
        )
    except (ValueError, KeyError) as error:  # e.g. the spaces of another env
        message = " ".join(str(error).split())[:200]
        raise UsageError(f"--trained-agent {path} does not fit {config.env}: {message}") from error
    model.num_timesteps = 0  # -n counts this run's steps, as in the zoo
    buffer = RunFolder.replay_buffer_beside(path)
    if config.algo in OFF_POLICY and buffer.with_suffix(".npz").is_file():
        load_replay_buffer(model.replay_buffer, buffer.with_suffix(".npz"))
    elif config.algo in OFF_POLICY and buffer.is_file():
        if config.trust_pickle:
            model.load_replay_buffer(buffer)
        else:
            log(
                f"{buffer} is a pickle (it can run code): starting with an empty "
                f"replay buffer; pass {TRUST_FLAG} to load it"
            )
    return model


def trained_agent_normalizer(config: ExperimentConfig) -> Callable[[VecEnv], VecNormalize] | None:
    """The trained agent's VecNormalize statistics, to go on adapting from."""
    model = Path(config.trained_agent)
    embedded = embedded_statistics(model)
    path = None if embedded is not None else RunFolder.of_model(model).vecnormalize_for(model)
    found = embedded is not None or path is not None
    if found != bool(config.normalize):
        raise UsageError(
            f"--trained-agent {config.trained_agent}: the model was trained "
            f"{'with' if found else 'without'} VecNormalize statistics and this "
            f"run has normalize={config.normalize}; set --hyperparams normalize="
            f"{'true' if found else 'false'}"
        )
    if embedded is not None:
        return adapting_normalizer(embedded, model)
    if path is None:
        return None
    return training_normalizer(path, config.trust_pickle)


def _weights_finite(policy: Any) -> list[tuple[str, bool]]:
    """(name, all finite) per weight tensor of a torch (SB3) or JAX (SBX) policy."""
    # SBX policies are torch Modules too (SB3's BasePolicy), with their weights held in
    # flax train states (actor_state, qf_state, ...) instead of torch parameters.
    jax_states = {
        attribute: state.params
        for attribute, state in vars(policy).items()
        if getattr(state, "params", None) is not None
    }
    if not jax_states:
        with torch.no_grad():
            return [(n, bool(torch.isfinite(p).all())) for n, p in policy.named_parameters()]
    import jax

    found = []
    for attribute, params in jax_states.items():
        for path, leaf in jax.tree_util.tree_leaves_with_path(params):
            name = f"{attribute}{jax.tree_util.keystr(path)}"
            found.append((name, bool(np.isfinite(np.asarray(leaf)).all())))
    return found


def save_after_failure(
    model: BaseAlgorithm, run: RunFolder, error: Exception
) -> tuple[Path | None, str]:
    """After ``error`` stopped training: a checked checkpoint if one can still be written,
    the traceback in the run folder, and the one line that says what happened and how to
    go on."""
    said = " ".join(str(error).split())
    what = (said if isinstance(error, EnvWorkerError) else f"{type(error).__name__}: {said}")[:400]
    how = f"resume with --resume {run.path}"
    with ignoring_more_signals():
        try:
            checkpoint: Path | None = save_checked_checkpoint(model, run)
            kept = f"saved {checkpoint}"
        except (OSError, TrainingDiverged) as save_error:  # a full disk fails again
            checkpoint = None
            last = run.checkpoints()
            kept = f"no new checkpoint ({type(save_error).__name__}: {save_error})" + (
                f", last one {last[0][1]}" if last else ""
            )
            if not last:
                how = "no checkpoint to resume from: start the run again once that is fixed"
        try:
            write_text(run.failure_log, "".join(traceback.format_exception(error)))
            details = f"; details in {run.failure_log}"
        except OSError:
            details = ""
    return checkpoint, f"{what}; {kept} ({how}){details}"
