"""Specification of the OSM / GraphML import: osmnx-style networkx graphs become simplified RoadGraphs."""

from __future__ import annotations

import math
import re
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from campusnav_env.maps.campus import generate_campus
from campusnav_env.maps.osm import (
    CoordinatesWarning,
    OsmImportWarning,
    graph_from_networkx,
    import_networkx,
    load_graphml,
    parse_wkt_linestring,
)

nx = pytest.importorskip("networkx")

LON0, LAT0 = -83.015, 40.0
METRES_PER_DEGREE = 6_371_008.8 * math.pi / 180.0

# Local layout in metres (x east, y north). Node 1 is a crossroads; 10 and 11 are degree-2 nodes of a curved street
# from 2 to 3; 20-21 is a detached street.
LAYOUT = {
    1: (0, 0),
    2: (0, 200),
    3: (200, 0),
    4: (0, -200),
    5: (-200, 0),
    6: (0, 350),
    7: (350, 0),
    10: (100, 230),
    11: (230, 100),
    20: (900, 900),
    21: (950, 900),
}


def lonlat(x: float, y: float) -> tuple[float, float]:
    return LON0 + x / (METRES_PER_DEGREE * math.cos(math.radians(LAT0))), LAT0 + y / METRES_PER_DEGREE


def wkt(points_m: list[tuple[float, float]]) -> str:
    return "LINESTRING (" + ", ".join("{} {}".format(*lonlat(x, y)) for x, y in points_m) + ")"


def osm_like_graph() -> nx.MultiDiGraph:
    """
    An osmnx-style MultiDiGraph in lon/lat with every case the importer handles: a degree-2 chain with a WKT bend,
    two-way streets stored as two directed edges, a one-way street, a multi-edge (a straight street and a WKT detour
    between the same nodes), a self-loop, a named node and a detached piece.
    """
    graph = nx.MultiDiGraph(name="osm-test", crs="epsg:4326")  # as osmnx saves one
    for node, (x, y) in LAYOUT.items():
        lon, lat = lonlat(x, y)
        graph.add_node(node, x=lon, y=lat)
    graph.nodes[4]["name"] = "Stadium"

    def two_way(u: int, v: int, **attrs: object) -> None:
        graph.add_edge(u, v, oneway=False, **attrs)
        graph.add_edge(v, u, oneway=False, **attrs)

    for u, v in ((1, 2), (1, 5), (2, 6), (3, 7), (1, 4), (20, 21), (2, 10), (11, 3)):
        two_way(u, v)
    graph.add_edge(1, 3, oneway=True, name="One-way street")
    graph.add_edge(1, 4, oneway=False, geometry=wkt([(0, 0), (-80, -100), (0, -200)]))  # longer twin of 1-4
    graph.add_edge(4, 4, oneway=False, geometry=wkt([(0, -200), (30, -250), (-30, -250), (0, -200)]))
    graph.add_edge(10, 11, oneway=False, name="Curve road", geometry=wkt([(100, 230), (180, 190), (230, 100)]))
    return graph


def test_osm_like_graph_imports_into_the_expected_road_graph() -> None:
    with pytest.warns(OsmImportWarning, match=r"7 of 9 intersections \(2 dropped"):
        result = import_networkx(osm_like_graph(), landmarks={"Dreese Lab": 6})
    graph = result.graph
    # Intersections and dead ends keep their input order; the chain nodes 10, 11 and the detached 20, 21 are gone
    assert result.node_ids == {1: 0, 2: 1, 3: 2, 4: 3, 5: 4, 6: 5, 7: 6}
    assert result.original_ids == (1, 2, 3, 4, 5, 6, 7)
    assert graph.n_nodes == 7 and graph.name == "osm-test"
    assert sorted(graph.roads) == [(0, 1), (0, 2), (0, 3), (0, 4), (1, 2), (1, 5), (2, 6)]
    # Lon/lat were projected to metres: the layout comes back up to a shift
    expected = np.array([LAYOUT[n] for n in result.original_ids], dtype=float)
    np.testing.assert_allclose(graph.positions - graph.positions[0], expected, atol=0.2)
    assert result.lonlat
    # The chain 2-10-11-3 is one road whose polyline keeps the WKT bend point
    chain = graph.geometries[graph.road_id(1, 2)]
    np.testing.assert_allclose(
        chain - graph.positions[0], [[0, 200], [100, 230], [180, 190], [230, 100], [200, 0]], atol=0.2
    )
    # Of the two 1-4 edges the shorter (straight) one is kept
    assert graph.lengths[graph.road_id(0, 3)] == pytest.approx(200.0, rel=1e-3)
    assert result.oneway == {(0, 2)}
    assert result.road_names == {(0, 2): "One-way street", (1, 2): "Curve road"}
    assert graph.landmarks == {"Stadium": 3, "Dreese Lab": 5}
    assert result.dropped_roads == {"self_loops": 1, "parallel": 1, "zero_length": 0, "crowded": 0}
    assert result.dropped_nodes == 2
    # The crossroads has a road in every compass slot, and the chain leaves node 2 towards the east
    assert graph.slots[0].tolist() == [1, 2, 3, 4]
    assert graph.slots[1].tolist() == [5, 2, 0, -1]


