"""Callbacks SB3 lacks: checked checkpoints, a divergence guard, evaluations that continue
after a resume, VecNormalize saved with the best model, a policy-video recorder, a
decaying entropy target and growing pushes."""

from __future__ import annotations

import math
import os
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback, EvalCallback
from stable_baselines3.common.vec_env import unwrap_vec_normalize

from minitaur_env.training import TrainingDiverged
from minitaur_env.training.checkpoints import save_checked_checkpoint
from minitaur_env.training.config import ExperimentConfig
from minitaur_env.training.envs import make_env
from minitaur_env.training.hyperparams import (
    entropy_decay,
    hard_draws,
    n_steps_after,
    noise_color_until,
    push_curriculum,
)
from minitaur_env.training.run_folder import RunFolder
from minitaur_env.training.safe_load import (
    embed_evaluation,
    embed_jax_state,
    embed_statistics,
    embedded_evaluation,
    save_normalizer,
)
from minitaur_env.training.video import record_video


class DivergenceGuardCallback(BaseCallback):
    """Stop training at the first non-finite loss or action.

    Losses are read from the logger after every update. Weights are checked by
    :func:`save_checked_checkpoint` before every checkpoint is written.
    """

    def _on_step(self) -> bool:
        for key, value in self.logger.name_to_value.items():
            if key.startswith("train/") and not math.isfinite(float(value)):
                raise TrainingDiverged(f"{key} became {value} at step {self.num_timesteps}")
        actions = self.locals.get("actions")
        if actions is not None and not np.all(np.isfinite(actions)):
            raise TrainingDiverged(f"the policy produced a NaN action at step {self.num_timesteps}")
        return True


class _StepSchedule(BaseCallback):
    """A setting applied from the model's own step count before training and after
    every step, so a resumed run continues where it stopped."""

    def _init_callback(self) -> None:
        self._apply()

    def _on_step(self) -> bool:
        self._apply()
        return True

    def _apply(self) -> None:
        raise NotImplementedError


class TargetEntropyDecay(_StepSchedule):
    """SAC's entropy target, held at ``initial`` until step ``start``, then decayed
    linearly to ``final`` at step ``end``.

    Set from the model's own step count before every update, so a resumed run continues
    the decay where it stopped, as SB3's learning-rate schedules do.
    """

    def __init__(self, initial: float, final: float, start: int, end: int) -> None:
        super().__init__()
        self.initial, self.final = initial, final
        self.start, self.end = start, max(end, start + 1)

    def value(self, step: int) -> float:
        fraction = min(max((step - self.start) / (self.end - self.start), 0.0), 1.0)
        return self.initial + fraction * (self.final - self.initial)

    def _apply(self) -> None:
        self.model.target_entropy = self.value(self.model.num_timesteps)
        self.logger.record("train/target_entropy", self.model.target_entropy)


class PushCurriculum(_StepSchedule):
    """Pushes that grow with training: the training envs' push forces are scaled by
    ``start`` at step 0, rising linearly to full force at step ``full_at``.

    Only the training envs are scaled; evaluations push at full force, so they measure
    the task itself. Set from the model's own step count (when it has moved by a
    hundredth), so a resumed run continues where it stopped.
    """

    STEP = 0.01  # the smallest change worth a call to every env worker

    def __init__(self, start: float, full_at: int) -> None:
        super().__init__()
        self.start, self.full_at = start, max(full_at, 1)
        self.applied: float | None = None

    def value(self, step: int) -> float:
        return self.start + (1.0 - self.start) * min(step / self.full_at, 1.0)

    def _apply(self) -> None:
        scale = self.value(self.model.num_timesteps)
        applied = self.applied
        if applied is None or abs(scale - applied) >= self.STEP or scale == 1.0 != applied:
            self.training_env.env_method("set_push_scale", scale)
            self.applied = scale
        self.logger.record("train/push_scale", self.applied)


class WhiteNoiseFrom(_StepSchedule):
    """Colored exploring noise until step ``step``, SAC's own white noise from then on: the
    policy's ``noise_color`` is set to 0 there, and again before a run resumed past
    ``step`` trains (its zip's policy_kwargs still name the color it started with)."""

    def __init__(self, step: int) -> None:
        super().__init__()
        self.step = step

    def _apply(self) -> None:
        if self.model.num_timesteps >= self.step and self.model.policy.noise_color:
            self.model.policy.noise_color = 0.0
        self.logger.record("train/noise_color", float(self.model.policy.noise_color))


