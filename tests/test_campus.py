"""Specification of the procedural campus: size, connectivity, irregularity, landmarks, determinism and speed."""

from __future__ import annotations

import time

import numpy as np
import pytest

from campusnav_env.maps.campus import GOALS, PLACES, default_campus, generate_campus
from campusnav_env.maps.compass import bearing_degrees
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.maps.road_graph import RoadGraph


@pytest.fixture(scope="module")
def campus() -> RoadGraph:
    return default_campus()


@pytest.fixture(scope="module")
def campus_1000() -> RoadGraph:
    return generate_campus(1000)


def crossing_roads(graph: RoadGraph) -> list[tuple[int, int]]:
    """Pairs of roads whose polylines cross (touching at a shared intersection does not count)."""
    segments, owner = [], []
    for road, line in enumerate(graph.geometries):
        segments.append(np.stack([line[:-1], line[1:]], axis=1))
        owner += [road] * (len(line) - 1)
    seg = np.concatenate(segments)
    owner = np.array(owner)
    p, q = seg[:, 0], seg[:, 1]
    low, high = seg.min(axis=1), seg.max(axis=1)

    def orient(o, s, t):
        return (s[..., 0] - o[..., 0]) * (t[..., 1] - o[..., 1]) - (s[..., 1] - o[..., 1]) * (t[..., 0] - o[..., 0])

    found = set()
    for i in range(len(seg)):
        near = np.all((low <= high[i]) & (high >= low[i]), axis=1) & (owner > owner[i])
        j = np.flatnonzero(near)
        if j.size == 0:
            continue
        crossing = (orient(p[j], q[j], p[i]) * orient(p[j], q[j], q[i]) < 0) & (
            orient(p[i], q[i], p[j]) * orient(p[i], q[i], q[j]) < 0
        )
        found.update((int(owner[i]), int(owner[k])) for k in j[crossing])
    return sorted(found)


@pytest.mark.parametrize("n_nodes", [8, 9, 37, 101, 250, 1000])
def test_exact_node_count_connected_and_at_most_four_roads(n_nodes: int) -> None:
    graph = generate_campus(n_nodes, seed=n_nodes)
    assert graph.n_nodes == n_nodes
    assert np.all(NavigationGraph(graph).hops_to(0) >= 0)
    assert graph.degrees.max() <= 4 and graph.degrees.min() >= 1


def test_too_few_nodes_or_bad_sizes_are_rejected() -> None:
    with pytest.raises(ValueError, match="at least 8"):
        generate_campus(7)
    with pytest.raises(ValueError, match="width"):
        generate_campus(20, width=0.0)
    with pytest.raises(ValueError, match="height"):
        generate_campus(20, height=float("nan"))
    with pytest.raises(TypeError, match="n_nodes"):
        generate_campus(20.5)


@pytest.mark.parametrize(("width", "height"), [(2500.0, 1700.0), (400.0, 3000.0)])
def test_everything_lies_inside_the_map_with_a_margin(width: float, height: float) -> None:
    graph = generate_campus(101, width=width, height=height)
    margin = 0.05 * min(width, height)
    assert np.all(graph.positions >= margin - 1e-9)
    assert np.all(graph.positions <= np.array([width, height]) - margin + 1e-9)
    points = np.concatenate(graph.geometries)
    assert np.all(points >= 0.0) and np.all(points <= np.array([width, height]))
    # ... and the streets fill the map rather than a corner of it
    span = graph.positions.max(axis=0) - graph.positions.min(axis=0)
    assert np.all(span >= 0.9 * (np.array([width, height]) - 2 * margin))


def test_same_seed_same_campus_other_seed_other_campus() -> None:
    first, again = generate_campus(101, seed=7), generate_campus(101, seed=7)
    assert first.fingerprint() == again.fingerprint()
    np.testing.assert_array_equal(first.positions, again.positions)
    assert first.roads == again.roads and first.landmarks == again.landmarks
    assert generate_campus(101, seed=8).fingerprint() != first.fingerprint()


