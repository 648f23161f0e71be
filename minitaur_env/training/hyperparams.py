"""Hyperparameter files (one YAML per algorithm, one entry per env id) and ``key=value``
overrides."""

from __future__ import annotations

import copy
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from minitaur_env.training import UsageError, env_name
from minitaur_env.training.files import parse_yaml, read_yaml

# Keys of a hyperparameter entry that configure the run rather than the algorithm. An
# entry's evaluation settings are its defaults for --eval-freq and --eval-episodes: a
# PPO run's 1M steps would spend two thirds of its time evaluating at SAC's every 10k
# (benchmarks/default_minutes.py).
RUN_KEYS = ("n_timesteps", "n_envs", "normalize", "policy", "eval_freq", "eval_episodes")
# Keys that take rl-baselines3-zoo's ``lin_<initial value>`` (linear decay to 0).
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")
# ``{final: -4, start: 0.5}``: SAC's entropy target, held at ``target_entropy`` until
# ``start`` (a fraction of n_timesteps), then decayed linearly to ``final`` at the end.
ENTROPY_DECAY_KEY = "target_entropy_decay"
ENTROPY_ALGOS = ("sac", "tqc", "crossq")  # the algorithms that tune an entropy coefficient
# ``{start: 0.2, full_at: 0.5}``: the training envs push at ``start`` times the env's push
# force at step 0, growing linearly to the full force at ``full_at`` (a fraction of
# n_timesteps). Evaluations always push at full force.
PUSH_CURRICULUM_KEY = "push_curriculum"
# ``{envs: 2, realism: {control_time_step: [0.012, 0.02]}}``: the first ``envs`` training
# envs draw those realism fields from these ranges, inside the env's own (the hard end of
# the randomization, met more often); the other training envs and every evaluation keep
# the env's own ranges.
HARD_DRAWS_KEY = "hard_draws"
# ``noise_color_until: 0.3``: SAC explores with the policy's colored noise (its
# ``noise_color``) until that fraction of n_timesteps, and with white noise after it.
NOISE_COLOR_UNTIL_KEY = "noise_color_until"
# ``n_steps_after: {at: 0.5, n_steps: 5}``: an off-policy run's n-step returns shorten
# from its ``n_steps`` to these at that fraction of n_timesteps: long returns carry the
# reward of a first walk back faster, short ones bias the end of training less.
N_STEPS_AFTER_KEY = "n_steps_after"
# Read by callbacks, not the algorithm.
CALLBACK_KEYS = (
    ENTROPY_DECAY_KEY,
    PUSH_CURRICULUM_KEY,
    HARD_DRAWS_KEY,
    NOISE_COLOR_UNTIL_KEY,
    N_STEPS_AFTER_KEY,
)
# ``mirror: true``: an off-policy run's replay buffer stores every transition twice, as it
# happened and as its left-right mirror image (replay_buffer.MirroredReplayBuffer).
MIRROR_KEY = "mirror"
# ``reward_time_step: 0.01``: the learner is paid each step's reward times 0.01 s over the
# episode's control step, so that the same speed pays the same under every drawn step (the
# env pays distance: five times as much per step at 20 ms as at 4 ms). Monitor files,
# evaluations and every reported return keep the env's own reward.
REWARD_TIME_STEP_KEY = "reward_time_step"


def hyperparams_file(algo: str) -> Path:
    return Path(str(resources.files("minitaur_env") / "hyperparams" / f"{algo}.yml"))


