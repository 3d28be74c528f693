"""
Load real road networks: osmnx-style networkx graphs and GraphML files, simplified into a :class:`RoadGraph`.

The input is a networkx ``Graph``, ``DiGraph``, ``MultiGraph`` or ``MultiDiGraph`` as osmnx makes them: nodes with
``x`` / ``y`` coordinates, edges with an optional ``geometry`` (a shapely ``LineString`` or its WKT text, from the
edge's ``u`` to its ``v``), ``oneway`` and ``name``. networkx itself is only needed to read GraphML files.

The import, step by step:

* **Coordinates.** ``x`` / ``y`` are taken as projected metres, unless they are longitude / latitude: when the graph's
  ``crs`` attribute names a geographic system (EPSG:4326, "longlat"), or, with no ``crs``, when every node has
  ``|x| <= 180`` and ``|y| <= 90``. Those are projected with a local equirectangular projection (scale taken at the
  mean latitude), with the origin at the south-west corner of the nodes' bounding box. Projected coordinates are
  kept as they are. Pass ``coords="lonlat"`` or ``coords="projected"`` to override the guess.
* **Edges.** Self-loops are dropped. Among several edges between the same two nodes (multi-edges, the two
  directions of a two-way street) the shortest is kept. Roads are undirected: the agent is a navigator on foot, so a
  one-way street is walkable both ways. The tag is not lost: a road is recorded as one-way in
  :attr:`OsmImport.oneway` when every edge joining its two nodes is tagged one-way and they all point the same way
  (after simplification: when any part of the chain is one-way).
* **Simplification** (``simplify=True``). Chains of degree-2 nodes become single polyline roads between
  intersections and dead ends (named nodes are kept as intersections). Chains that return to their start (loops)
  are dropped like self-loops, and parallel roads created between the same two intersections are deduplicated,
  keeping the shortest.
* **Crowded intersections.** A :class:`RoadGraph` intersection has at most four roads (one per compass slot). Where
  an intersection has more, the four roads kept are those whose initial bearings best cover the compass: the
  4-subset whose compass-slot assignment (the rule in :mod:`campusnav_env.road_graph`) has the smallest summed
  angular deviation, ties to the first subset in road order. The others are dropped with an
  :class:`OsmImportWarning` counting them.
* **Connectivity.** Only the largest connected component is kept (with a warning counting what was dropped), so
  isolated leftovers disappear and every start can reach every goal.
* **Landmarks.** Nodes with a non-empty string attribute ``name`` become landmarks (the first node wins when a name
  repeats), and the ``landmarks`` argument (name -> original node id) adds or overrides them.
* **Node ids** are renumbered ``0 .. N-1`` in the input graph's node order. The mapping from original ids is
  :attr:`OsmImport.node_ids` (from :func:`import_networkx`), or the second value of
  ``graph_from_networkx(..., return_mapping=True)``. Nodes removed by the simplification are not in it.
"""

from __future__ import annotations

import itertools
import math
import re
import warnings
from collections.abc import Hashable, Iterable, Mapping
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any, Literal

import numpy as np

from campusnav_env.road_graph import RoadGraph, _initial_bearing, compass_slots

EARTH_RADIUS_M = 6_371_008.8
_WKT_LINESTRING = re.compile(r"^\s*LINESTRING\s*(?:ZM|Z|M)?\s*\((?P<body>.*)\)\s*$", re.IGNORECASE | re.DOTALL)
_WKT_EMPTY = re.compile(r"^\s*LINESTRING\s*(?:ZM|Z|M)?\s*EMPTY\s*$", re.IGNORECASE)
_TRUE_STRINGS = frozenset({"true", "yes", "1", "-1"})


class OsmImportWarning(UserWarning):
    """Part of the input network was dropped on import (crowded intersections, disconnected pieces)."""


