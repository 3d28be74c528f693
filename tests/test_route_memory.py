"""The route memory: one graph of remembered transitions for every goal, and DCQN acting with it."""

from __future__ import annotations

import pickle
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.envs import BitFlippingEnv

from campusnav_env import CampusNavEnv
from campusnav_env.goal_env import CampusNavGoalEnv
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.route_evaluation import evaluate_routes
from sb3_dcqn import DCQN
from sb3_dcqn.route_memory import DEAD_END, NO_ROUTE, UNTRIED, RouteMemory, UntriedExplorer

pytestmark = pytest.mark.usefixtures("module_feature_cache")

SMALL = {"encoder": "pixels", "render_settings": RenderSettings(64, 48), "progress": False}


def explore_fully(env: CampusNavEnv, memory: RouteMemory, goal: int, through_goal: bool = False) -> None:
    """Feed ``memory`` every (state, action) of the env's open roads under ``goal``, as the env would answer
    (``through_goal``: the moves from the goal's own states too, as episodes for other goals drive them)."""
    table = env.graph.transition_table
    states = np.repeat(np.arange(table.shape[0]), table.shape[1])
    actions = np.tile(np.arange(table.shape[1]), table.shape[0])
    nodes, headings = env.graph.map.state_nodes, env.graph.map.state_headings
    keep = (nodes[states] != goal) | through_goal  # the episode ends at the goal: nobody acts there
    states, actions = states[keep], actions[keep]
    next_states, blocked = env.graph.move(states, actions)
    arrived = nodes[next_states] == goal
    rewards = np.where(arrived, env.goal_reward, np.where(blocked, env.collision_penalty, env.step_penalty))
    memory.add_batch(
        env.observations_at(nodes[states], headings[states], goal),
        actions,
        env.observations_at(nodes[next_states], headings[next_states], goal),
        rewards,
        arrived,
    )


def route_lengths(env: CampusNavEnv, memory: RouteMemory, goal: int) -> tuple[np.ndarray, np.ndarray]:
    """The memory's route length from every state away from ``goal``, and the env's hop distance."""
    nodes, headings = env.graph.map.state_nodes, env.graph.map.state_headings
    away = np.flatnonzero(nodes != goal)
    lengths = np.array(
        [len(memory.route_from(env.observation_at(nodes[s], headings[s], goal))) for s in away], dtype=np.int64
    )
    return lengths, env.node_distances(goal)[nodes[away]]


@pytest.fixture(scope="module")
def goal_env() -> CampusNavGoalEnv:
    return CampusNavGoalEnv(**SMALL)


@pytest.fixture(scope="module")
def plain_env() -> CampusNavEnv:
    return CampusNavEnv(goals=["Dreese Lab", "Cinema"], **SMALL)


# ------------------------------------------------------------------------------------------- one graph, every goal
def test_the_state_leaves_the_goal_keys_out(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env)
    assert memory.goal_keys == ("achieved_goal", "desired_goal")
    same_place = [goal_env.observation_at(5, 0, goal) for goal in (1, 2, 3)]
    assert len({memory.state_of(obs, add=True) for obs in same_place}) == 1


def test_a_goal_never_asked_for_is_routed_to_by_its_pictures_over_the_same_graph(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env)
    explore_fully(goal_env, memory, goal=3, through_goal=True)  # every transition seen under goal 3 only
    for other in (40, 77):  # never a goal of any transition: reached through achieved_goal
        lengths, hops = route_lengths(goal_env, memory, other)
        np.testing.assert_array_equal(lengths, hops)


def test_without_achieved_goal_goals_attach_by_their_successful_transitions(plain_env: CampusNavEnv) -> None:
    memory = RouteMemory.for_env(plain_env)
    assert memory.goal_keys == ("goal_views",)
    _, dreese = plain_env.resolve_goal("Dreese Lab")
    _, cinema = plain_env.resolve_goal("Cinema")
    explore_fully(plain_env, memory, dreese)
    lengths, hops = route_lengths(plain_env, memory, dreese)
    np.testing.assert_array_equal(lengths, hops)
    # Cinema was never reached under its own goal views: the memory knows no route there yet
    assert memory.route_from(plain_env.observation_at(0, 0, cinema)) == []


