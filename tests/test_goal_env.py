"""CampusNavGoal: any intersection as the goal, SB3's goal-env convention, held-out goals, goals pictured otherwise."""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

from campusnav_env import GOALS, evaluate_routes
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.goal_env import CampusNavGoalEnv, held_out_split
from campusnav_env.rendering.street_view import RenderSettings

SMALL_VIEWS = RenderSettings(width=64, height=48)


@pytest.fixture(scope="module")
def cache_dir(shared_cache_dir: Path) -> Path:
    """The session's feature cache (conftest.py): the campus's views are built once, not once per module."""
    return shared_cache_dir


def small_views(cache_dir: Path) -> ViewBuild:
    return ViewBuild(render_settings=SMALL_VIEWS, cache_dir=cache_dir, progress=False)


def make_env(cache_dir: Path, **kwargs) -> CampusNavGoalEnv:
    defaults = dict(encoder="pixels", view_build=small_views(cache_dir), view_dim=16)
    return CampusNavGoalEnv(**{**defaults, **kwargs})


def test_registered_id_makes_every_intersection_a_goal(cache_dir: Path) -> None:
    env = gym.make("CampusNavGoal-v0", encoder="pixels", view_build=small_views(cache_dir))
    goal_env = env.unwrapped
    assert isinstance(goal_env, CampusNavGoalEnv)
    assert goal_env.goal_nodes == list(range(101)) == goal_env.training_goals
    assert set(GOALS) <= set(goal_env.goal_names)  # landmarks keep their names, other intersections are "node k"
    assert sum(name.startswith("node ") for name in goal_env.goal_names) == 101 - len(goal_env.graph.landmarks)


def test_passes_gymnasium_and_sb3_env_checkers(cache_dir: Path) -> None:
    env = make_env(cache_dir, held_out_goals=[3, 4])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # SB3 says it detected a goal env; gymnasium that there is no spec
        gym_check_env(env)
        sb3_check_env(env, warn=True)


