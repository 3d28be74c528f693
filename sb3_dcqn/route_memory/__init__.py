"""The route memory: one graph of an agent's own transitions, over recognised places, for every goal.

Its parts, one concern each, stand behind :class:`RouteMemory` (see :mod:`sb3_dcqn.route_memory.memory`); the layer
that any discrete off-policy algorithm wears to use it is :mod:`sb3_dcqn.route_memory.layer`.
"""

from sb3_dcqn.route_memory.layer import RouteMemoryDCQN, RouteMemoryDQN, algorithm_name, with_route_memory
from sb3_dcqn.route_memory.memory import (
    BLOCKED,
    DEAD_END,
    DRIVEN,
    INFERRED,
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

__all__ = [
    "BLOCKED",
    "DEAD_END",
    "DRIVEN",
    "INFERRED",
    "NO_ROUTE",
    "OUTSIDE",
    "UNTRIED",
    "PlaceMatcher",
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
