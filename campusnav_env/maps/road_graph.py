"""
Road graph: intersections, roads, compass slots, the heading-relative transition table, hop distances and closures.

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

**Moving.** The agent's state is ``(node, heading)`` with flat index ``s = node * 4 + heading``; the actions are
``FORWARD, RIGHT, BACK, LEFT = 0, 1, 2, 3``. From ``(u, h)`` action ``a`` takes the road in slot ``d = (h + a) % 4``.
If there is no open road there the move is blocked and the agent stays at ``(u, h)`` (a collision). Otherwise it
arrives at ``v`` facing away from the road it came along: ``h' = (slot of the road at v + 2) % 4``, i.e. it keeps
going "straight on". Hence ``BACK`` always returns along the same road, and forward-then-back leaves the agent at
its start node facing the opposite way of the road it had taken, ``(d + 2) % 4``.

**Closures.** Closing a road writes -1 into both of its directions in :attr:`RoadGraph.node_table` and
:attr:`RoadGraph.transition_table` and bumps :attr:`RoadGraph.version`, which invalidates the cached hop distances.
A closure that would cut a protected node (by default every landmark) off from a node that can reach it now is
refused with :class:`RoadClosureError` unless ``force=True``. Reopening restores the tables exactly.
"""

from __future__ import annotations

import hashlib
import itertools
import json
from collections import deque
from collections.abc import Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import networkx

FORWARD, RIGHT, BACK, LEFT = 0, 1, 2, 3
ACTION_NAMES = ("forward", "right", "back", "left")
COMPASS = ("N", "E", "S", "W")

# Bearing of each compass slot, degrees clockwise from north
SLOT_BEARINGS = np.array([0.0, 90.0, 180.0, 270.0])
# All injective road -> slot maps for k roads, in lexicographic order (ties go to the first one)
_SLOT_MAPS = {k: np.array(list(itertools.permutations(range(4), k)), dtype=np.int64) for k in range(1, 5)}
# _ACTION_SLOT[h, a]: compass slot that action a points to at heading h
_ACTION_SLOT = (np.arange(4)[:, None] + np.arange(4)[None, :]) % 4
_COST_DECIMALS = 7
_FINGERPRINT_VERSION = b"campusnav-road-graph-v1"


class RoadClosureError(ValueError):
    """A road closure was refused because it would cut a protected node off from nodes that reach it now."""


def bearing_degrees(dx: np.ndarray | float, dy: np.ndarray | float) -> np.ndarray:
    """
    Compass bearing of a displacement, degrees clockwise from north in ``[0, 360)``.

    :param dx: Displacement east (metres)
    :param dy: Displacement north (metres)
    :return: ``degrees(atan2(dx, dy)) % 360``
    """
    return np.degrees(np.arctan2(dx, dy)) % 360.0


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


def require_networkx() -> Any:
    """The networkx module, or an ImportError that says how to install it."""
    try:
        import networkx
    except ImportError as error:  # pragma: no cover - networkx is installed in the test environment
        raise ImportError(
            "networkx is needed to import or export road graphs; install it with `pip install sb3-dcqn[osm]`"
        ) from error
    return networkx


