"""Specification of RoadGraph: compass slots, heading-relative moves, hop distances and road closures."""

from __future__ import annotations

import itertools
import pickle
import subprocess
import sys

import numpy as np
import pytest

from campusnav_env.maps.campus import default_campus, generate_campus
from campusnav_env.maps.road_graph import (
    ACTION_NAMES,
    BACK,
    COMPASS,
    FORWARD,
    LEFT,
    RIGHT,
    RoadClosureError,
    RoadGraph,
    bearing_degrees,
)


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
    assert graph.slots.shape == graph.node_table.shape == (6, 4)
    assert graph.transition_table.shape == (24, 4)
    assert graph.slots.dtype == graph.transition_table.dtype == np.int64
    np.testing.assert_allclose(graph.lengths, [100, 100, 100, 100, 100, 100])
    np.testing.assert_array_equal(graph.slots[0], [1, 2, 3, 4])  # N, E, S, W
    assert graph.version == 0 and graph.closed_roads == frozenset()


@pytest.mark.parametrize("graph_name", ["campus", "campus_1000"])
def test_every_road_is_reachable_by_exactly_one_action_at_every_heading(graph_name: str, request) -> None:
    graph: RoadGraph = request.getfixturevalue(graph_name)
    neighbours = [[] for _ in range(graph.n_nodes)]
    for u, v in graph.roads:
        neighbours[u].append(v)
        neighbours[v].append(u)
    table = graph.transition_table
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
        reached = {graph.step(0, heading, a)[0] for a in range(4)} - {0}
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
    assert graph.step(0, 0, FORWARD) == (1, 2, False)  # arrives facing south, away from the road
    assert graph.lengths[0] == pytest.approx(200.0)


@pytest.mark.parametrize("graph_name", ["campus", "campus_1000"])
def test_moving_then_back_returns_to_the_start_facing_the_other_way(graph_name: str, request) -> None:
    graph: RoadGraph = request.getfixturevalue(graph_name)
    table = graph.transition_table
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
                nxt, new_heading, blocked = campus.step(node, heading, action)
                if not blocked:
                    assert campus.slots[nxt, (new_heading + 2) % 4] == node


def test_blocked_action_keeps_the_state() -> None:
    graph = plus_graph()
    # Node 3 (south arm) only has a road to the north
    assert graph.step(3, 0, FORWARD) == (0, 0, False)
    assert graph.step(3, 0, BACK) == (3, 0, True)
    assert graph.step(3, 1, LEFT) == (0, 0, False)
    assert graph.step(3, 1, FORWARD) == (3, 1, True)
    assert graph.transition_table[3 * 4 + 0, BACK] == -1


def test_step_rejects_out_of_range_arguments() -> None:
    graph = plus_graph()
    with pytest.raises(ValueError, match="node 6"):
        graph.step(6, 0, 0)
    with pytest.raises(ValueError, match="heading"):
        graph.step(0, 4, 0)
    with pytest.raises(ValueError, match="action"):
        graph.step(0, 0, -1)


