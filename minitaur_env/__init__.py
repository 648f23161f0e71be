"""Gymnasium-native PyBullet Minitaur, faithful to the classic MinitaurBulletEnv-v0.

Importing the package registers ``MinitaurBullet-v0``, the classic id
``MinitaurBulletEnv-v0`` (the same env) and ``MinitaurBulletDuckEnv-v0``.
"""

from gymnasium.envs.registration import register, registry

from minitaur_env.env import MinitaurBulletDuckEnv, MinitaurBulletEnv
from minitaur_env.randomization import DynamicsRanges

__all__ = ["ENV_IDS", "DynamicsRanges", "MinitaurBulletDuckEnv", "MinitaurBulletEnv"]
__version__ = "0.1.0"

ENV_IDS = ("MinitaurBullet-v0", "MinitaurBulletEnv-v0", "MinitaurBulletDuckEnv-v0")

_SPECS = {
    "MinitaurBullet-v0": ("minitaur_env.env:MinitaurBulletEnv", 15.0),
    "MinitaurBulletEnv-v0": ("minitaur_env.env:MinitaurBulletEnv", 15.0),
    "MinitaurBulletDuckEnv-v0": ("minitaur_env.env:MinitaurBulletDuckEnv", 5.0),
}

for _env_id, (_entry_point, _threshold) in _SPECS.items():
    if _env_id not in registry:
        register(
            id=_env_id,
            entry_point=_entry_point,
            max_episode_steps=1000,
            reward_threshold=_threshold,
        )