def load_hyperparams(
    algo: str, env_id: str, conf_file: str | None = None, entry: str | None = None
) -> dict[str, Any]:
    """The entry for ``env_id`` (or ``default``) of the algorithm's YAML file.

    ``entry`` picks a named entry instead (e.g. ``tutorial``). An entry may name another
    with ``base: <key>`` to start from it.
    """
    path = Path(conf_file) if conf_file else hyperparams_file(algo)
    table = read_yaml(path, "hyperparameter file")
    if not isinstance(table, dict):
        raise UsageError(f"hyperparameter file {path} must map env ids to settings")
    if entry is not None:
        if entry not in table:
            names = ", ".join(k for k in table if isinstance(table[k], dict) or table[k] is None)
            raise UsageError(f"{path} has no entry {entry!r}; it has: {names}")
        return _resolve(table, entry, path)
    bare_id = env_name(env_id)
    key = bare_id if bare_id in table else "default"
    if key not in table:
        raise UsageError(f"{path} has no entry for {bare_id} and no 'default' entry")
    return _resolve(table, key, path)


def _resolve(table: dict[str, Any], key: str, path: Path, seen: tuple[str, ...] = ()) -> dict:
    if key in seen:
        raise UsageError(f"{path}: 'base' entries form a cycle: {' -> '.join((*seen, key))}")
    entry = dict(table.get(key) or {})
    base = entry.pop("base", None)
    if base is None:
        return entry
    if base not in table:
        raise UsageError(f"{path}: entry {key!r} has base {base!r}, which is not in the file")
    return {**_resolve(table, base, path, (*seen, key)), **entry}


def parse_overrides(pairs: list[str] | None, flag: str) -> dict[str, Any]:
    """``["lr=3e-4", "policy_kwargs={net_arch: [64, 64]}"]`` -> a dict of YAML values."""
    result: dict[str, Any] = {}
    for pair in pairs or []:
        key, sep, text = pair.partition("=")
        if not sep or not key.strip():
            raise UsageError(f"{flag} expects key=value, got {pair!r}")
        try:
            result[key.strip()] = parse_yaml(text)
        except yaml.YAMLError as error:
            raise UsageError(f"{flag} {key}: cannot parse {text!r}: {error}") from error
    return result


def algorithm_kwargs(hyperparams: dict[str, Any]) -> dict[str, Any]:
    """``hyperparams`` with the zoo's ``lin_0.001`` turned into a schedule SB3 accepts.

    The schedule decays linearly from the value to 0 over training, as the zoo's does;
    the config files keep the string, so the zoo reads them too.
    """
    from stable_baselines3.common.utils import LinearSchedule

    kwargs = copy.deepcopy(hyperparams)  # SBX's TQC writes into policy_kwargs
    for key in CALLBACK_KEYS:
        kwargs.pop(key, None)
    if mirrored(kwargs):
        from minitaur_env.training.replay_buffer import MirroredReplayBuffer

        # The buffer computes the n-step returns: SB3 sets up its own n-step buffer only
        # when no buffer class is given, and warns that n_steps is ignored otherwise.
        kwargs["replay_buffer_class"] = MirroredReplayBuffer
        kwargs["replay_buffer_kwargs"] = {
            "n_steps": kwargs.pop("n_steps", 1),
            "gamma": kwargs.get("gamma", 0.99),
        }
    kwargs.pop(MIRROR_KEY, None)
    kwargs.pop(REWARD_TIME_STEP_KEY, None)
    for key in SCHEDULE_KEYS:
        value = kwargs.get(key)
        if not isinstance(value, str):
            continue
        kind, _, number = value.partition("_")
        try:
            if kind != "lin":
                raise ValueError
            initial = float(number)
        except ValueError:
            raise UsageError(
                f"{key}: expected a number or lin_<number> (linear decay), got {value!r}"
            ) from None
        kwargs[key] = LinearSchedule(initial, 0.0, 1.0)
    return kwargs


