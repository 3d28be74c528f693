"""When a map counts as solved: the one definition of the bar, used by the command line and every benchmark.

The greedy routes from every (start, heading) reach the goal with a success rate of at least :data:`SOLVED_SUCCESS`
and an SPL of at least :data:`SOLVED_SPL`, for each goal on its own. Recovery after a closure has its own, lower SPL
bar (:mod:`campusnav_env.recovery`: success 0.99, SPL 0.95).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from campusnav_env.recovery import RouteEvaluation

__all__ = ["SOLVED_SPL", "SOLVED_SUCCESS", "is_solved", "solved_bar"]

SOLVED_SUCCESS = 0.99
SOLVED_SPL = 0.98


def is_solved(evaluation: RouteEvaluation) -> bool:
    """Whether a route evaluation is at the solved bar (every goal on its own)."""
    return evaluation.meets(SOLVED_SUCCESS, SOLVED_SPL, every_goal=True)


def solved_bar() -> str:
    """The bar in words: ``"success >= 0.99, SPL >= 0.98"``."""
    return f"success >= {SOLVED_SUCCESS}, SPL >= {SOLVED_SPL}"