def test_closing_writes_minus_one_both_ways_and_reopening_restores_the_exact_table() -> None:
    graph = default_campus()
    node_table, table = graph.node_table.copy(), graph.transition_table.copy()
    (u, v) = graph.sample_closures(1, np.random.default_rng(0))[0]
    graph.close_road(u, v)
    assert graph.closed_roads == frozenset({(u, v)}) and graph.version == 1
    assert graph.is_closed(v, u)
    assert v not in graph.node_table[u] and u not in graph.node_table[v]
    assert u in graph.slots[v] and v in graph.slots[u]  # slots ignore closures
    for a, b in ((u, v), (v, u)):
        rows = graph.transition_table[a * 4 : a * 4 + 4]
        assert not np.any((rows >= 0) & (rows // 4 == b))
    changed = np.argwhere(graph.transition_table != table)
    assert set(changed[:, 0] // 4) == {u, v} and len(changed) == 8  # 4 headings x 1 action, at both ends
    graph.reopen_road(v, u)
    np.testing.assert_array_equal(graph.node_table, node_table)
    np.testing.assert_array_equal(graph.transition_table, table)
    assert graph.closed_roads == frozenset() and graph.version == 2


def test_tables_are_read_only_views_that_follow_closures() -> None:
    graph = plus_graph()
    table = graph.transition_table
    with pytest.raises(ValueError):
        table[0, 0] = 5
    with pytest.raises(ValueError):
        graph.node_table[0, 0] = 5
    graph.close_road(1, 5)
    assert table[1 * 4 + 1, FORWARD] == -1  # the view held before the closure sees it


def test_closing_an_unknown_road_raises_key_error_naming_both_nodes() -> None:
    graph = plus_graph()
    with pytest.raises(KeyError, match=r"3.*4"):
        graph.close_road(3, 4)
    with pytest.raises(KeyError, match=r"1.*3"):
        graph.road_id(1, 3)


def test_closing_twice_raises_value_error() -> None:
    graph = plus_graph()
    graph.close_road(1, 5)
    with pytest.raises(ValueError, match="already closed"):
        graph.close_road(5, 1)
    assert graph.version == 1


def test_reopening_an_open_road_raises_value_error() -> None:
    graph = plus_graph()
    with pytest.raises(ValueError, match="not closed"):
        graph.reopen_road(0, 1)


def test_closure_cutting_a_landmark_off_is_refused_unless_forced() -> None:
    graph = plus_graph()
    with pytest.raises(RoadClosureError, match=r"\(0, 3\).*node 5 \(Goal\)"):
        graph.close_road(0, 3)  # node 3 would lose its way to the goal
    assert graph.closed_roads == frozenset() and graph.version == 0
    assert isinstance(RoadClosureError("x"), ValueError)
    graph.close_road(0, 3, force=True)
    assert graph.hops_to(5)[3] == -1


def test_closure_protection_uses_the_protect_argument() -> None:
    graph = plus_graph()
    graph.close_road(0, 3, protect=[])  # nothing protected
    graph.close_road(0, 2, protect=[5])  # the loop keeps everyone connected to 5
    with pytest.raises(RoadClosureError, match="node 4"):
        graph.close_road(0, 4, protect=[4])
    assert graph.hops_to(5).tolist() == [2, 1, 1, -1, 3, 0]


def test_dead_end_road_of_the_campus_cannot_be_closed(campus: RoadGraph) -> None:
    graph = campus.copy()
    dead_end = int(np.flatnonzero(graph.degrees == 1)[0])
    neighbour = int(graph.slots[dead_end][graph.slots[dead_end] >= 0][0])
    with pytest.raises(RoadClosureError):
        graph.close_road(dead_end, neighbour)


def test_hops_are_recomputed_after_a_closure_and_restored_after_reopening(campus: RoadGraph) -> None:
    graph = campus.copy()
    goal = graph.landmarks["Dreese Lab"]
    before = graph.hops_to(goal).copy()
    assert before[goal] == 0 and np.all(before >= 0)
    for neighbour in (int(v) for v in graph.slots[goal] if v >= 0):
        try:
            graph.close_road(goal, neighbour)
            break
        except RoadClosureError:
            continue
    assert graph.closed_roads == {(min(goal, neighbour), max(goal, neighbour))}
    after = graph.hops_to(goal)
    assert after[neighbour] > 1
    np.testing.assert_array_equal(after, _reference_hops(graph, goal))
    graph.reopen_road(goal, neighbour)
    np.testing.assert_array_equal(graph.hops_to(goal), before)


def test_hops_are_cached_per_goal_and_version_and_read_only() -> None:
    graph = plus_graph()
    first = graph.hops_to(5)
    assert graph.hops_to(5) is first
    with pytest.raises(ValueError):
        first[0] = 7
    graph.close_road(0, 1)
    assert graph.hops_to(5) is not first
    with pytest.raises(ValueError, match="goal 9"):
        graph.hops_to(9)


def test_hops_match_breadth_first_search_on_a_large_campus(campus_1000: RoadGraph) -> None:
    graph = campus_1000.copy()
    for u, v in graph.sample_closures(30, np.random.default_rng(1)):
        graph.close_road(u, v)
    for goal in (0, 499, 999):
        np.testing.assert_array_equal(graph.hops_to(goal), _reference_hops(graph, goal))


def test_shortest_path_follows_decreasing_hops(campus: RoadGraph) -> None:
    goal = campus.landmarks["Cinema"]
    path = campus.shortest_path(0, goal)
    hops = campus.hops_to(goal)
    assert path[0] == 0 and path[-1] == goal and len(path) == hops[0] + 1
    for a, b in itertools.pairwise(path):
        campus.road_id(a, b)
    graph = plus_graph()
    graph.close_road(0, 3, force=True)
    assert graph.shortest_path(3, 5) == []


def test_sample_closures_keeps_protected_nodes_reachable_and_is_deterministic(campus: RoadGraph) -> None:
    graph = campus.copy()
    roads = graph.sample_closures(11, np.random.default_rng(42))
    assert roads == graph.sample_closures(11, np.random.default_rng(42))
    assert roads != graph.sample_closures(11, np.random.default_rng(43))
    assert len(set(roads)) == 11 and all(road in graph.roads for road in roads)
    assert graph.closed_roads == frozenset()  # sampling does not close anything
    for u, v in roads:
        graph.close_road(u, v)  # each closure passes the protection check
    for node in graph.landmarks.values():
        assert np.all(graph.hops_to(node) >= 0)


def test_sample_closures_skips_closed_roads_and_honours_protect() -> None:
    graph = plus_graph()
    graph.close_road(1, 5)
    # Only the ring 0-1-5-2 had slack, and it is already broken: nothing else can go when node 5 is protected
    with pytest.raises(ValueError, match="cannot close 1 road"):
        graph.sample_closures(1, np.random.default_rng(0))
    roads = graph.sample_closures(5, np.random.default_rng(0), protect=[])
    assert sorted(roads) == [(0, 1), (0, 2), (0, 3), (0, 4), (2, 5)]
    with pytest.raises(ValueError, match="only 5 are open"):
        graph.sample_closures(6, np.random.default_rng(0), protect=[])
    assert graph.sample_closures(0, np.random.default_rng(0)) == []
    with pytest.raises(ValueError, match="non-negative"):
        graph.sample_closures(-1, np.random.default_rng(0))


def test_copy_has_independent_closures_and_shares_geometry(campus: RoadGraph) -> None:
    graph = campus.copy()
    other = graph.copy()
    u, v = graph.sample_closures(1, np.random.default_rng(0))[0]
    other.close_road(u, v)
    assert graph.closed_roads == frozenset() and other.closed_roads == {(u, v)}
    assert graph.version == 0 and other.version == 1
    assert other.positions is graph.positions and other.geometries[0] is graph.geometries[0]
    other.landmarks["Extra"] = 0
    assert "Extra" not in graph.landmarks


def test_pickling_keeps_closures_and_live_tables() -> None:
    graph = plus_graph()
    graph.close_road(1, 5)
    clone = pickle.loads(pickle.dumps(graph))
    assert clone.closed_roads == {(1, 5)} and clone.version == 1
    np.testing.assert_array_equal(clone.transition_table, graph.transition_table)
    clone.close_road(0, 2, protect=[])
    assert clone.node_table[0, 1] == -1 and clone.transition_table[0, RIGHT] == -1
    assert clone.fingerprint() == graph.fingerprint()
    with pytest.raises(ValueError):
        clone.positions[0, 0] = 1.0


def test_fingerprint_ignores_closures_and_name_but_not_landmarks() -> None:
    graph = plus_graph()
    print_before = graph.fingerprint()
    graph.close_road(1, 5)
    assert graph.fingerprint() == print_before
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


def _reference_hops(graph: RoadGraph, goal: int) -> np.ndarray:
    """Plain breadth-first search over the open roads, independent of RoadGraph.hops_to."""
    adjacency = {node: set() for node in range(graph.n_nodes)}
    for u, v in graph.roads:
        if (u, v) not in graph.closed_roads:
            adjacency[u].add(v)
            adjacency[v].add(u)
    hops = np.full(graph.n_nodes, -1)
    hops[goal] = 0
    frontier = [goal]
    while frontier:
        nxt = []
        for node in frontier:
            for other in adjacency[node]:
                if hops[other] < 0:
                    hops[other] = hops[node] + 1
                    nxt.append(other)
        frontier = nxt
    return hops