def entropy_decay(hyperparams: dict[str, Any], algo: str) -> tuple[float, float, float] | None:
    """``(initial, final, start)`` of a ``target_entropy_decay`` entry, or None without one.

    The initial target must be a number in the entry itself: a resumed model holds the
    decayed value, so the model cannot say where the decay began.
    """
    decay = hyperparams.get(ENTROPY_DECAY_KEY)
    if decay is None:
        return None
    prefix = ENTROPY_DECAY_KEY
    # Both backends read model.target_entropy at every update (SBX passes it to its
    # compiled step as a traced value, so a new value needs no recompiling).
    if algo not in ENTROPY_ALGOS:
        raise UsageError(f"{prefix}: only for {', '.join(ENTROPY_ALGOS)}, not {algo}")
    if not isinstance(decay, dict) or set(decay) - {"final", "start"} or "final" not in decay:
        expected = "{final: <number>, start: <fraction>}"
        raise UsageError(f"{prefix}: expected {expected}, got {decay!r}")
    if not str(hyperparams.get("ent_coef", "auto")).startswith("auto"):
        raise UsageError(f"{prefix}: needs ent_coef: auto (a fixed ent_coef ignores the target)")
    initial = hyperparams.get("target_entropy")
    final, start = decay["final"], decay.get("start", 0.0)
    for name, value in (("target_entropy", initial), (f"{prefix}.final", final)):
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            raise UsageError(f"{prefix}: {name} must be a number, got {value!r}")
    if not isinstance(start, (int, float)) or isinstance(start, bool) or not 0 <= start < 1:
        raise UsageError(f"{prefix}.start must be a fraction in [0, 1), got {start!r}")
    return float(initial), float(final), float(start)


def push_curriculum(hyperparams: dict[str, Any], env_pushes: Any) -> tuple[float, float] | None:
    """``(start, full_at)`` of a ``push_curriculum`` entry, or None without one.

    ``env_pushes`` is the env's ``pushes`` setting: a curriculum without pushes to scale
    would do nothing, so it is refused.
    """
    curriculum = hyperparams.get(PUSH_CURRICULUM_KEY)
    if curriculum is None:
        return None
    prefix = PUSH_CURRICULUM_KEY
    expected = "{start: <fraction of the force>, full_at: <fraction of n_timesteps>}"
    if not isinstance(curriculum, dict) or set(curriculum) != {"start", "full_at"}:
        raise UsageError(f"{prefix}: expected {expected}, got {curriculum!r}")
    start, full_at = curriculum["start"], curriculum["full_at"]
    for name, value, low_open in (("start", start, False), ("full_at", full_at, True)):
        number = isinstance(value, (int, float)) and not isinstance(value, bool)
        if not number or not (0 < value <= 1 if low_open else 0 <= value <= 1):
            interval = "(0, 1]" if low_open else "[0, 1]"
            raise UsageError(f"{prefix}.{name} must be a number in {interval}, got {value!r}")
    if env_pushes is None or env_pushes is False:
        raise UsageError(
            f"{prefix}: the env has no pushes to scale; add --env-kwargs 'realism={{pushes: true}}'"
        )
    return float(start), float(full_at)


def hard_draws(
    hyperparams: dict[str, Any], n_envs: int
) -> list[tuple[range, dict[str, Any]]] | None:
    """The training envs each group of a ``hard_draws`` entry narrows, with its realism
    fields, or None without one. One group is a mapping; several are a list of them, on
    consecutive envs from the first. Whether the ranges lie inside the env's own is the
    env's check (``narrow_realism``)."""
    entry = hyperparams.get(HARD_DRAWS_KEY)
    if entry is None:
        return None
    expected = (
        "{envs: <how many training envs>, realism: {<field>: [low, high], ...}}, or a list of them"
    )
    entries = entry if isinstance(entry, list) and entry else [entry]
    groups, first = [], 0
    for index, group in enumerate(entries):
        where = HARD_DRAWS_KEY if len(entries) == 1 else f"{HARD_DRAWS_KEY}[{index}]"
        if not isinstance(group, dict) or set(group) != {"envs", "realism"}:
            raise UsageError(f"{where}: expected {expected}, got {group!r}")
        envs, realism = group["envs"], group["realism"]
        if isinstance(envs, bool) or not isinstance(envs, int) or envs < 1:
            raise UsageError(f"{where}.envs must be a whole number from 1, got {envs!r}")
        if not isinstance(realism, dict) or not realism:
            raise UsageError(f"{where}.realism: expected a mapping of fields, got {realism!r}")
        groups.append((range(first, first + envs), realism))
        first += envs
    if first >= n_envs:
        raise UsageError(
            f"{HARD_DRAWS_KEY} narrows {first} training envs; at most {n_envs - 1} (n_envs is "
            f"{n_envs}: some training envs keep the env's own ranges)"
        )
    return groups


