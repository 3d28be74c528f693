"""CampusNavCity: the generated city (size, density, landmarks), real maps, the episode cap that grows with the map,
the env checkers, route evaluation and closures on a city.

Envs use pixel features of small views on a 150-intersection city, built once per module (the views are cached;
the cold build is most of this file's time).
"""

from __future__ import annotations

import itertools
import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import campusnav_env.city_env as city_env
import campusnav_env.env as env_module
from campusnav_env import GOALS, CampusNavCityEnv, CampusNavEnv, NavigationGraph, RoadClosureError, evaluate_routes
from campusnav_env.env import auto_max_steps, longest_shortest_route
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.maps.campus import default_campus, generate_campus, generate_city
from campusnav_env.rendering.street_view import RenderSettings

CITY_SIZE = 150
CITY = generate_city(CITY_SIZE, seed=0)
LONGEST = 18  # hops from the farthest start to Dreese Lab


@pytest.fixture(scope="module")
def env_kwargs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return dict(
        encoder="pixels",
        view_build=ViewBuild(
            render_settings=RenderSettings(width=64, height=48),
            cache_dir=tmp_path_factory.mktemp("cache"),
            progress=False,
        ),
    )


@pytest.fixture(scope="module")
def city(env_kwargs: dict[str, Any]) -> CampusNavCityEnv:
    """The city env every test shares (built once: this renders the views into the module's cache)."""
    return CampusNavCityEnv(n_intersections=CITY_SIZE, **env_kwargs)


def shortest_path_policy(env: CampusNavEnv, goal: int) -> Any:
    """A batched policy that reads the states off the views and moves one hop closer to ``goal`` on today's roads."""

    def policy(observations: dict[str, np.ndarray]) -> np.ndarray:
        states = env.states_of(observations)
        hops = env.graph.state_hops_to(goal)
        targets = env.graph.transition_table[states]
        worst = np.iinfo(np.int64).max
        remaining = np.where(targets >= 0, hops[np.maximum(targets, 0)], worst)
        return np.where(remaining < 0, worst, remaining).argmin(axis=1)

    return policy


def lengthening_closure(graph: NavigationGraph, goal: int) -> tuple[int, int]:
    """A road on the farthest start's route whose closure makes that route longer (and cuts nobody off the goal)."""
    farthest = int(np.argmax(graph.hops_to(goal)))
    for road in itertools.pairwise(graph.shortest_path(farthest, goal)):
        trial = graph.copy()
        try:
            trial.close_road(*road, protect=[goal])
        except RoadClosureError:
            continue
        if trial.hops_to(goal)[farthest] > graph.hops_to(goal)[farthest]:
            return road
    raise AssertionError("no closure on the route makes it longer")


# --- the generated city ------------------------------------------------------------------------------------------


def test_the_city_of_101_intersections_is_the_built_in_campus() -> None:
    city, campus = generate_city(101, seed=0), default_campus()
    np.testing.assert_array_equal(city.positions, campus.positions)
    assert city.roads == campus.roads and city.landmarks == campus.landmarks
    for ours, theirs in zip(city.geometries, campus.geometries, strict=True):
        np.testing.assert_array_equal(ours, theirs)


def test_the_city_keeps_the_campus_street_density_at_every_size() -> None:
    campus = default_campus()
    for n in (400, 1_600):
        city = generate_city(n, seed=0)
        assert city.n_nodes == n
        # The extent grows with sqrt(n / 101): four times the intersections, twice the width and height
        scale = np.sqrt(n / 101)
        np.testing.assert_allclose(np.ptp(city.positions, axis=0), scale * np.ptp(campus.positions, axis=0), rtol=0.05)
        assert np.mean(city.lengths) == pytest.approx(np.mean(campus.lengths), rel=0.1)
    # At the campus's fixed extent the streets of 1,600 intersections would be four times shorter
    assert np.mean(generate_campus(1_600, seed=0).lengths) < 0.3 * np.mean(campus.lengths)


def test_every_generated_city_has_the_four_goals_among_its_landmarks() -> None:
    for n in (8, 9, 20, 300, 1_000, 10_000):
        for seed in (0, 1) if n < 10_000 else (0,):
            graph = generate_city(n, seed=seed)
            assert set(GOALS) <= set(graph.landmarks), (n, seed)
            # at a through street, reachable from everywhere
            assert (NavigationGraph(graph).hops_to(graph.landmarks["Dreese Lab"]) >= 0).all()


