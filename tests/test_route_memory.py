"""The route memory: one graph of places for every goal, moves in compass slots, and DCQN acting with it."""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.envs import BitFlippingEnv

from campusnav_env import CampusNavEnv
from campusnav_env.goal_env import CampusNavGoalEnv
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.route_evaluation import evaluate_routes
from sb3_dcqn import DCQN
from sb3_dcqn.place_frame import PlaceFrame, place_frame_of
from sb3_dcqn.place_recognition import AlignedNearestPlace
from sb3_dcqn.replay import DCQNHerReplayBuffer
from sb3_dcqn.replay.revision import RevisionReplay
from sb3_dcqn.route_memory import (
    BLOCKED,
    DEAD_END,
    DRIVEN,
    INFERRED,
    NO_ROUTE,
    OUTSIDE,
    UNTRIED,
    RouteMemory,
    UntriedExplorer,
)

pytestmark = pytest.mark.usefixtures("shared_feature_cache")

SMALL = {"encoder": "pixels", "render_settings": RenderSettings(64, 48), "progress": False}


def transitions(env: CampusNavEnv, goal: int, states: np.ndarray, actions: np.ndarray) -> tuple[Any, ...]:
    """The batch of transitions ``(states[i], actions[i])`` as the env answers them, under ``goal``."""
    nodes, headings = env.graph.map.state_nodes, env.graph.map.state_headings
    next_states, blocked = env.graph.move(states, actions)
    arrived = nodes[next_states] == goal
    rewards = np.where(arrived, env.goal_reward, np.where(blocked, env.collision_penalty, env.step_penalty))
    return (
        env.observations_at(nodes[states], headings[states], goal),
        actions,
        env.observations_at(nodes[next_states], headings[next_states], goal),
        rewards,
        arrived,
    )


def explore_fully(env: CampusNavEnv, memory: RouteMemory, goal: int, through_goal: bool = False) -> None:
    """Feed ``memory`` every (state, action) of the env's open roads under ``goal`` (``through_goal``: the moves from
    the goal's own states too, as episodes for other goals drive them)."""
    n_states, n_actions = env.graph.transition_table.shape
    states = np.repeat(np.arange(n_states), n_actions)
    actions = np.tile(np.arange(n_actions), n_states)
    keep = (env.graph.map.state_nodes[states] != goal) | through_goal  # the episode ends at the goal
    memory.add_batch(*transitions(env, goal, states[keep], actions[keep]))


def once_per_slot(env: CampusNavEnv, goal: int) -> tuple[np.ndarray, np.ndarray, int]:
    """Each road driven in one direction only and each empty slot bumped once: one try per (intersection, slot) that
    is not the way back of a driven road. Returns the states, the actions and the number of roads driven."""
    state_of, slots = env.graph.map.state_of, env.graph.map.slots
    states, actions, driven = [], [], set()
    for node in range(env.graph.n_nodes):
        if node == goal:
            continue
        heading = int(np.flatnonzero(state_of[node] >= 0)[0])
        for slot in range(4):
            far = int(slots[node, slot])
            if far >= 0 and (far, node) in driven:
                continue  # the way back of a road driven from the other end
            states.append(int(state_of[node, heading]))
            actions.append((slot - heading) % 4)
            if far >= 0:
                driven.add((node, far))
    return np.array(states), np.array(actions), len(driven)


def every_start(env: CampusNavEnv, goal: int) -> tuple[np.ndarray, np.ndarray]:
    nodes, headings = env.graph.map.state_nodes, env.graph.map.state_headings
    away = np.flatnonzero((nodes != goal) & (env.node_distances(goal)[nodes] > 0))
    return nodes[away], headings[away]


def route_lengths(env: CampusNavEnv, memory: RouteMemory, goal: int) -> tuple[np.ndarray, np.ndarray]:
    """The memory's route length from every (start, heading) away from ``goal``, and the env's hop distance."""
    nodes, headings = every_start(env, goal)
    lengths = [
        len(memory.route_from(env.observation_at(node, heading, goal)))
        for node, heading in zip(nodes, headings, strict=True)
    ]
    return np.array(lengths, dtype=np.int64), env.node_distances(goal)[nodes]