def noise_color_until(hyperparams: dict[str, Any]) -> float | None:
    """The fraction of n_timesteps of a ``noise_color_until`` entry, or None without one.
    It needs colored noise to end: a policy whose ``policy_kwargs`` set ``noise_color``."""
    until = hyperparams.get(NOISE_COLOR_UNTIL_KEY)
    if until is None:
        return None
    if isinstance(until, bool) or not isinstance(until, (int, float)) or not 0 < until < 1:
        raise UsageError(
            f"{NOISE_COLOR_UNTIL_KEY} must be a fraction of n_timesteps in (0, 1), got {until!r}"
        )
    color = (hyperparams.get("policy_kwargs") or {}).get("noise_color", 0)
    if not color:
        raise UsageError(
            f"{NOISE_COLOR_UNTIL_KEY}: the policy explores with white noise already; it ends "
            "a policy's colored noise (policy: StabilizedMlpPolicy, policy_kwargs noise_color)"
        )
    return float(until)


def n_steps_after(hyperparams: dict[str, Any]) -> tuple[float, int] | None:
    """The fraction of n_timesteps and the shorter n of an ``n_steps_after`` entry, or
    None without one. It shortens an off-policy entry's ``n_steps``; the config refuses
    it for other algorithms (PPO's ``n_steps`` is its rollout length, not a return's)."""
    entry = hyperparams.get(N_STEPS_AFTER_KEY)
    if entry is None:
        return None
    expected = "{at: <fraction of n_timesteps>, n_steps: <a shorter n>}"
    if not isinstance(entry, dict) or set(entry) != {"at", "n_steps"}:
        raise UsageError(f"{N_STEPS_AFTER_KEY}: expected {expected}, got {entry!r}")
    at, shorter = entry["at"], entry["n_steps"]
    if isinstance(at, bool) or not isinstance(at, (int, float)) or not 0 < at < 1:
        raise UsageError(
            f"{N_STEPS_AFTER_KEY}.at must be a fraction of n_timesteps in (0, 1), got {at!r}"
        )
    longest = hyperparams.get("n_steps", 1)
    if isinstance(shorter, bool) or not isinstance(shorter, int) or not 1 <= shorter < longest:
        raise UsageError(
            f"{N_STEPS_AFTER_KEY}.n_steps must be a whole number from 1 to below the "
            f"entry's n_steps ({longest}), got {shorter!r}"
        )
    return float(at), shorter


def mirrored(hyperparams: dict[str, Any]) -> bool:
    """The ``mirror`` entry, false without one."""
    value = hyperparams.get(MIRROR_KEY, False)
    if not isinstance(value, bool):
        raise UsageError(f"{MIRROR_KEY} must be true or false, got {value!r}")
    if value and "replay_buffer_class" in hyperparams:
        raise UsageError(f"{MIRROR_KEY}: sets the replay buffer itself; drop replay_buffer_class")
    return value


def reward_time_step(hyperparams: dict[str, Any]) -> float | None:
    """The ``reward_time_step`` entry in seconds, or None without one."""
    value = hyperparams.get(REWARD_TIME_STEP_KEY)
    if value is None:
        return None
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if not number or not 0 < value < float("inf"):
        raise UsageError(
            f"{REWARD_TIME_STEP_KEY} must be a control step in seconds above 0, got {value!r}"
        )
    return float(value)