def test_a_collision_under_one_goal_removes_the_road_from_every_goals_routes(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env)
    explore_fully(goal_env, memory, goal=3, through_goal=True)
    nodes, headings = goal_env.graph.map.state_nodes, goal_env.graph.map.state_headings
    start = int(np.flatnonzero(goal_env.node_distances(60) >= 3)[0])
    observation = goal_env.observation_at(start, 0, 60)
    first = memory.route_from(observation)
    state, action = memory.state_of(observation), first[0]
    # The agent, driving to goal 3, bumps into the road the route to 60 starts with
    seen = goal_env.observation_at(start, 0, 3)
    memory.add(seen, action, seen, goal_env.collision_penalty, False)
    assert memory.next_state[state, action] == state
    assert memory.route_from(observation)[:1] != [action]
    assert memory.suspected >= 0 and nodes.size == headings.size


def test_a_reopened_road_is_learned_by_driving_it(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env)
    obs, there = goal_env.observation_at(0, 0, 9), goal_env.observation_at(1, 0, 9)
    memory.add(obs, 1, there, -0.005, False)
    memory.add(obs, 1, obs, -0.01, False)
    state = memory.state_of(obs)
    assert memory.next_state[state, 1] == state
    memory.add(obs, 1, there, -0.005, False)
    assert memory.next_state[state, 1] == memory.state_of(there)


def test_a_collision_makes_the_other_moves_into_the_same_state_untried_again() -> None:
    memory = RouteMemory(n_actions=2)
    a, b, c = np.array([0.0]), np.array([1.0]), np.array([2.0])
    memory.add(a, 0, c, 0.0, False)
    memory.add(b, 1, c, 0.0, False)
    memory.add(a, 0, a, 0.0, False)  # the road into c is closed
    assert memory.next_state[memory.state_of(b), 1] == UNTRIED and memory.suspected == 1


# -------------------------------------------------------------------------------------------------- exploration
def test_explore_actions_and_the_explorer_lead_to_the_nearest_untried_action() -> None:
    memory = RouteMemory(n_actions=2)
    line = [np.array([float(i)]) for i in range(4)]
    for i in range(3):
        memory.add(line[i], 0, line[i + 1], 0.0, False)
        memory.add(line[i], 1, line[i], 0.0, False)  # every action of 0..2 tried
    assert memory.path_to_untried(memory.state_of(line[0])) == [0, 0, 0, 0]
    assert memory.explore_actions(memory.states_of(np.stack(line)))[0] == 0
    explorer = UntriedExplorer(memory, n_envs=2)
    np.testing.assert_array_equal(explorer.actions(np.stack([line[0], line[3]])), [0, 0])
    assert explorer.actions(np.array([[9.0], [1.0]]))[0] == -1  # unseen: the memory has nothing


def test_frozen_lake_holes_are_dead_ends_and_routes_are_shortest() -> None:
    env = gym.make("FrozenLake-v1", is_slippery=False, map_name="8x8")
    memory = RouteMemory.for_env(env)
    table = env.unwrapped.P
    for state, moves in table.items():
        for action, [(_, following, reward, done)] in moves.items():
            if env.unwrapped.desc.flat[state] in b"GH":
                continue
            memory.add(np.int64(state), action, np.int64(following), reward, done)
    holes = set(memory.states_of(np.array([s for s in range(64) if env.unwrapped.desc.flat[s] == b"H"])).tolist())
    assert len(memory.route_from(np.int64(0))) == 14
    assert (memory.next_state[: memory.n_states] == DEAD_END).any()
    routes = memory.route_actions(np.arange(64))
    for state in range(64):
        if env.unwrapped.desc.flat[state] in b"GH" or routes[state] < 0:
            continue
        assert int(memory.next_state[memory.state_of(np.int64(state)), routes[state]]) not in holes