@dataclass(frozen=True)
class OsmImport:
    """
    The result of :func:`import_networkx`: the road graph and what the import did to the input.

    :param graph: The imported road graph
    :param node_ids: Original node id -> new node id, for the nodes that were kept
    :param original_ids: New node id -> original node id
    :param oneway: Roads (canonical ``(min, max)`` pairs of new ids) that were tagged one-way in the input
    :param road_names: Road -> ``name`` tag, where the input had one
    :param lonlat: Whether the coordinates were longitude / latitude and were projected
    :param dropped_roads: Roads dropped: ``self_loops``, ``parallel``, ``zero_length``, ``crowded`` (beyond four per
        intersection)
    :param dropped_nodes: Intersections dropped outside the largest connected component
    """

    graph: RoadGraph
    node_ids: dict[Hashable, int]
    original_ids: tuple[Hashable, ...]
    oneway: frozenset[tuple[int, int]]
    road_names: dict[tuple[int, int], str]
    lonlat: bool
    dropped_roads: dict[str, int] = field(default_factory=dict)
    dropped_nodes: int = 0


@dataclass
class _Road:
    """A road between two node indices of the input, with its polyline from ``u`` to ``v``."""

    u: int
    v: int
    points: np.ndarray
    length: float
    oneway: frozenset[tuple[int, int]]  # directions of the one-way edges it is made of
    two_way: bool  # some edge of it is not one-way
    name: str | None

    @property
    def key(self) -> tuple[int, int]:
        return (min(self.u, self.v), max(self.u, self.v))

    def leaving(self, node: int) -> np.ndarray:
        """The polyline oriented to start at ``node``."""
        return self.points if node == self.u else self.points[::-1]


def load_graphml(path: str | PathLike[str], **kwargs: Any) -> RoadGraph | tuple[RoadGraph, dict[Hashable, int]]:
    """
    Load a GraphML road network (for example saved by ``osmnx.save_graphml`` or ``networkx.write_graphml``).

    Node ids that are all integers in text form are converted to ``int`` (OSM ids), so that the ``landmarks``
    argument and the returned mapping can use them as osmnx does.

    :param path: The GraphML file
    :param kwargs: Passed to :func:`graph_from_networkx`; ``name`` defaults to the file's stem
    :raises FileNotFoundError: if the file does not exist
    """
    nx = _require_networkx()
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"GraphML file not found: {path}")
    graph = nx.read_graphml(path)
    nodes = list(graph.nodes)
    if nodes and all(isinstance(n, str) and re.fullmatch(r"-?\d+", n) for n in nodes):
        graph = nx.relabel_nodes(graph, {n: int(n) for n in nodes}, copy=True)
    kwargs.setdefault("name", path.stem)
    return graph_from_networkx(graph, **kwargs)


def graph_from_networkx(
    graph: Any,
    *,
    simplify: bool = True,
    name: str | None = None,
    landmarks: Mapping[str, Hashable] | None = None,
    coords: Literal["auto", "lonlat", "projected"] = "auto",
    return_mapping: bool = False,
) -> RoadGraph | tuple[RoadGraph, dict[Hashable, int]]:
    """
    Convert an osmnx-style networkx graph into a :class:`RoadGraph` (see the module docstring for the rules).

    :param graph: networkx ``Graph`` / ``DiGraph`` / ``MultiGraph`` / ``MultiDiGraph`` with node ``x`` / ``y``
    :param simplify: Merge chains of degree-2 nodes into polyline roads
    :param name: Name of the road graph; defaults to the graph's ``name`` attribute, else ``"osm"``
    :param landmarks: Extra landmarks, name -> original node id
    :param coords: ``"auto"`` (guess), ``"lonlat"`` or ``"projected"`` (metres)
    :param return_mapping: Also return the mapping original node id -> new node id
    :return: The road graph, or ``(graph, mapping)`` with ``return_mapping=True``
    """
    result = import_networkx(graph, simplify=simplify, name=name, landmarks=landmarks, coords=coords)
    if return_mapping:
        return result.graph, result.node_ids
    return result.graph


