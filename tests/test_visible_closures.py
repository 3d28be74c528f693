"""Visible closures: a closed road shows a barrier in the views of its two end nodes (``visible_closures=True``)."""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env
from stable_baselines3.common.vec_env import DummyVecEnv

from campusnav_env import CampusNavEnv, NavigationGraph, RoadClosureError
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.maps.campus import generate_campus
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.street_view import BARRIER_OFFSET, RenderSettings, StreetViewRenderer, view_bearings
from campusnav_env.rendering.world import build_world

SMALL_VIEWS = RenderSettings(width=64, height=48)


@pytest.fixture(scope="module")
def graph() -> RoadGraph:
    return generate_campus(16, seed=1)


def make_env(
    graph: RoadGraph, cache_dir: Path, render_settings: RenderSettings | None = SMALL_VIEWS, **kwargs
) -> CampusNavEnv:
    build = ViewBuild(render_settings=render_settings, cache_dir=cache_dir, progress=False)
    defaults = dict(world=graph, encoder="pixels", view_build=build)
    return CampusNavEnv(**{**defaults, "visible_closures": True, **kwargs})


def all_views(env: CampusNavEnv) -> np.ndarray:
    """Every node's observation views (heading north), as the agent gets them."""
    n = env.graph.n_nodes
    return env.observations_at(np.arange(n), np.zeros(n, dtype=int), env.goal_nodes[0])["views"]


def road_away_from_goal(env: CampusNavEnv) -> tuple[int, int]:
    """A road that neither ends at the goal nor cuts any node off from it."""
    probe = env.graph.copy()
    for road in env.graph.map.roads:
        if env.goal_nodes[0] not in road:
            try:
                probe.close_road(*road, protect=env.goal_nodes)
            except RoadClosureError:
                continue
            return road
    raise AssertionError("no such road")


def slot_of(graph: RoadGraph, node: int, neighbour: int) -> int:
    return int(np.flatnonzero(graph.slots[node] == neighbour)[0])


def reddish(image: np.ndarray) -> np.ndarray:
    """Pixels of an ``(..., 3)`` RGB image that are clearly red: the barrier's stripes (and the cones)."""
    image = image.astype(np.int64)
    return (image[..., 0] - image[..., 1] > 50) & (image[..., 0] - image[..., 2] > 50)


def far_slots(graph: RoadGraph, node: int, slot: int, degrees: float = 85.0) -> list[int]:
    """The views of ``node`` that look at least ``degrees`` away from view ``slot``: a barrier 12 m wide at
    ``BARRIER_OFFSET`` m down that view's road lies outside their 90-degree field of view."""
    bearings = view_bearings(graph)[node]
    apart = np.abs((bearings - bearings[slot] + 180.0) % 360.0 - 180.0)
    return [int(k) for k in np.flatnonzero(apart >= degrees)]


@pytest.mark.parametrize("view_dim", [None, 8])
def test_closing_changes_the_views_of_the_two_end_nodes_only_and_reopening_restores_them(
    graph: RoadGraph, tmp_path: Path, view_dim: int | None
) -> None:
    env = make_env(graph, tmp_path, view_dim=view_dim)
    before = all_views(env)
    u, v = road_away_from_goal(env)
    env.close_road(u, v, force=True)
    closed = all_views(env)
    changed = np.flatnonzero((closed != before).any(axis=1))
    assert changed.tolist() == sorted((u, v))
    obs, _ = env.reset(seed=0, options={"start": u})
    assert env.observation_space.contains(obs)
    env.reopen_road(u, v)
    np.testing.assert_array_equal(all_views(env), before)  # bit-identical: the open map's own rows


def test_the_goal_views_stay_the_pictures_of_the_open_map(graph: RoadGraph, tmp_path: Path) -> None:
    env = make_env(graph, tmp_path)
    goal = env.goal_nodes[0]
    road = next(road for road in graph.roads if goal in road)
    start = next(node for node in range(graph.n_nodes) if node not in (goal, *road))
    before = env.observation_at(start, 0, goal)["goal_views"]
    env.close_road(*road, force=True)
    after = env.observation_at(start, 0, goal)
    # The goal itself now shows the barrier, but what the agent was told to look for does not change
    assert not np.array_equal(env.observation_at(goal, 0, goal)["views"], before)
    np.testing.assert_array_equal(after["goal_views"], before)


def test_without_the_option_closures_stay_invisible(graph: RoadGraph, tmp_path: Path) -> None:
    env = make_env(graph, tmp_path, visible_closures=False)
    before = all_views(env)
    env.close_road(*road_away_from_goal(env), force=True)
    np.testing.assert_array_equal(all_views(env), before)


def test_closures_of_a_navigation_graph_passed_in_are_shown(graph: RoadGraph, tmp_path: Path) -> None:
    road = graph.roads[0]
    closing = make_env(graph, tmp_path)
    closing.close_road(*road, force=True)
    given = make_env(graph, tmp_path, world=NavigationGraph(graph, [road]))
    np.testing.assert_array_equal(all_views(given), all_views(closing))
    # Also closures made on the env's graph directly show up in the next observation
    direct = make_env(graph, tmp_path)
    direct.graph.close_road(*road, force=True)
    np.testing.assert_array_equal(all_views(direct), all_views(closing))


