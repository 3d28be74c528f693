"""A world whose pictures vary between visits (``view_variation``): K renders per view, built like the fixed views and
drawn per visit with the env's rng; fixed views (``None``) stay exactly what they were."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from campusnav_env import CampusNavEnv, ViewBuild, ViewVariation, evaluate_routes
from campusnav_env.features.feature_cache import cache_path, cached_batched_features, node_batches
from campusnav_env.features.view_source import ViewSource
from campusnav_env.goal_env import CampusNavGoalEnv
from campusnav_env.maps.campus import generate_campus
from campusnav_env.rendering.scene import WORLD_VERSION
from campusnav_env.rendering.street_view import RenderSettings, Shot, StreetViewRenderer
from campusnav_env.rendering.variation import VariedRenderer
from campusnav_env.rendering.world import build_world

SMALL_VIEWS = RenderSettings(width=64, height=48)
K = 3
VARIATION = ViewVariation(renders=K, hours=(8.0, 18.0), yaw_jitter_deg=4.0, seed=7)
GRAPH = generate_campus(16, seed=1)
N_VIEWS = 4


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("variation-cache")


def small_build(cache_dir: Path, **fields: Any) -> ViewBuild:
    return ViewBuild(render_settings=SMALL_VIEWS, cache_dir=cache_dir, progress=False, **fields)


def make_env(cache_dir: Path, **kwargs: Any) -> CampusNavEnv:
    defaults: dict[str, Any] = dict(
        world=GRAPH, goals=[0], encoder="pixels", view_variation=VARIATION, view_build=small_build(cache_dir)
    )
    return CampusNavEnv(**{**defaults, **kwargs})


def source(cache_dir: Path, variation: ViewVariation | None = VARIATION, **kwargs: Any) -> ViewSource:
    return ViewSource(
        GRAPH, "features", "pixels", None, SMALL_VIEWS, 0, cache_dir, False, variation=variation, **kwargs
    )


def view_blocks(env: CampusNavEnv, views: np.ndarray) -> np.ndarray:
    """``(B, 4, D)``: a batch of ``views`` rows cut into its four views."""
    return np.asarray(views).reshape(len(views), N_VIEWS, -1)


def render_of(env: CampusNavEnv, node: int, view: int, block: np.ndarray) -> int:
    """Which of the K renders of ``node``'s view ``view`` a drawn view block is (-1: none)."""
    renders = env._node_renders[node].reshape(K, N_VIEWS, -1)[:, view]
    matches = np.flatnonzero(np.abs(renders - block).max(axis=1) < 1e-6)
    return int(matches[0]) if matches.size == 1 else -1


# --- the renders ---------------------------------------------------------------------------------------------------


def test_the_k_renders_of_every_view_differ_and_each_is_the_same_in_every_build(tmp_path: Path) -> None:
    serial = source(tmp_path / "serial", workers=1).open_renders()
    assert serial.shape[:3] == (GRAPH.n_nodes, K, N_VIEWS)
    for k, other in [(0, 1), (0, 2), (1, 2)]:  # every view's renders differ from each other
        difference = np.abs(serial[:, k] - serial[:, other]).max(axis=-1)
        assert (difference > 1e-3).all(), f"renders {k} and {other} coincide somewhere"
    pool = source(tmp_path / "pool", workers=2).open_renders()  # another build, in worker processes
    np.testing.assert_allclose(pool, serial, rtol=1e-5, atol=1e-5)


def test_render_k_of_a_view_is_drawn_from_seed_node_view_and_k() -> None:
    shot, rng = VARIATION.shot(node=5, view=2, render=1)
    again, rng_again = VARIATION.shot(node=5, view=2, render=1)
    assert shot == again and rng.random() == rng_again.random()
    shots = [VARIATION.shot(node, view, render)[0] for node in range(16) for view in range(4) for render in range(K)]
    hours = np.array([s.time_of_day for s in shots])
    yaws = np.array([s.yaw_offset_deg for s in shots])
    assert ((hours >= 8.0) & (hours <= 18.0)).all() and np.ptp(hours) > 5.0  # spread over the window
    assert (np.abs(yaws) <= 4.0).all() and np.ptp(yaws) > 2.0
    assert all(s.cars for s in shots)
    assert VARIATION.shot(5, 2, 1)[0] != ViewVariation(renders=K, hours=(8.0, 18.0), seed=8).shot(5, 2, 1)[0]
    with pytest.raises(ValueError, match=r"render 3 out of range \[0, 3\)"):
        VARIATION.shot(5, 2, 3)


