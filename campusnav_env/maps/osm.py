"""
Load real road networks: osmnx-style networkx graphs and GraphML files, simplified into a :class:`RoadGraph`.

The input is a networkx ``Graph``, ``DiGraph``, ``MultiGraph`` or ``MultiDiGraph`` as osmnx makes them: nodes with
``x`` / ``y`` coordinates, edges with an optional ``geometry`` (a shapely ``LineString`` or its WKT text, from the
edge's ``u`` to its ``v``), ``oneway`` and ``name``. networkx itself is only needed to read GraphML files.

The import, step by step:

* **Coordinates.** ``x`` / ``y`` are projected metres or longitude / latitude degrees. The graph's ``crs`` attribute
  (osmnx writes one) decides: a geographic system (EPSG:4326, "longlat") means degrees, any other means metres.
  Without a ``crs`` the values decide: beyond ``|x| <= 180``, ``|y| <= 90`` they are metres; within those ranges they
  are degrees only if, read so, the map spans at most :data:`~campusnav_env.maps.extent.MAX_MAP_SPAN_M` (100 km, a
  road map), else metres, and a :class:`CoordinatesWarning` says which reading was chosen and why. (The two readings
  hardly compete: a map of at most 100 km in degrees spans a few degrees at most, which as metres would be a map a few
  metres across.) So 10 intersections laid out over 0-100 m are metres, not roads of 11,000 km.
  ``coords="lonlat"`` or ``coords="projected"`` overrides both the ``crs`` and the guess; values beyond the degree
  ranges under a geographic ``crs`` or ``coords="lonlat"`` are an error. Degrees are projected with a local
  equirectangular projection (scale taken at the mean latitude), with the origin at the south-west corner of the
  nodes' bounding box. Projected coordinates are kept as they are.
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
  4-subset whose compass-slot assignment (the rule in :mod:`campusnav_env.maps.compass`) has the smallest summed
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

from campusnav_env.maps.compass import compass_slots, initial_bearing
from campusnav_env.maps.disjoint_set import DisjointSet
from campusnav_env.maps.extent import MAX_MAP_SPAN_M, describe_length, span_m
from campusnav_env.maps.refusals import Refusal, RefusedInput, Setting
from campusnav_env.maps.road_graph import RoadGraph, require_networkx, road_key

EARTH_RADIUS_M = 6_371_008.8
_WKT_LINESTRING = re.compile(r"^\s*LINESTRING\s*(?:ZM|Z|M)?\s*\((?P<body>.*)\)\s*$", re.IGNORECASE | re.DOTALL)
_WKT_EMPTY = re.compile(r"^\s*LINESTRING\s*(?:ZM|Z|M)?\s*EMPTY\s*$", re.IGNORECASE)
# Geographic (degrees) coordinate systems as osmnx writes them; "+datum=WGS84" alone does not count (UTM uses it too)
_GEOGRAPHIC_CRS = re.compile(r"epsg:4326\b|^4326$|longlat|latlong|lonlat|^wgs ?84$", re.IGNORECASE)
_TRUE_STRINGS = frozenset({"true", "yes", "1", "-1"})


class OsmImportWarning(UserWarning):
    """Part of the input network was dropped on import (crowded intersections, disconnected pieces)."""


class CoordinatesWarning(Refusal, UserWarning):
    """
    A graph without a ``crs`` whose x / y could be degrees: how they were read (degrees or metres), and why; its
    ``fix`` is the other ``coords``.

    :param reason: How they were read, and why
    :param other: The other reading (``"lonlat"`` or ``"projected"``)
    """

    def __init__(self, reason: str, other: str) -> None:
        super().__init__(self._refuse(reason, "pass {fix} if that is wrong", fix=Setting("coords", other)))


class CoordinatesError(RefusedInput):
    """x / y said to be degrees (by ``coords='lonlat'`` or the graph's ``crs``) that are out of the degrees' ranges."""


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
    oneway: bool
    name: str | None

    @property
    def key(self) -> tuple[int, int]:
        return (min(self.u, self.v), max(self.u, self.v))

    def other(self, node: int) -> int:
        return self.v if node == self.u else self.u

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
    :raises ValueError: if it is not a GraphML file (empty, not XML, or XML of another kind), naming it
    """
    from xml.etree.ElementTree import ParseError

    nx = require_networkx()
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"GraphML file not found: {path}")
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: not a GraphML file (the file is empty)")
    try:
        graph = nx.read_graphml(path)
    except ParseError as error:
        raise ValueError(f"{path}: not a GraphML file (not valid XML: {error})") from None
    except nx.NetworkXError as error:  # XML, but no <graphml> document (or a malformed one)
        raise ValueError(f"{path}: not a GraphML file ({error})") from None
    nodes = list(graph.nodes)
    if nodes and all(isinstance(n, str) and re.fullmatch(r"-?\d+", n) for n in nodes):
        graph = nx.relabel_nodes(graph, {n: int(n) for n in nodes}, copy=True)
    kwargs.setdefault("name", path.stem)
    kwargs.setdefault("source", str(path))
    return graph_from_networkx(graph, **kwargs)