def test_graph_from_networkx_returns_the_mapping_on_request() -> None:
    with pytest.warns(OsmImportWarning):
        graph, mapping = graph_from_networkx(osm_like_graph(), return_mapping=True, name="mine")
    assert mapping[6] == 5 and graph.name == "mine"
    with pytest.warns(OsmImportWarning):
        assert graph_from_networkx(osm_like_graph()).fingerprint() == graph.fingerprint()


def test_without_simplification_chain_nodes_stay_intersections() -> None:
    with pytest.warns(OsmImportWarning, match=r"9 of 11"):
        result = import_networkx(osm_like_graph(), simplify=False)
    assert result.node_ids[10] == 7 and result.node_ids[11] == 8
    assert result.graph.n_roads == 9
    assert result.graph.degrees[7] == 2


def test_graphml_round_trip(tmp_path: Path) -> None:
    source = osm_like_graph()
    path = tmp_path / "campus.graphml"
    nx.write_graphml(source, path)
    with pytest.warns(OsmImportWarning):
        loaded, mapping = load_graphml(path, return_mapping=True, landmarks={"Dreese Lab": 6})
    with pytest.warns(OsmImportWarning):
        direct = graph_from_networkx(source, landmarks={"Dreese Lab": 6})
    assert loaded.fingerprint() == direct.fingerprint()
    assert loaded.name == "campus"  # the file's stem
    assert mapping[1] == 0 and all(isinstance(node, int) for node in mapping)  # OSM ids come back as ints


def test_osmnx_style_string_attributes_are_understood(tmp_path: Path) -> None:
    # osmnx.save_graphml writes every attribute as text
    source = osm_like_graph()
    for _, data in source.nodes(data=True):
        data["x"], data["y"] = repr(data["x"]), repr(data["y"])
    for _, _, data in source.edges(data=True):
        data["oneway"] = str(data["oneway"])
    path = tmp_path / "strings.graphml"
    nx.write_graphml(source, path)
    with pytest.warns(OsmImportWarning):
        loaded = load_graphml(path)
    with pytest.warns(OsmImportWarning):
        result = import_networkx(osm_like_graph())
    assert loaded.fingerprint() == result.graph.fingerprint()


def test_projected_coordinates_are_kept_as_they_are() -> None:
    graph = nx.Graph(crs="EPSG:32617")
    graph.add_node("a", x=10.0, y=20.0)
    graph.add_node("b", x=10.0, y=80.0)
    graph.add_edge("a", "b", oneway="yes")
    result = import_networkx(graph)
    assert not result.lonlat
    np.testing.assert_array_equal(result.graph.positions, [[10.0, 20.0], [10.0, 80.0]])
    assert result.oneway == {(0, 1)}  # undirected input: the tag is all there is
    graph.graph["crs"] = "+proj=utm +zone=17 +ellps=WGS84 +datum=WGS84 +units=m +no_defs"
    assert not import_networkx(graph).lonlat
    graph.graph["crs"] = "epsg:4326"
    assert import_networkx(graph).lonlat
    # Without a crs, numbers that fit degrees but would span 6,672 km as such are metres, and the import says so
    graph.graph.pop("crs")
    with pytest.warns(CoordinatesWarning, match=r"graph 'osm' has no crs: x/y read as metres .* 6,672 km"):
        assert not import_networkx(graph).lonlat
    # coords= settles it, silently
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert import_networkx(graph, coords="lonlat").lonlat
        assert not import_networkx(graph, coords="projected").lonlat