def test_a_shot_turns_the_camera_and_sets_the_hour_and_cars() -> None:
    renderer = StreetViewRenderer(build_world(GRAPH, seed=0), SMALL_VIEWS)
    plain = renderer.render_view(3, 1).astype(int)
    noon = renderer.render_view(3, 1, shot=Shot(time_of_day=None, cars=False)).astype(int)
    np.testing.assert_array_equal(noon, plain)  # a shot of the settings' own conditions changes nothing
    turned = renderer.render_view(3, 1, shot=Shot(yaw_offset_deg=5.0)).astype(int)
    evening = renderer.render_view(3, 1, rng=np.random.default_rng(0), shot=Shot(time_of_day=19.5)).astype(int)
    assert np.abs(turned - plain).mean() > 1.0 and np.abs(evening - plain).mean() > 5.0
    assert evening.mean() < plain.mean()  # an evening sky is darker than noon's


def test_varied_renderer_entries_are_the_nodes_renders_in_order() -> None:
    varied = VariedRenderer(build_world(GRAPH, seed=0), SMALL_VIEWS, VARIATION)
    np.testing.assert_array_equal(varied.render_node(4 * K + 2), varied.render(4, 2))
    shot, rng = VARIATION.shot(4, 1, 2)
    np.testing.assert_array_equal(varied.render(4, 2)[1], varied.renderer.render_view(4, 1, rng=rng, shot=shot))