class HardDraws(BaseCallback):
    """Each group's training envs draw its realism fields from its narrower ranges
    (``MinitaurBulletEnv.narrow_realism``), set when training starts or resumes; the other
    training envs and the evaluations keep the env's own. SB3 resets the envs before the
    first callback, so each narrowed env's first episode after a start or resume is still
    drawn from the env's own ranges."""

    def __init__(self, groups: list[tuple[range, dict[str, Any]]]) -> None:
        super().__init__()
        self.groups = groups

    def _on_training_start(self) -> None:
        for envs, realism in self.groups:
            self.training_env.env_method("narrow_realism", realism, indices=envs)

    def _on_step(self) -> bool:
        return True


class ShorterReturnsFrom(_StepSchedule):
    """The replay buffer's n-step returns at ``n_steps`` from step ``step`` on: the
    buffer computes the returns when it samples, so every update from then on learns
    from the shorter ones; set again before a run resumed past ``step`` trains (its zip
    still names the n it started with)."""

    def __init__(self, step: int, n_steps: int) -> None:
        super().__init__()
        self.step, self.n_steps = step, n_steps

    def _apply(self) -> None:
        buffer = self.model.replay_buffer
        if self.model.num_timesteps >= self.step and buffer.n_steps != self.n_steps:
            buffer.n_steps = self.model.n_steps = self.n_steps
        self.logger.record("train/n_steps", float(buffer.n_steps))


def schedules(config: ExperimentConfig) -> list[BaseCallback]:
    """The callbacks that change a setting as training goes, from the config's entry."""
    callbacks: list[BaseCallback] = []
    steps = config.n_timesteps
    decay = entropy_decay(config.hyperparams, config.algo)
    if decay is not None:
        initial, final, start = decay
        callbacks.append(TargetEntropyDecay(initial, final, int(start * steps), steps))
    curriculum = push_curriculum(config.hyperparams, config.env_pushes)
    if curriculum is not None:
        start, full_at = curriculum
        callbacks.append(PushCurriculum(start, int(full_at * steps)))
    groups = hard_draws(config.hyperparams, config.n_envs)
    if groups is not None:
        callbacks.append(HardDraws(groups))
    until = noise_color_until(config.hyperparams)
    if until is not None:
        callbacks.append(WhiteNoiseFrom(int(until * steps)))
    shorter = n_steps_after(config.hyperparams)
    if shorter is not None:
        at, n_steps = shorter
        callbacks.append(ShorterReturnsFrom(int(at * steps), n_steps))
    return callbacks