def test_degrees_without_a_crs_are_read_as_degrees_when_they_span_a_road_map() -> None:
    graph = osm_like_graph()  # lon/lat around Columbus, 1.1 km across
    del graph.graph["crs"]
    with pytest.warns(CoordinatesWarning, match=r"'osm-test' has no crs: x/y read as longitude/latitude .* 1\.1 km"):
        warnings.simplefilter("ignore", OsmImportWarning)
        assert import_networkx(graph).lonlat


def test_degrees_out_of_range_under_a_geographic_crs_are_an_error_naming_the_fix(tmp_path: Path) -> None:
    graph = nx.Graph(crs="epsg:4326")
    graph.add_node("a", x=500.0, y=20.0)
    graph.add_node("b", x=500.0, y=80.0)
    graph.add_edge("a", "b")
    path = tmp_path / "metres.graphml"
    nx.write_graphml(graph, path)
    message = (
        r"metres.graphml: its crs 'epsg:4326' says x/y are longitude/latitude, but they reach \|x\| = 500, "
        r"\|y\| = 80 \(degrees stay within 180 and 90\); if they are metres, pass coords='projected'"
    )
    with pytest.raises(ValueError, match=message):
        load_graphml(path)
    with pytest.raises(ValueError, match=r"graph 'osm': coords='lonlat' says x/y are longitude/latitude"):
        import_networkx(nx.Graph(graph, crs=None), coords="lonlat")
    assert load_graphml(path, coords="projected").n_nodes == 2


def test_two_one_way_edges_in_opposite_directions_make_a_two_way_road() -> None:
    graph = nx.MultiDiGraph(crs="EPSG:32617")
    graph.add_node(1, x=0.0, y=0.0)
    graph.add_node(2, x=0.0, y=100.0)
    graph.add_edge(1, 2, oneway=True)
    graph.add_edge(2, 1, oneway=True)
    assert import_networkx(graph).oneway == frozenset()


def test_crowded_intersection_keeps_the_four_roads_that_best_cover_the_compass() -> None:
    graph = nx.Graph(crs="EPSG:32617")
    graph.add_node(0, x=0.0, y=0.0)
    bearings = {1: 0.0, 2: 30.0, 3: 90.0, 4: 180.0, 5: 200.0, 6: 270.0}
    for node, bearing in bearings.items():
        angle = math.radians(bearing)
        graph.add_node(node, x=100 * math.sin(angle), y=100 * math.cos(angle))
        graph.add_edge(0, node)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = import_networkx(graph)
    messages = [str(w.message) for w in caught if issubclass(w.category, OsmImportWarning)]
    assert any("dropped 2 road(s) at 1 intersection(s)" in m for m in messages)
    assert any("5 of 7 intersections (2 dropped" in m for m in messages)
    assert result.dropped_roads["crowded"] == 2
    assert set(result.node_ids) == {0, 1, 3, 4, 6}
    assert result.graph.slots[0].tolist() == [1, 2, 3, 4]


def test_chains_that_loop_back_are_dropped_and_parallel_chains_deduplicated() -> None:
    graph = nx.Graph(crs="EPSG:32617")
    layout = {0: (0, 0), 1: (100, 0), 2: (50, 30), 3: (50, -60), 4: (-100, 0), 5: (-150, 50), 6: (200, 0)}
    layout |= {7: (500, 500), 8: (520, 500), 9: (510, 520)}
    for node, (x, y) in layout.items():
        graph.add_node(node, x=float(x), y=float(y))
    # Two chains from 0 to 1 (via 2, shorter; via 3), a loop 0-4-5-0, a dead end 1-6 and a detached ring 7-8-9
    graph.add_edges_from([(0, 2), (2, 1), (0, 3), (3, 1), (0, 4), (4, 5), (5, 0), (1, 6), (7, 8), (8, 9), (9, 7)])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing here counts as dropped intersections
        result = import_networkx(graph)
    assert result.node_ids == {0: 0, 1: 1, 6: 2}
    assert sorted(result.graph.roads) == [(0, 1), (1, 2)]
    np.testing.assert_allclose(result.graph.geometries[result.graph.road_id(0, 1)], [[0, 0], [50, 30], [100, 0]])
    assert result.dropped_roads["self_loops"] == 2 and result.dropped_roads["parallel"] == 1


