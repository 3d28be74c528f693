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
from pathlib import Path

import numpy as np

from campusnav_env.maps.road_graph import RoadGraph

REQUIRED_DATASETS = ("graph", "location", "rotation", "resnet_feature")


class Scene:
    """
    A loaded scene file: its road graph plus per-node view features (and images when the file has them).

    :param graph: The scene's states and transitions as a road graph
    :param node_features: ``(N, 4, D)`` features of each location's views in compass order (zeros where missing)
    :param node_images: ``(N, 4, H, W, 3)`` uint8 images as stored, in the same order (zeros where missing), or
        ``None``
    """

    def __init__(self, graph: RoadGraph, node_features: np.ndarray, node_images: np.ndarray | None) -> None:
        self.graph = graph
        self.node_features = node_features
        self.node_images = node_images


def _per_node_views(graph: RoadGraph, per_state: np.ndarray) -> np.ndarray:
    views = np.zeros((graph.n_nodes, 4, *per_state.shape[1:]), dtype=per_state.dtype)
    views[graph.state_nodes, graph.state_headings] = per_state
    return views


def load_scene_file(path: str | Path) -> Scene:
    """
    Load a Zhu et al.-format HDF5 scene file.

    :param path: The ``.h5`` file
    :return: the scene (graph, per-node features in compass order, images if the file has them)
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
    if features.ndim == 3:
        # k crops per state: average them; the feature axis is the longer one
        features = features.mean(axis=1 if features.shape[1] < features.shape[2] else 2)
    features = features.reshape(n_states, -1)

    # A location is a distinct position (to the millimetre); a heading is the rotation snapped to the compass
    positions, state_nodes = np.unique(np.round(locations[:, :2], 3), axis=0, return_inverse=True)
    state_headings = np.round(rotations / 90.0).astype(np.int64) % 4
    if landmarks is not None and not isinstance(landmarks, dict):
        raise ValueError(f"{path}: the 'landmarks' attribute must be a JSON object (name -> location index)")
    try:
        graph = RoadGraph.from_transitions(
            transitions, state_nodes.reshape(-1), state_headings, positions, landmarks=landmarks, name=path.stem
        )
    except ValueError as error:
        raise ValueError(f"{path}: {error}") from error
    node_images = None if images is None else _per_node_views(graph, images.astype(np.uint8))
    return Scene(graph, _per_node_views(graph, features), node_images)