def graph_from_networkx(
    graph: Any,
    *,
    simplify: bool = True,
    name: str | None = None,
    landmarks: Mapping[str, Hashable] | None = None,
    coords: Literal["auto", "lonlat", "projected"] = "auto",
    return_mapping: bool = False,
    source: str | None = None,
) -> RoadGraph | tuple[RoadGraph, dict[Hashable, int]]:
    """
    Convert an osmnx-style networkx graph into a :class:`RoadGraph` (see the module docstring for the rules).

    :param graph: networkx ``Graph`` / ``DiGraph`` / ``MultiGraph`` / ``MultiDiGraph`` with node ``x`` / ``y``
    :param simplify: Merge chains of degree-2 nodes into polyline roads
    :param name: Name of the road graph; defaults to the graph's ``name`` attribute, else ``"osm"``
    :param landmarks: Extra landmarks, name -> original node id
    :param coords: ``"auto"`` (the ``crs``, else a guess), ``"lonlat"`` or ``"projected"`` (metres)
    :param return_mapping: Also return the mapping original node id -> new node id
    :param source: What to call the input in warnings and errors (:func:`load_graphml`: the file); default: the name
    :return: The road graph, or ``(graph, mapping)`` with ``return_mapping=True``
    """
    result = import_networkx(graph, simplify=simplify, name=name, landmarks=landmarks, coords=coords, source=source)
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
    source: str | None = None,
) -> OsmImport:
    """
    Like :func:`graph_from_networkx`, but return the full :class:`OsmImport` record (mapping, one-way roads, road
    names and what was dropped).

    :raises KeyError: if a node has no ``x`` or ``y``, or a landmark names a node that is not in the graph
    :raises ValueError: on unusable coordinates or geometries (degrees out of range), or if no road is left
    """
    if coords not in ("auto", "lonlat", "projected"):
        raise ValueError(f"coords must be 'auto', 'lonlat' or 'projected', got {coords!r}")
    original_ids = list(graph.nodes)
    if not original_ids:
        raise ValueError("the graph has no nodes")
    index_of = {node: i for i, node in enumerate(original_ids)}
    raw = _node_coordinates(graph, original_ids)
    where = source or f"graph {name if name is not None else str(graph.graph.get('name') or 'osm')!r}"
    lonlat = _read_as_lonlat(graph, raw, coords, where)
    project = _local_projection(raw) if lonlat else None
    positions = project(raw) if project is not None else raw

    labels = _node_labels(graph, original_ids)
    for label, node in (landmarks or {}).items():
        if node not in index_of:
            raise KeyError(f"landmark {label!r} refers to node {node!r}, which is not in the graph")
        labels[label] = index_of[node]
    n_input = len(original_ids)
    dropped = {"self_loops": 0, "parallel": 0, "zero_length": 0, "crowded": 0}
    roads = _read_edges(graph, index_of, positions, project, dropped)
    if simplify:
        roads, intersections = _simplify(roads, n_input, set(labels.values()), dropped)
    else:
        intersections = set(range(n_input))
    roads = _prune_crowded(roads, n_input, dropped)
    if not roads:
        raise ValueError("no roads left to import (the network has only self-loops or isolated nodes)")

    kept = _largest_component(roads, n_input)
    new_id = {old: new for new, old in enumerate(kept)}
    n_lost_roads = sum(1 for road in roads if road.u not in new_id)
    roads = [road for road in roads if road.u in new_id]
    dropped_nodes = len(intersections) - len(kept)
    if dropped_nodes > 0:
        warnings.warn(
            f"kept the largest connected component: {len(kept)} of {len(intersections)} intersections "
            f"({dropped_nodes} dropped, with {n_lost_roads} road(s))",
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
        warnings.warn(
            f"{len(lost)} named node(s) outside the largest component were not made landmarks: {sorted(lost)}",
            OsmImportWarning,
            stacklevel=3,
        )

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
        a, b = new_id[road.u], new_id[road.v]
        key = road_key(a, b)
        if road.oneway:
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


def _node_coordinates(graph: Any, nodes: list[Hashable]) -> np.ndarray:
    coordinates = np.empty((len(nodes), 2), dtype=np.float64)
    for i, node in enumerate(nodes):
        data = graph.nodes[node]
        for column, key in enumerate(("x", "y")):
            if key not in data:
                raise KeyError(f"node {node!r} has no {key!r} coordinate")
            try:
                coordinates[i, column] = float(data[key])
            except (TypeError, ValueError) as error:
                raise ValueError(f"node {node!r} has a non-numeric {key!r}: {data[key]!r}") from error
        if not np.isfinite(coordinates[i]).all():
            raise ValueError(f"node {node!r} has non-finite coordinates {coordinates[i].tolist()}")
    return coordinates


def _read_as_lonlat(graph: Any, raw: np.ndarray, coords: str, where: str) -> bool:
    """Whether x / y are longitude / latitude (the rule in the module docstring); ``where`` names the input."""
    crs = graph.graph.get("crs")
    if coords != "auto" or crs is not None:
        lonlat = coords == "lonlat" if coords != "auto" else _GEOGRAPHIC_CRS.search(str(crs).strip()) is not None
        if lonlat and not _fit_degrees(raw):
            said = "{given}" if coords != "auto" else f"its crs {str(crs)!r}"
            raise CoordinatesError(
                f"{said} says x/y are longitude/latitude, but they reach |x| = {np.abs(raw[:, 0]).max():g}, "
                f"|y| = {np.abs(raw[:, 1]).max():g} (degrees stay within 180 and 90)",
                "if they are metres, pass {fix}",
                given=Setting("coords", coords) if coords != "auto" else None,
                fix=Setting("coords", "projected"),
                where=where,
            )
        return lonlat
    if not _fit_degrees(raw):
        return False  # not degrees: no guess to make
    as_degrees = max(span_m(_local_projection(raw)(raw)))
    lonlat = as_degrees <= MAX_MAP_SPAN_M
    if lonlat:
        reading = f"longitude/latitude (read so, the map spans {describe_length(as_degrees)})"
    else:
        reading = (
            f"metres (as degrees the map would span {describe_length(as_degrees)}, more than a road map's "
            f"{describe_length(MAX_MAP_SPAN_M)})"
        )
    warning = CoordinatesWarning(f"{where} has no crs: x/y read as {reading}", "projected" if lonlat else "lonlat")
    warnings.warn(warning, stacklevel=4)
    return lonlat


def _fit_degrees(raw: np.ndarray) -> bool:
    return bool(np.all(np.abs(raw[:, 0]) <= 180.0) and np.all(np.abs(raw[:, 1]) <= 90.0))


def _local_projection(raw: np.ndarray) -> Any:
    """Equirectangular projection to metres, scale at the mean latitude, origin at the south-west corner."""
    lon0, lat0 = raw[:, 0].min(), raw[:, 1].min()
    scale_x = math.radians(1.0) * EARTH_RADIUS_M * math.cos(math.radians(float(raw[:, 1].mean())))
    scale_y = math.radians(1.0) * EARTH_RADIUS_M

    def project(points: np.ndarray) -> np.ndarray:
        return np.stack([(points[:, 0] - lon0) * scale_x, (points[:, 1] - lat0) * scale_y], axis=1)

    return project


def _node_labels(graph: Any, nodes: list[Hashable]) -> dict[str, int]:
    labels: dict[str, int] = {}
    for i, node in enumerate(nodes):
        label = graph.nodes[node].get("name")
        if isinstance(label, str) and label.strip() and label not in labels:
            labels[label] = i
    return labels


def _truthy(value: Any) -> bool:
    """osmnx ``oneway`` values: bools, strings ("True", "yes", "-1"), or lists of them after osmnx simplification."""
    if isinstance(value, (list, tuple, set)):
        return any(_truthy(item) for item in value)
    if isinstance(value, str):
        return value.strip().lower() in _TRUE_STRINGS
    if isinstance(value, (bool, int, np.integer)):
        return bool(value)
    return False


def _road_name(value: Any) -> str | None:
    if isinstance(value, (list, tuple)):
        parts = [str(item) for item in value if isinstance(item, str) and item]
        return " / ".join(parts) or None
    return value if isinstance(value, str) and value else None


def parse_wkt_linestring(text: str) -> np.ndarray | None:
    """
    Parse a WKT ``LINESTRING`` (2D, or with Z / M values, which are ignored) without shapely.

    :return: The points, shape ``(k, 2)``, or ``None`` for ``LINESTRING EMPTY``
    :raises ValueError: if the text is not a LINESTRING
    """
    if _WKT_EMPTY.match(text):
        return None
    match = _WKT_LINESTRING.match(text)
    if match is None:
        raise ValueError(f"not a WKT LINESTRING: {text[:60]!r}")
    try:
        points = [[float(value) for value in pair.split()[:2]] for pair in match.group("body").split(",")]
    except ValueError as error:
        raise ValueError(f"bad coordinates in WKT LINESTRING: {text[:60]!r}") from error
    if any(len(point) != 2 for point in points):
        raise ValueError(f"bad coordinates in WKT LINESTRING: {text[:60]!r}")
    return np.array(points, dtype=np.float64)


def _edge_points(geometry: Any, edge: tuple[Hashable, Hashable]) -> np.ndarray | None:
    if geometry is None or (isinstance(geometry, float) and math.isnan(geometry)):
        return None
    try:
        if hasattr(geometry, "coords"):  # shapely LineString
            points = np.array([tuple(c)[:2] for c in geometry.coords], dtype=np.float64).reshape(-1, 2)
        elif isinstance(geometry, str):
            points = parse_wkt_linestring(geometry)
        else:
            points = np.asarray(geometry, dtype=np.float64)
    except ValueError as error:
        raise ValueError(f"edge {edge!r}: unusable geometry ({error})") from error
    if points is None:
        return None
    if points.ndim != 2 or points.shape[1] != 2 or points.shape[0] < 2 or not np.isfinite(points).all():
        raise ValueError(f"edge {edge!r}: geometry must be a polyline of at least two finite 2D points")
    return points


def _polyline_length(points: np.ndarray) -> float:
    return float(np.sqrt((np.diff(points, axis=0) ** 2).sum(axis=1)).sum())


def _read_edges(
    graph: Any,
    index_of: dict[Hashable, int],
    positions: np.ndarray,
    project: Any,
    dropped: dict[str, int],
) -> list[_Road]:
    """One road per connected pair of nodes (the shortest edge), with the one-way rule of the module docstring."""
    best: dict[tuple[int, int], _Road] = {}
    oneway_directions: dict[tuple[int, int], set[tuple[int, int]]] = {}
    two_way: set[tuple[int, int]] = set()
    # Edges per direction: in a directed graph a two-way street is one edge each way, not two parallel roads
    directed = bool(getattr(graph, "is_directed", lambda: False)())
    edge_count: dict[tuple[int, int], int] = {}
    for u_id, v_id, data in graph.edges(data=True):
        u, v = index_of[u_id], index_of[v_id]
        if u == v:
            dropped["self_loops"] += 1
            continue
        points = _edge_points(data.get("geometry"), (u_id, v_id))
        if points is None:
            points = np.stack([positions[u], positions[v]])
        else:
            if project is not None:
                points = project(points)
            # The geometry should run from u to v; accept it reversed too
            forward = np.linalg.norm(points[0] - positions[u]) + np.linalg.norm(points[-1] - positions[v])
            backward = np.linalg.norm(points[0] - positions[v]) + np.linalg.norm(points[-1] - positions[u])
            if backward < forward:
                points = points[::-1]
            points = points.copy()
            points[0], points[-1] = positions[u], positions[v]  # snap onto the nodes
        length = _polyline_length(points)
        if length <= 0.0:
            dropped["zero_length"] += 1
            continue
        key = road_key(u, v)
        if _truthy(data.get("oneway", False)):
            oneway_directions.setdefault(key, set()).add((u, v))
        else:
            two_way.add(key)
        direction = (u, v) if directed else key
        edge_count[direction] = edge_count.get(direction, 0) + 1
        road = _Road(u, v, points, length, False, _road_name(data.get("name")))
        if key not in best or length < best[key].length:
            best[key] = road
    for key, road in best.items():
        road.oneway = key not in two_way and len(oneway_directions.get(key, ())) == 1
        a, b = key
        dropped["parallel"] += max(edge_count.get((a, b), 0), edge_count.get((b, a), 0)) - 1
    return list(best.values())


def _simplify(
    roads: list[_Road], n_nodes: int, keep: set[int], dropped: dict[str, int]
) -> tuple[list[_Road], set[int]]:
    """Merge chains of degree-2 nodes into single roads; return the roads and the remaining intersections."""
    incident: list[list[_Road]] = [[] for _ in range(n_nodes)]
    for road in roads:
        incident[road.u].append(road)
        incident[road.v].append(road)
    intersections = {node for node in range(n_nodes) if len(incident[node]) != 2} | keep
    merged: dict[tuple[int, int], _Road] = {}
    used: set[int] = set()

    def walk(start: int, first: _Road) -> _Road:
        pieces = [first.leaving(start)]
        oneway, name, node, road = first.oneway, first.name, first.other(start), first
        used.add(id(first))
        while node not in intersections:
            road = next(r for r in incident[node] if r is not road)
            used.add(id(road))
            pieces.append(road.leaving(node)[1:])
            oneway = oneway or road.oneway
            name = name or road.name
            node = road.other(node)
        points = np.concatenate(pieces)
        return _Road(start, node, points, _polyline_length(points), oneway, name)

    chains = []
    for start in sorted(intersections):
        for road in incident[start]:
            if id(road) not in used:
                chains.append(walk(start, road))
    # Whatever is left are closed rings of degree-2 nodes, which become loops
    dropped["self_loops"] += sum(1 for _ in _rings(roads, used, incident, intersections))
    for chain in chains:
        if chain.u == chain.v:
            dropped["self_loops"] += 1
        elif chain.key in merged:
            dropped["parallel"] += 1
            if chain.length < merged[chain.key].length:
                merged[chain.key] = chain
        else:
            merged[chain.key] = chain
    return list(merged.values()), intersections


def _rings(roads: list[_Road], used: set[int], incident: list[list[_Road]], intersections: set[int]) -> Iterable[int]:
    """Yield one node per ring of degree-2 nodes not reached from any intersection, marking its roads used."""
    for road in roads:
        if id(road) in used:
            continue
        node, current = road.u, road
        yield node
        while id(current) not in used:
            used.add(id(current))
            node = current.other(node)
            current = next(r for r in incident[node] if r is not current)


def _prune_crowded(roads: list[_Road], n_nodes: int, dropped: dict[str, int]) -> list[_Road]:
    """Keep at most four roads per intersection: those whose bearings best cover the compass."""
    incident: list[list[_Road]] = [[] for _ in range(n_nodes)]
    for road in roads:
        incident[road.u].append(road)
        incident[road.v].append(road)
    removed: set[int] = set()
    crowded_nodes = 0
    for node in range(n_nodes):
        current = [road for road in incident[node] if id(road) not in removed]
        if len(current) <= 4:
            continue
        crowded_nodes += 1
        current.sort(key=lambda road: road.key)
        bearings = np.array([initial_bearing(road.leaving(node)) for road in current])
        subsets = np.array(list(itertools.combinations(range(len(current)), 4)), dtype=np.int64)
        _, cost = compass_slots(bearings[subsets])
        best = set(subsets[int(np.argmin(cost))].tolist())  # first minimum: ties go to the first subset
        for i, road in enumerate(current):
            if i not in best:
                removed.add(id(road))
    if removed:
        dropped["crowded"] += len(removed)
        warnings.warn(
            f"dropped {len(removed)} road(s) at {crowded_nodes} intersection(s) with more than 4 roads, keeping the "
            "4 whose bearings best cover N/E/S/W",
            OsmImportWarning,
            stacklevel=4,
        )
    return [road for road in roads if id(road) not in removed]


def _largest_component(roads: list[_Road], n_nodes: int) -> list[int]:
    """Nodes of the largest connected component (ties: the one with the lowest node), in ascending order."""
    components = DisjointSet(n_nodes)
    for road in roads:
        components.union(road.u, road.v)
    members: dict[int, list[int]] = {}
    for road in roads:
        for node in (road.u, road.v):
            members.setdefault(components.find(node), [])
    for node in range(n_nodes):
        root = components.find(node)
        if root in members:
            members[root].append(node)
    largest = max(members.values(), key=lambda nodes: (len(nodes), -nodes[0]))
    return largest
