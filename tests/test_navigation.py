"""Specification of the navigation core: the move rule, closures (with protection), hop distances and sampling."""

from __future__ import annotations

import itertools
import pickle

import numpy as np
import pytest

from campusnav_env.maps.campus import default_campus, generate_campus
from campusnav_env.maps.compass import BACK, FORWARD, LEFT, RIGHT
from campusnav_env.maps.navigation import NavigationGraph, RoadClosureError
from campusnav_env.maps.road_graph import RoadGraph


@pytest.fixture(scope="module")
def campus_1000() -> RoadGraph:
    return generate_campus(1000, seed=3)


def plus_graph() -> NavigationGraph:
    """A crossroads at node 0 with arms N (1), E (2), S (3), W (4), and a loop 1-5-2 in the north-east."""
    positions = np.array([[0, 0], [0, 100], [100, 0], [0, -100], [-100, 0], [100, 100]], dtype=float)
    road_graph = RoadGraph(positions, [(0, 1), (2, 0), (0, 3), (0, 4), (1, 5), (5, 2)], landmarks={"Goal": 5})
    return NavigationGraph(road_graph)


def step(graph: NavigationGraph, node: int, heading: int, action: int) -> tuple[int, int, bool]:
    """The move rule on one (node, heading): ``(node', heading', blocked)``."""
    state, blocked = graph.move(graph.map.state_index(node, heading), action)
    return int(state) // 4, int(state) % 4, bool(blocked)


def test_a_move_follows_the_table_and_a_blocked_move_keeps_the_state() -> None:
    graph = plus_graph()
    assert step(graph, 3, 0, FORWARD) == (0, 0, False)  # node 3 (south arm) only has a road to the north
    assert step(graph, 3, 0, BACK) == (3, 0, True)
    assert step(graph, 3, 1, LEFT) == (0, 0, False)
    assert step(graph, 0, 0, RIGHT) == (2, 1, False)  # east along (0, 2), arriving facing east
    # Batched: any shape, the same rule element-wise
    states = np.array([[12, 12], [0, 0]])
    actions = np.array([[FORWARD, BACK], [RIGHT, RIGHT]])
    nxt, blocked = graph.move(states, actions)
    assert nxt.tolist() == [[0, 12], [9, 9]] and blocked.tolist() == [[False, True], [False, False]]


def test_move_rejects_out_of_range_states_and_actions() -> None:
    graph = plus_graph()
    with pytest.raises(ValueError, match="states must be in"):
        graph.move(24, 0)
    with pytest.raises(ValueError, match="actions must be in"):
        graph.move(0, -1)
    with pytest.raises(ValueError, match="actions must be in"):
        graph.move([0, 1], [0, 4])