class RoadGraph:
    """
    An undirected road network whose intersections have at most four roads, with heading-relative moves.

    :param positions: Intersection coordinates, shape ``(N, 2)``, metres (x east, y north)
    :param roads: Undirected roads as node pairs; stored canonically as ``(min, max)``, list index = road id
    :param geometries: Optional polyline of each road, shape ``(k, 2)`` with ``k >= 2``, from ``roads[i][0]`` to
        ``roads[i][1]`` as given (reversed when stored canonically), endpoints included; straight lines if ``None``
    :param landmarks: Optional mapping from a landmark name to its node
    :param name: Name of the graph
    """

    def __init__(
        self,
        positions: np.ndarray,
        roads: Sequence[tuple[int, int]],
        *,
        geometries: Sequence[np.ndarray] | None = None,
        landmarks: Mapping[str, int] | None = None,
        name: str = "road-graph",
    ) -> None:
        positions = np.array(positions, dtype=np.float64)
        if positions.ndim != 2 or positions.shape[1] != 2 or positions.shape[0] == 0:
            raise ValueError(f"positions must have shape (N, 2) with N >= 1, got {positions.shape}")
        bad = np.flatnonzero(~np.isfinite(positions).all(axis=1))
        if bad.size:
            raise ValueError(f"positions of node {int(bad[0])} are not finite: {positions[bad[0]].tolist()}")
        n_nodes = positions.shape[0]
        given = self._validate_roads(roads, n_nodes)
        canonical = [(min(u, v), max(u, v)) for u, v in given]
        points, offsets = self._build_geometries(positions, given, geometries)
        # Road length = difference of the running length at its last and first point
        running = np.concatenate([[0.0], np.cumsum(np.sqrt((np.diff(points, axis=0) ** 2).sum(axis=1)))])
        lengths = running[offsets[1:] - 1] - running[offsets[:-1]]
        short = np.flatnonzero(~(lengths > 0.0))
        if short.size:
            raise ValueError(f"road {int(short[0])} {given[short[0]]} has zero length")

        self.name = str(name)
        self.n_nodes = n_nodes
        self.n_states = n_nodes * 4
        for array in (positions, points, lengths):
            array.flags.writeable = False
        self.positions = positions
        self.roads = canonical
        self.geometries = np.split(points, offsets[1:-1]) if canonical else []
        self.lengths = lengths
        self.landmarks = self._validate_landmarks(landmarks, n_nodes)
        self._road_index = {road: i for i, road in enumerate(canonical)}
        self._build_slots(points, offsets)
        self._closed: set[int] = set()
        self.version = 0
        self._init_tables()

    # ------------------------------------------------------------------ construction
    @staticmethod
    def _validate_roads(roads: Sequence[tuple[int, int]], n_nodes: int) -> list[tuple[int, int]]:
        given: list[tuple[int, int]] = []
        seen: dict[tuple[int, int], int] = {}
        degree = np.zeros(n_nodes, dtype=np.int64)
        for i, road in enumerate(roads):
            try:
                u, v = (int(x) for x in road)
            except (TypeError, ValueError) as error:
                raise ValueError(f"road {i} must be a pair of node ids, got {road!r}") from error
            for node in (u, v):
                if not 0 <= node < n_nodes:
                    raise ValueError(f"road {i} ({u}, {v}) refers to node {node}, out of range [0, {n_nodes})")
            if u == v:
                raise ValueError(f"road {i} ({u}, {v}) is a self loop")
            key = (min(u, v), max(u, v))
            if key in seen:
                raise ValueError(f"road {i} ({u}, {v}) duplicates road {seen[key]} {key}")
            seen[key] = i
            degree[u] += 1
            degree[v] += 1
            given.append((u, v))
        crowded = np.flatnonzero(degree > 4)
        if crowded.size:
            node = int(crowded[0])
            raise ValueError(f"node {node} has {int(degree[node])} roads, at most 4 are allowed")
        return given

    @staticmethod
    def _build_geometries(
        positions: np.ndarray, given: list[tuple[int, int]], geometries: Sequence[np.ndarray] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        """
        Validate the polylines and store them canonically (from the lower to the higher node id).

        :return: ``(points, offsets)``: all polylines concatenated, shape ``(M, 2)``, and the start of each road's
            points, shape ``(E + 1,)``
        """
        ends = np.array(given, dtype=np.int64).reshape(-1, 2)
        if geometries is None:
            points = np.stack([positions[ends.min(axis=1)], positions[ends.max(axis=1)]], axis=1).reshape(-1, 2)
            offsets = np.arange(0, 2 * len(given) + 1, 2, dtype=np.int64)
        else:
            if len(geometries) != len(given):
                raise ValueError(f"got {len(geometries)} geometries for {len(given)} roads")
            lines = [np.asarray(geometry, dtype=np.float64) for geometry in geometries]
            for i, line in enumerate(lines):
                if line.ndim != 2 or line.shape[1] != 2 or line.shape[0] < 2:
                    raise ValueError(
                        f"geometry of road {i} {given[i]} must have shape (k, 2) with k >= 2, got {line.shape}"
                    )
            counts = np.array([line.shape[0] for line in lines], dtype=np.int64)
            offsets = np.concatenate([[0], np.cumsum(counts)])
            points = np.concatenate(lines) if lines else np.zeros((0, 2))
            bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
            if bad.size:
                i = int(np.searchsorted(offsets, bad[0], side="right") - 1)
                raise ValueError(f"geometry of road {i} {given[i]} has non-finite coordinates")
            first, last = offsets[:-1], offsets[1:] - 1
            tolerance = 1e-6 * max(1.0, float(np.abs(positions).max()))
            for column, index in ((0, first), (1, last)):
                off = np.abs(points[index] - positions[ends[:, column]]).max(axis=1) > tolerance
                if off.any():
                    i = int(np.flatnonzero(off)[0])
                    node = int(ends[i, column])
                    raise ValueError(
                        f"geometry of road {i} {given[i]} ends at {points[index[i]].tolist()} but node {node} is at "
                        f"{positions[node].tolist()}"
                    )
            # Snap the endpoints exactly onto the nodes so that bearings and lengths match them
            points[first] = positions[ends[:, 0]]
            points[last] = positions[ends[:, 1]]
            # Reverse the roads given from the higher to the lower node id (vectorised index permutation)
            flip = np.repeat(ends[:, 0] > ends[:, 1], counts)
            local = np.arange(points.shape[0]) - np.repeat(first, counts)
            reversed_index = np.repeat(last, counts) - local
            points = points[np.where(flip, reversed_index, np.arange(points.shape[0]))]
        return points, offsets

    @staticmethod
    def _validate_landmarks(landmarks: Mapping[str, int] | None, n_nodes: int) -> dict[str, int]:
        result: dict[str, int] = {}
        for label, node in (landmarks or {}).items():
            if not isinstance(label, str) or not label:
                raise ValueError(f"landmark names must be non-empty strings, got {label!r}")
            try:
                index = int(node)
            except (TypeError, ValueError) as error:
                raise ValueError(f"landmark {label!r} must map to a node id, got {node!r}") from error
            if not 0 <= index < n_nodes:
                raise ValueError(f"landmark {label!r} is at node {index}, out of range [0, {n_nodes})")
            result[label] = index
        return result

    def _build_slots(self, points: np.ndarray, offsets: np.ndarray) -> None:
        """Compute the compass slot of every road end, vectorised per degree class."""
        n_roads = len(self.roads)
        ends = np.array(self.roads, dtype=np.int64).reshape(n_roads, 2)
        # Bearing of each road leaving its lower endpoint (end 0) and its higher endpoint (end 1)
        out_bearing = np.empty((n_roads, 2), dtype=np.float64)
        first, last = offsets[:-1], offsets[1:] - 1
        for column, origin, neighbour in ((0, first, first + 1), (1, last, last - 1)):
            delta = points[neighbour] - points[origin]
            out_bearing[:, column] = bearing_degrees(delta[:, 0], delta[:, 1])
            # Rare repeated points: use the first point that differs from the node
            for e in np.flatnonzero(np.all(delta == 0.0, axis=1)):
                line = self.geometries[e]
                out_bearing[e, column] = initial_bearing(line if column == 0 else line[::-1])
        # Incidence lists: for every (road, end) the node it leaves from, grouped by node in road-id order
        end_node = ends.ravel()
        order = np.argsort(end_node, kind="stable")
        degree = np.bincount(end_node, minlength=self.n_nodes)
        start = np.concatenate([[0], np.cumsum(degree)[:-1]])
        end_slot = np.full(2 * n_roads, -1, dtype=np.int64)
        for k in range(1, 5):
            nodes_k = np.flatnonzero(degree == k)
            if nodes_k.size == 0:
                continue
            members = order[(start[nodes_k][:, None] + np.arange(k)[None, :])]  # (M, k) flat (road, end) ids
            slots_k, _ = compass_slots(out_bearing.ravel()[members])
            end_slot[members] = slots_k
        end_slot = end_slot.reshape(n_roads, 2)
        slots = np.full((self.n_nodes, 4), -1, dtype=np.int64)
        road_at = np.full((self.n_nodes, 4), -1, dtype=np.int64)
        entry = np.full((self.n_nodes, 4), -1, dtype=np.int64)  # slot of the same road at the other end
        road_ids = np.arange(n_roads)
        for this, other in ((0, 1), (1, 0)):
            slots[ends[:, this], end_slot[:, this]] = ends[:, other]
            road_at[ends[:, this], end_slot[:, this]] = road_ids
            entry[ends[:, this], end_slot[:, this]] = end_slot[:, other]
        # Flat state reached through each (node, slot) when the road is open
        arrival = np.where(slots >= 0, slots * 4 + (entry + 2) % 4, -1)
        for array in (slots, road_at, arrival, end_slot):
            array.flags.writeable = False
        self.slots = slots
        self._road_at = road_at
        self._arrival = arrival
        self._end_slot = end_slot

    def _init_tables(self) -> None:
        self._node_table = self.slots.copy()
        self._transition = self._arrival[:, _ACTION_SLOT].reshape(self.n_states, 4)
        self._refresh_views()
        self._hops_cache: dict[int, np.ndarray] = {}
        self._hops_version = self.version
        self._adjacency: list[list[tuple[int, int]]] | None = None

    def _refresh_views(self) -> None:
        # Read-only views: callers see every closure in place but cannot write into the tables
        self.node_table = self._node_table.view()
        self.node_table.flags.writeable = False
        self.transition_table = self._transition.view()
        self.transition_table.flags.writeable = False

    # ------------------------------------------------------------------ queries
    @property
    def state_nodes(self) -> np.ndarray:
        """``(n_states,)`` intersection of each flat state ``s = node * 4 + heading``."""
        return np.repeat(np.arange(self.n_nodes, dtype=np.int64), 4)

    @property
    def state_headings(self) -> np.ndarray:
        """``(n_states,)`` compass heading of each flat state."""
        return np.tile(np.arange(4, dtype=np.int64), self.n_nodes)

    @property
    def n_roads(self) -> int:
        """Number of roads (open or closed)."""
        return len(self.roads)

    @property
    def degrees(self) -> np.ndarray:
        """Number of roads at each node, ignoring closures, shape ``(N,)``."""
        return (self.slots >= 0).sum(axis=1)

    @property
    def closed_roads(self) -> frozenset[tuple[int, int]]:
        """The closed roads as canonical ``(min, max)`` pairs."""
        return frozenset(self.roads[e] for e in self._closed)

    def road_id(self, u: int, v: int) -> int:
        """
        Id of the road between two nodes (either order).

        :raises KeyError: if there is no road between ``u`` and ``v``
        """
        u, v = int(u), int(v)
        try:
            return self._road_index[(min(u, v), max(u, v))]
        except KeyError:
            raise KeyError(f"no road between nodes {u} and {v}") from None

    def is_closed(self, u: int, v: int) -> bool:
        """Whether the road between ``u`` and ``v`` is closed (``KeyError`` if there is none)."""
        return self.road_id(u, v) in self._closed

    def step(self, node: int, heading: int, action: int) -> tuple[int, int, bool]:
        """
        Apply a heading-relative action.

        :param node: Current node
        :param heading: Current heading (compass slot 0..3)
        :param action: ``FORWARD``, ``RIGHT``, ``BACK`` or ``LEFT``
        :return: ``(node', heading', blocked)``; when blocked the state is unchanged
        """
        if not 0 <= node < self.n_nodes:
            raise ValueError(f"node {node} out of range [0, {self.n_nodes})")
        if not 0 <= heading < 4 or not 0 <= action < 4:
            raise ValueError(f"heading and action must be in 0..3, got heading={heading}, action={action}")
        nxt = int(self._transition[node * 4 + heading, action])
        if nxt < 0:
            return int(node), int(heading), True
        return nxt // 4, nxt % 4, False

    def hops_to(self, goal: int) -> np.ndarray:
        """
        Shortest-path distances in hops (roads travelled) from every node to ``goal`` over open roads.

        Cached per ``(goal, version)``; the returned array is read-only.

        :return: Shape ``(N,)`` int64, ``-1`` where the goal is unreachable
        """
        goal = self._check_node(goal, "goal")
        if self._hops_version != self.version:
            self._hops_cache.clear()
            self._hops_version = self.version
        hops = self._hops_cache.get(goal)
        if hops is None:
            hops = self._bfs_hops(goal)
            hops.flags.writeable = False
            self._hops_cache[goal] = hops
        return hops

    def shortest_path(self, start: int, goal: int) -> list[int]:
        """
        One shortest path (in hops) over open roads, as a node list from ``start`` to ``goal``.

        Ties go to the lowest compass slot. Returns an empty list when the goal is unreachable.
        """
        start = self._check_node(start, "start")
        hops = self.hops_to(goal)
        if hops[start] < 0:
            return []
        path = [start]
        node = start
        while hops[node] > 0:
            row = self._node_table[node]
            node = int(next(v for v in row if v >= 0 and hops[v] == hops[node] - 1))
            path.append(node)
        return path

    def _bfs_hops(self, goal: int) -> np.ndarray:
        # Frontier-at-a-time BFS in numpy: one vectorised step per hop, fast for 10,000 nodes
        hops = np.full(self.n_nodes, -1, dtype=np.int64)
        hops[goal] = 0
        frontier = np.array([goal], dtype=np.int64)
        distance = 0
        while frontier.size:
            distance += 1
            nxt = self._node_table[frontier].ravel()
            nxt = nxt[nxt >= 0]
            nxt = np.unique(nxt[hops[nxt] < 0])
            hops[nxt] = distance
            frontier = nxt
        return hops

    def _check_node(self, node: int, what: str = "node") -> int:
        index = int(node)
        if not 0 <= index < self.n_nodes:
            raise ValueError(f"{what} {node} out of range [0, {self.n_nodes})")
        return index

    # ------------------------------------------------------------------ closures
    def close_road(self, u: int, v: int, *, protect: Iterable[int] | None = None, force: bool = False) -> None:
        """
        Close the road between ``u`` and ``v`` in both directions.

        :param protect: Nodes that must stay reachable from every node that reaches them now; defaults to all
            landmark nodes
        :param force: Close even if a protected node gets cut off
        :raises KeyError: if there is no such road
        :raises ValueError: if the road is already closed
        :raises RoadClosureError: if the closure would cut a protected node off (and ``force`` is False)
        """
        road = self.road_id(u, v)
        a, b = self.roads[road]
        if road in self._closed:
            raise ValueError(f"road ({a}, {b}) is already closed")
        if not force:
            protected = self._protected_nodes(protect)
            cut = self._cut_protected(road, self._closed, protected)
            if cut is not None:
                node, n_cut = cut
                labels = [label for label, n in self.landmarks.items() if n == node]
                label = f" ({', '.join(labels)})" if labels else ""
                raise RoadClosureError(
                    f"closing road ({a}, {b}) would cut protected node {node}{label} off from {n_cut} node(s) that "
                    "reach it now; pass force=True to close it anyway"
                )
        self._closed.add(road)
        self._set_road_open(road, False)

    def reopen_road(self, u: int, v: int) -> None:
        """
        Reopen a closed road, restoring both directions of the tables exactly.

        :raises KeyError: if there is no such road
        :raises ValueError: if the road is not closed
        """
        road = self.road_id(u, v)
        if road not in self._closed:
            a, b = self.roads[road]
            raise ValueError(f"road ({a}, {b}) is not closed")
        self._closed.remove(road)
        self._set_road_open(road, True)

    def _set_road_open(self, road: int, is_open: bool) -> None:
        for end, node in enumerate(self.roads[road]):
            slot = self._end_slot[road, end]
            self._node_table[node, slot] = self.slots[node, slot] if is_open else -1
            row = np.where(self._node_table[node] >= 0, self._arrival[node], -1)
            self._transition[node * 4 : node * 4 + 4] = row[_ACTION_SLOT]
        self.version += 1

    def sample_closures(
        self, k: int, rng: np.random.Generator, *, protect: Iterable[int] | None = None
    ) -> list[tuple[int, int]]:
        """
        Draw ``k`` distinct open roads that can be closed together without cutting any protected node off.

        Greedy random selection with rejection: roads are tried in random order and kept when closing them (on top of
        those kept so far) leaves every protected node reachable from every node that reaches it now. The roads are
        returned (canonical pairs, in the order drawn), not closed.

        :param k: Number of roads
        :param rng: Source of randomness (the result is deterministic for a given generator state)
        :param protect: Protected nodes; defaults to all landmark nodes
        :raises ValueError: if ``k`` is negative or no such set of ``k`` roads exists
        """
        if k < 0:
            raise ValueError(f"k must be non-negative, got {k}")
        protected = self._protected_nodes(protect)
        candidates = [e for e in range(self.n_roads) if e not in self._closed]
        if k > len(candidates):
            raise ValueError(f"cannot close {k} roads: only {len(candidates)} are open")
        chosen: list[int] = []
        closed = set(self._closed)
        for index in rng.permutation(len(candidates)):
            if len(chosen) == k:
                break
            road = candidates[int(index)]
            # Greedy is exact here: a road rejected now stays a bridge to a protected node after further closures
            if self._cut_protected(road, closed, protected) is None:
                chosen.append(road)
                closed.add(road)
        if len(chosen) < k:
            raise ValueError(
                f"cannot close {k} roads without cutting a protected node off: at most {len(chosen)} can be closed"
            )
        return [self.roads[e] for e in chosen]

    def _protected_nodes(self, protect: Iterable[int] | None) -> set[int]:
        if protect is None:
            return set(self.landmarks.values())
        return {self._check_node(node, "protected node") for node in protect}

    def _road_adjacency(self) -> list[list[tuple[int, int]]]:
        """(neighbour, road id) lists over all roads, open or closed; built once, shared by copies."""
        if self._adjacency is None:
            self._adjacency = [
                [(v, e) for v, e in zip(row, road_row, strict=True) if v >= 0]
                for row, road_row in zip(self.slots.tolist(), self._road_at.tolist(), strict=True)
            ]
        return self._adjacency

    def _cut_protected(self, road: int, closed: set[int], protected: set[int]) -> tuple[int, int] | None:
        """
        If closing ``road`` on top of ``closed`` disconnects some node from a protected node, return that protected
        node and the number of nodes cut off from it; otherwise ``None``.
        """
        if not protected:
            return None
        adjacency = self._road_adjacency()  # closed roads are skipped through ``closed``
        u, v = self.roads[road]
        # Search from u without the road, stopping early once v is found (the usual case: a nearby cycle)
        side_u = self._component(u, adjacency, closed, road, stop=v)
        if v in side_u:
            return None
        side_v = self._component(v, adjacency, closed, road, stop=None)
        for side, other in ((side_u, side_v), (side_v, side_u)):
            hit = protected & side
            if hit:
                return min(hit), len(other)
        return None

    @staticmethod
    def _component(
        source: int, adjacency: list[list[tuple[int, int]]], closed: set[int], skip: int, stop: int | None
    ) -> set[int]:
        seen = {source}
        queue = deque([source])
        while queue:
            node = queue.popleft()
            for nxt, e in adjacency[node]:
                if nxt in seen or e == skip or e in closed:
                    continue
                seen.add(nxt)
                if nxt == stop:
                    return seen
                queue.append(nxt)
        return seen

    # ------------------------------------------------------------------ copies, identity, export
    def copy(self) -> RoadGraph:
        """A copy with independent closures; the immutable geometry (positions, polylines, slots) is shared."""
        clone = object.__new__(type(self))
        clone.__dict__.update(self.__dict__)
        clone.landmarks = dict(self.landmarks)
        clone.roads = list(self.roads)
        clone.geometries = list(self.geometries)
        clone._closed = set(self._closed)
        clone._node_table = self._node_table.copy()
        clone._transition = self._transition.copy()
        clone._refresh_views()
        clone._hops_cache = dict(self._hops_cache)  # cached arrays are read-only, safe to share
        return clone

    def __getstate__(self) -> dict[str, Any]:
        # The public tables are views of the private ones; pickling would detach them, so they are rebuilt on load
        state = self.__dict__.copy()
        for key in ("node_table", "transition_table", "_hops_cache", "_adjacency"):
            state.pop(key, None)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        for array in (self.positions, self.lengths, self.slots, self._road_at, self._arrival, self._end_slot):
            array.flags.writeable = False
        for line in self.geometries:
            line.flags.writeable = False
        self._refresh_views()
        self._hops_cache = {}
        self._hops_version = self.version
        self._adjacency = None

    def fingerprint(self) -> str:
        """
        SHA-256 hex digest of the positions, roads, geometries and landmarks (not the name, not the closures).

        Stable across processes and platforms (explicit little-endian dtypes, landmarks sorted by name) and
        independent of the order in which the roads were listed.
        """
        digest = hashlib.sha256(_FINGERPRINT_VERSION)
        digest.update(np.ascontiguousarray(self.positions, dtype="<f8").tobytes())
        roads = np.asarray(self.roads, dtype="<i8").reshape(-1, 2)
        order = np.lexsort((roads[:, 1], roads[:, 0]))  # independent of the order the roads were listed in
        digest.update(roads[order].tobytes())
        if self.geometries:
            lines = [self.geometries[i] for i in order]
            digest.update(np.array([len(line) for line in lines], dtype="<i8").tobytes())
            digest.update(np.ascontiguousarray(np.concatenate(lines), dtype="<f8").tobytes())
        digest.update(json.dumps(sorted(self.landmarks.items())).encode("utf-8"))
        return digest.hexdigest()

    def to_networkx(self) -> networkx.Graph:
        """
        Export to an undirected ``networkx.Graph``.

        Nodes carry ``x``, ``y`` and, for landmarks, ``name``; edges carry ``road_id``, ``length``, ``closed`` and the
        polyline as a WKT ``geometry`` string, so that :func:`campusnav_env.maps.osm.graph_from_networkx` reads it back.
        """
        nx = require_networkx()
        graph = nx.Graph(name=self.name, crs="local metres")
        names: dict[int, str] = {}
        for label, node in self.landmarks.items():
            names.setdefault(node, label)
        for node, (x, y) in enumerate(self.positions.tolist()):
            attrs: dict[str, Any] = {"x": x, "y": y}
            if node in names:
                attrs["name"] = names[node]
            graph.add_node(node, **attrs)
        for e, (u, v) in enumerate(self.roads):
            points = ", ".join(f"{x!r} {y!r}" for x, y in self.geometries[e].tolist())
            graph.add_edge(
                u,
                v,
                road_id=e,
                length=float(self.lengths[e]),
                closed=e in self._closed,
                geometry=f"LINESTRING ({points})",
            )
        return graph

    def __repr__(self) -> str:
        return (
            f"RoadGraph(name={self.name!r}, n_nodes={self.n_nodes}, n_roads={self.n_roads}, "
            f"landmarks={len(self.landmarks)}, closed={len(self._closed)})"
        )


def initial_bearing(line: np.ndarray) -> float:
    """Bearing of the first non-degenerate segment of a polyline, leaving ``line[0]``."""
    deltas = line[1:] - line[0]
    moved = np.flatnonzero(np.any(deltas != 0.0, axis=1))
    if moved.size == 0:
        raise ValueError(f"polyline starting at {line[0].tolist()} has zero length")
    dx, dy = deltas[moved[0]]
    return float(bearing_degrees(dx, dy))
