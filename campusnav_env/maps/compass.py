"""
Compass conventions: headings, heading-relative actions, bearings, the rule that gives each road a compass slot and
the bearing each view looks along.

**Compass slots.** Every intersection has four compass slots, ``0 = N, 1 = E, 2 = S, 3 = W`` (bearings 0, 90, 180 and
270 degrees clockwise from north, ``bearing = degrees(atan2(dx, dy)) % 360``). Each road leaving an intersection
occupies exactly one slot, so an intersection has at most four roads.

**Slot assignment.** The paper defines the actions by angular sectors around the agent's heading, but on an irregular
street grid sectors are ambiguous: two roads can fall into the same sector (one would be unreachable) and a sector can
be empty while a road sits on its border. Instead, the roads of an intersection are given distinct slots by an
exhaustive search over all injective road-to-slot maps (at most ``4! = 24``) that minimises the summed circular
angular difference between each road's *initial* bearing (its first polyline segment leaving the intersection) and
the bearing of its slot. Ties (to 1e-7 degree) go to the smaller sum of squared differences, then to the
lexicographically first map with the roads ordered by bearing (so the road with the smaller bearing takes the lower
slot number). Because the slots are distinct and action ``a`` at heading ``h`` points to slot ``(h + a) % 4`` (a
bijection between actions and slots for every heading), every road is reachable by exactly one action at every
heading, and no road is ever lost to a crowded sector.

**Actions.** ``FORWARD, RIGHT, BACK, LEFT = 0, 1, 2, 3``, relative to the heading: from ``(node, heading h)`` action
``a`` takes the road in slot ``(h + a) % 4``.

**View bearings.** View ``d`` of a node looks along the initial bearing of the road in slot ``d``, or along the slot's
compass bearing where the slot is empty (:func:`view_bearings`), so the road seen ahead is the road the action takes.
"""

from __future__ import annotations

import itertools
from typing import Protocol

import numpy as np

__all__ = [
    "ACTION_NAMES",
    "ACTION_SLOT",
    "BACK",
    "COMPASS",
    "FORWARD",
    "LEFT",
    "RIGHT",
    "SLOT_BEARINGS",
    "SlottedMap",
    "bearing_degrees",
    "compass_slots",
    "initial_bearing",
    "view_bearings",
]

FORWARD, RIGHT, BACK, LEFT = 0, 1, 2, 3
ACTION_NAMES = ("forward", "right", "back", "left")
COMPASS = ("N", "E", "S", "W")

# Bearing of each compass slot, degrees clockwise from north
SLOT_BEARINGS = np.array([0.0, 90.0, 180.0, 270.0])
# ACTION_SLOT[h, a]: compass slot that action a points to at heading h
ACTION_SLOT = (np.arange(4)[:, None] + np.arange(4)[None, :]) % 4
ACTION_SLOT.flags.writeable = False
# All injective road -> slot maps for k roads, in lexicographic order (ties go to the first one)
_SLOT_MAPS = {k: np.array(list(itertools.permutations(range(4), k)), dtype=np.int64) for k in range(1, 5)}
_COST_DECIMALS = 7


class SlottedMap(Protocol):
    """
    What :func:`view_bearings` reads of a map (a :class:`~campusnav_env.maps.road_graph.RoadGraph` has both): a
    protocol rather than the class, so that this module, which the road graph builds on, never imports it back.
    """

    @property
    def n_nodes(self) -> int: ...

    @property
    def slot_bearings(self) -> np.ndarray | None: ...


def bearing_degrees(dx: np.ndarray | float, dy: np.ndarray | float) -> np.ndarray:
    """
    Compass bearing of a displacement, degrees clockwise from north in ``[0, 360)``.

    :param dx: Displacement east (metres)
    :param dy: Displacement north (metres)
    :return: ``degrees(atan2(dx, dy)) % 360``
    """
    return np.degrees(np.arctan2(dx, dy)) % 360.0


def initial_bearing(line: np.ndarray) -> float:
    """
    Bearing of the first non-degenerate segment of a polyline, leaving ``line[0]``.

    :param line: Polyline of shape ``(k, 2)``
    :return: The bearing in degrees
    :raises ValueError: if all points coincide
    """
    deltas = line[1:] - line[0]
    moved = np.flatnonzero(np.any(deltas != 0.0, axis=1))
    if moved.size == 0:
        raise ValueError(f"polyline starting at {line[0].tolist()} has zero length")
    dx, dy = deltas[moved[0]]
    return float(bearing_degrees(dx, dy))


def compass_slots(bearings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """
    Assign distinct compass slots to the roads of intersections (the rule in the module docstring).

    :param bearings: Initial bearings in degrees, shape ``(M, k)`` with ``1 <= k <= 4``: ``M`` intersections with
        ``k`` roads each
    :return: ``(slots, cost)``: the slot of each road, shape ``(M, k)`` int64, and the minimal summed circular
        deviation in degrees, shape ``(M,)``
    """
    bearings = np.asarray(bearings, dtype=np.float64)
    if bearings.ndim != 2 or not 1 <= bearings.shape[1] <= 4:
        raise ValueError(f"bearings must have shape (M, k) with 1 <= k <= 4, got {bearings.shape}")
    n_rows, k = bearings.shape
    # Order roads by bearing (stable) so that the lexicographic tie-break does not depend on the input order
    order = np.argsort(bearings, axis=1, kind="stable")
    sorted_bearings = np.take_along_axis(bearings, order, axis=1)
    diff = np.abs(sorted_bearings[:, :, None] - SLOT_BEARINGS[None, None, :]) % 360.0
    diff = np.minimum(diff, 360.0 - diff)  # (M, k, 4)
    maps = _SLOT_MAPS[k]  # (m, k)
    picked = diff[:, np.arange(k)[None, :], maps]  # (M, m, k)
    cost = np.round(picked.sum(axis=2), _COST_DECIMALS)
    cost_sq = np.round((picked**2).sum(axis=2), _COST_DECIMALS - 3)
    best = cost.min(axis=1, keepdims=True)
    cost_sq = np.where(cost == best, cost_sq, np.inf)
    choice = np.argmin(cost_sq, axis=1)  # first minimum: lexicographic tie-break
    slots = np.empty((n_rows, k), dtype=np.int64)
    np.put_along_axis(slots, order, maps[choice], axis=1)
    return slots, best[:, 0]


def view_bearings(graph: SlottedMap) -> np.ndarray:
    """
    The bearing each view of each node looks along (degrees clockwise from north, in ``[0, 360)``).

    View ``d`` of a node looks along the initial bearing of the road in compass slot ``d`` (its first non-degenerate
    polyline segment leaving the node, ``graph.slot_bearings``), so that what the agent sees ahead in view ``d`` is the
    road that the action pointing to slot ``d`` takes; an empty slot keeps its compass bearing ``90 * d``. Graphs
    without compass slots (built from scene files, ``slot_bearings`` is ``None``) get the compass bearings everywhere.

    :param graph: The road network
    :return: ``(N, 4)`` float64 array, read-only
    """
    if graph.slot_bearings is None:
        bearings = np.tile(SLOT_BEARINGS, (graph.n_nodes, 1))
    else:
        bearings = np.array(graph.slot_bearings, dtype=np.float64)
        if bearings.shape != (graph.n_nodes, 4):
            raise ValueError(f"slot_bearings must have shape ({graph.n_nodes}, 4), got {bearings.shape}")
    bearings.flags.writeable = False
    return bearings
