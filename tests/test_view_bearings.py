"""
Specification of the view bearings: the road seen straight ahead in view ``d`` of a node is the road that the action
pointing to compass slot ``d`` takes, however far that road lies from the slot's compass bearing.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from campusnav_env.maps.campus import default_campus, generate_campus
from campusnav_env.maps.compass import SLOT_BEARINGS, view_bearings
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.street_view import RenderSettings, StreetViewRenderer
from campusnav_env.rendering.world import World, build_world

TINY = RenderSettings(width=16, height=16)


def _circular(a: float, b: float) -> float:
    """Absolute circular difference of two bearings in degrees, in [0, 180]."""
    d = abs(a - b) % 360.0
    return min(d, 360.0 - d)


def _leaving_bearing(line: np.ndarray) -> float:
    """Bearing of the first non-degenerate segment of a polyline leaving ``line[0]`` (computed here, not imported)."""
    start = line[0]
    for point in line[1:]:
        dx, dy = float(point[0] - start[0]), float(point[1] - start[1])
        if dx != 0.0 or dy != 0.0:
            return math.degrees(math.atan2(dx, dy)) % 360.0
    raise AssertionError("degenerate polyline")


def _road_end_bearings(graph: RoadGraph) -> dict[tuple[int, int], float]:
    """(node, road id) -> initial bearing of the road leaving that node, from the stored polylines alone."""
    out = {}
    for road, ((u, v), line) in enumerate(zip(graph.roads, graph.geometries, strict=True)):
        out[u, road] = _leaving_bearing(np.asarray(line))
        out[v, road] = _leaving_bearing(np.asarray(line)[::-1])
    return out


def _bare_renderer(graph: RoadGraph) -> StreetViewRenderer:
    """A renderer over the graph's roads alone (no buildings, trees or fields: cheap to set up on big maps)."""
    return StreetViewRenderer(World(graph=graph, buildings=(), trees=(), fields=()), TINY)


def _compass_deviation(graph: RoadGraph) -> float:
    """Largest circular deviation of a road end from its slot's compass bearing (what the old renderer looked along)."""
    deviation = np.abs(np.asarray(graph.slot_bearings) - SLOT_BEARINGS) % 360.0
    deviation = np.minimum(deviation, 360.0 - deviation)
    return float(deviation[graph.slots >= 0].max())


def _check_views_look_down_the_roads_that_actions_take(graph: RoadGraph) -> None:
    renderer = _bare_renderer(graph)
    ends = _road_end_bearings(graph)
    np.testing.assert_array_equal(renderer.view_bearings, view_bearings(graph))
    worst, n_roads, n_empty = 0.0, 0, 0
    for state in range(graph.n_states):
        node, heading = int(graph.state_nodes[state]), int(graph.state_headings[state])
        for action in range(4):
            slot = (heading + action) % 4
            seen = renderer.view_bearing(node, slot)
            assert seen == renderer.view_bearings[node, slot]
            road = int(graph.transition_roads[state, action])
            if road < 0:  # no road in that slot: the view keeps the compass bearing
                assert seen == 90.0 * slot, (node, slot, seen)
                n_empty += 1
            else:
                worst = max(worst, _circular(seen, ends[node, road]))
                n_roads += 1
    assert worst <= 1e-9, f"a view deviates {worst} degrees from the road its action takes"
    assert n_roads == 4 * 2 * graph.n_roads  # every road end, seen from each of the four headings
    assert n_roads + n_empty == 4 * graph.n_states


@pytest.mark.parametrize(("n_nodes", "seed"), [(37, 0), (101, 2), (250, 1), (1000, 3)])
def test_views_of_generated_campuses_look_down_the_roads_their_actions_take(n_nodes, seed):
    graph = generate_campus(n_nodes, seed=seed)
    # Every one of these maps has road ends far (> 45 degrees) from their slot's compass bearing
    assert _compass_deviation(graph) > 45.0
    _check_views_look_down_the_roads_that_actions_take(graph)