def test_the_map_seed_changes_the_streets_and_the_default_is_a_1000_city(
    env_kwargs: dict[str, Any], city: CampusNavCityEnv, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert city.graph.map.fingerprint() == CITY.fingerprint()
    assert generate_city(CITY_SIZE, seed=1).fingerprint() != CITY.fingerprint()
    # Without arguments the env generates 1,000 intersections with seed 0 (a small city stands in for the test)
    asked: list[tuple[int, int]] = []

    def recording_generate_city(n_intersections: int, seed: int = 0) -> Any:
        asked.append((n_intersections, seed))
        return CITY

    monkeypatch.setattr(city_env, "generate_city", recording_generate_city)
    CampusNavCityEnv(**env_kwargs)
    CampusNavCityEnv(map_seed=3, **env_kwargs)
    assert asked == [(1_000, 0), (1_000, 3)]


# --- the episode cap -----------------------------------------------------------------------------------------------


def test_auto_cap_is_four_times_the_longest_route_and_never_below_200() -> None:
    # seed 0, Dreese Lab: the longest routes of benchmarks/results/scale.md
    for n, longest, cap in ((101, 17, 200), (1_000, 45, 200), (10_000, 132, 528)):
        graph = NavigationGraph(generate_city(n, seed=0))
        goal = graph.landmarks["Dreese Lab"]
        assert longest_shortest_route(graph, [goal]) == longest
        assert auto_max_steps(graph, [goal]) == cap
    # Several goals: the worst start for the worst goal
    graph = NavigationGraph(generate_city(1_000, seed=0))
    goals = [graph.landmarks[name] for name in GOALS]
    assert longest_shortest_route(graph, goals) == max(int(graph.hops_to(goal).max()) for goal in goals)


def test_city_cap_defaults_to_auto_and_an_int_still_works(env_kwargs: dict[str, Any], city: CampusNavCityEnv) -> None:
    assert city.max_steps == 200  # 4 x 18 hops is under the floor
    short = CampusNavCityEnv(n_intersections=CITY_SIZE, max_steps=5, **env_kwargs)
    short.reset(seed=0, options={"start": int(np.argmax(short.node_distances(short.goal_nodes[0])))})
    ends = [short.step(0)[2:4] for _ in range(5)]
    assert ends[-1] == (False, True) and all(end == (False, False) for end in ends[:-1])
    with pytest.raises(ValueError, match="max_steps must be an int or 'auto'"):
        CampusNavCityEnv(n_intersections=CITY_SIZE, max_steps="longest", **env_kwargs)


def test_auto_cap_reads_the_open_map_once_at_construction(
    env_kwargs: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(env_module, "AUTO_MAX_STEPS_FLOOR", 1)  # the floor out of the way: the cap is 4 x 18 hops
    goal = CITY.landmarks["Dreese Lab"]
    road = lengthening_closure(NavigationGraph(CITY), goal)
    closed = NavigationGraph(CITY, closed_roads=[road])
    # CampusNavEnv takes "auto" too; the closures of a NavigationGraph passed in do not count
    passed_closed = CampusNavEnv(world=closed, goals="Dreese Lab", max_steps="auto", **env_kwargs)
    assert passed_closed.longest_route() > LONGEST and passed_closed.max_steps == 4 * LONGEST
    # nor do closures made later
    city = CampusNavCityEnv(world=CITY, **env_kwargs)
    assert city.max_steps == 4 * LONGEST
    city.close_road(*road)
    assert city.longest_route() > LONGEST and city.max_steps == 4 * LONGEST


# --- real maps and arguments ---------------------------------------------------------------------------------------


def test_world_takes_a_real_map_instead(env_kwargs: dict[str, Any]) -> None:
    osm = pytest.importorskip("campusnav_env.maps.osm")
    nx = pytest.importorskip("networkx")
    streets = nx.grid_2d_graph(6, 5)  # 30 intersections 120 m apart, in metres
    real = nx.Graph()
    for node in streets.nodes:
        real.add_node(f"{node[0]}-{node[1]}", x=120.0 * node[0], y=120.0 * node[1])
    real.add_edges_from((f"{u[0]}-{u[1]}", f"{v[0]}-{v[1]}") for u, v in streets.edges)
    real.nodes["5-4"]["name"] = "Library"
    graph = osm.import_networkx(real, simplify=False).graph
    env = gym.make("CampusNavCity-v0", world=graph, goals="Library", **env_kwargs).unwrapped
    assert env.graph.n_nodes == 30 and env.goal_names == ["Library"]
    assert env.max_steps == 200  # the same cap rule: 4 x 9 hops is under the floor
    with pytest.raises(ValueError, match=r"n_intersections and map_seed .* must not be given"):
        CampusNavCityEnv(world=graph, n_intersections=30, goals="Library", **env_kwargs)
    with pytest.raises(
        TypeError, match="world must be a RoadGraph, a NavigationGraph or a GraphML file's path, got str 'campus'"
    ):
        CampusNavCityEnv(world="campus", **env_kwargs)
    with pytest.raises(KeyError, match="unknown goal 'Dreese Lab'"):
        CampusNavCityEnv(world=graph, **env_kwargs)  # the default goal is the generated city's


def test_campusnav_arguments_pass_through(env_kwargs: dict[str, Any], city: CampusNavCityEnv) -> None:
    projected = CampusNavCityEnv(n_intersections=CITY_SIZE, view_dim=8, goals=list(GOALS), **env_kwargs)
    obs, info = projected.reset(seed=0)
    assert obs["views"].shape == (4 * 8,) and info["goal"] in GOALS
    assert projected.goal_names == list(GOALS)
    picture = CampusNavCityEnv(n_intersections=CITY_SIZE, render_mode="rgb_array", **env_kwargs)
    picture.reset(seed=0)
    assert picture.render().ndim == 3


def test_registered_city_passes_gymnasium_and_sb3_env_checkers(env_kwargs: dict[str, Any]) -> None:
    env = gym.make("CampusNavCity-v0", n_intersections=CITY_SIZE, **env_kwargs)
    assert isinstance(env.unwrapped, CampusNavCityEnv) and env.unwrapped.graph.n_nodes == CITY_SIZE
    assert env.unwrapped.goal_names == ["Dreese Lab"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # not even a warning
        gym_check_env(env.unwrapped)
        sb3_check_env(env.unwrapped, warn=True)


# --- route evaluation and closures ---------------------------------------------------------------------------------


def test_route_evaluation_and_closures_work_on_the_city(city: CampusNavCityEnv) -> None:
    goal = city.goal_nodes[0]
    policy = shortest_path_policy(city, goal)
    report = evaluate_routes(city, policy)
    assert report.success_rate == 1.0 and report.spl == pytest.approx(1.0)
    assert len(report.routes) == int((city.node_distances(goal) > 0)[city.graph.map.state_nodes].sum())
    # Close a road that the farthest start's route needs: its routes go round, none along the closed road
    farthest = int(np.argmax(city.node_distances(goal)))
    road = lengthening_closure(city.graph, goal)
    before = int(city.node_distances(goal)[farthest])
    city.close_road(*road)
    try:
        closed = evaluate_routes(city, policy)
        assert closed.success_rate == 1.0 and closed.spl == pytest.approx(1.0)
        assert int(city.node_distances(goal)[farthest]) > before
        for route in closed.routes:
            steps = set(zip(route.nodes[:-1], route.nodes[1:], strict=True))
            assert road not in steps and road[::-1] not in steps
    finally:
        city.reopen_road(*road)
    assert int(city.node_distances(goal)[farthest]) == before


def test_visible_closures_show_on_the_city(env_kwargs: dict[str, Any]) -> None:
    env = CampusNavCityEnv(n_intersections=CITY_SIZE, visible_closures=True, **env_kwargs)
    u, v = CITY.roads[0]
    open_views = env.observation_at(u, env.headings_at(u)[0], "Dreese Lab")["views"].copy()
    env.close_road(u, v, force=True)
    assert not np.array_equal(env.observation_at(u, env.headings_at(u)[0], "Dreese Lab")["views"], open_views)
    env.reopen_road(u, v)
    np.testing.assert_array_equal(env.observation_at(u, env.headings_at(u)[0], "Dreese Lab")["views"], open_views)