def drive(
    env: CampusNavEnv, memory: RouteMemory, goal: int, policy: Any, episodes: int, seed: int, until: Any = None
) -> int:
    """Episodes of ``policy(observation) -> action`` under ``goal``, every transition remembered, until ``until()``
    holds; returns the steps."""
    steps = 0
    for episode in range(episodes):
        if until is not None and until():
            break
        observation, _ = env.reset(seed=seed + episode, options={"goal": goal})
        for _ in range(env.max_steps):
            action = int(policy(observation))
            following, reward, terminated, truncated, info = env.step(action)
            memory.add(observation, action, following, reward, terminated, info.get("is_success"))
            observation, steps = following, steps + 1
            if terminated or truncated:
                break
    return steps


@pytest.fixture(scope="module")
def goal_env() -> CampusNavGoalEnv:
    return CampusNavGoalEnv(**SMALL)


@pytest.fixture(scope="module")
def plain_env() -> CampusNavEnv:
    return CampusNavEnv(goals=["Dreese Lab", "Cinema"], **SMALL)


# ----------------------------------------------------------------------------------------------- the env's frame
def test_campusnav_declares_its_frame_and_it_is_read_through_wrappers_and_vec_envs(plain_env: CampusNavEnv) -> None:
    frame = place_frame_of(plain_env)
    assert frame == PlaceFrame(
        place_keys=("views",),
        n_slots=4,
        frame_key="heading",
        reverse_action=2,
        views_per_place=4,
        goal_pictures={"goal_views": "views"},
    )
    vec_env = make_vec_env(lambda: plain_env, n_envs=1)  # Monitor inside a DummyVecEnv
    assert place_frame_of(vec_env) == frame
    assert place_frame_of(gym.wrappers.TimeLimit(plain_env, 50)) == frame
    assert place_frame_of(gym.make("FrozenLake-v1")) is None  # no declaration: pose states, as before


def test_the_goal_env_declares_its_agents_own_views_as_the_place_never_the_achieved_goal(goal_env) -> None:
    frame = place_frame_of(goal_env)
    assert frame.place_keys == ("observation",) and dict(frame.goal_pictures) == {"desired_goal": "observation"}
    assert not frame.goals_pictured_otherwise


def test_a_declaration_that_does_not_fit_the_spaces_is_named() -> None:
    space = spaces.Dict({"views": spaces.Box(0, 1, (8,)), "heading": spaces.Box(0, 1, (4,))})
    with pytest.raises(ValueError, match="place_keys"):
        PlaceFrame.from_declaration({"place_keys": ["view"]}, space, spaces.Discrete(4))
    with pytest.raises(ValueError, match="one-hot over the 3 actions"):
        PlaceFrame.from_declaration({"place_keys": ["views"], "frame_key": "heading"}, space, spaces.Discrete(3))
    with pytest.raises(ValueError, match="views_per_place 3"):
        PlaceFrame.from_declaration({"place_keys": ["views"], "views_per_place": 3}, space, spaces.Discrete(4))
    with pytest.raises(ValueError, match="unknown entries"):
        PlaceFrame.from_declaration({"place_keys": ["views"], "frames": "heading"}, space, spaces.Discrete(4))


# ------------------------------------------------------------------------------------------ places, not poses
def test_a_place_is_one_state_at_every_heading_and_for_every_goal(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env)
    node = int(np.flatnonzero(goal_env.graph.map.degrees >= 3)[0])
    poses = [goal_env.observation_at(node, heading, goal) for heading in goal_env.headings_at(node) for goal in (1, 2)]
    assert len(poses) >= 6 and {memory.state_of(obs, add=True) for obs in poses} == {0}
    posed = RouteMemory.for_env(goal_env, place_frame=None)  # the memory before places: a state per heading
    assert len({posed.state_of(obs, add=True) for obs in poses}) == len(goal_env.headings_at(node))


def test_one_try_per_road_and_per_empty_slot_routes_every_start_at_every_heading(plain_env: CampusNavEnv) -> None:
    _, goal = plain_env.resolve_goal("Dreese Lab")
    states, actions, roads = once_per_slot(plain_env, goal)
    memory = RouteMemory.for_env(plain_env)
    memory.add_batch(*transitions(plain_env, goal, states, actions))
    # One try per (intersection, slot) but the way back of each road: every road's reverse is inferred
    assert memory.n_tried == states.size and roads == plain_env.graph.map.n_roads
    assert (memory.outcome[: memory.n_states] == INFERRED).sum() == roads
    lengths, hops = route_lengths(plain_env, memory, goal)
    np.testing.assert_array_equal(lengths, hops)
    nodes, headings = every_start(plain_env, goal)
    observations = plain_env.observations_at(nodes, headings, goal)
    assert (memory.route_actions(observations) >= 0).all()  # no unseen start state, whatever its heading
    # The same tries as poses route only from the heading each was tried at
    posed = RouteMemory.for_env(plain_env, place_frame=None)
    posed.add_batch(*transitions(plain_env, goal, states, actions))
    assert (posed.route_actions(observations) < 0).mean() > 0.5


