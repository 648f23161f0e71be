"""Which episode seeds each purpose plays: one plan, so that no episode serves two purposes.

Judging plays fixed blocks of small seeds, the ones published figures were measured on:
the report's episodes start at ``REPORT_SEED`` (evaluate.py, ship, package and the docs'
tables), shipping's selection at ``SELECTION_SEED`` and the study of which drawn
dynamics a policy falls on at ``FALLS_SEED``. A run's own envs, its training
envs, the env of its periodic evaluations and its videos, draw seeds at 2**84 and above, laid out by
purpose, run seed, the env step the session started at and the env's index: a resumed
session never replays a seed of an earlier one, of the other purpose or of a judging
block, whatever step it resumes at (a run once re-seeded at ``seed + steps`` and so,
resumed at 10,000 steps, trained on its own evaluation episodes).
"""

from __future__ import annotations

import dataclasses

REPORT_SEED = 12345
SELECTION_SEED = 5000
FALLS_SEED = 20000  # benchmarks/falls_by_draw.py: which draws a policy falls on
JUDGING_SEED_LIMIT = 2**32  # judging blocks lie below; a run's own seeds far above

_PURPOSES = {"training": 1, "evaluation": 2, "video": 3}
_RUN_SEED_BITS, _STEP_BITS, _ENV_BITS = 32, 40, 12
MAX_ENVS = 2**_ENV_BITS


@dataclasses.dataclass(frozen=True)
class SeedPlan:
    """The seeds a run with seed ``run_seed`` and ``n_envs`` training envs plays."""

    run_seed: int
    n_envs: int = 1

    def __post_init__(self) -> None:
        if not 0 <= self.run_seed < 2**_RUN_SEED_BITS:
            raise ValueError(f"run seed {self.run_seed} is outside 0..2**32-1")
        if not 1 <= self.n_envs <= MAX_ENVS:
            raise ValueError(f"n_envs {self.n_envs} is outside 1..{MAX_ENVS}")

    def training(self, started_at: int = 0) -> range:
        """Reset seeds of the training envs (env i: the i-th) in a session from ``started_at``."""
        first = self._first("training", started_at)
        return range(first, first + self.n_envs)

    def evaluation(self, started_at: int = 0) -> range:
        """The reset seed of the periodic-evaluation env in a session from ``started_at``;
        its later episodes follow from that env's generator."""
        first = self._first("evaluation", started_at)
        return range(first, first + 1)

    def video(self) -> range:
        """The reset seed of every policy video a run records (the same start each time,
        so that the videos compare the policies)."""
        first = self._first("video", 0)
        return range(first, first + 1)

    def _first(self, purpose: str, started_at: int) -> int:
        if not 0 <= started_at < 2**_STEP_BITS:
            raise ValueError(f"a session cannot start at env step {started_at}")
        layout = (_PURPOSES[purpose] << _RUN_SEED_BITS) | self.run_seed
        return ((layout << _STEP_BITS) | started_at) << _ENV_BITS


def judging_block(first_seed: int, episodes: int, purpose: str = "episodes") -> range:
    """The seeds of ``episodes`` judged episodes from ``first_seed``, refused (ValueError)
    where they would reach the seeds runs draw for themselves."""
    if first_seed < 0 or first_seed + episodes > JUDGING_SEED_LIMIT:
        raise ValueError(
            f"{purpose} seeds {first_seed}..{first_seed + episodes - 1} must lie in "
            f"0..{JUDGING_SEED_LIMIT - 1}"
        )
    return range(first_seed, first_seed + episodes)
