"""Recovery after a closure: how many episodes, env steps and seconds of training until the routes are good again.

Training produces a timeline of route evaluations (:class:`RouteEvaluation`, each the greedy policy's
:class:`~campusnav_env.route_evaluation.RouteReport` from every start) and closures (:class:`ClosureRecord`). A
closure's *window* runs from the closure to the next one (or the end of training). The agent has *recovered* at the
first evaluation in the window whose success rate and SPL are both at or above their thresholds (defaults 0.99 and
0.95); the recovery is the number of training episodes, env steps and training seconds (evaluation excluded) from the
closure to that evaluation. A closure the agent never recovered from within its window is reported as such: it counts
as infinitely slow in the median, never dropped.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # plain records: the evaluation (and the env behind it) is not imported at run time
    from campusnav_env.route_evaluation import RouteReport

__all__ = [
    "DEFAULT_SPL_THRESHOLD",
    "DEFAULT_SUCCESS_THRESHOLD",
    "ClosureRecord",
    "Recovery",
    "RouteEvaluation",
    "measure_recoveries",
    "median_recovery",
    "recovery_table",
]

DEFAULT_SUCCESS_THRESHOLD = 0.99
DEFAULT_SPL_THRESHOLD = 0.95
Road = tuple[int, int]


@dataclass(frozen=True)
class RouteEvaluation:
    """
    The greedy policy's routes from every start at one point of training.

    :param step: Env steps of training so far (the model's ``num_timesteps``)
    :param episode: Training episodes so far
    :param train_seconds: Training wall time so far, evaluations excluded
    :param report: The routes and their scores
    :param others: Routes to other named goal sets evaluated at the same time (e.g. goals never trained on)
    :param critics: The same routes driven by the critics alone, where the evaluated policy also plans over a memory
        (DCQN's ``route_memory``): what the weights know, beside what the agent's memory adds
    """

    step: int
    episode: int
    train_seconds: float
    report: RouteReport
    others: dict[str, RouteReport] = field(default_factory=dict)
    critics: RouteReport | None = None

    @property
    def success_rate(self) -> float:
        return self.report.success_rate

    @property
    def spl(self) -> float:
        return self.report.spl

    def meets(self, success_threshold: float, spl_threshold: float, every_goal: bool = False) -> bool:
        """
        Whether success rate and SPL are both at or above the thresholds.

        :param every_goal: Also for each goal on its own (not only over all routes)
        """
        return self.report.meets(success_threshold, spl_threshold, every_goal)


@dataclass(frozen=True)
class ClosureRecord:
    """
    A change of the road network during training.

    :param description: What was asked for (e.g. ``"episode 2000: close 81-82"``)
    :param step: Env steps of training when it happened
    :param episode: Training episodes when it happened
    :param train_seconds: Training wall time when it happened, evaluations excluded
    :param closed: Roads closed
    :param reopened: Roads reopened
    :param refused: Roads that were asked for but not closed, with the reason
    :param evaluation_index: Number of route evaluations made before it (its window starts there)
    :param routes_affected: Greedy routes of the last evaluation before it that travelled a closed road
    """

    description: str
    step: int
    episode: int
    train_seconds: float
    closed: tuple[Road, ...]
    reopened: tuple[Road, ...]
    refused: tuple[tuple[str, str], ...]
    evaluation_index: int
    routes_affected: int | None = None

    @property
    def changed(self) -> bool:
        return bool(self.closed or self.reopened)


@dataclass(frozen=True)
class Recovery:
    """
    How the agent fared after one closure.

    :param closure: The closure
    :param right_after: The first evaluation after it (made before any more training when the callback can)
    :param recovered_at: The first evaluation in its window at the thresholds, or ``None``
    :param last: The last evaluation in its window
    """

    closure: ClosureRecord
    right_after: RouteEvaluation | None
    recovered_at: RouteEvaluation | None
    last: RouteEvaluation | None

    @property
    def recovered(self) -> bool:
        return self.recovered_at is not None

    @property
    def episodes(self) -> float:
        """Training episodes from the closure to recovery (``inf`` if never recovered)."""
        return math.inf if self.recovered_at is None else float(self.recovered_at.episode - self.closure.episode)

    @property
    def steps(self) -> float:
        """Env steps from the closure to recovery (``inf`` if never recovered)."""
        return math.inf if self.recovered_at is None else float(self.recovered_at.step - self.closure.step)

    @property
    def seconds(self) -> float:
        """Training seconds (evaluations excluded) from the closure to recovery (``inf`` if never recovered)."""
        if self.recovered_at is None:
            return math.inf
        return self.recovered_at.train_seconds - self.closure.train_seconds


def measure_recoveries(
    closures: Sequence[ClosureRecord],
    evaluations: Sequence[RouteEvaluation],
    success_threshold: float = DEFAULT_SUCCESS_THRESHOLD,
    spl_threshold: float = DEFAULT_SPL_THRESHOLD,
    every_goal: bool = False,
) -> list[Recovery]:
    """
    The recovery after every closure that changed the network (see the module docstring).

    :param closures: Closures in the order they happened
    :param evaluations: Route evaluations in the order they were made
    :param every_goal: Recovered only when each goal is at the thresholds on its own
    :return: one :class:`Recovery` per closure that closed or reopened a road
    """
    recoveries = []
    changed = [c for c in closures if c.changed]
    for k, closure in enumerate(changed):
        end = changed[k + 1].evaluation_index if k + 1 < len(changed) else len(evaluations)
        window = list(evaluations[closure.evaluation_index : end])
        recovered_at = next((e for e in window if e.meets(success_threshold, spl_threshold, every_goal)), None)
        recoveries.append(
            Recovery(
                closure=closure,
                right_after=window[0] if window else None,
                recovered_at=recovered_at,
                last=window[-1] if window else None,
            )
        )
    return recoveries


def median_recovery(recoveries: Sequence[Recovery], measure: str = "episodes") -> float:
    """
    Median of ``"episodes"``, ``"steps"`` or ``"seconds"`` over the recoveries; unrecovered ones count as ``inf``.

    :return: the median (``inf`` when at least half never recovered; ``nan`` for no recoveries)
    """
    if measure not in ("episodes", "steps", "seconds"):
        raise ValueError(f"measure must be 'episodes', 'steps' or 'seconds', got {measure!r}")
    values = sorted(getattr(r, measure) for r in recoveries)
    if not values:
        return math.nan
    middle = len(values) // 2
    if len(values) % 2:
        return values[middle]
    low, high = values[middle - 1], values[middle]
    return math.inf if math.isinf(high) else (low + high) / 2


def _number(value: float, digits: int = 0) -> str:
    return "not recovered" if math.isinf(value) else f"{value:.{digits}f}"


def recovery_table(recoveries: Sequence[Recovery]) -> str:
    """A Markdown table: one row per closure, then the medians."""
    lines = [
        "| closure | roads | routes using them | success right after | recovered after (episodes) | env steps | "
        "seconds | success / SPL at the end |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in recoveries:
        roads = ", ".join(f"{u}-{v}" for u, v in r.closure.closed) or "reopened " + ", ".join(
            f"{u}-{v}" for u, v in r.closure.reopened
        )
        affected = "-" if r.closure.routes_affected is None else str(r.closure.routes_affected)
        after = "-" if r.right_after is None else f"{r.right_after.success_rate:.3f}"
        end = "-" if r.last is None else f"{r.last.success_rate:.3f} / {r.last.spl:.3f}"
        lines.append(
            f"| {r.closure.description} | {roads} | {affected} | {after} | {_number(r.episodes)} | "
            f"{_number(r.steps)} | {_number(r.seconds, 1)} | {end} |"
        )
    if recoveries:
        lines.append(
            f"| **median** | | | | {_number(median_recovery(recoveries, 'episodes'))} | "
            f"{_number(median_recovery(recoveries, 'steps'))} | "
            f"{_number(median_recovery(recoveries, 'seconds'), 1)} | |"
        )
    return "\n".join(lines)
