"""The experience graph (transitions over exact observations) and replay search over it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer

from campusnav_env import CampusNavEnv
from campusnav_env.maps.navigation import RoadClosureError
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.route_evaluation import evaluate_routes
from sb3_dcqn import DCQN
from sb3_dcqn.replay import LeanNStepDictReplayBuffer, RevisionDictReplayBuffer
from sb3_dcqn.replay.revision import digest
from sb3_dcqn.replay_graph import UNKNOWN, UNTRIED, ExperienceGraph, ReplaySearchPolicy, observation_digests

GOAL = "Dreese Lab"


@pytest.fixture(scope="module")
def env() -> CampusNavEnv:
    return CampusNavEnv(encoder="pixels", render_settings=RenderSettings(64, 48), goals=GOAL, progress=False)


def explore_fully(env: CampusNavEnv, graph: ExperienceGraph, order: np.random.Generator | None = None) -> None:
    """Feed ``graph`` every (state, action) of the env's current roads, as the env would answer it."""
    table = env.graph.transition_table
    states = np.repeat(np.arange(table.shape[0]), table.shape[1])
    actions = np.tile(np.arange(table.shape[1]), table.shape[0])
    if order is not None:
        pick = order.permutation(states.size)
        states, actions = states[pick], actions[pick]
    _, goal_node = env.resolve_goal(GOAL)
    goal_state_nodes = env.graph.map.state_nodes
    keep = goal_state_nodes[states] != goal_node  # the episode ends at the goal: nobody acts there
    states, actions = states[keep], actions[keep]
    next_states, blocked = env.graph.move(states, actions)
    arrived = goal_state_nodes[next_states] == goal_node
    rewards = np.where(arrived, env.goal_reward, np.where(blocked, env.collision_penalty, env.step_penalty))
    nodes, headings = env.graph.map.state_nodes, env.graph.map.state_headings
    graph.add_batch(
        env.observations_at(nodes[states], headings[states], GOAL),
        actions,
        env.observations_at(nodes[next_states], headings[next_states], GOAL),
        rewards,
        arrived,
    )