def test_named_nodes_are_kept_as_intersections() -> None:
    graph = nx.Graph(crs="EPSG:32617")
    for node, y in enumerate((0.0, 50.0, 100.0)):
        graph.add_node(node, x=0.0, y=y)
    graph.nodes[1]["name"] = "Chapel"
    graph.add_edges_from([(0, 1), (1, 2)])
    result = import_networkx(graph)
    assert result.graph.n_nodes == 3 and result.graph.landmarks == {"Chapel": 1}


def test_road_graph_export_round_trips(tmp_path: Path) -> None:
    campus = generate_campus(60, seed=5)
    exported = campus.to_networkx()
    assert exported.nodes[campus.landmarks["Cinema"]]["name"] == "Cinema"
    assert import_networkx(exported, simplify=False).graph.fingerprint() == campus.fingerprint()
    path = tmp_path / "campus.graphml"
    nx.write_graphml(exported, path)
    assert load_graphml(path, simplify=False).fingerprint() == campus.fingerprint()


def test_missing_file_raises_file_not_found_naming_the_path(tmp_path: Path) -> None:
    missing = tmp_path / "nowhere.graphml"
    with pytest.raises(FileNotFoundError, match=re.escape(str(missing))):
        load_graphml(missing)


@pytest.mark.parametrize(
    ("text", "why"),
    [
        ("", "the file is empty"),
        ("not xml at all\n", "not valid XML: syntax error: line 1"),
        ('<?xml version="1.0"?>\n<html><body/></html>\n', "file not successfully read as graphml"),
    ],
)
def test_a_file_that_is_not_graphml_is_named_with_what_it_is(tmp_path: Path, text: str, why: str) -> None:
    path = tmp_path / "streets.graphml"
    path.write_text(text)
    with pytest.raises(ValueError, match=rf"^{re.escape(str(path))}: not a GraphML file \({re.escape(why)}"):
        load_graphml(path)


def test_missing_coordinates_raise_key_error_naming_the_node() -> None:
    graph = nx.Graph()
    graph.add_node("a", x=0.0, y=0.0)
    graph.add_node("b", x=1.0)
    graph.add_edge("a", "b")
    with pytest.raises(KeyError, match=r"node 'b' has no 'y'"):
        import_networkx(graph)
    graph.nodes["b"]["y"] = "north"
    with pytest.raises(ValueError, match=r"node 'b' has a non-numeric 'y'"):
        import_networkx(graph)


def test_bad_input_is_rejected_with_a_clear_error() -> None:
    graph = nx.Graph(crs="EPSG:32617")
    graph.add_node(1, x=0.0, y=0.0)
    graph.add_node(2, x=0.0, y=10.0)
    graph.add_edge(1, 2, geometry="POINT (0 0)")
    with pytest.raises(ValueError, match=r"edge \(1, 2\).*LINESTRING"):
        import_networkx(graph)
    graph.edges[1, 2]["geometry"] = "LINESTRING EMPTY"  # treated as no geometry
    assert import_networkx(graph).graph.n_roads == 1
    with pytest.raises(KeyError, match="node 99"):
        import_networkx(graph, landmarks={"Ghost": 99})
    with pytest.raises(ValueError, match="coords"):
        import_networkx(graph, coords="feet")
    graph.remove_edge(1, 2)
    with pytest.raises(ValueError, match="no roads left"):
        import_networkx(graph)


def test_wkt_linestrings_are_parsed_without_shapely() -> None:
    np.testing.assert_array_equal(parse_wkt_linestring("LINESTRING (1 2, 3.5 -4)"), [[1, 2], [3.5, -4]])
    np.testing.assert_array_equal(parse_wkt_linestring("linestring z (1 2 9, 3 4 9)"), [[1, 2], [3, 4]])
    assert parse_wkt_linestring("LINESTRING EMPTY") is None
    with pytest.raises(ValueError, match="bad coordinates"):
        parse_wkt_linestring("LINESTRING (1 a, 2 3)")


def test_missing_networkx_gives_an_install_hint(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setitem(sys.modules, "networkx", None)
    path = tmp_path / "x.graphml"
    path.write_text("<graphml/>")
    with pytest.raises(ImportError, match=r"pip install sb3-dcqn\[osm\]"):
        load_graphml(path)
    with pytest.raises(ImportError, match=r"pip install sb3-dcqn\[osm\]"):
        generate_campus(8).to_networkx()
