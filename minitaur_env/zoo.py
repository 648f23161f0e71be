"""Run an rl-baselines3-zoo script with this package's env ids registered.

``rl_zoo3.train`` and ``rl_zoo3.enjoy`` take ``--gym-packages minitaur_env``; the zoo's
other scripts (``record_video``, ``push_to_hub``, ...) have no such flag, so they are run
through this module instead::

    python -m minitaur_env.zoo record_video -f logs --algo sac --env MinitaurBulletEnv-v0 -n 1000
"""

from __future__ import annotations

import importlib.util
import runpy
import sys

import minitaur_env  # noqa: F401  (registers the env ids)


def main(argv: list[str]) -> None:
    if not argv or argv[0].startswith("-"):
        sys.exit("usage: python -m minitaur_env.zoo SCRIPT [zoo arguments], e.g. record_video")
    script = argv[0].removeprefix("rl_zoo3.")
    if importlib.util.find_spec("rl_zoo3") is None:
        sys.exit("minitaur_env.zoo: rl_zoo3 is not installed (pip install 'minitaur-env[zoo]')")
    if importlib.util.find_spec(f"rl_zoo3.{script}") is None:
        sys.exit(f"minitaur_env.zoo: rl_zoo3 has no script {script!r}")
    sys.argv = [f"rl_zoo3.{script}", *argv[1:]]
    runpy.run_module(f"rl_zoo3.{script}", run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main(sys.argv[1:])
