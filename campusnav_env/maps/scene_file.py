"""Scene files in the format of Zhu et al.'s target-driven navigation dumps (HDF5), as a navigation graph.

A scene file holds one row per *state* (a camera pose): ``location`` ``(S, 2)``, ``rotation`` ``(S,)`` in degrees,
``graph`` ``(S, A)`` with the next state of each action or -1 where the move is impossible, ``resnet_feature``
``(S, D)`` (or ``(S, D, k)`` / ``(S, k, D)`` for ``k`` crops, averaged here), optionally ``observation``
``(S, H, W, 3)`` uint8 images and ``shortest_path_distance`` ``(S, S)``. Someone holding the real CampusNav.h5 (or an
AI2-THOR dump) can train on it with the same code as on the built-in campus.

Mapping onto CampusNav's model: an *intersection* (node) is a distinct location; a state's *heading* is its rotation
snapped to the compass (0 N, 90 E, 180 S, 270 W); a node's four views are the features of the states at that location
facing N, E, S, W (zeros where the file has no such state). Actions mean whatever the file's ``graph`` says (for
AI2-THOR dumps: forward, backward, turn left, turn right). A *road* is a pair of locations joined by some transition;
closing it removes every transition between them, both ways. Landmark names may be given as a JSON attribute
``landmarks`` (name -> location index) on the file's root; otherwise goals are location indices.
"""

from __future__ import annotations

import json
from collections import deque
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from campusnav_env.features.encoders import ThumbnailEncoder
from campusnav_env.maps.road_graph import RoadClosureError

REQUIRED_DATASETS = ("graph", "location", "rotation", "resnet_feature")
_THUMBNAIL = (48, 64)


class SceneGraph:
    """
    A scene file's states and transitions, with closures, in the interface the environment expects.

    :param transitions: ``(S, A)`` next state per action, -1 where impossible
    :param locations: ``(S, 2)`` location of each state
    :param rotations: ``(S,)`` rotation of each state in degrees
    :param landmarks: Optional name -> node (location index)
    :param name: Name of the scene
    """

    def __init__(
        self,
        transitions: np.ndarray,
        locations: np.ndarray,
        rotations: np.ndarray,
        *,
        landmarks: dict[str, int] | None = None,
        name: str = "scene",
    ) -> None:
        self.name = name
        self._open_table = np.asarray(transitions, dtype=np.int64)
        self.n_states = self._open_table.shape[0]
        rounded = np.round(np.asarray(locations, dtype=np.float64), 3)
        unique, self.state_nodes = np.unique(rounded, axis=0, return_inverse=True)
        self.state_nodes = self.state_nodes.reshape(-1).astype(np.int64)
        self.positions = unique
        self.n_nodes = unique.shape[0]
        self.state_headings = (np.round(np.asarray(rotations, dtype=np.float64) / 90.0).astype(np.int64)) % 4
        pairs = {(int(u), int(v)) for u, v in self._node_transitions() if u != v}
        self.roads = sorted({(min(u, v), max(u, v)) for u, v in pairs})
        self.geometries = [self.positions[[u, v]] for u, v in self.roads]
        self.landmarks = dict(landmarks or {})
        for landmark, node in self.landmarks.items():
            if not 0 <= node < self.n_nodes:
                raise ValueError(f"landmark {landmark!r}: location {node} out of range [0, {self.n_nodes})")
        self._closed: set[tuple[int, int]] = set()
        self.version = 0
        self.transition_table = self._open_table.copy()
        self._hops: dict[tuple[int, int], np.ndarray] = {}

    def _node_transitions(self) -> np.ndarray:
        states, actions = np.nonzero(self._open_table >= 0)
        return np.stack([self.state_nodes[states], self.state_nodes[self._open_table[states, actions]]], axis=1)

    @property
    def closed_roads(self) -> frozenset[tuple[int, int]]:
        return frozenset(self._closed)

    def _rebuild_table(self) -> None:
        table = self._open_table.copy()
        source = self.state_nodes[:, None].repeat(table.shape[1], axis=1)
        target = np.where(table >= 0, self.state_nodes[np.maximum(table, 0)], -1)
        for u, v in self._closed:
            blocked = ((source == u) & (target == v)) | ((source == v) & (target == u))
            table[blocked] = -1
        self.transition_table = table
        self.version += 1

    def hops_to(self, goal: int) -> np.ndarray:
        """Fewest actions from each location (its best state) to any state at ``goal``; -1 if unreachable."""
        if not 0 <= goal < self.n_nodes:
            raise ValueError(f"goal location {goal} out of range [0, {self.n_nodes})")
        key = (goal, self.version)
        if key not in self._hops:
            state_hops = self._state_hops_to(goal)
            node_hops = np.full(self.n_nodes, np.iinfo(np.int64).max, dtype=np.int64)
            reachable = state_hops >= 0
            np.minimum.at(node_hops, self.state_nodes[reachable], state_hops[reachable])
            node_hops[node_hops == np.iinfo(np.int64).max] = -1
            self._hops = {k: v for k, v in self._hops.items() if k[1] == self.version}
            self._hops[key] = node_hops
        return self._hops[key]

    def _state_hops_to(self, goal: int) -> np.ndarray:
        # Breadth-first search backwards from the goal's states over the reversed transitions
        predecessors: list[list[int]] = [[] for _ in range(self.n_states)]
        for state, nxt in zip(*np.nonzero(self.transition_table >= 0), strict=True):
            predecessors[int(self.transition_table[state, nxt])].append(int(state))
        hops = np.full(self.n_states, -1, dtype=np.int64)
        queue = deque(int(s) for s in np.flatnonzero(self.state_nodes == goal))
        for state in queue:
            hops[state] = 0
        while queue:
            state = queue.popleft()
            for previous in predecessors[state]:
                if hops[previous] < 0:
                    hops[previous] = hops[state] + 1
                    queue.append(previous)
        return hops

    def close_road(self, u: int, v: int, *, protect: Iterable[int] | None = None, force: bool = False) -> None:
        """Remove every transition between locations ``u`` and ``v``; see ``RoadGraph.close_road``."""
        road = (min(u, v), max(u, v))
        if road not in self.roads:
            raise KeyError(f"no road between locations {u} and {v} in scene {self.name!r}")
        if road in self._closed:
            raise ValueError(f"road ({u}, {v}) is already closed")
        protected = list(self.landmarks.values()) if protect is None else [int(p) for p in protect]
        before = {p: self.hops_to(p) >= 0 for p in protected}
        self._closed.add(road)
        self._rebuild_table()
        if force:
            return
        for node, reached_before in before.items():
            cut_off = np.flatnonzero(reached_before & (self.hops_to(node) < 0))
            if cut_off.size:
                self._closed.discard(road)
                self._rebuild_table()
                raise RoadClosureError(
                    f"closing road ({u}, {v}) would cut location {node} off from {cut_off.size} location(s) "
                    f"(e.g. {int(cut_off[0])}); pass force=True to close it anyway"
                )

    def reopen_road(self, u: int, v: int) -> None:
        road = (min(u, v), max(u, v))
        if road not in self._closed:
            raise ValueError(f"road ({u}, {v}) is not closed")
        self._closed.discard(road)
        self._rebuild_table()


