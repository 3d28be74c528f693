"""Maps of any size and kind: a hand-made map in metres builds an env, a map too large to build is refused before any
view is, the projection fits what a small map's views span, and the shipped example map and closure schedule work.

The map of the issue: 10 intersections with x/y in metres over 0-100 m, saved without a ``crs`` (which once read as
degrees: roads of 8,896 km and a view build that never finished) and with one. Cheap ``pixels`` views, 64 x 48.
"""

from __future__ import annotations

import ast
import re
import warnings
from fnmatch import fnmatch
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import campusnav_env  # noqa: F401  (registers the ids)
from campusnav_env import env as env_module
from campusnav_env.closures import ClosureSchedule
from campusnav_env.env import CampusNavEnv
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.maps.examples import EXAMPLES, example_path
from campusnav_env.maps.extent import MAX_MAP_SPAN_M, MAX_ROAD_NETWORK_M, MapExtentError, check_map_extent
from campusnav_env.maps.osm import CoordinatesWarning, load_graphml
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.rendering.world import build_world

nx = pytest.importorskip("networkx")

ROOT = Path(__file__).resolve().parents[1]
FAST = {
    "encoder": "pixels",
    "view_build": ViewBuild(render_settings=RenderSettings(width=64, height=48), progress=False),
}
# 10 intersections over 100 m x 80 m (x/y in metres, all within the ranges of degrees): a 2 x 3 grid with four dead ends
TOWN = {
    0: (0, 0),
    1: (50, 0),
    2: (100, 0),
    3: (0, 80),
    4: (50, 80),
    5: (100, 80),
    6: (20, 40),
    7: (80, 35),
    8: (25, 60),
    9: (75, 55),
}
TOWN_ROADS = [(0, 1), (1, 2), (3, 4), (4, 5), (0, 3), (2, 5), (1, 4), (0, 6), (2, 7), (3, 8), (5, 9)]

pytestmark = pytest.mark.usefixtures("shared_feature_cache")


def write_town(path: Path, crs: str | None = None) -> Path:
    graph = nx.Graph()
    if crs is not None:
        graph.graph["crs"] = crs
    for node, (x, y) in TOWN.items():
        graph.add_node(node, x=float(x), y=float(y))
    graph.nodes[4]["name"] = "Library"
    graph.add_edges_from(TOWN_ROADS)
    nx.write_graphml(graph, path)
    return path