def all_observations(env: CampusNavEnv) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The observation at every state not at the goal, and the hops from its node to the goal."""
    _, goal_node = env.resolve_goal(GOAL)
    nodes, headings = env.graph.map.state_nodes, env.graph.map.state_headings
    away = nodes != goal_node
    return env.observations_at(nodes[away], headings[away], GOAL), env.node_distances(goal_node)[nodes[away]]


def closable_road_on_a_route(env: CampusNavEnv, distances: np.ndarray) -> tuple[int, int]:
    """A road between nodes at different distances from the goal whose closure cuts nobody off (probed, undone)."""
    for u, v in sorted(env.graph.map.roads):
        if distances[u] != distances[v]:
            try:
                env.close_road(u, v)
            except RoadClosureError:
                continue
            env.reopen_road(u, v)
            return u, v
    raise AssertionError("no road to close")


def box(value: float) -> np.ndarray:
    return np.array([value], dtype=np.float32)


# ---------------------------------------------------------------------------------------------------------- digests
def test_a_dict_observation_digest_is_the_buffer_digest_of_its_keys_in_sorted_order() -> None:
    observation = {"b": np.array([[1.0, 2.0]], np.float32), "a": np.array([[3.0]], np.float32)}
    expected = digest(observation["a"][0].tobytes() + observation["b"][0].tobytes())
    assert observation_digests(observation) == [expected]


def test_digests_cast_to_the_observation_space_dtype() -> None:
    space = spaces.Box(0.0, 1.0, (2,), np.float32)
    assert observation_digests(np.array([[0.5, 1.0]], np.float64), space) == observation_digests(
        np.array([[0.5, 1.0]], np.float32)
    )


# ------------------------------------------------------------------------------------------------------ the graph
def test_a_new_outcome_replaces_the_old_one_and_a_collision_removes_the_edge() -> None:
    graph = ExperienceGraph(n_actions=2)
    assert graph.add(box(0), 0, box(1), -0.005, False)
    assert graph.add(box(1), 1, box(2), 1.0, True)  # state 2: the goal
    start = graph.state_of(box(0))
    assert graph.distance_of(box(0)) == 2 and graph.route_action(box(0)) == 0
    assert not graph.add(box(0), 0, box(1), -0.005, False)  # the same outcome again changes nothing

    assert graph.add(box(0), 0, box(0), -0.01, False)  # the road closed: a collision
    assert graph.next_state[start, 0] == start
    assert graph.distance_of(box(0)) == UNKNOWN and graph.route_action(box(0)) == -1
    assert graph.distance_of(box(1)) == 1

    graph.add(box(0), 0, box(1), -0.005, False)  # and reopened
    assert graph.distance_of(box(0)) == 2


def test_a_failed_termination_is_no_route() -> None:
    graph = ExperienceGraph(n_actions=2)
    graph.add(box(0), 0, box(9), -1.0, True)  # terminated, but not rewarded: a failure
    assert graph.distance_of(box(0)) == UNKNOWN
    graph.add(box(0), 1, box(8), 1.0, True)
    assert graph.distance_of(box(0)) == 1 and graph.route_action(box(0)) == 1


def test_unseen_observations_have_no_state_and_no_route() -> None:
    graph = ExperienceGraph(n_actions=4)
    assert graph.state_of(box(5)) == -1 and graph.distance_of(box(5)) == UNKNOWN
    assert graph.route_actions(np.array([-1, -1])).tolist() == [-1, -1]


def test_the_nearest_untried_action_is_reached_over_known_edges() -> None:
    graph = ExperienceGraph(n_actions=2)
    # A chain 0 -> 1 -> 2 with action 0; action 1 tried (a collision) at 0 and 1; nothing tried at 2 yet
    graph.add(box(0), 0, box(1), -0.005, False)
    graph.add(box(1), 0, box(2), -0.005, False)
    graph.add(box(0), 1, box(0), -0.01, False)
    graph.add(box(1), 1, box(1), -0.01, False)
    zero, two = graph.state_of(box(0)), graph.state_of(box(2))
    assert graph.path_to_untried(zero) == [0, 0, 0]  # drive twice, then try action 0 at state 2
    assert graph.explore_actions(np.array([zero, two])).tolist() == [0, 0]
    assert graph.frontier().tolist() == [two]
    graph.add(box(2), 0, box(2), -0.01, False)
    assert graph.path_to_untried(zero) == [0, 0, 1]
    graph.add(box(2), 1, box(2), -0.01, False)
    assert graph.path_to_untried(zero) is None and graph.frontier().size == 0
    assert graph.explore_actions(np.array([zero])).tolist() == [-1]
    assert graph.untried_actions(two).size == 0 and graph.n_tried == 6


def reference_hops(successors: np.ndarray, success: np.ndarray) -> np.ndarray:
    """Hops to a success by a plain breadth-first search back from the success pairs (collisions: self-loops)."""
    n = successors.shape[0]
    before: list[list[int]] = [[] for _ in range(n)]
    for state, following in zip(*np.nonzero(~success), strict=True):
        target = int(successors[state, following])
        if target != state:
            before[target].append(int(state))
    hops = np.full(n, UNKNOWN)
    queue = [int(s) for s in np.flatnonzero(success.any(axis=1))]
    hops[queue] = 1
    for state in queue:  # grows as it goes: breadth first
        for earlier in before[state]:
            if hops[earlier] == UNKNOWN:
                hops[earlier] = hops[state] + 1
                queue.append(earlier)
    return hops


@pytest.mark.parametrize("one_by_one", [True, False])
def test_distances_match_a_plain_search_on_a_random_graph(one_by_one: bool) -> None:
    rng = np.random.default_rng(1)
    n = 300
    successors = rng.integers(0, n, size=(n, 3))
    successors = np.where(rng.random((n, 3)) < 0.3, np.arange(n)[:, None], successors)  # collisions
    success = rng.random((n, 3)) < 0.01
    graph = ExperienceGraph(n_actions=3)
    graph.states_of(np.arange(n, dtype=np.float32)[:, None], add=True)  # state i: observation i
    pairs = rng.permutation(n * 3)
    states, actions = pairs // 3, pairs % 3
    after = np.where(success, -1, successors)[states, actions].astype(np.float32)  # successes lead to observation -1
    rewards = np.where(success[states, actions], 1.0, -0.005)
    if one_by_one:
        for state, action, following, reward in zip(states, actions, after, rewards, strict=True):
            graph.add(box(state), int(action), box(following), float(reward), bool(reward > 0))
    else:
        graph.add_batch(states.astype(np.float32)[:, None], actions, after[:, None], rewards, rewards > 0)
    expected = reference_hops(successors, success)
    np.testing.assert_array_equal(graph.distances()[:n], expected)
    # A route's first action leads to a state one hop closer, or is the success itself
    routed = np.flatnonzero(expected != UNKNOWN)
    first = graph.route_actions(routed)
    closer = expected[successors[routed, first]] == expected[routed] - 1
    assert (closer | success[routed, first]).all()


def test_shortest_stored_routes_are_the_maps_shortest_paths(env: CampusNavEnv) -> None:
    graph = ExperienceGraph.for_env(env)
    explore_fully(env, graph, np.random.default_rng(0))  # in random order: distances kept up to date edge by edge
    observations, hops = all_observations(env)
    states = graph.states_of(observations)
    assert (states >= 0).all()
    np.testing.assert_array_equal(graph.distances()[states], hops)
    # Each route's first action leads one hop closer
    _, goal_node = env.resolve_goal(GOAL)
    actions = graph.route_actions(states)
    next_states, blocked = env.graph.move(env.states_of(observations), actions)
    assert not blocked.any()
    np.testing.assert_array_equal(env.node_distances(goal_node)[env.graph.map.state_nodes[next_states]], hops - 1)


def test_routes_follow_a_closure_once_it_is_seen(env: CampusNavEnv) -> None:
    graph = ExperienceGraph.for_env(env)
    explore_fully(env, graph)
    _, goal_node = env.resolve_goal(GOAL)
    before = env.node_distances(goal_node)
    road = closable_road_on_a_route(env, before)
    env.close_road(*road)
    try:
        explore_fully(env, graph)  # the closed road's moves are now collisions: those edges are replaced
        observations, hops = all_observations(env)
        assert (hops != before[env.graph.map.state_nodes[env.states_of(observations)]]).any()
        np.testing.assert_array_equal(graph.distances()[graph.states_of(observations)], hops)
    finally:
        env.reopen_road(*road)


# -------------------------------------------------------------------------------------------- from a replay buffer
@pytest.mark.parametrize("buffer_class", [DictReplayBuffer, RevisionDictReplayBuffer, LeanNStepDictReplayBuffer])
def test_the_graph_reads_a_replay_buffer_filled_by_dcqn(env: CampusNavEnv, buffer_class: type) -> None:
    model = DCQN(
        "MultiInputPolicy",
        env,
        buffer_size=150,  # 400 steps wrap it: the oldest are overwritten, the rest read oldest first
        learning_starts=10_000,  # collect only
        replay_buffer_class=buffer_class,
        policy_kwargs={"net_arch": [16]},
        seed=0,
    )
    model.learn(400)
    buffer = model.replay_buffer
    assert buffer.full
    graph = ExperienceGraph.for_env(env)
    graph.add_replay_buffer(buffer)
    stored = {key: array[:, 0] for key, array in buffer.observations.items()}
    stored_next = {key: array[:, 0] for key, array in buffer.next_observations.items()}
    states, next_states = env.states_of(stored), env.states_of(stored_next)
    actions = buffer.actions[:, 0].reshape(-1).astype(np.int64)
    pairs = set(zip(states.tolist(), actions.tolist(), strict=True))
    assert graph.n_tried == len(pairs)
    # Every stored transition is an edge of the graph
    graph_states, graph_next = graph.states_of(stored), graph.states_of(stored_next)
    for state, action, following in zip(graph_states, actions, graph_next, strict=True):
        assert graph.next_state[state, action] == following
    # The graph's states are the world's (one per world state seen), and every edge it holds is the world's own move
    world_of = dict(zip(graph_states.tolist(), states.tolist(), strict=True))
    world_of |= dict(zip(graph_next.tolist(), next_states.tolist(), strict=True))
    assert len(world_of) == len(set(states.tolist()) | set(next_states.tolist())) == len(set(world_of.values()))
    tried_states, tried_actions = np.nonzero(graph.next_state >= 0)
    assert len(tried_states) == graph.n_tried
    world_moves, _ = env.graph.move(np.array([world_of[s] for s in tried_states.tolist()]), tried_actions)
    edges = graph.next_state[tried_states, tried_actions].tolist()
    np.testing.assert_array_equal(world_moves, [world_of[s] for s in edges])


def test_refresh_reads_what_was_added_since_and_agrees_with_a_full_read(env: CampusNavEnv) -> None:
    model = DCQN("MultiInputPolicy", env, buffer_size=500, learning_starts=10_000, policy_kwargs={"net_arch": [16]})
    model.learn(100)
    search = ReplaySearchPolicy(model)
    assert search.graph.n_tried > 0
    model.learn(150, reset_num_timesteps=False)
    assert search.refresh() > 0
    full = ExperienceGraph.for_env(env)
    full.add_replay_buffer(model.replay_buffer)
    assert search.graph.n_tried == full.n_tried
    assert search.graph.n_states == full.n_states


def test_an_optimize_memory_buffer_cannot_be_read() -> None:
    class Lean:
        optimize_memory_usage = True

    with pytest.raises(ValueError, match="optimize_memory_usage"):
        ExperienceGraph(4).add_replay_buffer(Lean())


# ----------------------------------------------------------------------------------------------- replay search
def test_replay_search_drives_shortest_routes_on_a_fully_explored_map(env: CampusNavEnv) -> None:
    model = DCQN("MultiInputPolicy", env, learning_starts=10_000, policy_kwargs={"net_arch": [16]}, seed=0)
    graph = ExperienceGraph.for_env(env)
    explore_fully(env, graph)
    search = ReplaySearchPolicy(model, graph)
    report = evaluate_routes(env, search)
    assert report.success_rate == 1.0
    assert report.spl == pytest.approx(1.0)


def test_replay_search_falls_back_to_the_models_greedy_action(env: CampusNavEnv) -> None:
    model = DCQN("MultiInputPolicy", env, learning_starts=10_000, policy_kwargs={"net_arch": [16]}, seed=0)
    search = ReplaySearchPolicy(model, ExperienceGraph.for_env(env))  # knows nothing
    observations, _ = all_observations(env)
    greedy, _ = model.predict(observations, deterministic=True)
    np.testing.assert_array_equal(search(observations), greedy)
    single = {key: value[0] for key, value in observations.items()}
    action, _ = search.predict(single)
    assert np.ndim(action) == 0 and action == greedy[0]


def test_untried_marks_are_minus_one() -> None:
    graph = ExperienceGraph(3, capacity=1)
    graph.add(box(0), 2, box(1), 0.0, False)  # grows past its capacity
    assert graph.next_state[graph.state_of(box(0))].tolist() == [UNTRIED, UNTRIED, graph.state_of(box(1))]


def test_dcqn_replay_search_plans_greedy_actions_over_its_own_buffer_and_explores_as_before(
    env: CampusNavEnv, tmp_path: Path
) -> None:
    # No gradient step: the critics know nothing, so whatever routes well comes from the stored transitions
    kwargs = dict(learning_starts=100_000, buffer_size=20_000, policy_kwargs={"net_arch": [16]}, seed=0)
    model = DCQN("MultiInputPolicy", env, replay_search=True, exploration_fraction=1.0, **kwargs)
    model.learn(6_000)
    graph = ExperienceGraph.for_env(env)
    graph.add_replay_buffer(model.replay_buffer)
    observations, _ = all_observations(env)
    known = graph.route_actions(graph.states_of(observations)) >= 0
    assert known.mean() > 0.5
    actions, _ = model.predict(observations, deterministic=True)
    np.testing.assert_array_equal(actions[known], graph.route_actions(graph.states_of(observations))[known])
    greedy, _ = model.policy.predict(observations, deterministic=True)
    np.testing.assert_array_equal(actions[~known], greedy[~known])  # the critics' choice where nothing is stored
    searched = evaluate_routes(env, lambda batch: model.predict(batch, deterministic=True)[0])
    critics = evaluate_routes(env, lambda batch: model.policy.predict(batch, deterministic=True)[0])
    assert searched.success_rate > critics.success_rate + 0.3
    # Exploration does not plan: the same seed collects the same transitions with and without the option
    plain = DCQN("MultiInputPolicy", env, exploration_fraction=1.0, **kwargs)
    plain.learn(6_000)
    np.testing.assert_array_equal(plain.replay_buffer.actions[:6_000], model.replay_buffer.actions[:6_000])
    # A model saved and loaded without its buffer acts on its critics; with the buffer loaded, it plans again
    model.save(tmp_path / "model.zip")
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    loaded = DCQN.load(tmp_path / "model.zip", env=env)
    np.testing.assert_array_equal(loaded.predict(observations, deterministic=True)[0][~known], greedy[~known])
    assert loaded.replay_search
    loaded.load_replay_buffer(tmp_path / "buffer.pkl")
    np.testing.assert_array_equal(loaded.predict(observations, deterministic=True)[0], actions)
