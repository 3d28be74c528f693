"""CampusNavEnv: spaces, rewards, starts, episode ends, info, closures, rendering, registration and bad input."""

from __future__ import annotations

import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from campusnav_env import GOALS, CampusNavEnv, NavigationGraph, RoadClosureError, road_key
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.maps.campus import generate_campus
from campusnav_env.maps.compass import BACK, FORWARD
from campusnav_env.rendering.street_view import RenderSettings

SMALL_VIEWS = RenderSettings(width=64, height=48)


@pytest.fixture(scope="module")
def cache_dir(shared_cache_dir: Path) -> Path:
    """The session's feature cache (conftest.py): the campus's views are built once, not once per module."""
    return shared_cache_dir


def small_views(cache_dir: Path) -> ViewBuild:
    return ViewBuild(render_settings=SMALL_VIEWS, cache_dir=cache_dir, progress=False)


def make_env(cache_dir: Path, **kwargs) -> CampusNavEnv:
    defaults = dict(encoder="pixels", view_build=small_views(cache_dir))
    return CampusNavEnv(**{**defaults, **kwargs})


def test_registered_ids_make_the_single_and_multi_goal_campus(cache_dir: Path) -> None:
    kwargs = dict(encoder="pixels", view_build=small_views(cache_dir))
    single = gym.make("CampusNav-v0", **kwargs)
    multi = gym.make("CampusNavMulti-v0", **kwargs)
    assert single.unwrapped.goal_names == ["Dreese Lab"]
    assert multi.unwrapped.goal_names == list(GOALS)
    assert single.unwrapped.graph.n_nodes == 101


def test_passes_gymnasium_and_sb3_env_checkers(cache_dir: Path) -> None:
    for mode in ("features", "image"):
        env = gym.make(
            "CampusNav-v0",
            observation_mode=mode,
            render_mode="rgb_array",
            encoder="pixels",
            view_build=small_views(cache_dir),
        ).unwrapped
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # not even a warning
            gym_check_env(env)
            sb3_check_env(env, warn=True)