# --------------------------------------------------------------------------------------------------- saving, errors
def test_the_memory_pickles_and_answers_the_same(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env)
    explore_fully(goal_env, memory, goal=3, through_goal=True)
    copy = pickle.loads(pickle.dumps(memory))
    batch = goal_env.observations_at(np.arange(20), np.zeros(20, dtype=np.int64), 50)
    np.testing.assert_array_equal(copy.route_actions(batch), memory.route_actions(batch))
    assert copy.n_states == memory.n_states and copy.nbytes() == memory.nbytes()
    assert (memory.route_actions(batch) != NO_ROUTE).all()


def test_bad_arguments_name_what_is_wrong() -> None:
    space = spaces.Dict({"views": spaces.Box(0, 1, (2,)), "goal": spaces.Box(0, 1, (2,))})
    with pytest.raises(ValueError, match="not keys of the observation space"):
        RouteMemory(4, space, goal_keys=["target"])
    with pytest.raises(ValueError, match="leave nothing"):
        RouteMemory(4, space, goal_keys=["views", "goal"])
    with pytest.raises(ValueError, match="need a Dict observation space"):
        RouteMemory(4, spaces.Box(0, 1, (2,)), goal_keys=["goal"])
    with pytest.raises(ValueError, match="out of range"):
        RouteMemory(2).add(np.array([0.0]), 5, np.array([1.0]), 0.0, False)


# --------------------------------------------------------------------------------------------------- DCQN with it
def test_dcqn_with_route_memory_reaches_frozen_lakes_goal_and_keeps_dqns_predict_otherwise(tmp_path: Path) -> None:
    env = gym.make("FrozenLake-v1", is_slippery=False, map_name="8x8")
    model = DCQN(
        "MlpPolicy", env, route_memory=True, explore_untried=True, learning_starts=100, exploration_fraction=1.0, seed=0
    )
    model.learn(3_000)
    observation, _ = env.reset(seed=0)
    for _ in range(30):
        action, _ = model.predict(observation, deterministic=True)
        observation, reward, terminated, truncated, _ = env.step(int(action))
        if terminated or truncated:
            break
    assert reward == 1.0
    batch = np.arange(64)
    np.testing.assert_array_equal(model.predict(batch, deterministic=True)[0][batch < 60][:1], [1])
    model.save(tmp_path / "lake.zip")
    loaded = DCQN.load(tmp_path / "lake.zip")  # no replay buffer: the memory is in the model's file
    np.testing.assert_array_equal(loaded.predict(batch, deterministic=True)[0], model.predict(batch, True)[0])
    plain = DCQN("MlpPolicy", env, explore_untried=True, learning_starts=10, seed=0)
    plain.learn(200)
    np.testing.assert_array_equal(
        plain.predict(batch, deterministic=True)[0], plain.policy.predict(batch, deterministic=True)[0]
    )


def test_dcqn_route_memory_on_bit_flipping_reaches_visited_goals_in_hamming_steps() -> None:
    env = BitFlippingEnv(n_bits=4, continuous=False, max_steps=4)
    model = DCQN("MultiInputPolicy", env, route_memory=True, explore_untried=True, learning_starts=200, seed=0)
    model.learn(1_500)
    reached = asked = 0
    for episode in range(12):
        observation, _ = env.reset(seed=episode)
        distance = int(np.abs(observation["observation"] - observation["desired_goal"]).sum())
        asked += distance > 0  # a goal drawn equal to the start ends the episode at any step
        for step in range(1, 5):
            action, _ = model.predict(observation, deterministic=True)
            observation, _, terminated, _, _ = env.step(action)
            if terminated:
                reached += distance > 0 and step == distance
                break
    assert asked >= 8 and reached == asked


def test_route_memory_on_campusnav_is_evaluated_beside_its_critics(plain_env: CampusNavEnv) -> None:
    model = DCQN("MultiInputPolicy", plain_env, route_memory=True, explore_untried=True, learning_starts=100, seed=0)
    model.learn(600)
    with_memory = evaluate_routes(plain_env, lambda obs: model.predict(obs, deterministic=True)[0], max_steps=40)
    critics = evaluate_routes(plain_env, lambda obs: model.policy.predict(obs, deterministic=True)[0], max_steps=40)
    assert with_memory.success_rate > critics.success_rate