def import_networkx(
    graph: Any,
    *,
    simplify: bool = True,
    name: str | None = None,
    landmarks: Mapping[str, Hashable] | None = None,
    coords: Literal["auto", "lonlat", "projected"] = "auto",
) -> OsmImport:
    """
    Like :func:`graph_from_networkx`, but return the full :class:`OsmImport` record (mapping, one-way roads, road
    names and what was dropped).

    :raises KeyError: if a node has no ``x`` or ``y``, or a landmark names a node that is not in the graph
    :raises ValueError: on unusable coordinates or geometries, or if no road is left
    """
    if coords not in ("auto", "lonlat", "projected"):
        raise ValueError(f"coords must be 'auto', 'lonlat' or 'projected', got {coords!r}")
    original_ids = list(graph.nodes)
    index_of = {node: i for i, node in enumerate(original_ids)}
    raw = _node_coordinates(graph, original_ids)
    lonlat = _is_lonlat(graph, raw) if coords == "auto" else coords == "lonlat"
    project = _local_projection(raw) if lonlat else None
    positions = project(raw) if project is not None else raw

    labels = _node_labels(graph, original_ids)
    for label, node in (landmarks or {}).items():
        if node not in index_of:
            raise KeyError(f"landmark {label!r} refers to node {node!r}, which is not in the graph")
        labels[label] = index_of[node]
    dropped = {"self_loops": 0, "parallel": 0, "zero_length": 0, "crowded": 0}
    roads = _read_edges(graph, index_of, positions, project, dropped)
    if simplify:
        roads = _simplify(roads, len(original_ids), set(labels.values()), dropped)
    roads = _prune_crowded(roads, len(original_ids), dropped)
    kept_nodes = _largest_component(roads, len(original_ids), set(labels.values()) if not simplify else set())
    if not roads:
        raise ValueError("the network has no roads left after the import (only self-loops or isolated nodes?)")

    n_candidates = len({n for road in roads for n in (road.u, road.v)} | set(labels.values()) if simplify else [])
    kept = sorted(kept_nodes)
    new_id = {old: new for new, old in enumerate(kept)}
    roads = [road for road in roads if road.u in new_id]
    total_nodes = n_candidates if simplify else len(original_ids)
    dropped_nodes = total_nodes - len(kept)
    if dropped_nodes > 0:
        warnings.warn(
            f"kept the largest connected component: {len(kept)} of {total_nodes} intersections "
            f"({dropped_nodes} dropped, with {sum(1 for _ in ())} roads)",
            OsmImportWarning,
            stacklevel=3,
        )
    graph_landmarks: dict[str, int] = {}
    lost = []
    for label, node in labels.items():
        if node in new_id:
            graph_landmarks[label] = new_id[node]
        elif landmarks is not None and label in landmarks:
            raise ValueError(f"landmark {label!r} (node {original_ids[node]!r}) is not in the largest component")
        else:
            lost.append(label)
    if lost:
        warnings.warn(f"{len(lost)} named node(s) outside the largest component dropped", OsmImportWarning, stacklevel=3)

    road_graph = RoadGraph(
        positions[kept],
        [(new_id[road.u], new_id[road.v]) for road in roads],
        geometries=[road.points for road in roads],
        landmarks=graph_landmarks,
        name=name if name is not None else str(graph.graph.get("name") or "osm"),
    )
    oneway = set()
    road_names = {}
    for road in roads:
        key = (min(new_id[road.u], new_id[road.v]), max(new_id[road.u], new_id[road.v]))
        if not road.two_way and len(road.oneway) == 1 or (simplify and road.oneway and _is_chain(road)):
            oneway.add(key)
        if road.name:
            road_names[key] = road.name
    return OsmImport(
        graph=road_graph,
        node_ids={original_ids[old]: new for old, new in new_id.items()},
        original_ids=tuple(original_ids[old] for old in kept),
        oneway=frozenset(oneway),
        road_names=road_names,
        lonlat=lonlat,
        dropped_roads=dropped,
        dropped_nodes=dropped_nodes,
    )