def test_an_inferred_way_back_routes_but_is_not_untried(plain_env: CampusNavEnv) -> None:
    _, goal = plain_env.resolve_goal("Dreese Lab")
    memory = RouteMemory.for_env(plain_env)
    start = int(plain_env.graph.map.state_of[0, plain_env.headings_at(0)[0]])
    memory.add_batch(*transitions(plain_env, goal, np.array([start]), np.array([0])))
    far = int(plain_env.graph.map.state_nodes[plain_env.graph.move(start, 0)[0]])
    here, there = (
        memory.state_of(plain_env.observation_at(0, 0, goal)),
        memory.state_of(plain_env.observation_at(far, plain_env.headings_at(far)[0], goal)),
    )
    assert memory.outcome[here].tolist().count(DRIVEN) == 1 and memory.n_tried == 1
    back = int(np.flatnonzero(memory.outcome[there] == INFERRED)[0])
    assert memory.target[there, back] == here and back not in memory.untried_slots(there)


def test_one_bump_closes_a_road_at_every_heading_both_ways_for_every_goal(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env)
    explore_fully(goal_env, memory, goal=3, through_goal=True)
    graph = goal_env.graph
    u, v = next((u, v) for u, v in graph.map.roads if goal_env.node_distances(60)[u] > 2)
    slot = int(np.flatnonzero(graph.map.slots[u] == v)[0])
    heading = goal_env.headings_at(u)[0]
    seen = goal_env.observation_at(u, heading, 3)
    memory.add(seen, (slot - heading) % 4, seen, goal_env.collision_penalty, False)  # one bump, under goal 3
    graph.close_road(u, v, force=True)
    try:
        for goal in (60, 77):  # goals never asked for: the road is gone from their routes too, from both ends
            lengths, hops = route_lengths(goal_env, memory, goal)
            reachable = hops > 0
            np.testing.assert_array_equal(lengths[reachable], hops[reachable])
    finally:
        graph.reopen_road(u, v)
    there = memory.state_of(goal_env.observation_at(v, goal_env.headings_at(v)[0], 3))
    back = int(np.flatnonzero(graph.map.slots[v] == u)[0])
    assert memory.outcome[memory.state_of(seen), slot] == BLOCKED and memory.outcome[there, back] == BLOCKED


def test_a_reopened_road_is_retried_in_training_once_it_has_aged_and_never_in_evaluation(plain_env) -> None:
    _, goal = plain_env.resolve_goal("Dreese Lab")
    memory = RouteMemory.for_env(plain_env, retry_after=50)
    explore_fully(plain_env, memory, goal)
    nodes, headings = every_start(plain_env, goal)
    start = int(np.flatnonzero(plain_env.node_distances(goal)[nodes] >= 3)[0])
    observation = plain_env.observation_at(nodes[start], headings[start], goal)
    action = int(memory.route_actions(_batch(observation))[0])
    memory.add(observation, action, observation, plain_env.collision_penalty, False)  # closed: a bump
    detour = memory.route_actions(_batch(observation))[0]
    assert detour != action and memory.route_actions(_batch(observation), retry=True)[0] == detour  # too recent
    memory.clock += 50  # transitions elsewhere: the closure is a fact that has aged
    assert memory.route_actions(_batch(observation), retry=True)[0] == action  # training tries the road again
    assert memory.route_actions(_batch(observation))[0] == detour  # evaluation never drives a road seen closed
    next_state, _ = plain_env.graph.move(int(plain_env.graph.map.state_of[nodes[start], headings[start]]), action)
    arrived = plain_env.observation_at(
        int(plain_env.graph.map.state_nodes[next_state]), int(plain_env.graph.map.state_headings[next_state]), goal
    )
    memory.add(observation, action, arrived, plain_env.step_penalty, False)  # it is open again
    assert memory.route_actions(_batch(observation))[0] == action