class CheckpointEveryCallback(BaseCallback):
    """A checked checkpoint each time the step count passes a multiple of ``save_freq``.

    Counting the model's own steps (not this callback's calls) keeps checkpoints on
    the same multiples after a resume and whatever the number of envs.
    """

    def __init__(self, run: RunFolder, save_freq: int) -> None:
        super().__init__()
        self.run = run
        self.save_freq = save_freq
        self._next = 0

    def _init_callback(self) -> None:
        self._next = (self.model.num_timesteps // self.save_freq + 1) * self.save_freq

    def _on_step(self) -> bool:
        if self.num_timesteps >= self._next:
            save_checked_checkpoint(self.model, self.run)
            self._next = (self.num_timesteps // self.save_freq + 1) * self.save_freq
        return True


class VideoRecorderCallback(BaseCallback):
    """Every ``video_freq`` env steps, record an episode of the deterministic policy.

    The episode runs in an env of its own (its own seed, its own simulator), and the
    policy is only queried, so training's env and random streams are untouched.
    Videos go to ``run_dir/videos/`` and a copy to ``shared_dir``.
    """

    def __init__(
        self,
        env_id: str,
        env_kwargs: dict[str, Any],
        video_freq: int,
        video_length: int,
        run_videos_dir: str | Path,
        shared_dir: str | Path | None,
        name_prefix: str,
        seed: int = 0,
        fps: float = 50.0,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        self.env_id = env_id
        self.env_kwargs = env_kwargs
        self.video_freq = video_freq
        self.video_length = video_length
        self.run_videos_dir = Path(run_videos_dir)
        self.shared_dir = Path(shared_dir) if shared_dir else None
        self.name_prefix = name_prefix
        self.seed = seed
        self.fps = fps
        self.videos: list[Path] = []
        self._env = None
        self._last_video_step = 0

    def _init_callback(self) -> None:
        self._last_video_step = self.num_timesteps

    def _on_step(self) -> bool:
        if self.num_timesteps - self._last_video_step >= self.video_freq:
            self._last_video_step = self.num_timesteps
            path = self.run_videos_dir / f"{self.name_prefix}-step-{self.num_timesteps}.mp4"
            try:
                self.record(path)
            except OSError as error:
                # A video is a view of the run, not the run: a full or read-only videos
                # folder costs this video, not the training.
                said = " ".join(str(error).split())
                print(f"video at step {self.num_timesteps} skipped: {said}", file=sys.stderr)
        return True

    def record(self, path: Path) -> Path:
        if self._env is None:
            self._env = make_env(self.env_id, self.env_kwargs, render_mode="rgb_array")
        normalizer = unwrap_vec_normalize(self.model.get_env())

        def policy(obs: np.ndarray) -> np.ndarray:
            if normalizer is not None:
                obs = normalizer.normalize_obs(obs)
            action, _ = self.model.predict(obs, deterministic=True)
            return action

        stats = record_video(
            self._env, policy, path, max_steps=self.video_length, fps=self.fps, seed=self.seed
        )
        self.videos.append(path)
        if self.shared_dir is not None:
            self.shared_dir.mkdir(parents=True, exist_ok=True)
            shutil.copyfile(path, self.shared_dir / path.name)
        if self.verbose:
            print(f"video: {path} ({stats['frames']} frames, return {stats['returns'][0]:.2f})")
        return path

    def _on_training_end(self) -> None:
        if self._env is not None:
            self._env.close()
            self._env = None


class PromoteBestModel(BaseCallback):
    """EvalCallback's new-best hook: EvalCallback saved the new best model in the run's
    staging folder (in place, as SB3 does); this embeds the statistics and the evaluation
    that made it the best in it and moves it over ``best_model.zip`` in one
    ``os.replace``, then writes the statistics' zoo copies beside it. A kill at any point
    leaves the previous best model whole, with its own score."""

    def __init__(self, run: RunFolder) -> None:
        super().__init__()
        self.run = run

    def _on_step(self) -> bool:
        staged = self.run.staging_dir / self.run.best_model.name
        normalizer = self.model.get_vec_normalize_env()
        if normalizer is not None:
            embed_statistics(staged, normalizer)
        embed_jax_state(staged, self.model)
        evaluation = self.parent  # EvalCallback sets best_mean_reward before calling us
        embed_evaluation(staged, evaluation.num_timesteps, evaluation.best_mean_reward)
        os.replace(staged, self.run.best_model)
        if normalizer is not None:
            # The zoo's enjoy --load-best reads <env>/vecnormalize.pkl, as the zoo itself
            # writes it: the best model's until the final model's replaces it.
            for path in (
                self.run.vecnormalize_beside(self.run.best_model),
                self.run.zoo_vecnormalize,
            ):
                save_normalizer(normalizer, path)
        return True


class PublishEvaluations(BaseCallback):
    """EvalCallback's after-evaluation hook: EvalCallback rewrote ``evaluations.npz`` in
    the staging folder; this moves it over the run's in one ``os.replace``."""

    def __init__(self, run: RunFolder) -> None:
        super().__init__()
        self.run = run

    def _on_step(self) -> bool:
        os.replace(self.run.staging_dir / self.run.evaluations.name, self.run.evaluations)
        return True


class ResumableEvalCallback(EvalCallback):
    """SB3's EvalCallback, able to go on with a resumed run's evaluation history.

    EvalCallback keeps its history and call count in attributes it sets in ``__init__``
    (``evaluations_*``, ``best_mean_reward``, ``n_calls``); :meth:`continue_from` sets
    them from the run's evaluations.npz. ``tests/test_sb3_internals.py`` fails if a
    new SB3 renames them.
    """

    def continue_from(self, evaluations: Path, best_model: Path, steps: int, n_envs: int) -> None:
        if evaluations.exists():
            with np.load(evaluations) as data:
                self.evaluations_timesteps = list(data["timesteps"])
                self.evaluations_results = [list(r) for r in data["results"]]
                self.evaluations_length = [list(r) for r in data["ep_lengths"]]
        means = [float(np.mean(r)) for r in self.evaluations_results]
        # The best model's own record counts too: the evaluations may have been torn, or
        # rewound past the evaluation that saved it, and a worse model must not replace it.
        recorded = embedded_evaluation(best_model) if best_model.is_file() else None
        if recorded is not None:
            means.append(recorded[1])
        self.best_mean_reward = max(means, default=-np.inf)
        # EvalCallback counts its calls from 0; continue the run's count so that
        # evaluations stay on multiples of eval_freq, as before the stop.
        self.n_calls = steps // n_envs
