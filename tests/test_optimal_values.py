"""Q* by value iteration: exact on a hand-made map, and its greedy policy drives shortest routes on the campus."""

from __future__ import annotations

import numpy as np
import pytest

from campusnav_env.maps.campus import default_campus
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.optimal_values import optimal_q_values


@pytest.fixture()
def line() -> NavigationGraph:
    """Three intersections in a row, one state each: action 0 drives on, action 1 hits a wall."""
    transitions = np.array([[1, -1], [2, -1], [-1, -1]])
    graph = RoadGraph.from_transitions(transitions, [0, 1, 2], [0, 0, 0], [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    return NavigationGraph(graph)


def test_q_star_of_a_hand_made_map_matches_the_bellman_equation_by_hand(line: NavigationGraph) -> None:
    q = optimal_q_values(line, goal=2, gamma=0.9, goal_reward=1.0, step_penalty=-0.005, collision_penalty=-0.01)
    # Next to the goal: driving on arrives (1.0, episode over); the wall costs 0.01 and the agent stays
    assert q[1, 0] == pytest.approx(1.0)
    assert q[1, 1] == pytest.approx(-0.01 + 0.9 * 1.0)
    # Two moves away: a step, then the value next to the goal
    assert q[0, 0] == pytest.approx(-0.005 + 0.9 * 1.0)
    assert q[0, 1] == pytest.approx(-0.01 + 0.9 * (-0.005 + 0.9 * 1.0))
    np.testing.assert_array_equal(q[2], [0.0, 0.0])  # the goal is terminal


def test_the_greedy_policy_of_q_star_takes_a_shortest_route_from_every_state_even_after_a_closure() -> None:
    graph = NavigationGraph(default_campus())
    goal = graph.map.landmarks["Dreese Lab"]
    graph.close_road(69, 81, protect=[goal])
    q = optimal_q_values(graph, goal, gamma=0.95)
    hops = graph.state_hops_to(goal)
    states = np.flatnonzero(hops > 0)
    next_states, blocked = graph.move(states, q[states].argmax(axis=1))
    assert not blocked.any()
    # Every greedy move brings the agent one action closer: the greedy routes are shortest routes
    np.testing.assert_array_equal(hops[next_states], hops[states] - 1)
    # And Q* of the best action follows from the route length k: k - 1 discounted step penalties, then the goal
    farthest = states[np.argmax(hops[states])]
    steps = int(hops[farthest]) - 1
    expected = sum(0.95**i * -0.005 for i in range(steps)) + 0.95**steps * 1.0
    assert q[farthest].max() == pytest.approx(expected)


def test_bad_discounts_and_goals_are_refused(line: NavigationGraph) -> None:
    with pytest.raises(ValueError, match="gamma must be in"):
        optimal_q_values(line, goal=2, gamma=1.0)
    with pytest.raises(ValueError, match="goal"):
        optimal_q_values(line, goal=7, gamma=0.9)