def test_features_observation_holds_compass_views_goal_views_and_heading(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    obs, info = env.reset(seed=0)
    assert set(obs) == {"views", "goal_views", "heading"}
    assert obs["views"].shape == obs["goal_views"].shape == (4 * 64,)
    assert obs["views"].dtype == np.float32
    assert obs["heading"][info["heading"]] == 1.0 and obs["heading"].sum() == 1.0
    goal_obs = env.observation_at(info["goal_node"], 0, "Dreese Lab")
    np.testing.assert_array_equal(goal_obs["views"], goal_obs["goal_views"])
    assert env.observation_space.contains(obs)


def test_batched_observations_equal_single_ones(cache_dir: Path) -> None:
    for mode in ("features", "image"):
        env = make_env(cache_dir, observation_mode=mode)
        nodes, headings = np.array([0, 5, 5, 42]), np.array([0, 1, 3, 2])
        batch = env.observations_at(nodes, headings, "Dreese Lab")
        for i, (node, heading) in enumerate(zip(nodes, headings, strict=True)):
            single = env.observation_at(int(node), int(heading), "Dreese Lab")
            if mode == "features":
                for key in single:  # the same rows copied out of the same arrays: exact
                    np.testing.assert_array_equal(batch[key][i], single[key])
            else:
                np.testing.assert_array_equal(batch[i], single)
                assert env.observation_space.contains(batch[i])


def test_view_dim_projects_every_view_onto_its_leading_principal_axes(cache_dir: Path) -> None:
    env = make_env(cache_dir, view_dim=16)
    obs, _ = env.reset(seed=0)
    assert obs["views"].shape == obs["goal_views"].shape == (4 * 16,)
    assert env.observation_space.contains(obs)
    # Views that differ before the projection still differ after it: the agent can tell the same states apart
    projected = env.observations_at(np.arange(101), np.zeros(101, dtype=int), "Dreese Lab")["views"].reshape(-1, 16)
    full = make_env(cache_dir).observations_at(np.arange(101), np.zeros(101, dtype=int), "Dreese Lab")["views"]
    distinct_full = np.unique(full.reshape(404, -1).round(4), axis=0).shape[0]
    assert np.unique(projected.round(4), axis=0).shape[0] == distinct_full
    # More than the views span (no more axes than the 64 features of the pixels encoder): fitted to that, and said
    # (tests/test_small_maps.py: a map with fewer views than features)
    message = r"view_dim 100000 is more than this map's 404 views of 64 features span \(at most 64 axes\): using .* 64"
    with pytest.warns(UserWarning, match=message):
        assert make_env(cache_dir, view_dim=100_000).observation_space["views"].shape == (4 * 64,)
    with pytest.raises(ValueError, match="view_dim must be an int of at least 1"):
        make_env(cache_dir, view_dim=0)
    with pytest.raises(ValueError, match="does not apply to observation mode 'image'"):
        make_env(cache_dir, view_dim=16, observation_mode="image")


def test_image_observation_tiles_current_views_front_first_over_goal_views(cache_dir: Path) -> None:
    env = make_env(cache_dir, observation_mode="image")
    obs, info = env.reset(seed=1)
    assert obs.shape == (3, 96, 256) and obs.dtype == np.uint8
    east_facing = env.observation_at(info["node"], 1, "Dreese Lab")
    north_facing = env.observation_at(info["node"], 0, "Dreese Lab")
    # Facing east, the first tile (front) is the east view, which is the second tile when facing north
    np.testing.assert_array_equal(east_facing[:, :48, :64], north_facing[:, :48, 64:128])
    np.testing.assert_array_equal(east_facing[:, 48:], north_facing[:, 48:])


def test_rewards_for_goal_step_and_collision(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    graph = env.graph.map
    goal = env.goal_nodes[0]
    # Start next to the goal, facing the road towards it
    neighbour_slot = int(np.flatnonzero(graph.slots[goal] >= 0)[0])
    neighbour = int(graph.slots[goal, neighbour_slot])
    slot_to_goal = int(np.flatnonzero(graph.slots[neighbour] == goal)[0])
    env.reset(seed=0, options={"start": neighbour, "heading": slot_to_goal})
    _, reward, terminated, truncated, info = env.step(FORWARD)
    assert (reward, terminated, truncated) == (1.0, True, False)
    assert info["is_success"] and info["node"] == goal and info["shortest_distance"] == 0

    # A node with an empty slot: facing it and going forward is a collision, the agent stays
    node = int(np.flatnonzero((graph.slots < 0).any(axis=1) & (np.arange(graph.n_nodes) != goal))[0])
    empty_slot = int(np.flatnonzero(graph.slots[node] < 0)[0])
    env.reset(seed=0, options={"start": node, "heading": empty_slot})
    _, reward, terminated, _, info = env.step(FORWARD)
    assert reward == -0.01 and info["collision"] and info["node"] == node and not terminated
    assert info["action_mask"][FORWARD] == 0

    # Any other move costs the step penalty; back returns along the same road
    open_slot = int(np.flatnonzero(graph.slots[node] >= 0)[0])
    env.reset(seed=0, options={"start": node, "heading": open_slot})
    _, reward, _, _, info = env.step(FORWARD)
    if info["node"] != goal:
        assert reward == -0.005 and not info["collision"]
        _, _, _, _, info = env.step(BACK)
        assert info["node"] == node


def test_starts_are_uniform_over_nodes_that_reach_the_goal(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    starts = [env.reset(seed=seed)[1]["node"] for seed in range(600)]
    assert env.goal_nodes[0] not in starts
    counts = np.bincount(starts, minlength=env.graph.n_nodes)
    assert (counts > 0).sum() > 0.9 * (env.graph.n_nodes - 1)
    assert counts.max() < 20  # 600 draws over 100 nodes: about 6 each


def test_truncates_at_the_step_limit(cache_dir: Path) -> None:
    env = make_env(cache_dir, max_steps=5)
    _, info = env.reset(seed=0)
    node = info["node"]
    empty = np.flatnonzero(env.graph.map.slots[node] < 0)
    action = int((empty[0] - info["heading"]) % 4) if empty.size else BACK
    for step in range(5):
        _, _, terminated, truncated, info = env.step(action)
        assert not terminated
        assert truncated == (step == 4)
    assert info["is_success"] is False


def test_multi_goal_draws_every_goal_and_reset_option_fixes_one(cache_dir: Path) -> None:
    env = make_env(cache_dir, goals=list(GOALS))
    goals = {env.reset(seed=seed)[1]["goal"] for seed in range(40)}
    assert goals == set(GOALS)
    assert env.reset(seed=0, options={"goal": "Cinema"})[1]["goal"] == "Cinema"


def test_closing_a_road_blocks_it_updates_distances_and_reopens(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    goal = env.goal_nodes[0]
    before = env.node_distances(goal).copy()
    slots = env.graph.map.slots
    neighbour = int(slots[goal][slots[goal] >= 0][0])
    try:
        env.close_road(goal, neighbour)
    except RoadClosureError:
        pytest.skip("the goal's first road is a bridge")
    assert (goal, neighbour) in env.closed_roads or (neighbour, goal) in env.closed_roads
    assert env.node_distances(goal)[neighbour] > 1
    slot = int(np.flatnonzero(slots[neighbour] == goal)[0])
    env.reset(seed=0, options={"start": neighbour, "heading": slot})
    _, reward, _, _, info = env.step(FORWARD)
    assert info["collision"] and reward == -0.01
    env.reopen_road(goal, neighbour)
    np.testing.assert_array_equal(env.node_distances(goal), before)


def test_closures_are_per_env_and_refuse_cutting_the_goal_off(cache_dir: Path) -> None:
    graph = generate_campus()
    env = make_env(cache_dir, world=graph)
    other = make_env(cache_dir, world=graph)
    goal = env.goal_nodes[0]
    roads = [r for r in graph.roads if goal in r]
    for road in roads[:-1]:
        env.close_road(*road, force=True)
    with pytest.raises(RoadClosureError, match="cut"):
        env.close_road(*roads[-1])
    assert other.closed_roads == frozenset()
    # A navigation graph passed in keeps its own closures; the env starts from them and works on a copy
    shared = NavigationGraph(graph, [roads[0]])
    third = make_env(cache_dir, world=shared)
    assert third.closed_roads == {roads[0]}
    third.reopen_road(*roads[0])
    assert shared.closed_roads == {roads[0]}
    with pytest.raises(KeyError, match="0"):
        env.close_road(0, 0)


def test_render_returns_an_rgb_map_that_shows_the_route(cache_dir: Path) -> None:
    env = make_env(cache_dir, render_mode="rgb_array")
    env.reset(seed=0)
    first = env.render()
    assert first.ndim == 3 and first.shape[2] == 3 and first.dtype == np.uint8
    for _ in range(3):
        env.step(env.action_space.sample())
    assert not np.array_equal(first, env.render())


def test_bad_input_gives_clear_errors(cache_dir: Path) -> None:
    with pytest.raises(KeyError, match="Nowhere"):
        make_env(cache_dir, goals="Nowhere")
    with pytest.raises(ValueError, match="out of range"):
        make_env(cache_dir, goals=10_000)
    with pytest.raises(ValueError, match="observation_mode"):
        make_env(cache_dir, observation_mode="lidar")
    with pytest.raises(ValueError, match="encoder"):
        make_env(cache_dir, encoder="vgg")
    env = make_env(cache_dir)
    with pytest.raises(ValueError, match="start node"):
        env.reset(options={"start": 999})
    with pytest.raises(ValueError, match="is the goal"):
        env.reset(options={"start": env.goal_nodes[0]})
    # A start cut off from the goal (a forced closure) would only time out: refused, naming the closed road
    slots = env.graph.map.slots
    dead_end = int(np.flatnonzero(env.graph.map.degrees == 1)[0])
    road = road_key(dead_end, int(slots[dead_end].max()))
    env.close_road(*road, force=True)
    with pytest.raises(ValueError, match=rf"start node {dead_end} cannot reach the goal .*{road}"):
        env.reset(options={"start": dead_end})
    env.reopen_road(*road)
    with pytest.raises(KeyError, match="goal"):
        env.reset(options={"goal": "Cinema"})
    with pytest.raises(KeyError, match="teleport"):
        env.reset(options={"teleport": True})
    env.reset(seed=0)
    with pytest.raises(ValueError, match="invalid action"):
        env.step(7)


def test_package_imports_without_sb3_or_sb3_dcqn_and_registers_the_ids() -> None:
    code = (
        "import sys, gymnasium, campusnav_env; "
        "loaded = [m for m in sys.modules if m.split('.')[0] in ('sb3_dcqn', 'stable_baselines3')]; "
        "assert not loaded, loaded; "
        "assert 'CampusNav-v0' in gymnasium.registry and 'CampusNavMulti-v0' in gymnasium.registry"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_states_of_inverts_observations_at() -> None:
    env = CampusNavEnv(
        encoder="pixels", view_build=ViewBuild(render_settings=RenderSettings(width=32, height=24), progress=False)
    )
    states = np.arange(env.graph.n_states)
    nodes, headings = env.graph.map.state_nodes[states], env.graph.map.state_headings[states]
    observations = env.observations_at(nodes, headings, env.goal)
    np.testing.assert_array_equal(env.states_of(observations), states)
    observation, info = env.reset(seed=3)
    single = {key: value[None] for key, value in observation.items()}
    assert env.states_of(single)[0] == env.graph.map.state_of[info["node"], info["heading"]]
    with pytest.raises(ValueError, match="not this env's views"):
        env.states_of({**observations, "views": observations["views"] + 1.0})