class Scene:
    """A loaded scene file: its graph plus per-node view features (and thumbnails when the file has images)."""

    def __init__(self, graph: SceneGraph, node_features: np.ndarray, node_images: np.ndarray | None) -> None:
        self.graph = graph
        self.node_features = node_features
        self.node_images = node_images


def _per_node_views(graph: SceneGraph, per_state: np.ndarray) -> np.ndarray:
    views = np.zeros((graph.n_nodes, 4, *per_state.shape[1:]), dtype=per_state.dtype)
    views[graph.state_nodes, graph.state_headings] = per_state
    return views


def load_scene_file(path: str | Path) -> Scene:
    """
    Load a Zhu et al.-format HDF5 scene file.

    :param path: The ``.h5`` file
    :return: the scene (graph, per-node features in compass order, thumbnails if the file has images)
    :raises FileNotFoundError: no such file
    :raises KeyError: a required dataset is missing (named)
    :raises ValueError: datasets with inconsistent shapes or transitions to states that do not exist
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"scene file not found: {path}")
    try:
        import h5py
    except ImportError as error:
        raise ImportError('reading scene files needs h5py: pip install "sb3-dcqn[h5]"') from error

    try:
        file = h5py.File(path, "r")
    except OSError as error:
        raise ValueError(f"{path}: not a readable HDF5 file ({error})") from error
    with file:
        missing = [name for name in REQUIRED_DATASETS if name not in file]
        if missing:
            raise KeyError(f"{path}: missing dataset(s) {missing}; a scene file needs {list(REQUIRED_DATASETS)}")
        transitions = np.asarray(file["graph"][()], dtype=np.int64)
        locations = np.asarray(file["location"][()], dtype=np.float64)
        rotations = np.asarray(file["rotation"][()], dtype=np.float64).reshape(-1)
        features = np.asarray(file["resnet_feature"][()], dtype=np.float32)
        images = np.asarray(file["observation"][()]) if "observation" in file else None
        landmarks = json.loads(file.attrs["landmarks"]) if "landmarks" in file.attrs else None

    n_states = transitions.shape[0]
    if transitions.ndim != 2:
        raise ValueError(f"{path}: 'graph' must be 2-D (states, actions), got shape {transitions.shape}")
    for name, array in (("location", locations), ("rotation", rotations), ("resnet_feature", features)):
        if array.shape[0] != n_states:
            raise ValueError(f"{path}: {name!r} has {array.shape[0]} rows but 'graph' has {n_states} states")
    if locations.ndim != 2 or locations.shape[1] < 2:
        raise ValueError(f"{path}: 'location' must have shape (S, 2), got {locations.shape}")
    bad = np.flatnonzero(((transitions < -1) | (transitions >= n_states)).any(axis=1))
    if bad.size:
        raise ValueError(f"{path}: 'graph' row {int(bad[0])} points to a state outside [0, {n_states}) (or < -1)")
    if features.ndim == 3:
        # k crops per state: average them; the feature axis is the longer one
        features = features.mean(axis=1 if features.shape[1] < features.shape[2] else 2)
    features = features.reshape(n_states, -1)

    graph = SceneGraph(transitions, locations[:, :2], rotations, landmarks=landmarks, name=path.stem)
    duplicates = np.unique(graph.state_nodes * 4 + graph.state_headings).size != n_states
    if duplicates:
        raise ValueError(f"{path}: two states share a location and compass heading; cannot form per-node views")
    node_images = None
    if images is not None:
        thumbnails = ThumbnailEncoder(height=_THUMBNAIL[0], width=_THUMBNAIL[1]).encode(images.astype(np.uint8))
        node_images = _per_node_views(graph, thumbnails)
    return Scene(graph, _per_node_views(graph, features), node_images)
