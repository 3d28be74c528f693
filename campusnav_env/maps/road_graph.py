"""
Road graph: the fixed map of a navigation task. Intersections, roads and their polylines, landmarks, the agent's
states and the transition table with every road open.

A :class:`RoadGraph` never changes after it is built, so many environments can share one. Closures are the changing
part and live apart from it, in :class:`campusnav_env.maps.navigation.NavigationGraph`.

Two kinds of maps build a ``RoadGraph``:

- **Street networks** (the generated campus, OpenStreetMap imports) through the constructor. Each road leaving an
  intersection occupies one compass slot (the rule in :mod:`campusnav_env.maps.compass`); the agent's state is
  ``(node, heading)`` with flat index ``s = node * 4 + heading``. From ``(u, h)`` action ``a`` takes the road in slot
  ``d = (h + a) % 4``; where there is no road the move is blocked and the agent stays at ``(u, h)``. Otherwise it
  arrives at ``v`` facing away from the road it came along, ``h' = (slot of the road at v + 2) % 4``: it keeps going
  "straight on". Hence ``BACK`` always returns along the same road, and forward-then-back leaves the agent at its
  start facing the opposite way of the road it had taken, ``(d + 2) % 4``.
- **Scene files** (Zhu et al.'s dumps) through :meth:`RoadGraph.from_transitions`: the file's states (a location and
  a compass heading each) and its transition table, whose actions mean whatever the file says. A *road* is a pair of
  locations joined by some transition, drawn as a straight line.

Either way the graph offers the same facts: ``state_nodes``/``state_headings`` of every state, ``transitions`` (next
state per action, -1 where no move is possible) and ``transition_roads`` (the road each transition travels, -1 for
none), which is all that moving, closing roads and measuring hop distances need.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Collection, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from campusnav_env.maps.compass import ACTION_SLOT, COMPASS, SLOT_BEARINGS, bearing_degrees, compass_slots
from campusnav_env.maps.refusals import Refusal

if TYPE_CHECKING:
    import networkx

__all__ = ["NoSuchRoadError", "RoadGraph", "require_networkx", "road_key"]

_FINGERPRINT_VERSION = b"campusnav-road-graph-v1"
_SCENE_FINGERPRINT_VERSION = b"campusnav-scene-graph-v1"


class NoSuchRoadError(Refusal, KeyError):
    """
    A road that is not on the map: a ``KeyError`` that says which (``u``, ``v``) and why, an end that is no node of the
    map (``missing``) or no road between two nodes that are.

    :param u: One end, as given
    :param v: The other end, as given
    :param map_name: The map's name
    :param n_nodes: Its number of nodes (ids ``0 .. n_nodes - 1``)
    """

    def __init__(self, u: int, v: int, map_name: str, n_nodes: int) -> None:
        self.u, self.v = int(u), int(v)
        self.missing = tuple(node for node in dict.fromkeys((self.u, self.v)) if not 0 <= node < n_nodes)
        ids = f"the map {map_name!r} (node ids 0..{n_nodes - 1})"
        if len(self.missing) == 1:
            reason = f"node {self.missing[0]} is not on {ids}"
        elif self.missing:
            reason = f"nodes {self.u} and {self.v} are not on {ids}"
        else:
            reason = f"no road between nodes {self.u} and {self.v} in {map_name!r}"
        super().__init__(self._refuse(reason))


def road_key(u: int, v: int) -> tuple[int, int]:
    """The canonical ``(min, max)`` node pair of the undirected road between ``u`` and ``v``."""
    u, v = int(u), int(v)
    return (u, v) if u <= v else (v, u)


def require_networkx() -> Any:
    """The networkx module, or an ImportError that says how to install it."""
    try:
        import networkx
    except ImportError as error:  # pragma: no cover - networkx is installed in the test environment
        raise ImportError(
            "networkx is needed to import or export road graphs; install it with `pip install sb3-dcqn[osm]`"
        ) from error
    return networkx


def _read_only(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


class RoadGraph:
    """
    An immutable road network whose intersections have at most four roads, with heading-relative moves.

    :param positions: Intersection coordinates, shape ``(N, 2)``, metres (x east, y north)
    :param roads: Undirected roads as node pairs; stored canonically as ``(min, max)``, list index = road id
    :param geometries: Optional polyline of each road, shape ``(k, 2)`` with ``k >= 2``, from ``roads[i][0]`` to
        ``roads[i][1]`` as given (reversed when stored canonically), endpoints included; straight lines if ``None``
    :param landmarks: Optional mapping from a landmark name to its node
    :param name: Name of the graph
    """

    slots: np.ndarray | None
    slot_bearings: np.ndarray | None

    def __init__(
        self,
        positions: np.ndarray,
        roads: Sequence[tuple[int, int]],
        *,
        geometries: Sequence[np.ndarray] | None = None,
        landmarks: Mapping[str, int] | None = None,
        name: str = "road-graph",
    ) -> None:
        positions = _check_positions(positions)
        n_nodes = positions.shape[0]
        given = _validate_roads(roads, n_nodes, max_degree=4)
        points, offsets = _build_geometries(positions, given, geometries)
        # Road length = difference of the running length at its last and first point
        running = np.concatenate([[0.0], np.cumsum(np.sqrt((np.diff(points, axis=0) ** 2).sum(axis=1)))])
        lengths = running[offsets[1:] - 1] - running[offsets[:-1]]
        short = np.flatnonzero(~(lengths > 0.0))
        if short.size:
            raise ValueError(f"road {int(short[0])} {given[short[0]]} has zero length")
        roads = [road_key(u, v) for u, v in given]
        geometries = np.split(points, offsets[1:-1]) if roads else []
        slots, road_at, arrival, slot_bearings = _compass_structure(n_nodes, roads, points, offsets)
        self._set_parts(
            name=name,
            positions=positions,
            roads=roads,
            geometries=geometries,
            lengths=lengths,
            landmarks=landmarks,
            state_nodes=np.repeat(np.arange(n_nodes, dtype=np.int64), 4),
            state_headings=np.tile(np.arange(4, dtype=np.int64), n_nodes),
            transitions=arrival[:, ACTION_SLOT].reshape(-1, 4),
            transition_roads=road_at[:, ACTION_SLOT].reshape(-1, 4),
        )
        self.slots = _read_only(slots)
        self.slot_bearings = _read_only(slot_bearings)

    @classmethod
    def from_transitions(
        cls,
        transitions: np.ndarray,
        state_nodes: np.ndarray,
        state_headings: np.ndarray,
        positions: np.ndarray,
        *,
        landmarks: Mapping[str, int] | None = None,
        name: str = "scene",
    ) -> RoadGraph:
        """
        A graph over explicit states and transitions, as in a scene file.

        :param transitions: ``(S, A)`` next state of each action, -1 where the move is impossible
        :param state_nodes: ``(S,)`` node (location) of each state
        :param state_headings: ``(S,)`` compass heading (0 N, 1 E, 2 S, 3 W) of each state; no two states may share a
            node and a heading
        :param positions: ``(N, 2)`` coordinates of the nodes
        :param landmarks: Optional mapping from a landmark name to its node
        :param name: Name of the graph
        :return: the graph; its roads are the node pairs joined by some transition, drawn as straight lines, and it
            has no compass slots (``slots`` and ``slot_bearings`` are ``None``)
        :raises ValueError: on inconsistent shapes, out-of-range entries or duplicate ``(node, heading)`` pairs
        """
        positions = _check_positions(positions)
        n_nodes = positions.shape[0]
        transitions = np.array(transitions, dtype=np.int64)
        if transitions.ndim != 2 or transitions.shape[1] == 0:
            raise ValueError(f"transitions must have shape (S, A) with A >= 1, got {transitions.shape}")
        n_states = transitions.shape[0]
        state_nodes = np.array(state_nodes, dtype=np.int64).reshape(-1)
        state_headings = np.array(state_headings, dtype=np.int64).reshape(-1)
        for label, array, high in (("state_nodes", state_nodes, n_nodes), ("state_headings", state_headings, 4)):
            if array.shape != (n_states,):
                raise ValueError(f"{label} has {array.shape[0]} entries for {n_states} states")
            bad = np.flatnonzero((array < 0) | (array >= high))
            if bad.size:
                raise ValueError(f"{label}[{int(bad[0])}] = {int(array[bad[0]])} is out of range [0, {high})")
        bad = np.flatnonzero(((transitions < -1) | (transitions >= n_states)).any(axis=1))
        if bad.size:
            raise ValueError(f"transition row {int(bad[0])} points to a state outside [0, {n_states}) (or < -1)")
        if np.unique(state_nodes * 4 + state_headings).size != n_states:
            raise ValueError("two states share a node and a compass heading")
        source, action = np.nonzero(transitions >= 0)
        ends = np.sort(np.stack([state_nodes[source], state_nodes[transitions[source, action]]], axis=1), axis=1)
        moving = ends[:, 0] != ends[:, 1]  # turning on the spot travels no road
        pairs = np.unique(ends[moving], axis=0).reshape(-1, 2)
        roads = [(int(u), int(v)) for u, v in pairs]
        transition_roads = np.full(transitions.shape, -1, dtype=np.int64)
        if roads:
            road_ids = np.searchsorted(pairs[:, 0] * n_nodes + pairs[:, 1], ends[:, 0] * n_nodes + ends[:, 1])
            transition_roads[source[moving], action[moving]] = road_ids[moving]
        geometries = [positions[[u, v]] for u, v in roads]
        graph = cls.__new__(cls)
        graph._set_parts(
            name=name,
            positions=positions,
            roads=roads,
            geometries=geometries,
            lengths=np.array([np.linalg.norm(g[1] - g[0]) for g in geometries], dtype=np.float64),
            landmarks=landmarks,
            state_nodes=state_nodes,
            state_headings=state_headings,
            transitions=transitions,
            transition_roads=transition_roads,
        )
        graph.slots = None
        graph.slot_bearings = None
        return graph

    def _set_parts(
        self,
        *,
        name: str,
        positions: np.ndarray,
        roads: list[tuple[int, int]],
        geometries: Sequence[np.ndarray],
        lengths: np.ndarray,
        landmarks: Mapping[str, int] | None,
        state_nodes: np.ndarray,
        state_headings: np.ndarray,
        transitions: np.ndarray,
        transition_roads: np.ndarray,
    ) -> None:
        self.name = str(name)
        self.n_nodes = positions.shape[0]
        self.n_states = state_nodes.shape[0]
        self.n_actions = transitions.shape[1]
        self.positions = _read_only(positions)
        self.roads: tuple[tuple[int, int], ...] = tuple(roads)
        self.geometries: tuple[np.ndarray, ...] = tuple(_read_only(np.asarray(g, dtype=np.float64)) for g in geometries)
        self.lengths = _read_only(np.asarray(lengths, dtype=np.float64))
        self._landmarks = _validate_landmarks(landmarks, self.n_nodes)
        self.state_nodes = _read_only(state_nodes)
        self.state_headings = _read_only(state_headings)
        state_of = np.full((self.n_nodes, 4), -1, dtype=np.int64)
        state_of[state_nodes, state_headings] = np.arange(self.n_states)
        self.state_of = _read_only(state_of)
        self.transitions = _read_only(transitions)
        self.transition_roads = _read_only(transition_roads)
        self._road_index = {road: i for i, road in enumerate(self.roads)}

    # ------------------------------------------------------------------ queries
    @property
    def landmarks(self) -> dict[str, int]:
        """Landmark name -> node (a copy: the graph itself never changes)."""
        return dict(self._landmarks)

    @property
    def n_roads(self) -> int:
        """Number of roads."""
        return len(self.roads)

    @property
    def degrees(self) -> np.ndarray:
        """Number of roads at each node, shape ``(N,)``."""
        ends = np.asarray(self.roads, dtype=np.int64).reshape(-1)
        return np.bincount(ends, minlength=self.n_nodes)

    def road_id(self, u: int, v: int) -> int:
        """
        Id of the road between two nodes (either order).

        :raises NoSuchRoadError: (a ``KeyError``) if there is no road between ``u`` and ``v``, naming an end that is
            not on the map
        """
        try:
            return self._road_index[road_key(u, v)]
        except KeyError:
            raise NoSuchRoadError(u, v, self.name, self.n_nodes) from None

    def check_node(self, node: int, what: str = "node") -> int:
        """
        ``node`` as an int, checked to be a node of this graph.

        :param what: What the node is, for the error message
        :raises ValueError: if it is out of range
        """
        if isinstance(node, bool) or not isinstance(node, (int, np.integer)):
            raise TypeError(f"{what} must be an int node id, got {node!r}")
        if not 0 <= int(node) < self.n_nodes:
            raise ValueError(f"{what} {node} out of range [0, {self.n_nodes})")
        return int(node)

    def state_index(self, node: int, heading: int) -> int:
        """
        Flat index of the state ``(node, heading)``.

        :raises ValueError: if the node is out of range or has no state with that heading
        """
        node = self.check_node(node)
        if not 0 <= heading < 4 or self.state_of[node, heading] < 0:
            available = [COMPASS[h] for h in np.flatnonzero(self.state_of[node] >= 0)]
            raise ValueError(f"node {node} has no state with heading {heading!r} (available: {available})")
        return int(self.state_of[node, heading])

    # ------------------------------------------------------------------ identity, export
    def fingerprint(self) -> str:
        """
        SHA-256 hex digest of the positions, roads, geometries and landmarks (and, for graphs built from
        transitions, the states and transitions); not the name.

        Stable across processes and platforms (explicit little-endian dtypes, landmarks sorted by name) and
        independent of the order in which the roads were listed.
        """
        digest = hashlib.sha256(_FINGERPRINT_VERSION if self.slots is not None else _SCENE_FINGERPRINT_VERSION)
        digest.update(np.ascontiguousarray(self.positions, dtype="<f8").tobytes())
        roads = np.asarray(self.roads, dtype="<i8").reshape(-1, 2)
        order = np.lexsort((roads[:, 1], roads[:, 0]))  # independent of the order the roads were listed in
        digest.update(roads[order].tobytes())
        if self.geometries:
            lines = [self.geometries[i] for i in order]
            digest.update(np.array([len(line) for line in lines], dtype="<i8").tobytes())
            digest.update(np.ascontiguousarray(np.concatenate(lines), dtype="<f8").tobytes())
        digest.update(json.dumps(sorted(self._landmarks.items())).encode("utf-8"))
        if self.slots is None:
            for array in (self.state_nodes, self.state_headings, self.transitions):
                digest.update(np.ascontiguousarray(array, dtype="<i8").tobytes())
        return digest.hexdigest()

    def to_networkx(self, closed_roads: Collection[tuple[int, int]] = ()) -> networkx.Graph:
        """
        Export to an undirected ``networkx.Graph``.

        Nodes carry ``x``, ``y`` and, for landmarks, ``name``; edges carry ``road_id``, ``length``, ``closed`` and the
        polyline as a WKT ``geometry`` string, so that :func:`campusnav_env.maps.osm.graph_from_networkx` reads it back.

        :param closed_roads: Roads to mark ``closed=True``
        """
        nx = require_networkx()
        closed = {road_key(u, v) for u, v in closed_roads}
        graph = nx.Graph(name=self.name, crs="local metres")
        names: dict[int, str] = {}
        for label, node in self._landmarks.items():
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
                closed=(u, v) in closed,
                geometry=f"LINESTRING ({points})",
            )
        return graph

    def __getstate__(self) -> dict[str, Any]:
        return self.__dict__.copy()

    def __setstate__(self, state: dict[str, Any]) -> None:
        # Unpickled arrays come back writable: the graph is immutable, so make them read-only again
        self.__dict__.update(state)
        for value in state.values():
            if isinstance(value, np.ndarray):
                value.flags.writeable = False
        for line in self.geometries:
            line.flags.writeable = False

    def __repr__(self) -> str:
        return (
            f"RoadGraph(name={self.name!r}, n_nodes={self.n_nodes}, n_roads={self.n_roads}, "
            f"n_states={self.n_states}, landmarks={len(self._landmarks)})"
        )


# ---------------------------------------------------------------------- construction helpers
def _check_positions(positions: np.ndarray) -> np.ndarray:
    positions = np.array(positions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 2 or positions.shape[0] == 0:
        raise ValueError(f"positions must have shape (N, 2) with N >= 1, got {positions.shape}")
    bad = np.flatnonzero(~np.isfinite(positions).all(axis=1))
    if bad.size:
        raise ValueError(f"positions of node {int(bad[0])} are not finite: {positions[bad[0]].tolist()}")
    return positions


def _validate_roads(roads: Sequence[tuple[int, int]], n_nodes: int, max_degree: int) -> list[tuple[int, int]]:
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
        key = road_key(u, v)
        if key in seen:
            raise ValueError(f"road {i} ({u}, {v}) duplicates road {seen[key]} {key}")
        seen[key] = i
        degree[u] += 1
        degree[v] += 1
        given.append((u, v))
    crowded = np.flatnonzero(degree > max_degree)
    if crowded.size:
        node = int(crowded[0])
        raise ValueError(f"node {node} has {int(degree[node])} roads, at most {max_degree} are allowed")
    return given


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
        return points, offsets
    if len(geometries) != len(given):
        raise ValueError(f"got {len(geometries)} geometries for {len(given)} roads")
    lines = [np.asarray(geometry, dtype=np.float64) for geometry in geometries]
    for i, line in enumerate(lines):
        if line.ndim != 2 or line.shape[1] != 2 or line.shape[0] < 2:
            raise ValueError(f"geometry of road {i} {given[i]} must have shape (k, 2) with k >= 2, got {line.shape}")
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


def _compass_structure(
    n_nodes: int, roads: list[tuple[int, int]], points: np.ndarray, offsets: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """
    Compass slots of every road end, vectorised per degree class.

    :return: ``(slots, road_at, arrival, slot_bearings)``, each ``(N, 4)``: the neighbour in each slot (-1 if
        empty), the road id in each slot (-1), the flat state reached through each slot (-1), and the initial bearing
        of the road in each slot (the slot's compass bearing where it is empty)
    """
    n_roads = len(roads)
    ends = np.array(roads, dtype=np.int64).reshape(n_roads, 2)
    # Bearing of each road leaving its lower endpoint (end 0) and its higher endpoint (end 1): the first segment
    # whose points differ (polylines may repeat a point)
    out_bearing = np.empty((n_roads, 2), dtype=np.float64)
    first, last = offsets[:-1], offsets[1:] - 1
    for column, origin, step in ((0, first, 1), (1, last, -1)):
        neighbour = origin + step
        delta = points[neighbour] - points[origin]
        repeated = np.all(delta == 0.0, axis=1)
        while repeated.any():  # rare: advance past repeated points (lengths > 0 guarantees one differs)
            neighbour = np.where(repeated, neighbour + step, neighbour)
            delta = points[neighbour] - points[origin]
            repeated = np.all(delta == 0.0, axis=1)
        out_bearing[:, column] = bearing_degrees(delta[:, 0], delta[:, 1])
    # Incidence lists: for every (road, end) the node it leaves from, grouped by node in road-id order
    end_node = ends.ravel()
    order = np.argsort(end_node, kind="stable")
    degree = np.bincount(end_node, minlength=n_nodes)
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
    slots = np.full((n_nodes, 4), -1, dtype=np.int64)
    road_at = np.full((n_nodes, 4), -1, dtype=np.int64)
    entry = np.full((n_nodes, 4), -1, dtype=np.int64)  # slot of the same road at the other end
    slot_bearings = np.tile(SLOT_BEARINGS, (n_nodes, 1))
    road_ids = np.arange(n_roads)
    for this, other in ((0, 1), (1, 0)):
        slots[ends[:, this], end_slot[:, this]] = ends[:, other]
        road_at[ends[:, this], end_slot[:, this]] = road_ids
        entry[ends[:, this], end_slot[:, this]] = end_slot[:, other]
        slot_bearings[ends[:, this], end_slot[:, this]] = out_bearing[:, this]
    # Flat state reached through each (node, slot): the far node, facing away from the road
    arrival = np.where(slots >= 0, slots * 4 + (entry + 2) % 4, -1)
    return slots, road_at, arrival, slot_bearings