def test_a_barrier_in_the_views_leaves_a_place_the_place_it_was() -> None:
    env = CampusNavEnv(visible_closures=True, **SMALL)
    memory = RouteMemory.for_env(env)
    u, v = env.graph.map.roads[0]
    open_views = [env.observation_at(u, heading, env.goal_nodes[0]) for heading in env.headings_at(u)]
    states = {memory.state_of(obs, add=True) for obs in open_views}
    env.close_road(u, v, force=True)
    closed_view = env.observation_at(u, env.headings_at(u)[0], env.goal_nodes[0])
    assert not np.array_equal(closed_view["views"], open_views[0]["views"])  # the barrier is in the picture
    assert {memory.state_of(closed_view, add=True)} == states and memory.n_states == 1


def test_training_tries_an_aged_closure_when_passing_by_it_whatever_the_goal(plain_env: CampusNavEnv) -> None:
    _, dreese = plain_env.resolve_goal("Dreese Lab")
    memory = RouteMemory.for_env(plain_env, retry_after=50)
    explore_fully(plain_env, memory, dreese)
    u, v = next(road for road in plain_env.graph.map.roads if dreese not in road)
    slot = int(np.flatnonzero(plain_env.graph.map.slots[u] == v)[0])
    heading = plain_env.headings_at(u)[0]
    here = plain_env.observation_at(u, heading, dreese)
    memory.add(here, (slot - heading) % 4, here, plain_env.collision_penalty, False)
    memory.clock += 50
    aged = memory.route_actions(_batch(here), retry=True)[0]
    assert aged == (slot - heading) % 4  # the closed road next to it, although the route to Dreese Lab is elsewhere
    assert memory.route_actions(_batch(here))[0] != aged  # evaluation never drives it


class AliasedLine(gym.Env):
    """A line of places 0-1-2-3 where places 1 and 3 picture the same: one slot leads to two places."""

    metadata = {"place_frame": {"place_keys": ["view"]}}

    def __init__(self) -> None:
        self.observation_space = spaces.Dict({"view": spaces.Box(0, 9, (1,)), "goal": spaces.Box(0, 9, (1,))})
        self.action_space = spaces.Discrete(2)  # 0: forward, 1: back (absolute: no frame)

    def picture(self, place: int, goal: int = 0) -> dict[str, np.ndarray]:
        return {"view": np.array([{3: 1}.get(place, place)], dtype=np.float32), "goal": np.array([goal], np.float32)}


def test_two_places_that_picture_the_same_are_counted_and_never_routed_from() -> None:
    env = AliasedLine()
    memory = RouteMemory.for_env(env)
    memory.add(env.picture(1), 1, env.picture(0), 1.0, True)  # place 0 is the goal, reached from 1
    for place, action, following in ((0, 0, 1), (1, 0, 2), (2, 1, 1)):
        memory.add(env.picture(place), action, env.picture(following), 0.0, False)
    assert memory.n_states == 3 and memory.aliased == set()
    assert memory.route_from(env.picture(2)) == [1, 1]  # back, back
    memory.add(env.picture(2), 0, env.picture(3), 0.0, False)  # forward from 2 shows "place 1" again...
    memory.add(env.picture(3), 1, env.picture(2), 0.0, False)  # ...whose back led to 0, and now leads to 2
    assert memory.aliased == set()  # one odd outcome could be a glitch: the latest wins
    memory.add(env.picture(1), 1, env.picture(0), 0.0, False)  # back to 0 again...
    memory.add(env.picture(3), 1, env.picture(2), 0.0, False)  # ...and to 2 again: two places, one picture
    assert memory.aliased == {memory.state_of(env.picture(1))}
    assert memory.route_from(env.picture(2)) == []  # no route goes through a place that is two places


# ---------------------------------------------------------------------------------------------------- goals
def test_a_goal_never_asked_for_is_routed_to_by_its_pictures_over_the_same_graph(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env)
    explore_fully(goal_env, memory, goal=3, through_goal=True)  # every transition seen under goal 3 only
    for other in (40, 77):  # never a goal of any transition: its pictures show a remembered place
        lengths, hops = route_lengths(goal_env, memory, other)
        np.testing.assert_array_equal(lengths, hops)


