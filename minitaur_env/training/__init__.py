"""Training and evaluation as a Python API: experiments, run folders, env factories.

``Experiment.create(config).run()`` is what ``train.py`` does; sweeps, notebooks and tests
call the same API.
"""


class UsageError(Exception):
    """A mistake in what the user asked for; the scripts print it as one line."""


class TrainingDiverged(RuntimeError):
    """A loss, an action, an observation or a network weight became NaN or infinite."""


def missing_dependency(program: str, error: ModuleNotFoundError) -> str:
    """The one line a script prints when the ``train`` extra is not installed."""
    return (
        f"{program}: error: {error.name} is not installed; training and evaluation need "
        "the train extra: pip install torch==2.13.0 'minitaur-env[train]'"
    )


_API = {
    "Experiment": "minitaur_env.training.experiment",
    "ExperimentConfig": "minitaur_env.training.experiment",
    "RunResult": "minitaur_env.training.experiment",
    "RunFolder": "minitaur_env.training.run_folder",
}
__all__ = ["TrainingDiverged", "UsageError", "missing_dependency", *_API]


def __getattr__(name: str):
    # Imported on first use: the error classes above must not pull in torch and SB3.
    if name in _API:
        import importlib

        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