@pytest.fixture(scope="module")
def town(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_town(tmp_path_factory.mktemp("maps") / "town.graphml")


def test_a_map_in_metres_without_a_crs_is_read_as_metres_and_says_so(town: Path) -> None:
    with pytest.warns(CoordinatesWarning, match=r"town.graphml has no crs: x/y read as metres .*8,896 km.*lonlat"):
        graph = load_graphml(town)
    assert graph.n_nodes == 10
    np.testing.assert_allclose(graph.positions, [TOWN[node] for node in sorted(TOWN)])
    assert graph.lengths.max() == pytest.approx(80.0)


def test_a_crs_decides_without_a_word(tmp_path: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        graph = load_graphml(write_town(tmp_path / "utm.graphml", crs="EPSG:32617"))
    np.testing.assert_allclose(graph.positions, [TOWN[node] for node in sorted(TOWN)])


def test_an_env_builds_and_steps_on_the_metres_map_with_the_default_view_dim_of_the_yaml(town: Path) -> None:
    # The shipped YAML's view_dim 64 is more than 40 views span: fitted to 39, said once
    with pytest.warns(CoordinatesWarning), pytest.warns(UserWarning, match=r"view_dim 64 .* 40 views .* view_dim 39"):
        env = gym.make("CampusNav-v0", world=town, goals="Library", view_dim=64, **FAST).unwrapped
    assert env.observation_space["views"].shape == (4 * 39,)
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)
    _, reward, _, _, info = env.step(0)
    assert np.isfinite(reward) and info["goal"] == "Library"
    # Nothing lost to the fit: views that differ without a projection still differ
    with pytest.warns(CoordinatesWarning):
        full = CampusNavEnv(world=town, goals="Library", **FAST)
    nodes, headings = np.arange(10), np.zeros(10, dtype=int)
    projected = env.observations_at(nodes, headings, "Library")["views"].reshape(40, -1)
    unprojected = full.observations_at(nodes, headings, "Library")["views"].reshape(40, -1)
    assert np.unique(projected.round(4), axis=0).shape[0] == np.unique(unprojected.round(4), axis=0).shape[0]


def test_a_view_dim_the_views_can_fill_is_kept_and_a_bad_one_is_an_error(town: Path) -> None:
    with pytest.warns(CoordinatesWarning):
        graph = load_graphml(town)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        env = CampusNavEnv(world=graph, goals="Library", view_dim=39, **FAST)
    assert env.observation_space["views"].shape == (4 * 39,)
    for bad in (0, -3, 2.5, True, "64"):
        with pytest.raises(ValueError, match=r"view_dim must be an int of at least 1, got"):
            CampusNavEnv(world=graph, goals="Library", view_dim=bad, **FAST)  # type: ignore[arg-type]


def test_degrees_forced_on_a_metres_map_are_refused_before_any_view_is_built(
    town: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_views(*args: object, **kwargs: object) -> None:
        raise AssertionError("the view build started")

    monkeypatch.setattr(env_module, "ViewSource", no_views)
    message = (
        r"map '.*town.graphml': too large to build its street views: it spans 8,132 km x 8,896 km and its roads add up"
        r" to 58,362 km \(the longest, road 0-3, 8,896 km\); the limits are 100 km across and 40,000 km of road\. "
        r"If x/y are metres read as longitude/latitude, load the map with coords='projected' \(the env's map_coords\)"
    )
    with pytest.raises(MapExtentError, match=message):
        CampusNavEnv(world=town, map_coords="lonlat", goals="Library", **FAST)


def test_map_coords_reads_the_file_as_told_and_only_applies_to_a_file(town: Path) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # told: no guess to report
        env = CampusNavEnv(world=str(town), map_coords="projected", goals="Library", **FAST)
    assert env.graph.map.lengths.max() == pytest.approx(80.0)
    with pytest.raises(ValueError, match=r"map_coords must be one of \('auto', 'lonlat', 'projected'\), got 'feet'"):
        CampusNavEnv(world=town, map_coords="feet", goals="Library", **FAST)
    with pytest.raises(ValueError, match=r"map_coords='lonlat' says how to read a GraphML file; world is not one"):
        CampusNavEnv(world="campus", map_coords="lonlat", **FAST)
    with pytest.raises(FileNotFoundError, match=r"GraphML file not found: no-such-map\.graphml"):
        CampusNavEnv(world="no-such-map.graphml", **FAST)


def _straight_roads(xs: list[float]) -> RoadGraph:
    """Intersections on a line at ``xs`` (m), each joined to the next."""
    positions = np.array([[x, 0.0] for x in xs])
    return RoadGraph(positions, [(i, i + 1) for i in range(len(xs) - 1)], name="line")


def test_the_city_env_takes_a_graphml_path_too() -> None:
    city = gym.make("CampusNavCity-v0", world=example_path("small_town.graphml"), goals="Library", **FAST).unwrapped
    assert city.graph.n_nodes == 15 and city.goal_names == ["Library"]
    # UTM metres cannot be degrees: told they are, the import refuses
    with pytest.raises(
        ValueError, match=r"small_town.graphml: coords='lonlat' says .* \|x\| = 329981, \|y\| = 4.429e\+06"
    ):
        gym.make("CampusNavCity-v0", world=example_path("small_town.graphml"), map_coords="lonlat", **FAST)


def test_the_extent_limits_are_the_documented_ones() -> None:
    check_map_extent(_straight_roads([0.0, MAX_MAP_SPAN_M]))  # 100 km across: built
    with pytest.raises(MapExtentError, match=r"map 'line': .* spans 101 km x 0 m .* \(the longest, road 0-1, 101 km\)"):
        check_map_extent(_straight_roads([0.0, MAX_MAP_SPAN_M + 1000.0]))
    # Within 100 km, but back and forth: 410 roads of 99 km, more road than 40,000 km
    zigzag = RoadGraph(
        np.array([[99_000.0 * (i % 2), 10.0 * i] for i in range(411)]), [(i, i + 1) for i in range(410)], name="zigzag"
    )
    assert zigzag.lengths.sum() > MAX_ROAD_NETWORK_M
    with pytest.raises(MapExtentError, match=r"map 'from a file': .* roads add up to 40,590 km .* 40,000 km of road"):
        check_map_extent(zigzag, source="from a file")
    with pytest.raises(MapExtentError, match="too large to build its street views"):
        build_world(zigzag)


def test_the_examples_ship_with_the_package_and_are_found_by_name() -> None:
    assert [example_path(name).name for name in EXAMPLES] == ["small_town.graphml", "closures.yml"]
    assert all(example_path(name).is_file() for name in EXAMPLES)
    with pytest.raises(FileNotFoundError, match=r"no example named 'columbus.graphml'; the examples are small_town"):
        example_path("columbus.graphml")
    # pip install ships them: each matches a package-data pattern of campusnav_env
    package_data = (ROOT / "pyproject.toml").read_text().split("[tool.setuptools.package-data]")[1]
    patterns = ast.literal_eval(re.search(r"^campusnav_env = (\[.*\])$", package_data, re.MULTILINE).group(1))
    for name in EXAMPLES:
        relative = example_path(name).relative_to(ROOT / "campusnav_env").as_posix()
        assert any(fnmatch(relative, pattern) for pattern in patterns), relative


def test_the_example_town_and_its_closure_schedule_drive_an_env() -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("error", CoordinatesWarning)  # it has a crs: metres, no guess
        graph = load_graphml(example_path("small_town.graphml"))
    assert graph.n_nodes == 15 and graph.n_roads == 19
    assert sorted(graph.landmarks) == ["Library", "Market", "Station", "Town hall"]
    assert np.ptp(graph.positions, axis=0) == pytest.approx([670, 469], abs=1.0)
    goals = sorted(graph.landmarks)
    env = gym.make("CampusNavMulti-v0", world=example_path("small_town.graphml"), goals=goals, **FAST).unwrapped
    schedule = ClosureSchedule.from_yaml(example_path("closures.yml"))
    assert [event.describe() for event in schedule.ordered()] == [
        "step 2000: close 4-5",
        "step 4000: close the next road on the route (busiest)",
    ]
    schedule.validate(env.graph, protect=env.goal_nodes)  # its roads exist and keep every goal reachable
    check_env(env, skip_render_check=True)
    env.close_road(4, 5)
    obs, info = env.reset(seed=1, options={"goal": "Library"})
    for _ in range(20):
        obs, _, terminated, truncated, info = env.step(int(np.flatnonzero(info["action_mask"])[0]))
        assert env.observation_space.contains(obs)
        if terminated or truncated:
            break