def test_the_memory_never_reads_the_achieved_goal_where_a_frame_is_declared(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env)
    explore_fully(goal_env, memory, goal=3, through_goal=True)
    observation = goal_env.observation_at(0, goal_env.headings_at(0)[0], 50)
    withheld = {**observation, "achieved_goal": np.zeros_like(observation["achieved_goal"])}
    assert memory.route_from(withheld) == memory.route_from(observation) != []


def test_goal_views_show_their_place_before_any_success_and_goals_match_within_the_tolerance(plain_env) -> None:
    _, cinema = plain_env.resolve_goal("Cinema")
    _, dreese = plain_env.resolve_goal("Dreese Lab")
    memory = RouteMemory.for_env(plain_env)
    explore_fully(plain_env, memory, dreese)  # Cinema was driven through, never reached as a goal
    lengths, hops = route_lengths(plain_env, memory, cinema)
    np.testing.assert_array_equal(lengths, hops)
    posed = RouteMemory.for_env(plain_env, place_frame=None)  # poses: goals only by the successes that reached them
    explore_fully(plain_env, posed, dreese)
    observation = plain_env.observation_at(0, plain_env.headings_at(0)[0], dreese)
    nudged = {**observation, "goal_views": observation["goal_views"] + np.float32(5e-5)}
    assert posed.route_from(plain_env.observation_at(0, plain_env.headings_at(0)[0], cinema)) == []
    assert posed.route_from(nudged) == posed.route_from(observation) != []  # the env's tolerance, 1e-4
    assert posed.route_from({**observation, "goal_views": observation["goal_views"] + np.float32(1e-3)}) == []


def test_a_success_the_env_reports_attaches_a_goal_whatever_its_reward() -> None:
    memory = RouteMemory(n_actions=2)
    a, b = np.array([0.0]), np.array([1.0])
    memory.add(a, 1, b, 0.0, True, success=True)  # BitFlipping-style: reward 0 at the goal, -1 elsewhere
    assert memory.outcome[0, 1] == DRIVEN and memory.route_from(a) == [1]
    memory.add(b, 0, a, 0.0, True, success=False)  # an end that is no success: a dead end
    assert memory.outcome[1, 0] == DEAD_END


# ------------------------------------------------------------------------------------------------ bounds
def test_a_full_memory_does_not_send_the_explorer_back_to_the_same_move_forever() -> None:
    memory = RouteMemory(n_actions=1, max_states=2)
    line = [np.array([float(i)]) for i in range(4)]
    memory.add(line[0], 0, line[1], 0.0, False)
    memory.add(line[1], 0, line[2], 0.0, False)  # state 2 would be the third: past the cap
    assert memory.n_states == 2 and memory.outcome[1, 0] == OUTSIDE
    assert memory.path_to_untried(0) is None and UntriedExplorer(memory).actions(np.stack(line[:2]))[1] == -1


def test_the_memory_grows_past_its_first_thousand_states_and_keeps_them() -> None:
    memory = RouteMemory(n_actions=1)
    line = np.arange(3_000, dtype=np.float64)[:, None]
    memory.add_batch(line[:-1], np.zeros(2_999, dtype=np.int64), line[1:], np.zeros(2_999), np.zeros(2_999, bool))
    assert memory.n_states == 3_000 and len(memory.route_from(line[0])) == 0  # no goal: no route
    assert (memory.target[: memory.n_states - 1, 0] == np.arange(1, 3_000)).all()
    copy = pickle.loads(pickle.dumps(memory))
    assert copy.n_states == 3_000 and (copy.target[:2_999, 0] == memory.target[:2_999, 0]).all()


def test_the_route_cache_is_bounded_in_bytes(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env, max_cache_bytes=4096)
    explore_fully(goal_env, memory, goal=3, through_goal=True)
    for goal in range(goal_env.graph.n_nodes):
        memory.route_actions(goal_env.observations_at(np.array([0]), np.array([goal_env.headings_at(0)[0]]), goal))
    assert 0 < memory.cache_nbytes() <= 4096 and memory.nbytes() > 0


