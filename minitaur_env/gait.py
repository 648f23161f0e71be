"""A gait prior: the policy modulates a trotting trajectory generator and adds residuals.

After Iscen et al. 2018 ("Policies Modulating Trajectory Generators", PMTG) and the
classic ``minitaur_trotting_env``: a periodic generator drives the diagonal leg pairs
half a cycle apart, so a policy that outputs zeros already trots forward; the policy
learns to change the trot's frequency and amplitudes and to correct each leg. The
generator's phase is part of the observation, so the policy knows where in the cycle
the legs are.

The wrapped env is the classic one, unchanged: the generator only writes its leg-model
action. ``MinitaurBulletTrot-v0`` and ``MinitaurBulletTrotRandomized-v0`` register it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from minitaur_env.checks import boolean, checked_action, from_mapping, integer, number
from minitaur_env.env import MAX_HISTORY, MinitaurBulletEnv, with_history
from minitaur_env.robot import NUM_MOTORS
from minitaur_env.settings import CLASSIC_CONTROL_STEP, MAX_CONTROL_STEP

# Front-left and back-right legs swing together, back-left and front-right half a cycle
# later (the leg order of the action: front-left, back-left, front-right, back-right).
TROT_PHASE_OFFSETS = np.array([0.0, math.pi, math.pi, 0.0])
MODULATION_ENTRIES = 3  # frequency, extension amplitude, swing amplitude


@dataclasses.dataclass(frozen=True)
class Trot:
    """The trotting generator and how far the policy may move it.

    Leg ``i`` at phase ``p_i = p + offset_i`` is commanded the leg-model action
    ``extension * cos(p_i)`` (entry ``i``) and ``-swing * sin(p_i)`` (entry ``4 + i``),
    plus the policy's residual; the phase advances by ``2 pi frequency dt`` per step.
    The defaults trot forward open loop at about 0.9 m/s under the classic dynamics and
    stay upright under Tan et al.'s randomization, though not under pushes (measured by
    ``benchmarks/gait_prior.py``).

    - ``frequency`` (Hz, in (0, 10]): the stepping frequency.
    - ``extension``, ``swing`` (in [0, 1]): amplitudes in leg-model units (1 is pi/4 rad).
    - ``modulation`` (in [0, 1)): the policy scales the frequency and both amplitudes by
      ``1 + modulation * u`` with its ``u`` in [-1, 1].
    - ``residual`` (in [0, 2]): the policy adds ``residual * u`` to each leg-model entry.
      The sum is clipped to the env's [-1, 1].
    """

    frequency: float = 4.0
    extension: float = 0.7
    swing: float = 0.3
    modulation: float = 0.5
    residual: float = 0.3

    def __post_init__(self) -> None:
        number("gait frequency", self.frequency, 0, 10, low_open=True, unit="Hz")
        number("gait extension", self.extension, 0, 1)
        number("gait swing", self.swing, 0, 1)
        number("gait modulation", self.modulation, 0, 1, high_open=True)
        number("gait residual", self.residual, 0, 2)

    @classmethod
    def coerce(cls, value: Trot | Mapping[str, Any] | None) -> Trot:
        """A :class:`Trot` from itself, a mapping of its fields (``--env-kwargs``) or None."""
        if value is None:
            return cls()
        if isinstance(value, Trot):
            return value
        if isinstance(value, Mapping):
            return from_mapping(cls, value)
        raise ValueError(f"gait must be a mapping of {cls.__name__} settings, got {value!r}")

    def leg_actions(self, phase: float, extension: float, swing: float) -> np.ndarray:
        """The generator's leg-model action at ``phase`` with the given amplitudes."""
        leg_phases = phase + TROT_PHASE_OFFSETS
        return np.concatenate([extension * np.cos(leg_phases), -swing * np.sin(leg_phases)])