def test_a_killed_varied_build_resumes_where_it_stopped(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    entries = GRAPH.n_nodes * K  # 48 renders of four views: six batches of 8
    rendered: list[int] = []
    render_node = VariedRenderer.render_node

    def killed_after_20(self: VariedRenderer, entry: int) -> np.ndarray:
        if len(rendered) == 20:
            raise KeyboardInterrupt  # Ctrl-C in the third batch
        rendered.append(entry)
        return render_node(self, entry)

    def logged(self: VariedRenderer, entry: int) -> np.ndarray:
        rendered.append(entry)
        return render_node(self, entry)

    monkeypatch.setattr(VariedRenderer, "render_node", killed_after_20)
    with pytest.raises(KeyboardInterrupt):
        source(tmp_path / "cache", workers=1).open_renders()
    done = {entry // 8 for entry in rendered[:16]}  # the two batches finished before the interrupt
    rendered.clear()
    monkeypatch.setattr(VariedRenderer, "render_node", logged)
    resumed = source(tmp_path / "cache", workers=1).open_renders()
    assert sorted(rendered) == [e for e in range(entries) if e // 8 not in done]  # only what was left
    assert len(node_batches(entries)) == 6 and done == {0, 1}
    np.testing.assert_allclose(resumed, source(tmp_path / "clean", workers=1).open_renders(), rtol=1e-6, atol=1e-6)


# --- fixed views stay what they were --------------------------------------------------------------------------------


def test_fixed_views_keep_todays_cache_entry_and_draw_nothing_from_the_rng(tmp_path: Path) -> None:
    # Today's entry: keyed by the graph, the world and the render settings, one entry per node
    fixed = source(tmp_path, variation=None)
    todays_parts = {"graph": GRAPH.fingerprint(), "world": f"v{WORLD_VERSION}-seed0", "render": SMALL_VIEWS.key()}
    assert fixed.key_parts == todays_parts
    encoder = fixed.encoder
    marked = np.random.default_rng(0).normal(size=(GRAPH.n_nodes, N_VIEWS, *encoder.output_shape)).astype(np.float32)

    def marked_build(batches: list[range]) -> list[tuple[range, np.ndarray]]:  # today's build, standing in
        return [(nodes, marked[nodes.start : nodes.stop]) for nodes in batches]

    cached_batched_features(todays_parts, GRAPH.n_nodes, encoder, marked_build, cache_dir=tmp_path, progress=False)
    assert cache_path(todays_parts, GRAPH.n_nodes, encoder, cache_dir=tmp_path).exists()
    env = make_env(tmp_path, view_variation=None, view_build=small_build(tmp_path, normalize_features=False))
    assert not env.observations_vary and env._open_renders.shape[1] == 1
    nodes = np.arange(GRAPH.n_nodes)
    state = env.np_random.bit_generator.state
    views = env.observations_at(nodes, np.zeros(GRAPH.n_nodes, dtype=int), 0)["views"]
    np.testing.assert_allclose(views, marked.reshape(GRAPH.n_nodes, -1), atol=1e-6)  # read from today's entry
    assert env.np_random.bit_generator.state == state  # fixed views draw nothing: today's episodes
    assert source(tmp_path).key_parts == {**todays_parts, "variation": VARIATION.key()}  # a varied world's own key


# --- visits ---------------------------------------------------------------------------------------------------------


def test_every_visit_draws_one_render_per_view_with_the_env_rng(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    env.reset(seed=0)
    assert env.observations_vary and env._open_renders.shape == (
        GRAPH.n_nodes,
        K,
        *env.observation_space["views"].shape,
    )
    node, visits = 5, 300
    views = view_blocks(env, env.observations_at(np.full(visits, node), np.zeros(visits, dtype=int), 0)["views"])
    drawn = np.array([[render_of(env, node, view, views[i, view]) for view in range(N_VIEWS)] for i in range(visits)])
    assert (drawn >= 0).all()  # every view is one of its K renders
    for view in range(N_VIEWS):  # each render about a third of the visits
        counts = np.bincount(drawn[:, view], minlength=K)
        assert (np.abs(counts / visits - 1 / K) < 0.1).all(), counts
    assert len({tuple(row) for row in drawn}) > K  # the views are drawn apart, not one render for all four
    # The env's own rng: the same seed draws the same renders
    env.reset(seed=11)
    first = env.observations_at(np.full(20, node), np.zeros(20, dtype=int), 0)["views"]
    env.reset(seed=11)
    np.testing.assert_array_equal(env.observations_at(np.full(20, node), np.zeros(20, dtype=int), 0)["views"], first)


def test_reset_with_a_seed_reproduces_an_episode(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    actions = np.random.default_rng(0).integers(4, size=25)

    def episode(seed: int) -> list[np.ndarray]:
        observation, _ = env.reset(seed=seed)
        seen = [observation["views"]]
        for action in actions:
            observation, *_ = env.step(int(action))
            seen.append(observation["views"])
        return seen

    first, again, other = episode(3), episode(3), episode(4)
    np.testing.assert_array_equal(np.stack(first), np.stack(again))
    assert not np.array_equal(np.stack(first), np.stack(other))


def test_the_standardisation_is_fit_on_every_render(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    every_view = view_blocks(env, env._open_renders.reshape(GRAPH.n_nodes * K, -1))  # all K renders of all views
    every_view = every_view.reshape(-1, every_view.shape[-1])
    np.testing.assert_allclose(every_view.mean(axis=0), 0.0, atol=1e-4)
    np.testing.assert_allclose(every_view.std(axis=0), 1.0, atol=1e-3)


def test_states_of_finds_the_place_in_any_drawn_renders(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    env.reset(seed=0)
    states = np.arange(env.graph.n_states)
    nodes, headings = env.graph.map.state_nodes[states], env.graph.map.state_headings[states]
    observations = env.observations_at(nodes, headings, 0)
    np.testing.assert_array_equal(env.states_of(observations), states)
    mixed = view_blocks(env, observations["views"]).copy()
    mixed[0, 1] = mixed[-1, 1]  # one view from another place
    with pytest.raises(ValueError, match="picture different intersections"):
        env.states_of({**observations, "views": mixed.reshape(len(states), -1)})


@pytest.mark.parametrize("mode", ["features", "image"])
def test_the_env_checkers_pass_with_variation(cache_dir: Path, mode: str) -> None:
    env = gym.make(
        "CampusNav-v0",
        world=GRAPH,
        observation_mode=mode,
        encoder="pixels",
        view_variation=2,
        view_build=small_build(cache_dir) if mode == "features" else ViewBuild(cache_dir=cache_dir, progress=False),
    ).unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        gym_check_env(env)
        sb3_check_env(env, warn=True)


def test_goal_views_are_the_goals_first_render_all_episode(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    observation, info = env.reset(seed=0)
    goal_row = env._open_renders[info["goal_node"], 0]
    for action in range(4):
        np.testing.assert_array_equal(observation["goal_views"], goal_row)
        observation, *_ = env.step(action)
    goal_env = CampusNavGoalEnv(
        world=GRAPH, encoder="pixels", view_variation=VARIATION, view_build=small_build(cache_dir)
    )
    observation, info = goal_env.reset(seed=0, options={"goal": 7})
    np.testing.assert_array_equal(observation["desired_goal"], goal_env._open_renders[7, 0])
    np.testing.assert_array_equal(observation["achieved_goal"], goal_env._open_renders[info["node"], 0])
    assert goal_env.compute_reward(goal_env._open_renders[7, 0], observation["desired_goal"], info) == 1.0


def test_visible_closures_re_render_every_render_of_the_barrier_views(cache_dir: Path) -> None:
    env = make_env(cache_dir, visible_closures=True)
    u, v = next(road for road in env.graph.map.roads if 0 not in road)  # not at the goal
    slot = int(np.flatnonzero(env.graph.map.slots[u] == v)[0])
    before = env._node_renders[u].reshape(K, N_VIEWS, -1).copy()
    env.close_road(u, v, force=True)
    after = env._node_renders[u].reshape(K, N_VIEWS, -1)
    assert (np.abs(after[:, slot] - before[:, slot]).max(axis=1) > 1e-3).all()  # every render shows the barrier
    env.reopen_road(u, v)
    np.testing.assert_array_equal(env._node_renders[u].reshape(K, N_VIEWS, -1), before)


# --- route evaluation -----------------------------------------------------------------------------------------------


def test_route_evaluation_draws_the_views_and_runs_routes_to_the_step_limit(cache_dir: Path) -> None:
    varied, fixed = make_env(cache_dir), make_env(cache_dir, view_variation=None)
    seen: list[dict[str, np.ndarray]] = []

    def turn_back(observations: dict[str, np.ndarray]) -> np.ndarray:  # loops between two intersections
        seen.append(observations)
        return np.full(len(observations["heading"]), 2)

    evaluate_routes(fixed, turn_back, max_steps=12)
    assert len(seen) < 12  # fixed views: a revisit is a loop, stopped at once
    seen.clear()
    report = evaluate_routes(varied, turn_back, max_steps=12)
    assert len(seen) == 12  # varied views: no revisit proves a loop; routes run to the step limit
    assert report.success_rate < 1.0 and all(route.steps == 12 for route in report.routes if not route.success)
    # Back and back again: step 2 sees the (node, heading) of step 0 of every route still running, in other renders
    first, third = (varied.states_of(observations) for observations in (seen[0], seen[2]))
    again = {state: row for state, row in zip(first.tolist(), seen[0]["views"], strict=True)}
    differ = [
        np.abs(again[state] - row).max() > 1e-3 for state, row in zip(third.tolist(), seen[2]["views"], strict=True)
    ]
    assert len(differ) > 10 and np.mean(differ) > 0.5


# --- the settings ---------------------------------------------------------------------------------------------------


def test_view_variation_is_given_as_an_int_a_mapping_or_the_object() -> None:
    assert ViewVariation.of(None) is None
    assert ViewVariation.of(8) == ViewVariation(renders=8)
    assert ViewVariation.of({"renders": 8, "hours": [9, 17]}) == ViewVariation(renders=8, hours=(9.0, 17.0))
    assert ViewVariation.of(VARIATION) is VARIATION
    assert VARIATION.key() != ViewVariation(renders=K, hours=(8.0, 18.0), yaw_jitter_deg=4.0, seed=8).key()


@pytest.mark.parametrize(
    ("value", "error", "match"),
    [
        ({"renders": 0}, ValueError, r"ViewVariation\.renders must be an int >= 1"),
        ({"hours": (17, 9)}, ValueError, r"ViewVariation\.hours must be a window"),
        ({"hours": (9, 25)}, ValueError, r"ViewVariation\.hours must be a window"),
        ({"hours": "noon"}, TypeError, r"ViewVariation\.hours must be a pair of hours"),
        ({"yaw_jitter_deg": 40}, ValueError, r"ViewVariation\.yaw_jitter_deg must be in \[0, 15\]"),
        ({"cars": "yes"}, TypeError, r"ViewVariation\.cars must be True or False"),
        ({"seed": -1}, ValueError, r"ViewVariation\.seed must be an int >= 0"),
        ({"render": 8}, TypeError, r"view_variation: unknown field\(s\) \['render'\]; the fields are \['renders'"),
        (True, TypeError, r"view_variation must be None, an int"),
    ],
)
def test_bad_variation_settings_name_the_field(value: Any, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        ViewVariation.of(value)


def test_render_settings_that_fix_the_hour_or_cars_are_refused_with_a_variation(tmp_path: Path) -> None:
    settings = RenderSettings(64, 48, time_of_day=18.0)
    with pytest.raises(ValueError, match=r"leave render_settings' time_of_day at None and cars at False"):
        ViewSource(GRAPH, "features", "pixels", None, settings, 0, tmp_path, False, variation=VARIATION)


def test_registered_ids_take_the_variation_as_yaml_gives_it(cache_dir: Path) -> None:
    env = gym.make(
        "CampusNavMulti-v0",
        world=GRAPH,
        goals=[0, 5],
        encoder="pixels",
        view_variation={"renders": 2, "hours": [9, 17]},
        view_build={"render_settings": {"width": 64, "height": 48}, "cache_dir": str(cache_dir), "progress": False},
    )
    nav = env.unwrapped
    assert nav.view_variation == ViewVariation(renders=2, hours=(9.0, 17.0)) and nav._open_renders.shape[1] == 2
    assert isinstance(nav, CampusNavEnv) and nav.view_build.render_settings == SMALL_VIEWS
    for env_id in ("CampusNavGoal-v0", "CampusNavCity-v0"):  # the other envs pass it on
        other = gym.make(env_id, world=GRAPH, encoder="pixels", view_variation=2, view_build=small_build(cache_dir))
        assert other.unwrapped.observations_vary and other.unwrapped._open_renders.shape[1] == 2, env_id
