"""Training and evaluation as a Python API: experiments, run folders, env factories.

``Experiment.create(config).run()`` is what ``train.py`` does; sweeps, notebooks and tests
call the same API.
"""

import argparse
from typing import NoReturn

# The choices the scripts' flags offer, named here so that the scripts parse their flags
# (and answer --help or a typo) without importing torch; ``algorithms``, ``envs`` and
# ``progress`` act on them.
ALGORITHM_NAMES = ("sac", "td3", "ppo", "a2c", "tqc", "crossq")
BACKENDS = ("sb3", "sbx")
# "auto": several envs grouped over the CPU cores, a single env in the calling process.
VEC_ENVS = ("auto", "dummy", "grouped")
PROGRESS_MODES = ("auto", "bar", "lines", "none")
DEFAULT_ENV = "MinitaurBulletEnv-v0"


def env_name(env_id: str) -> str:
    """The id without a module prefix (``my_pkg:MyEnv-v0`` -> ``MyEnv-v0``), for file names."""
    return env_id.split(":")[-1]


class OneLineErrorParser(argparse.ArgumentParser):
    """An ArgumentParser whose errors are one line, not the whole usage block."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see --help)\n")


class UsageError(Exception):
    """A mistake in what the user asked for; the scripts print it as one line."""


class TrainingDiverged(RuntimeError):
    """A loss, an action, an observation or a network weight became NaN or infinite."""


def missing_dependency(program: str, error: ModuleNotFoundError) -> str:
    """The one line a script prints when the ``train`` extra is not installed."""
    return (
        f"{program}: error: {error.name} is not installed; training and evaluation need "
        "the train extra: pip install 'minitaur-env[train]' (playing an "
        "exported .onnx policy needs only 'minitaur-env[onnx]')"
    )


_API = {
    "Experiment": "minitaur_env.training.experiment",
    "ExperimentConfig": "minitaur_env.training.config",
    "RunResult": "minitaur_env.training.results",
    "RunFolder": "minitaur_env.training.run_folder",
}
__all__ = [
    "ALGORITHM_NAMES",
    "BACKENDS",
    "DEFAULT_ENV",
    "PROGRESS_MODES",
    "VEC_ENVS",
    "env_name",
    "OneLineErrorParser",
    "TrainingDiverged",
    "UsageError",
    "missing_dependency",
    *_API,
]


def __getattr__(name: str):
    # Imported on first use: the error classes above must not pull in torch and SB3.
    if name in _API:
        import importlib

        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