def test_closing_writes_minus_one_both_ways_and_reopening_restores_the_exact_table() -> None:
    graph = NavigationGraph(default_campus())
    table = graph.transition_table.copy()
    (u, v) = graph.sample_closures(1, np.random.default_rng(0))[0]
    graph.close_road(u, v)
    assert graph.closed_roads == frozenset({(u, v)}) and graph.version == 1
    assert graph.is_closed(v, u)
    for a, b in ((u, v), (v, u)):
        rows = graph.transition_table[a * 4 : a * 4 + 4]
        assert not np.any((rows >= 0) & (rows // 4 == b))
    changed = np.argwhere(graph.transition_table != table)
    assert set(changed[:, 0] // 4) == {u, v} and len(changed) == 8  # 4 headings x 1 action, at both ends
    assert u in graph.map.slots[v] and v in graph.map.slots[u]  # the fixed map is untouched
    np.testing.assert_array_equal(graph.map.transitions, table)
    graph.reopen_road(v, u)
    np.testing.assert_array_equal(graph.transition_table, table)
    assert graph.closed_roads == frozenset() and graph.version == 2


def test_the_table_is_a_read_only_view_that_follows_closures() -> None:
    graph = plus_graph()
    table = graph.transition_table
    with pytest.raises(ValueError):
        table[0, 0] = 5
    graph.close_road(1, 5)
    assert table[1 * 4 + 1, FORWARD] == -1  # the view held before the closure sees it
    assert step(graph, 1, 1, FORWARD) == (1, 1, True)


def test_closing_an_unknown_road_raises_key_error_naming_both_nodes() -> None:
    graph = plus_graph()
    with pytest.raises(KeyError, match=r"3 and 4"):
        graph.close_road(3, 4)
    with pytest.raises(KeyError, match=r"1 and 3"):
        graph.is_closed(1, 3)


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
    assert issubclass(RoadClosureError, ValueError)
    graph.close_road(0, 3, force=True)
    assert graph.hops_to(5)[3] == -1


def test_closure_protection_uses_the_protect_argument() -> None:
    graph = plus_graph()
    graph.close_road(0, 3, protect=[])  # nothing protected
    graph.close_road(0, 2, protect=[5])  # the loop keeps everyone connected to 5
    with pytest.raises(RoadClosureError, match="node 4"):
        graph.close_road(0, 4, protect=[4])
    assert graph.hops_to(5).tolist() == [2, 1, 1, -1, 3, 0]


def test_protection_counts_only_nodes_that_reach_the_protected_node_now() -> None:
    graph = plus_graph()
    graph.close_road(0, 3, force=True)  # node 3 is cut off already
    graph.close_road(0, 2)  # allowed: node 3 cannot lose a route it does not have
    assert graph.closed_roads == frozenset({(0, 3), (0, 2)})
    assert graph.hops_to(5).tolist() == [2, 1, 1, -1, 3, 0]
    # The nodes that do reach the goal are still protected: closing 0-1 would cut 0 and 4 off
    with pytest.raises(RoadClosureError, match=r"\(0, 1\) would cut protected node 5 \(Goal\) off from 2 node"):
        graph.close_road(0, 1)
    assert graph.closed_roads == frozenset({(0, 3), (0, 2)})


def test_dead_end_road_of_the_campus_cannot_be_closed() -> None:
    graph = NavigationGraph(default_campus())
    dead_end = int(np.flatnonzero(graph.map.degrees == 1)[0])
    neighbour = int(graph.map.slots[dead_end][graph.map.slots[dead_end] >= 0][0])
    with pytest.raises(RoadClosureError):
        graph.close_road(dead_end, neighbour)


def test_hops_are_recomputed_after_a_closure_and_restored_after_reopening() -> None:
    graph = NavigationGraph(default_campus())
    goal = graph.landmarks["Dreese Lab"]
    before = graph.hops_to(goal).copy()
    assert before[goal] == 0 and np.all(before >= 0)
    for neighbour in (int(v) for v in graph.map.slots[goal] if v >= 0):
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


def test_state_hops_equal_node_hops_at_every_heading_on_a_street_network() -> None:
    graph = NavigationGraph(default_campus())
    goal = graph.landmarks["Cinema"]
    np.testing.assert_array_equal(graph.state_hops_to(goal), np.repeat(graph.hops_to(goal), 4))


def test_hops_are_cached_until_the_next_closure_and_read_only() -> None:
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
    graph = NavigationGraph(campus_1000)
    for u, v in graph.sample_closures(30, np.random.default_rng(1)):
        graph.close_road(u, v)
    for goal in (0, 499, 999):
        np.testing.assert_array_equal(graph.hops_to(goal), _reference_hops(graph, goal))


def test_shortest_path_follows_decreasing_hops() -> None:
    campus = NavigationGraph(default_campus())
    goal = campus.landmarks["Cinema"]
    path = campus.shortest_path(0, goal)
    hops = campus.hops_to(goal)
    assert path[0] == 0 and path[-1] == goal and len(path) == hops[0] + 1
    for a, b in itertools.pairwise(path):
        campus.map.road_id(a, b)
    graph = plus_graph()
    graph.close_road(0, 3, force=True)
    assert graph.shortest_path(3, 5) == []


def test_sample_closures_keeps_protected_nodes_reachable_and_is_deterministic() -> None:
    graph = NavigationGraph(default_campus())
    roads = graph.sample_closures(11, np.random.default_rng(42))
    assert roads == graph.sample_closures(11, np.random.default_rng(42))
    assert roads != graph.sample_closures(11, np.random.default_rng(43))
    assert len(set(roads)) == 11 and all(road in graph.map.roads for road in roads)
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


def test_the_protection_check_agrees_with_a_full_search_on_a_large_campus(campus_1000: RoadGraph) -> None:
    # The local shortcut (a road whose ends stay connected cuts nothing) must give the same verdicts as full searches
    graph = NavigationGraph(campus_1000)
    protected = sorted(graph.landmarks.values())
    verdicts = set()
    for road in campus_1000.roads[::7]:
        after = NavigationGraph(campus_1000, [road])  # closed without a check
        keeps_every_route = all(np.array_equal(after.hops_to(p) >= 0, graph.hops_to(p) >= 0) for p in protected)
        try:
            graph.close_road(*road)
            graph.reopen_road(*road)
            allowed = True
        except RoadClosureError:
            allowed = False
        assert allowed == keeps_every_route, road
        verdicts.add(allowed)
    assert verdicts == {True, False}  # both kinds of road were checked


def test_copies_and_graphs_over_one_map_have_independent_closures() -> None:
    campus = default_campus()
    graph = NavigationGraph(campus)
    other = graph.copy()
    u, v = graph.sample_closures(1, np.random.default_rng(0))[0]
    other.close_road(u, v)
    assert graph.closed_roads == frozenset() and other.closed_roads == {(u, v)}
    assert graph.version == 0 and other.version == 1
    assert other.map is graph.map is campus
    assert other.copy().closed_roads == {(u, v)}
    assert NavigationGraph(campus, [(u, v)]).closed_roads == {(u, v)}


def test_pickling_keeps_closures_and_live_tables() -> None:
    graph = plus_graph()
    graph.close_road(1, 5)
    clone = pickle.loads(pickle.dumps(graph))
    assert clone.closed_roads == {(1, 5)} and clone.version == 1
    np.testing.assert_array_equal(clone.transition_table, graph.transition_table)
    clone.close_road(0, 2, protect=[])
    assert clone.transition_table[0, RIGHT] == -1 and graph.transition_table[0, RIGHT] >= 0


def _reference_hops(graph: NavigationGraph, goal: int) -> np.ndarray:
    """Plain breadth-first search over the open roads, independent of NavigationGraph.hops_to."""
    adjacency: dict[int, set[int]] = {node: set() for node in range(graph.n_nodes)}
    for u, v in graph.map.roads:
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
