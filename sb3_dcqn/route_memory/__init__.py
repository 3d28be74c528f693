"""The route memory: one graph of an agent's own transitions, over recognised places, for every goal.

Its parts, one concern each, stand behind :class:`RouteMemory` (see :mod:`sb3_dcqn.route_memory.memory`):
:mod:`~sb3_dcqn.route_memory.places` (the recogniser), :mod:`~sb3_dcqn.route_memory.edges` (the moves),
:mod:`~sb3_dcqn.route_memory.goals` (where goals are), :mod:`~sb3_dcqn.route_memory.planner` (routes, the bounded
cache), :mod:`~sb3_dcqn.route_memory.explorer` (the way to the untried) and :mod:`~sb3_dcqn.route_memory.evidence`
(its predictions scored: where they fail, it stands aside). The layer that any discrete off-policy algorithm wears
to use it is :mod:`sb3_dcqn.route_memory.layer`.
"""

from sb3_dcqn.route_memory.edges import Outcome
from sb3_dcqn.route_memory.layer import RouteMemoryDCQN, RouteMemoryDQN, algorithm_name, with_route_memory
from sb3_dcqn.route_memory.memory import (
    BLOCKED,
    DEAD_END,
    DRIVEN,
    INFERRED,
    INFERRED_BLOCKED,
    NO_ROUTE,
    OUTSIDE,
    UNTRIED,
    PlaceMatcher,
    RouteMemory,
    UntriedExplorer,
    batch_of_one,
    default_goal_keys,
    select_rows,
)
from sb3_dcqn.route_memory.places import Answer, PlaceRecogniser

__all__ = [
    "BLOCKED",
    "DEAD_END",
    "DRIVEN",
    "INFERRED",
    "INFERRED_BLOCKED",
    "NO_ROUTE",
    "OUTSIDE",
    "UNTRIED",
    "Answer",
    "Outcome",
    "PlaceMatcher",
    "PlaceRecogniser",
    "RouteMemory",
    "RouteMemoryDCQN",
    "RouteMemoryDQN",
    "UntriedExplorer",
    "algorithm_name",
    "batch_of_one",
    "default_goal_keys",
    "select_rows",
    "with_route_memory",
]