# ---------------------------------------------------------------------------------------------- exploration
def test_the_explorer_returns_to_the_nearest_untried_slot_and_envs_seek_different_ones() -> None:
    memory = RouteMemory(n_actions=2)
    line = [np.array([float(i)]) for i in range(4)]
    for i in range(3):
        memory.add(line[i], 0, line[i + 1], 0.0, False)
        memory.add(line[i], 1, line[i], 0.0, False)  # every action of 0..2 tried
    memory.add(line[3], 1, line[3], 0.0, False)  # 3 has only action 0 untried
    assert memory.path_to_untried(0) == [0, 0, 0, 0]
    assert memory.explore_actions(np.stack(line))[0] == 0
    explorer = UntriedExplorer(memory, n_envs=2)
    np.testing.assert_array_equal(explorer.actions(np.stack([line[0], line[3]])), [0, 0])
    assert explorer.actions(np.array([[9.0], [1.0]]))[0] == -1  # unseen: the memory has nothing
    memory.add(line[3], 0, np.array([4.0]), 0.0, False)  # two untried pairs now: 4's actions
    both = UntriedExplorer(memory, n_envs=2)
    both.actions(np.stack([line[3], line[3]]))
    assert both._targets[0] != both._targets[1]  # two envs at one state do not chase one pair


def test_exploring_with_the_memory_covers_the_campus_in_about_one_try_per_slot(plain_env: CampusNavEnv) -> None:
    _, goal = plain_env.resolve_goal("Dreese Lab")
    memory = RouteMemory.for_env(plain_env)
    explorer = UntriedExplorer(memory)
    rng = np.random.default_rng(0)

    def explore(observation: dict[str, np.ndarray]) -> int:
        action = int(explorer.actions(_batch(observation))[0])
        return action if action >= 0 else int(rng.integers(4))

    steps = drive(
        plain_env,
        memory,
        goal,
        explore,
        episodes=200,
        seed=0,
        until=lambda: memory.n_states > 0 and memory.frontier().size == 0,
    )
    nodes = plain_env.graph.n_nodes
    assert memory.frontier().size == 0 and memory.n_states == nodes
    # Depth-first exploration of an unknown graph drives each road at most twice and bumps each empty slot once
    roads = plain_env.graph.map.n_roads
    assert steps <= 2 * roads + (4 * nodes - 2 * roads)


# --------------------------------------------------------------------------------------------- FrozenLake, saving
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
    assert (memory.outcome[: memory.n_states] == DEAD_END).any()
    routes = memory.route_actions(np.arange(64))
    for state in range(64):
        if env.unwrapped.desc.flat[state] in b"GH" or routes[state] < 0:
            continue
        assert int(memory.target[memory.state_of(np.int64(state)), routes[state]]) not in holes


def test_the_memory_pickles_and_answers_the_same(goal_env: CampusNavGoalEnv) -> None:
    memory = RouteMemory.for_env(goal_env)
    explore_fully(goal_env, memory, goal=3, through_goal=True)
    copy = pickle.loads(pickle.dumps(memory))
    batch = goal_env.observations_at(np.arange(20), np.array([goal_env.headings_at(n)[0] for n in range(20)]), 50)
    np.testing.assert_array_equal(copy.route_actions(batch), memory.route_actions(batch))
    assert copy.n_states == memory.n_states and copy.nbytes() == memory.nbytes()
    assert (memory.route_actions(batch) != NO_ROUTE).all()
    copy.add_batch(*transitions(goal_env, 3, np.array([0]), np.array([1])))  # and it grows on


def test_a_memory_saved_as_one_pose_table_before_places_loads_as_poses() -> None:
    a, b, c = (np.array([float(i)]) for i in range(3))
    saved = {  # what RouteMemory.__getstate__ wrote before places (next_state: -1 untried, -2 dead end, s: collision)
        "n_actions": 2, "observation_space": None, "goal_keys": (), "success_reward": 0.0, "max_states": 100,
        "place_matcher": None, "next_state": np.array([[1, 0], [2, -1], [-2, -2]], dtype=np.int32),
        "_state_of": {digest: i for i, digest in enumerate(RouteMemory(2)._digests(np.stack([a, b, c])))},
        "_reached": {b"": {2}}, "_place_of": {}, "_place_vectors": [], "_place_states": [],
    }  # fmt: skip
    memory = RouteMemory.__new__(RouteMemory)
    memory.__setstate__(saved)
    assert memory.place_frame is None and memory.n_states == 3
    assert memory.outcome[:3].tolist() == [[DRIVEN, BLOCKED], [DRIVEN, UNTRIED], [DEAD_END, DEAD_END]]
    assert memory.route_from(a) == [0, 0]  # to the goal reached at c, over the remembered moves


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
    with pytest.raises(ValueError, match="unknown settings \\['max_state'\\]"):
        DCQN("MlpPolicy", "CartPole-v1", route_memory={"max_state": 3})