def test_views_of_the_default_campus_look_down_the_roads_their_actions_take():
    graph = default_campus()
    assert _compass_deviation(graph) == pytest.approx(98.6, abs=0.05)  # node 42: the road to 43 at 81 sits in S
    _check_views_look_down_the_roads_that_actions_take(graph)
    renderer = _bare_renderer(graph)
    assert graph.slots[42, 2] == 43
    assert renderer.view_bearing(42, 2) == pytest.approx(81.36, abs=0.01)  # not 180


def _lonlat(x: float, y: float) -> tuple[float, float]:
    metres_per_degree = 6_371_008.8 * math.pi / 180.0
    return -83.015 + x / (metres_per_degree * math.cos(math.radians(40.0))), 40.0 + y / metres_per_degree


def _wkt(points_m: list[tuple[float, float]]) -> str:
    return "LINESTRING (" + ", ".join("{} {}".format(*_lonlat(x, y)) for x, y in points_m) + ")"


def test_views_of_an_osm_import_look_down_the_roads_their_actions_take():
    nx = pytest.importorskip("networkx")
    from campusnav_env.maps.osm import graph_from_networkx

    # A crossroads A whose roads leave at about 10, 60, 100 and 290 degrees: the road to D (100) takes slot S, 80
    # degrees off. The road to C bends right after A and repeats its first point (the first segment is degenerate);
    # the road to E runs through the degree-2 node F, which the import merges away.
    layout = {"A": (0, 0), "B": (35, 200), "C": (250, 60), "D": (200, -35), "E": (-300, 200), "F": (-190, 70)}
    source = nx.MultiDiGraph(name="osm-bearings", crs="epsg:4326")  # lon/lat, as osmnx says
    for node, (x, y) in layout.items():
        lon, lat = _lonlat(x, y)
        source.add_node(node, x=lon, y=lat)
    edges = {
        ("A", "B"): None,
        ("A", "C"): _wkt([(0, 0), (0, 0), (87, 50), (250, 60)]),
        ("A", "D"): None,
        ("A", "F"): None,
        ("F", "E"): _wkt([(-190, 70), (-230, 170), (-300, 200)]),
    }
    for (u, v), geometry in edges.items():
        attrs = {} if geometry is None else {"geometry": geometry}
        source.add_edge(u, v, oneway=False, **attrs)
    graph, ids = graph_from_networkx(source, return_mapping=True)
    assert graph.n_nodes == 5 and "F" not in ids
    a = ids["A"]
    assert graph.slots[a].tolist() == [ids["B"], ids["C"], ids["D"], ids["E"]]
    assert _compass_deviation(graph) == pytest.approx(80.0, abs=1.0)
    _check_views_look_down_the_roads_that_actions_take(graph)
    renderer = _bare_renderer(graph)
    assert renderer.view_bearing(a, 1) == pytest.approx(60.1, abs=0.5)  # the bend, not the chord to C (76.5)
    assert renderer.view_bearing(ids["B"], 1) == 90.0  # an empty slot of a dead end


def test_degenerate_first_segments_are_skipped():
    # Road 0-1 repeats node 0's point twice before bending east; road 0-2 repeats node 2's point at its far end
    positions = np.array([[0.0, 0.0], [100.0, 100.0], [0.0, -100.0]])
    geometries = [
        np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0], [30.0, 10.0], [100.0, 100.0]]),
        np.array([[0.0, 0.0], [-20.0, -50.0], [0.0, -100.0], [0.0, -100.0]]),
    ]
    graph = RoadGraph(positions, [(0, 1), (0, 2)], geometries=geometries)
    _check_views_look_down_the_roads_that_actions_take(graph)
    renderer = _bare_renderer(graph)
    assert renderer.view_bearing(0, 1) == pytest.approx(math.degrees(math.atan2(30.0, 10.0)))
    assert renderer.view_bearing(2, 0) == pytest.approx(math.degrees(math.atan2(-20.0, 50.0)) % 360.0)