def test_default_campus_is_the_seed_zero_campus_shared_and_immutable() -> None:
    campus = default_campus()
    assert campus is default_campus()  # generated once per process
    assert campus.fingerprint() == generate_campus().fingerprint()
    assert campus.n_nodes == 101
    with pytest.raises(ValueError, match="read-only"):
        campus.transitions[0, 0] = -1
    # Closures live in navigation graphs over the shared map, never in the map itself
    one, two = NavigationGraph(campus), NavigationGraph(campus)
    u, v = one.sample_closures(1, np.random.default_rng(0))[0]
    one.close_road(u, v)
    assert two.closed_roads == frozenset() and NavigationGraph(default_campus()).closed_roads == frozenset()


@pytest.mark.parametrize("graph_name", ["campus", "campus_1000"])
def test_streets_are_irregular_bends_diagonals_dead_ends_uneven_blocks(graph_name: str, request) -> None:
    graph: RoadGraph = request.getfixturevalue(graph_name)
    n_roads = graph.n_roads
    bent = sum(len(line) > 2 for line in graph.geometries)
    assert bent >= 0.15 * n_roads
    ends = np.array(graph.roads)
    chord = graph.positions[ends[:, 1]] - graph.positions[ends[:, 0]]
    off_axis = np.abs((bearing_degrees(chord[:, 0], chord[:, 1]) % 90.0) - 45.0) < 25.0  # within 20-70 deg of N/E
    assert off_axis.sum() >= 0.03 * n_roads
    dead_ends = np.sum(graph.degrees == 1)
    assert dead_ends >= 0.02 * graph.n_nodes
    assert np.sum(graph.degrees == 4) >= 0.15 * graph.n_nodes  # still plenty of crossroads
    assert graph.lengths.std() / graph.lengths.mean() > 0.25  # blocks of different sizes


@pytest.mark.parametrize(("n_nodes", "seed"), [(101, 0), (101, 1), (101, 2), (1000, 0)])
def test_roads_do_not_cross(n_nodes: int, seed: int, campus_1000: RoadGraph) -> None:
    graph = campus_1000 if (n_nodes, seed) == (1000, 0) else generate_campus(n_nodes, seed=seed)
    assert crossing_roads(graph) == []


def test_no_road_passes_through_another_intersection(campus: RoadGraph) -> None:
    for road, line in enumerate(campus.geometries):
        a, b = line[:-1], line[1:]
        others = np.setdiff1d(np.arange(campus.n_nodes), campus.roads[road])
        pts = campus.positions[others][:, None, :]
        ab = b - a
        t = np.clip(((pts - a) * ab).sum(-1) / (ab * ab).sum(-1), 0.0, 1.0)
        distance = np.linalg.norm(pts - (a + t[..., None] * ab), axis=-1).min()
        assert distance > 0.1 * campus.lengths[road], road


def test_goals_spread_one_per_quadrant_and_are_not_dead_ends(campus: RoadGraph) -> None:
    assert set(GOALS) <= set(campus.landmarks)
    centre = np.array([2500.0, 1700.0]) / 2
    quadrants = {tuple(campus.positions[campus.landmarks[goal]] > centre) for goal in GOALS}
    assert len(quadrants) == 4
    assert all(campus.degrees[campus.landmarks[goal]] >= 2 for goal in GOALS)
    # North-west, south-east, north-east, south-west
    expected = {"Dreese Lab": (False, True), "Town house": (True, False), "Cinema": (True, True)}
    for goal, quadrant in expected.items():
        assert tuple(campus.positions[campus.landmarks[goal]] > centre) == quadrant


def test_landmarks_are_the_goals_and_eight_places_at_distinct_nodes(campus: RoadGraph) -> None:
    assert set(campus.landmarks) == set(GOALS) | set(PLACES)
    assert len(PLACES) == 8
    assert len(set(campus.landmarks.values())) == len(campus.landmarks)


def test_small_campus_names_as_many_places_as_it_has_nodes() -> None:
    graph = generate_campus(8)
    assert set(GOALS) <= set(graph.landmarks)
    assert len(graph.landmarks) == 8 and len(set(graph.landmarks.values())) == 8


def test_ten_thousand_nodes_generate_in_seconds() -> None:
    start = time.perf_counter()
    graph = generate_campus(10_000)
    elapsed = time.perf_counter() - start
    print(f"generate_campus(10_000): {elapsed:.2f} s")
    assert graph.n_nodes == 10_000
    assert np.all(NavigationGraph(graph).hops_to(graph.landmarks["Dreese Lab"]) >= 0)
    assert graph.degrees.max() <= 4