@pytest.mark.parametrize("size", [(64, 48), (160, 120)])
def test_the_barrier_stands_ahead_in_the_view_down_the_closed_road(graph: RoadGraph, size: tuple[int, int]) -> None:
    width, height = size
    renderer = StreetViewRenderer(build_world(graph, seed=0), RenderSettings(width=width, height=height))
    u, v = graph.roads[0]
    for node, other in ((u, v), (v, u)):
        slot = slot_of(graph, node, other)
        open_views = renderer.render_node(node)
        closed_views = renderer.render_node(node, closed_roads={(other, node)})
        # The barrier's image ahead: 12 m of road at BARRIER_OFFSET m, from the ground up to about the horizon
        f = renderer.fx / BARRIER_OFFSET
        rows = slice(int(renderer.cy - 0.5 * f), int(renderer.cy + 2.5 * f) + 1)
        cols = slice(int(renderer.cx - 5.0 * f), int(renderer.cx + 5.0 * f) + 1)
        ahead_open = open_views[slot, rows, cols].astype(np.int64)
        ahead_closed = closed_views[slot, rows, cols].astype(np.int64)
        assert reddish(ahead_open).sum() == 0
        assert reddish(ahead_closed).mean() > 0.03
        assert (np.abs(ahead_closed - ahead_open).sum(axis=2) > 60).mean() > 0.15
        others = far_slots(graph, node, slot)
        assert others  # the test looks at a road whose other views look well away from it
        for k in others:
            np.testing.assert_array_equal(closed_views[k], open_views[k])


def test_re_encodings_are_cached_in_memory_and_on_disk(
    graph: RoadGraph, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    rendered: list[tuple[int, frozenset]] = []
    render_node = StreetViewRenderer.render_node

    def counting(self: StreetViewRenderer, node: int, **kwargs) -> np.ndarray:
        rendered.append((node, frozenset(kwargs.get("closed_roads", ()))))
        return render_node(self, node, **kwargs)

    monkeypatch.setattr(StreetViewRenderer, "render_node", counting)
    env = make_env(graph, tmp_path)
    assert len(rendered) == graph.n_nodes  # the open map, once
    u, v = road_away_from_goal(env)
    rendered.clear()
    env.close_road(u, v, force=True)
    first = all_views(env)
    assert sorted(node for node, _ in rendered) == sorted((u, v))
    env.reopen_road(u, v)
    env.close_road(u, v, force=True)  # in memory
    np.testing.assert_array_equal(all_views(env), first)
    assert len(rendered) == 2
    again = make_env(graph, tmp_path)  # on disk: neither the open map nor the closure is rendered again
    again.close_road(u, v, force=True)
    np.testing.assert_array_equal(all_views(again), first)
    assert len(rendered) == 2
    # Another set of closed roads at u is another picture
    w = next(int(n) for n in graph.slots[u] if n >= 0 and n != v)
    env.close_road(u, w, force=True)
    assert sorted(node for node, _ in rendered[2:]) == sorted((u, w))
    assert rendered[2:][[node for node, _ in rendered[2:]].index(u)][1] == {
        tuple(sorted((u, v))),
        tuple(sorted((u, w))),
    }


@pytest.mark.parametrize("view_dim", [None, 8])
def test_re_encoded_views_go_through_the_transform_fit_on_the_open_map(
    graph: RoadGraph, tmp_path: Path, view_dim: int | None
) -> None:
    env = make_env(graph, tmp_path, view_dim=view_dim)
    transform = env._features
    u, v = road_away_from_goal(env)
    env.close_road(u, v, force=True)
    assert env._features is transform  # not refit
    # The one-node path (render, encode, transform) on the open roads reproduces the open map's rows
    for node in (u, v):
        encoded = env._view_source.renders_with(node, frozenset())
        np.testing.assert_allclose(transform.transform(encoded)[0], env._open_views[node], atol=1e-4)


def test_image_observations_show_the_barrier(graph: RoadGraph, tmp_path: Path) -> None:
    env = make_env(graph, tmp_path, observation_mode="image", render_settings=None)
    u, v = road_away_from_goal(env)
    slot = slot_of(graph, u, v)
    before = env._node_views.copy()
    env.close_road(u, v, force=True)
    after = env._node_views
    assert np.flatnonzero((after != before).reshape(graph.n_nodes, -1).any(axis=1)).tolist() == [u, v]
    assert reddish(after[u, slot].transpose(1, 2, 0)).sum() > reddish(before[u, slot].transpose(1, 2, 0)).sum() + 10
    assert far_slots(graph, u, slot)
    for k in far_slots(graph, u, slot):
        np.testing.assert_array_equal(after[u, k], before[u, k])
    obs, _ = env.reset(seed=0, options={"start": u, "heading": slot})
    np.testing.assert_array_equal(obs[:, :48, :64], after[u, slot])  # the front tile


@pytest.mark.parametrize("mode", ["features", "image"])
def test_passes_the_env_checkers_with_a_road_closed(graph: RoadGraph, tmp_path: Path, mode: str) -> None:
    settings = SMALL_VIEWS if mode == "features" else None
    env = gym.make(
        "CampusNav-v0",
        world=graph,
        observation_mode=mode,
        encoder="pixels",
        view_build=ViewBuild(render_settings=settings, cache_dir=tmp_path, progress=False),
        visible_closures=True,
    ).unwrapped
    env.close_road(*road_away_from_goal(env))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env)
        sb3_check_env(env, warn=True)


def test_closures_through_a_vec_env_just_work(graph: RoadGraph, tmp_path: Path) -> None:
    envs = DummyVecEnv([lambda: make_env(graph, tmp_path) for _ in range(2)])
    reference = make_env(graph, tmp_path)
    u, v = road_away_from_goal(reference)
    reference.close_road(u, v, force=True)
    envs.env_method("close_road", u, v, force=True)
    for views in envs.env_method("observations_at", np.arange(16), np.zeros(16, dtype=int), reference.goal_nodes[0]):
        np.testing.assert_array_equal(views["views"], all_views(reference))


def test_scene_file_envs_refuse_the_option(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="visible_closures needs a renderer"):
        CampusNavEnv.from_scene_file(tmp_path / "scene.h5", goals=[0], visible_closures=True)