def test_observation_follows_the_goal_env_convention(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    obs, info = env.reset(seed=0)
    assert set(obs) == {"observation", "achieved_goal", "desired_goal", "heading"}
    assert obs["achieved_goal"].shape == obs["desired_goal"].shape == obs["observation"].shape == (64,)
    np.testing.assert_allclose(obs["desired_goal"], env.goal_vector(info["goal_node"]))
    np.testing.assert_allclose(obs["achieved_goal"], env.goal_vector(info["node"]))
    # Without other goal render settings the achieved goal is what the agent sees
    np.testing.assert_allclose(obs["achieved_goal"], obs["observation"])
    # At the goal, the achieved goal is the desired one
    path = env.graph.shortest_path(info["node"], info["goal_node"])
    at_goal = env.observation_at(path[-1], env.headings_at(path[-1])[0], info["goal_node"])
    np.testing.assert_allclose(at_goal["achieved_goal"], at_goal["desired_goal"])


def _walk_with_a_collision_to_the_goal(env: CampusNavGoalEnv, seed: int) -> tuple[list, list, list, dict]:
    """
    From ``env.reset(seed=seed)``: bump into a missing road once, then take a shortest route to the goal.

    :return: ``(rewards, achieved goals, infos, last observation)`` of every step
    """
    obs, info = env.reset(seed=seed)
    table = env.graph.transition_table
    hops = env.graph.state_hops_to(info["goal_node"])
    rewards, achieved, infos = [], [], []
    blocked = np.flatnonzero(table[env.graph.map.state_of[info["node"], env.heading]] < 0)
    terminated = truncated = False
    while not (terminated or truncated):
        state = env.graph.map.state_of[env.node, env.heading]
        if not infos and len(blocked):  # first step: the missing road
            action = int(blocked[0])
        else:  # then any action whose next state is one hop closer
            action = int(np.flatnonzero((table[state] >= 0) & (hops[table[state]] == hops[state] - 1))[0])
        obs, reward, terminated, truncated, info = env.step(action)
        assert reward == env.compute_reward(obs["achieved_goal"], obs["desired_goal"], info)
        rewards.append(reward)
        achieved.append(obs["achieved_goal"])
        infos.append(info)
    assert terminated and not truncated and info["node"] == info["goal_node"]
    return rewards, achieved, infos, obs


def test_compute_reward_is_what_step_returns_collisions_and_the_goal_included(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    # a start with a missing road in front and the goal some steps away
    rewards, achieved, infos, obs = _walk_with_a_collision_to_the_goal(env, seed=1)
    assert rewards[0] == env.collision_penalty and rewards[-1] == env.goal_reward
    assert env.step_penalty in rewards[1:-1]
    desired = np.repeat(obs["desired_goal"][None], len(achieved), 0)
    batch = env.compute_reward(np.array(achieved), desired, infos)
    np.testing.assert_array_equal(batch, rewards)
    # A dict of arrays is accepted too (what DCQN's HER buffer keeps)
    flags = {"collision": np.array([i["collision"] for i in infos])}
    np.testing.assert_array_equal(env.compute_reward(np.array(achieved), desired, flags), rewards)
    # The goal reward wins over a collision flag: a relabelled goal reached by the step is reached
    np.testing.assert_array_equal(
        env.compute_reward(np.array(achieved), desired, {"collision": np.ones(len(achieved), dtype=bool)}),
        [env.collision_penalty] * (len(achieved) - 1) + [env.goal_reward],
    )


def test_compute_reward_without_the_collision_flag_says_what_is_missing(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    obs, _ = env.reset(seed=0)
    with pytest.raises(KeyError, match="copy_info_dict=True"):
        env.compute_reward(obs["achieved_goal"][None], obs["desired_goal"][None], [{}])


def test_compute_terminated_is_true_exactly_at_the_goal(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    goals = np.stack([env.goal_vector(node) for node in range(env.graph.n_nodes)])
    reached = env.compute_terminated(goals[:, None, :], goals[None, :, :], {})
    np.testing.assert_array_equal(reached, np.eye(env.graph.n_nodes, dtype=bool))
    np.testing.assert_array_equal(env.goal_nodes_of(goals), np.arange(env.graph.n_nodes))


def test_held_out_goals_are_never_drawn_but_can_be_asked_for(cache_dir: Path) -> None:
    training, held_out = held_out_split(101, 0.2, seed=0)
    assert len(held_out) == 20 and not set(training) & set(held_out)
    env = make_env(cache_dir, goals=training, held_out_goals=held_out)
    drawn = set()
    for seed in range(300):
        _, info = env.reset(seed=seed)
        drawn.add(info["goal_node"])
    assert drawn <= set(training) and len(drawn) > 60
    _, info = env.reset(options={"goal": held_out[0]})
    assert info["goal_node"] == held_out[0]
    allowed = env.relabelling_allowed(np.stack([env.goal_vector(node) for node in range(101)]))
    np.testing.assert_array_equal(~allowed, np.isin(np.arange(101), held_out))


def test_default_goals_are_every_intersection_not_held_out(cache_dir: Path) -> None:
    env = make_env(cache_dir, held_out_goals=["Dreese Lab", 5])
    assert env.goal_nodes[env.goal_names.index("Dreese Lab")] in env.held_out_goals
    assert 5 in env.held_out_goals and 5 not in env.training_goals and len(env.training_goals) == 99


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        (dict(goals=[1, 2], held_out_goals=[2]), ValueError, r"share intersections \[2\]"),
        (dict(held_out_goals=list(range(101))), ValueError, "no goal left"),
        (dict(held_out_goals=["Nowhere"]), KeyError, "Nowhere"),
        (dict(observation_mode="image"), ValueError, "features"),
    ],
)
def test_bad_goal_arguments_are_refused_with_the_reason(cache_dir: Path, kwargs: dict, error: type, match: str) -> None:
    with pytest.raises(error, match=match):
        make_env(cache_dir, **kwargs)


def test_goals_pictured_otherwise_still_equal_the_achieved_goal_at_the_goal(cache_dir: Path) -> None:
    dusk = RenderSettings(width=64, height=48, time_of_day=19.5)
    env = make_env(cache_dir, goal_render_settings=dusk)
    obs, info = env.reset(seed=0)
    assert not np.allclose(obs["achieved_goal"], obs["observation"], atol=1e-3)  # the goal's camera differs
    goal = info["goal_node"]
    at_goal = env.observation_at(goal, env.headings_at(goal)[0], goal)
    np.testing.assert_allclose(at_goal["achieved_goal"], at_goal["desired_goal"])
    assert env.observation_space.contains(obs)


def test_evaluate_routes_takes_any_intersection_by_id_or_name(cache_dir: Path) -> None:
    env = make_env(cache_dir)
    graph = env.graph

    def oracle(observations: dict[str, np.ndarray]) -> np.ndarray:
        states = env.states_of(observations)
        goals = env.goal_nodes_of(observations["desired_goal"])
        hops = np.stack([graph.state_hops_to(int(goal)) for goal in goals])  # (batch, n_states)
        nexts = graph.transition_table[states]  # (batch, 4)
        cost = np.where(nexts >= 0, hops[np.arange(states.size)[:, None], np.maximum(nexts, 0)], 10**6)
        return cost.argmin(axis=1)

    report = evaluate_routes(env, oracle, goals=[17, "Cinema"])
    assert {route.goal for route in report.routes} == {env.resolve_goal(17)[0], "Cinema"}
    assert report.success_rate == 1.0 and report.spl == pytest.approx(1.0)


def test_goals_pictured_in_several_conditions_draw_one_per_episode(cache_dir: Path) -> None:
    evening = RenderSettings(width=64, height=48, time_of_day=17.0)
    env = make_env(cache_dir, goal_render_settings=[None, evening])
    conditions = set()
    for seed in range(20):
        obs, info = env.reset(seed=seed)
        conditions.add(env._condition)
        goal = info["goal_node"]
        at_goal = env.observation_at(goal, env.headings_at(goal)[0], goal)  # in the episode's condition
        np.testing.assert_allclose(at_goal["achieved_goal"], at_goal["desired_goal"])
        assert env.goal_nodes_of(obs["desired_goal"]) == goal
    assert conditions == {0, 1}
    noon, _ = env.reset(seed=0, options={"goal_condition": 0, "goal": 5})
    dusk, _ = env.reset(seed=0, options={"goal_condition": 1, "goal": 5})
    assert not np.allclose(noon["desired_goal"], dusk["desired_goal"], atol=1e-3)
    np.testing.assert_allclose(noon["achieved_goal"], noon["observation"])  # condition None: the agent's own views
    with pytest.raises(ValueError, match="goal_condition 2 out of range"):
        env.reset(options={"goal_condition": 2})
