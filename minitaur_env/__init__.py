"""Gymnasium-native PyBullet Minitaur, faithful to the classic MinitaurBulletEnv-v0.

Importing the package registers ``MinitaurBullet-v0``, the classic id
``MinitaurBulletEnv-v0`` (the same env), ``MinitaurBulletDuckEnv-v0`` and
``MinitaurBulletRandomized-v0``: the same task under Tan et al. 2018's randomization
(``preset="tan2018"``: :meth:`DynamicsRanges.tan2018` and :meth:`Realism.tan2018`) with a
3 ms PD latency. ``MinitaurBulletTrot-v0`` and
``MinitaurBulletTrotRandomized-v0`` are the first and the last with a gait prior: the
policy modulates a trotting generator and adds residuals (:class:`TrottingGait`).
"""

from gymnasium.envs.registration import register, registry

from minitaur_env.env import MinitaurBulletDuckEnv, MinitaurBulletEnv
from minitaur_env.gait import Trot, TrottingGait
from minitaur_env.randomization import DynamicsRanges, Pushes
from minitaur_env.settings import Realism

__all__ = [
    "ENV_IDS",
    "DynamicsRanges",
    "MinitaurBulletDuckEnv",
    "MinitaurBulletEnv",
    "Pushes",
    "Realism",
    "Trot",
    "TrottingGait",
]
__version__ = "0.2.0"

ENV_IDS = (
    "MinitaurBullet-v0",
    "MinitaurBulletEnv-v0",
    "MinitaurBulletDuckEnv-v0",
    "MinitaurBulletRandomized-v0",
    "MinitaurBulletTrot-v0",
    "MinitaurBulletTrotRandomized-v0",
)

# Plain values only, so that the zoo's env_kwargs.yml and --env-kwargs can state them.
RANDOMIZED_KWARGS = {"preset": "tan2018"}

_SPECS = {
    "MinitaurBullet-v0": ("minitaur_env.env:make_minitaur_env", 15.0, {}),
    "MinitaurBulletEnv-v0": ("minitaur_env.env:make_minitaur_env", 15.0, {}),
    "MinitaurBulletDuckEnv-v0": ("minitaur_env.env:MinitaurBulletDuckEnv", 5.0, {}),
    "MinitaurBulletRandomized-v0": (
        "minitaur_env.env:make_minitaur_env",
        15.0,
        RANDOMIZED_KWARGS,
    ),
    "MinitaurBulletTrot-v0": ("minitaur_env.gait:make_trotting_env", 15.0, {}),
    "MinitaurBulletTrotRandomized-v0": (
        "minitaur_env.gait:make_trotting_env",
        15.0,
        RANDOMIZED_KWARGS,
    ),
}

for _env_id, (_entry_point, _threshold, _kwargs) in _SPECS.items():
    if _env_id not in registry:
        register(
            id=_env_id,
            entry_point=_entry_point,
            max_episode_steps=1000,
            reward_threshold=_threshold,
            kwargs=dict(_kwargs),
        )