def test_graphs_without_compass_slots_keep_the_compass_bearings():
    graph = RoadGraph.from_transitions(
        transitions=np.array([[1], [0]]), state_nodes=[0, 1], state_headings=[0, 2], positions=[[0.0, 0.0], [30, 90]]
    )
    assert graph.slot_bearings is None
    np.testing.assert_array_equal(view_bearings(graph), np.tile(SLOT_BEARINGS, (2, 1)))


def test_view_bearings_read_only_the_node_count_and_the_slot_bearings_of_a_map():
    # The compass needs no road graph (which is built on the compass): any map with these two will do
    class Slotted:
        n_nodes = 1
        slot_bearings = np.array([[10.0, 100.0, 190.0, 280.0]])

    np.testing.assert_array_equal(view_bearings(Slotted()), [[10.0, 100.0, 190.0, 280.0]])


def test_view_bearings_are_read_only_and_checked():
    renderer = _bare_renderer(generate_campus(37, seed=0))
    with pytest.raises(ValueError, match="read-only"):
        renderer.view_bearings[0, 0] = 1.0
    with pytest.raises(ValueError, match="direction"):
        renderer.view_bearing(0, 4)
    with pytest.raises(ValueError, match="direction"):
        renderer.view_bearing(0, True)
    with pytest.raises(ValueError, match="node 37"):
        renderer.view_bearing(37, 0)


def _road_share_ahead(renderer: StreetViewRenderer, node: int, direction: int) -> float:
    """
    Share of the ground 15-35 m straight ahead (within 4 m of the view's centre line) that shows asphalt.

    The asphalt colour is taken from the bottom centre of the same view: the camera stands on the junction, whose
    asphalt shows at the bottom of every view whatever it looks along. The band starts beyond the zebra crossings.
    """
    view = renderer.render_view(node, direction).astype(np.float64)
    h, w = view.shape[:2]
    asphalt = np.median(view[h - 2 :, w // 2 - 2 : w // 2 + 2].reshape(-1, 3), axis=0)
    rows = np.arange(h)
    with np.errstate(divide="ignore"):
        distance = renderer.fy * renderer.eye / (rows - renderer.cy)
    hits = []
    for row in rows[(distance >= 15.0) & (distance <= 35.0)]:
        half = renderer.fx * 4.0 / distance[row]
        cols = np.flatnonzero(np.abs(np.arange(w) - renderer.cx) <= half)
        hits.append(np.abs(view[row, cols] - asphalt).max(axis=1) <= 16.0)
    hits = np.concatenate(hits)
    assert hits.size >= 8
    return float(hits.mean())


def test_the_road_a_view_looks_down_is_drawn_straight_ahead(monkeypatch):
    graph = default_campus()
    renderer = StreetViewRenderer(build_world(graph, seed=0), RenderSettings(width=64, height=48))
    # The road end farthest from its slot's compass bearing: at node 42 the road to 43 leaves at 81 but sits in S
    deviation = np.abs(np.asarray(graph.slot_bearings) - SLOT_BEARINGS) % 360.0
    deviation = np.where(graph.slots >= 0, np.minimum(deviation, 360.0 - deviation), -1.0)
    node, slot = (int(i) for i in np.unravel_index(np.argmax(deviation), deviation.shape))
    assert (node, slot) == (42, 2)
    assert _road_share_ahead(renderer, node, slot) > 0.8
    # The renderer before view bearings looked along the compass bearing (180 here): grass and sidewalks ahead
    monkeypatch.setattr(renderer, "view_bearings", np.tile(SLOT_BEARINGS, (graph.n_nodes, 1)))
    assert _road_share_ahead(renderer, node, slot) < 0.2
