"""Specification of RoadGraph, the fixed map: compass slots, the open transition table, identity and validation.

Moving, closures and hop distances are the navigation core's (tests/test_navigation.py)."""

from __future__ import annotations

import itertools
import pickle
import subprocess
import sys

import numpy as np
import pytest

from campusnav_env.maps.campus import default_campus, generate_campus
from campusnav_env.maps.compass import ACTION_NAMES, BACK, COMPASS, FORWARD, LEFT, RIGHT, bearing_degrees
from campusnav_env.maps.road_graph import RoadGraph, road_key


@pytest.fixture(scope="module")
def campus() -> RoadGraph:
    return default_campus()


@pytest.fixture(scope="module")
def campus_1000() -> RoadGraph:
    return generate_campus(1000, seed=3)


def plus_graph() -> RoadGraph:
    """A crossroads at node 0 with arms N (1), E (2), S (3), W (4), and a loop 1-5-2 in the north-east."""
    positions = np.array([[0, 0], [0, 100], [100, 0], [0, -100], [-100, 0], [100, 100]], dtype=float)
    return RoadGraph(positions, [(0, 1), (2, 0), (0, 3), (0, 4), (1, 5), (5, 2)], landmarks={"Goal": 5})


def open_move(graph: RoadGraph, node: int, heading: int, action: int) -> tuple[int, int] | None:
    """Where the open transition table takes ``(node, heading)`` under ``action``; ``None`` where there is no road."""
    target = int(graph.transitions[graph.state_index(node, heading), action])
    return None if target < 0 else (target // 4, target % 4)


def test_constants_follow_the_contract() -> None:
    assert (FORWARD, RIGHT, BACK, LEFT) == (0, 1, 2, 3)
    assert ACTION_NAMES == ("forward", "right", "back", "left")
    assert COMPASS == ("N", "E", "S", "W")
    assert bearing_degrees(0.0, 1.0) == 0.0
    assert bearing_degrees(1.0, 0.0) == 90.0
    assert bearing_degrees(0.0, -1.0) == 180.0
    assert bearing_degrees(-1.0, 0.0) == 270.0


def test_attributes_and_shapes() -> None:
    graph = plus_graph()
    assert graph.n_nodes == 6 and graph.n_states == 24 and graph.n_roads == 6
    assert graph.roads[1] == (0, 2)  # canonical (min, max)
    assert graph.slots.shape == graph.slot_bearings.shape == graph.state_of.shape == (6, 4)
    assert graph.transitions.shape == graph.transition_roads.shape == (24, 4)
    assert graph.slots.dtype == graph.transitions.dtype == np.int64
    np.testing.assert_allclose(graph.lengths, [100, 100, 100, 100, 100, 100])
    np.testing.assert_array_equal(graph.slots[0], [1, 2, 3, 4])  # N, E, S, W
    np.testing.assert_array_equal(graph.state_nodes, np.repeat(np.arange(6), 4))
    np.testing.assert_array_equal(graph.state_headings, np.tile(np.arange(4), 6))
    assert graph.state_index(2, 3) == 11 and graph.degrees.tolist() == [4, 2, 2, 1, 1, 2]
    # Each transition records the road it travels: facing north at node 0, RIGHT takes road (0, 2)
    assert graph.roads[graph.transition_roads[0, RIGHT]] == (0, 2)
    assert graph.transition_roads[3 * 4 + 0, BACK] == -1  # node 3 has no road to the south


def test_the_map_is_immutable() -> None:
    graph = plus_graph()
    for array in (graph.positions, graph.transitions, graph.transition_roads, graph.slots, graph.geometries[0]):
        with pytest.raises(ValueError, match="read-only"):
            array[0, 0] = -1
    graph.landmarks["Extra"] = 0  # a copy
    assert "Extra" not in graph.landmarks


def test_slot_bearings_are_the_initial_bearings_of_the_roads_and_compass_bearings_where_empty() -> None:
    # Node 0: a road leaving north-east at 30 degrees (slot N) and one bent road leaving south before turning east
    positions = np.array([[0.0, 0.0], [50.0, 86.6025], [100.0, -50.0]])
    bent = np.array([[0.0, 0.0], [0.0, -50.0], [100.0, -50.0]])
    graph = RoadGraph(positions, [(0, 1), (0, 2)], geometries=[positions[[0, 1]], bent])
    assert graph.slots[0].tolist() == [1, -1, 2, -1]
    np.testing.assert_allclose(graph.slot_bearings[0], [30.0, 90.0, 180.0, 270.0], atol=1e-4)
    # Node 2's only road leaves due west: slot W at 270 degrees, the other slots keep their compass bearings
    assert graph.slots[2].tolist() == [-1, -1, -1, 0]
    np.testing.assert_allclose(graph.slot_bearings[2], [0.0, 90.0, 180.0, 270.0], atol=1e-4)


@pytest.mark.parametrize("graph_name", ["campus", "campus_1000"])
def test_every_road_is_reachable_by_exactly_one_action_at_every_heading(graph_name: str, request) -> None:
    graph: RoadGraph = request.getfixturevalue(graph_name)
    neighbours = [[] for _ in range(graph.n_nodes)]
    for u, v in graph.roads:
        neighbours[u].append(v)
        neighbours[v].append(u)
    table = graph.transitions
    for node in range(graph.n_nodes):
        expected = sorted(neighbours[node])
        for heading in range(4):
            reached = [int(s) // 4 for s in table[node * 4 + heading] if s >= 0]
            assert sorted(reached) == expected, (node, heading)


def test_slots_minimise_the_total_angular_deviation(campus: RoadGraph) -> None:
    slot_bearings = np.array([0.0, 90.0, 180.0, 270.0])

    def deviation(bearing: float, slot: int) -> float:
        d = abs(bearing - slot_bearings[slot]) % 360
        return min(d, 360 - d)

    for node in range(campus.n_nodes):
        roads = [(d, int(v)) for d, v in enumerate(campus.slots[node]) if v >= 0]
        bearings = []
        for _, v in roads:
            line = campus.geometries[campus.road_id(node, v)]
            line = line if campus.roads[campus.road_id(node, v)][0] == node else line[::-1]
            bearings.append(float(bearing_degrees(*(line[1] - line[0]))))
        chosen = sum(deviation(b, d) for b, (d, _) in zip(bearings, roads, strict=True))
        best = min(
            sum(deviation(b, d) for b, d in zip(bearings, perm, strict=True))
            for perm in itertools.permutations(range(4), len(roads))
        )
        assert chosen == pytest.approx(best, abs=1e-6), node


def test_crowded_sector_does_not_lose_a_road() -> None:
    # Two roads leave towards the north (340 and 25 degrees) and one east: the sector rule would merge the first two
    positions = np.array([[0, 0], [-34.2, 94.0], [42.3, 90.6], [100, 0]], dtype=float)
    graph = RoadGraph(positions, [(0, 1), (0, 2), (0, 3)])
    assert graph.slots[0].tolist() == [2, 3, -1, 1]  # 25 deg -> N, 90 deg -> E, 340 deg -> W
    for heading in range(4):
        reached = {open_move(graph, 0, heading, a)[0] for a in range(4) if open_move(graph, 0, heading, a)}
        assert reached == {1, 2, 3}


def test_slot_ties_are_broken_deterministically() -> None:
    # A single road at exactly 45 degrees is as close to N as to E: the lower slot wins
    graph = RoadGraph(np.array([[0.0, 0.0], [10.0, 10.0]]), [(0, 1)])
    assert graph.slots[0].tolist() == [1, -1, -1, -1]
    assert graph.slots[1].tolist() == [-1, -1, 0, -1]  # 225 degrees: S and W tie, S wins


def test_forward_follows_the_initial_bearing_of_a_bent_road() -> None:
    # The road to node 1 ends due east of node 0 but leaves it heading north: it takes the north slot
    positions = np.array([[0, 0], [100, 0]], dtype=float)
    bent = np.array([[0, 0], [0, 50], [100, 50], [100, 0]], dtype=float)
    graph = RoadGraph(positions, [(0, 1)], geometries=[bent])
    assert graph.slots[0, 0] == 1 and graph.slots[1, 0] == 0
    assert open_move(graph, 0, 0, FORWARD) == (1, 2)  # arrives facing south, away from the road
    assert graph.lengths[0] == pytest.approx(200.0)


@pytest.mark.parametrize("graph_name", ["campus", "campus_1000"])
def test_moving_then_back_returns_to_the_start_facing_the_other_way(graph_name: str, request) -> None:
    graph: RoadGraph = request.getfixturevalue(graph_name)
    table = graph.transitions
    states, actions = np.nonzero(table >= 0)
    nxt = table[states, actions]
    back = table[nxt, BACK]
    slot_taken = (states % 4 + actions) % 4
    np.testing.assert_array_equal(back // 4, states // 4)
    np.testing.assert_array_equal(back % 4, (slot_taken + 2) % 4)


def test_arrival_heading_points_away_from_the_road_just_travelled(campus: RoadGraph) -> None:
    for node in range(campus.n_nodes):
        for heading in range(4):
            for action in range(4):
                arrival = open_move(campus, node, heading, action)
                if arrival is not None:
                    nxt, new_heading = arrival
                    assert campus.slots[nxt, (new_heading + 2) % 4] == node


def test_an_empty_slot_has_no_transition() -> None:
    graph = plus_graph()
    # Node 3 (south arm) only has a road to the north
    assert open_move(graph, 3, 0, FORWARD) == (0, 0)
    assert open_move(graph, 3, 0, BACK) is None
    assert open_move(graph, 3, 1, LEFT) == (0, 0)
    assert open_move(graph, 3, 1, FORWARD) is None
    assert graph.transitions[3 * 4 + 0, BACK] == -1
    with pytest.raises(ValueError, match="node 6"):
        graph.state_index(6, 0)
    with pytest.raises(ValueError, match="heading 4"):
        graph.state_index(0, 4)


def test_road_ids_and_keys_are_canonical() -> None:
    graph = plus_graph()
    assert road_key(5, 1) == road_key(1, 5) == (1, 5)
    assert graph.road_id(5, 1) == graph.road_id(1, 5) == graph.roads.index((1, 5))
    with pytest.raises(KeyError, match=r"1 and 3"):
        graph.road_id(1, 3)


def test_pickling_keeps_the_map_and_its_immutability() -> None:
    graph = plus_graph()
    clone = pickle.loads(pickle.dumps(graph))
    np.testing.assert_array_equal(clone.transitions, graph.transitions)
    assert clone.roads == graph.roads and clone.landmarks == graph.landmarks
    assert clone.fingerprint() == graph.fingerprint()
    with pytest.raises(ValueError):
        clone.positions[0, 0] = 1.0


def test_a_graph_from_explicit_transitions_derives_its_roads() -> None:
    # Two locations, two headings each: forward moves between them, action 1 turns on the spot
    transitions = np.array([[2, 1], [-1, 0], [-1, 3], [0, 2]])
    graph = RoadGraph.from_transitions(
        transitions, [0, 0, 1, 1], [0, 2, 0, 2], np.array([[0.0, 0.0], [0.0, 10.0]]), landmarks={"Door": 1}
    )
    assert graph.roads == ((0, 1),) and graph.slots is None and graph.n_actions == 2
    assert graph.transition_roads.tolist() == [[0, -1], [-1, -1], [-1, -1], [0, -1]]  # turning travels no road
    assert graph.lengths.tolist() == [10.0] and graph.state_index(1, 2) == 3
    with pytest.raises(ValueError, match="share a node and a compass heading"):
        RoadGraph.from_transitions(transitions, [0, 0, 0, 1], [0, 0, 0, 2], np.array([[0.0, 0.0], [0.0, 1.0]]))
    with pytest.raises(ValueError, match="transition row 1"):
        RoadGraph.from_transitions([[1], [7]], [0, 1], [0, 0], np.array([[0.0, 0.0], [0.0, 1.0]]))


def test_fingerprint_ignores_the_name_but_not_landmarks() -> None:
    graph = plus_graph()
    print_before = graph.fingerprint()
    renamed = RoadGraph(graph.positions, list(reversed(graph.roads)), landmarks={"Goal": 5}, name="other")
    assert renamed.fingerprint() == print_before  # also independent of the road order
    moved = RoadGraph(graph.positions, graph.roads, landmarks={"Goal": 4})
    assert moved.fingerprint() != print_before


def test_fingerprint_is_stable_across_processes(campus: RoadGraph) -> None:
    code = "from campusnav_env.maps.campus import default_campus; print(default_campus().fingerprint())"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert result.stdout.strip() == campus.fingerprint()


@pytest.mark.parametrize(
    ("positions", "roads", "message"),
    [
        (np.zeros((3, 3)), [(0, 1)], r"shape \(N, 2\)"),
        (np.array([[0, 0], [np.nan, 1]]), [(0, 1)], "node 1 are not finite"),
        (np.eye(2), [(0, 2)], "node 2, out of range"),
        (np.eye(2), [(1, 1)], "self loop"),
        (np.eye(2), [(0, 1), (1, 0)], r"road 1 \(1, 0\) duplicates road 0"),
        (np.array([[0, 0], [1, 0], [0, 1], [-1, 0], [0, -1], [1, 1]]), [(0, i) for i in range(1, 6)], "node 0 has 5"),
        (np.zeros((2, 2)), [(0, 1)], "zero length"),
        (np.eye(2), [(0, "a")], "pair of node ids"),
    ],
)
def test_invalid_graphs_are_rejected_with_a_message_naming_the_culprit(positions, roads, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        RoadGraph(np.asarray(positions, dtype=float), roads)


def test_invalid_geometries_and_landmarks_are_rejected() -> None:
    positions = np.array([[0.0, 0.0], [10.0, 0.0]])
    with pytest.raises(ValueError, match=r"road 0 \(0, 1\) ends at \[5.0, 5.0\] but node 1"):
        RoadGraph(positions, [(0, 1)], geometries=[np.array([[0.0, 0.0], [5.0, 5.0]])])
    with pytest.raises(ValueError, match=r"shape \(k, 2\)"):
        RoadGraph(positions, [(0, 1)], geometries=[np.array([[0.0, 0.0]])])
    with pytest.raises(ValueError, match="1 roads"):
        RoadGraph(positions, [(0, 1)], geometries=[])
    with pytest.raises(ValueError, match="landmark 'Far' is at node 2"):
        RoadGraph(positions, [(0, 1)], landmarks={"Far": 2})
    # A geometry given from v to u is stored from the lower node id to the higher
    graph = RoadGraph(positions, [(1, 0)], geometries=[np.array([[10.0, 0.0], [5.0, 3.0], [0.0, 0.0]])])
    np.testing.assert_allclose(graph.geometries[0], [[0, 0], [5, 3], [10, 0]])