# --------------------------------------------------------------------------------------------------- DCQN with it
def test_dcqn_with_route_memory_reaches_frozen_lakes_goal_and_keeps_dqns_predict_otherwise(tmp_path: Path) -> None:
    env = gym.make("FrozenLake-v1", is_slippery=False, map_name="8x8")
    model = DCQN("MlpPolicy", env, route_memory=True, learning_starts=100, exploration_fraction=1.0, seed=0)
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
    np.testing.assert_array_equal(
        loaded.predict(batch, deterministic=True)[0], model.predict(batch, deterministic=True)[0]
    )
    plain = DCQN("MlpPolicy", env, learning_starts=10, seed=0)
    plain.learn(200)
    assert plain.memory is None
    np.testing.assert_array_equal(
        plain.predict(batch, deterministic=True)[0], plain.policy.predict(batch, deterministic=True)[0]
    )


def test_dcqn_passes_the_memorys_settings_and_reads_the_envs_frame(plain_env: CampusNavEnv) -> None:
    model = DCQN(
        "MultiInputPolicy",
        plain_env,
        route_memory={"explore": False, "success_reward": -0.5, "max_states": 77, "retry_after": 9},
        learning_starts=10,
    )
    memory = model.memory
    assert (memory.success_reward, memory.max_states, memory.retry_after) == (-0.5, 77, 9)
    assert memory.place_frame == place_frame_of(plain_env) and not model.explores_untried
    assert model.policy.q_net.heading_key == "heading"  # the critics score compass slots, from the same declaration
    opted_out = DCQN("MultiInputPolicy", plain_env, policy_kwargs={"heading_key": None})
    assert opted_out.policy.q_net.heading_key is None


def test_dcqn_matches_goals_pictured_otherwise_and_its_hindsight_buffer_revises() -> None:
    night = CampusNavGoalEnv(goal_render_settings=RenderSettings(64, 48, time_of_day=19.5), **SMALL)
    assert place_frame_of(night).goals_pictured_otherwise
    model = DCQN("MultiInputPolicy", night, route_memory=True, replay_buffer_class=HerReplayBuffer, learning_starts=250)
    assert isinstance(model.memory.place_matcher, AlignedNearestPlace)
    # A closure the memory learns stops the stale transitions through it voting in the critics' replay too
    assert isinstance(model.replay_buffer, RevisionReplay) and isinstance(model.replay_buffer, DCQNHerReplayBuffer)
    model.learn(300)
    assert len(model.memory.goal_pictures()) > 0  # the goal photos shown: the matcher's sample of their conditions
    day = DCQN("MultiInputPolicy", CampusNavEnv(**SMALL), route_memory=True, learning_starts=10)
    assert day.memory.place_matcher is None  # goals pictured as the views are: exact matches


def test_dcqn_route_memory_on_bit_flipping_reaches_visited_goals_in_hamming_steps() -> None:
    env = BitFlippingEnv(n_bits=4, continuous=False, max_steps=4)
    model = DCQN("MultiInputPolicy", env, route_memory=True, learning_starts=200, seed=0)
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


def test_route_memory_on_campusnav_routes_every_start_and_heading_of_the_places_it_saw(plain_env) -> None:
    model = DCQN("MultiInputPolicy", plain_env, route_memory=True, learning_starts=100, seed=0)
    model.learn(600)
    with_memory = evaluate_routes(plain_env, lambda obs: model.predict(obs, deterministic=True)[0], max_steps=40)
    critics = evaluate_routes(plain_env, lambda obs: model.policy.predict(obs, deterministic=True)[0], max_steps=40)
    assert with_memory.success_rate > critics.success_rate
    # Every heading of a place the memory routed from at one heading is routed too: no unseen start states
    routed = {(route.goal, route.start) for route in with_memory.routes if route.success}
    failed_at_a_routed_place = [
        route for route in with_memory.routes if (route.goal, route.start) in routed and not route.success
    ]
    assert routed and failed_at_a_routed_place == []


def _batch(observation: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return {key: np.asarray(value)[None] for key, value in observation.items()}