class TrottingGait(gym.Wrapper[np.ndarray, np.ndarray, np.ndarray, np.ndarray]):
    """The policy modulates a :class:`Trot` and adds residuals (PMTG).

    Action ``Box(-1, 1, (11,))``: entries 0-7 are residuals on the env's leg-model
    action (same order), 8-10 modulate the frequency, the extension and the swing
    amplitude. Observation: the env's, then ``sin`` and ``cos`` of the generator's phase,
    then with ``observe_control_step`` the episode's control step in units of 10 ms.
    ``info`` gains ``gait_phase`` (rad) and ``gait_frequency`` (Hz).

    Under randomized timing (3-20 ms in Tan et al.'s preset) the same action moves the
    robot up to six times farther on one episode than on another, and the phase history
    cannot tell a long step from a fast gait; a robot's controller knows its own loop
    period, so ``observe_control_step`` lets the policy know it too. The latency stays
    hidden, as on the robot.
    """

    def __init__(
        self,
        env: gym.Env,
        trot: Trot | Mapping[str, Any] | None = None,
        observe_control_step: bool = False,
    ) -> None:
        super().__init__(env)
        self.trot = Trot.coerce(trot)
        self.observe_control_step = boolean("observe_control_step", observe_control_step)
        self.action_space = spaces.Box(-1.0, 1.0, (NUM_MOTORS + MODULATION_ENTRIES,), np.float32)
        inner = env.observation_space
        assert isinstance(inner, spaces.Box)
        low, high = [-1.0, -1.0], [1.0, 1.0]
        if self.observe_control_step:
            # In units of the classic 10 ms: the longest step the env accepts, repeated.
            longest = MAX_CONTROL_STEP * env.unwrapped.action_repeat / CLASSIC_CONTROL_STEP
            low, high = [*low, 0.0], [*high, longest]
        self.observation_space = spaces.Box(
            np.concatenate([inner.low, low]).astype(np.float32),
            np.concatenate([inner.high, high]).astype(np.float32),
            dtype=np.float32,
        )
        self._phase = 0.0

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        observation, info = self.env.reset(seed=seed, options=options)
        self._phase = 0.0
        return self._observe(observation), info

    def step(
        self, action: np.ndarray
    ) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        leg_action, frequency = self.leg_action(action)
        observation, reward, terminated, truncated, info = self.env.step(leg_action)
        info["gait_phase"] = self._phase
        info["gait_frequency"] = frequency
        # The control step may be drawn per episode (randomized dynamics): read it each step.
        self._phase = (self._phase + 2 * math.pi * frequency * self.env.unwrapped.dt) % (
            2 * math.pi
        )
        return self._observe(observation), reward, terminated, truncated, info

    def leg_action(self, action: np.ndarray) -> tuple[np.ndarray, float]:
        """The env's leg-model action for the policy's ``action`` now, and the frequency."""
        given = np.clip(checked_action(action, NUM_MOTORS + MODULATION_ENTRIES), -1.0, 1.0)
        trot = self.trot
        scale = 1.0 + trot.modulation * given[NUM_MOTORS:]
        generated = trot.leg_actions(self._phase, trot.extension * scale[1], trot.swing * scale[2])
        residual = trot.residual * given[:NUM_MOTORS]
        return np.clip(generated + residual, -1.0, 1.0), trot.frequency * float(scale[0])

    def _observe(self, observation: np.ndarray) -> np.ndarray:
        extra = [math.sin(self._phase), math.cos(self._phase)]
        if self.observe_control_step:
            extra.append(self.env.unwrapped.dt / CLASSIC_CONTROL_STEP)
        return np.concatenate([observation, extra]).astype(np.float32)


def make_trotting_env(
    render_mode: str | None = None,
    gait: Trot | Mapping[str, Any] | None = None,
    history: int = 1,
    observe_control_step: bool = False,
    **kwargs: Any,
) -> gym.Env:
    """``MinitaurBulletEnv(render_mode, **kwargs)`` driven through a :class:`TrottingGait`
    (``observe_control_step``: whether the observation ends with the control step).

    ``history`` (1 to 16): the policy sees the last ``history`` observations, newest last,
    flattened into one vector (the first observation repeated at reset). Under latency
    and pushes a single observation says where the body is but not where it is going; the
    classic observation has no base velocity.
    """
    integer("history", history, 1, MAX_HISTORY)  # before the simulator is built
    boolean("observe_control_step", observe_control_step)
    env = MinitaurBulletEnv(render_mode, **kwargs)
    return with_history(TrottingGait(env, gait, observe_control_step), history)


def has_gait_prior(env_id: str) -> bool:
    """Whether ``env_id`` is registered with the gait prior (its spec's entry point is
    :func:`make_trotting_env`), so that its policies' actions are the prior's."""
    entry_point = gym.spec(env_id).entry_point
    if callable(entry_point):
        return entry_point is make_trotting_env
    return entry_point == f"{__name__}:{make_trotting_env.__name__}"
