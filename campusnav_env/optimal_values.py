"""The exact optimal action values Q* of a CampusNav map, by value iteration.

CampusNav is a known, deterministic MDP once the map is given: the states are the (intersection, heading) pairs of
the :class:`~campusnav_env.maps.navigation.NavigationGraph` (closures included), the move rule is
:meth:`~campusnav_env.maps.navigation.NavigationGraph.move`, and the rewards are the env's: ``goal_reward`` for the move
that arrives at the goal (which ends the episode), ``collision_penalty`` for a blocked move (the agent stays),
``step_penalty`` for every other move. Q* of the discounted, infinite-horizon problem is the fixed point of

    Q(s, a) = r(s, a) + gamma * (1 - arrived(s, a)) * max_a' Q(s', a'),

which value iteration reaches to any tolerance (the Bellman operator is a gamma-contraction). The env's step limit
(truncation) is not part of Q*: SB3's buffers bootstrap through timeouts as well, so this is the quantity the
critics estimate, and what the over-estimation of a learned Q is measured against. States at the goal are terminal:
their values are 0.
"""

from __future__ import annotations

import numpy as np

from campusnav_env.maps.navigation import NavigationGraph

__all__ = ["optimal_q_values"]


def optimal_q_values(
    graph: NavigationGraph,
    goal: int,
    gamma: float,
    goal_reward: float = 1.0,
    step_penalty: float = -0.005,
    collision_penalty: float = -0.01,
    tolerance: float = 1e-10,
    max_iterations: int = 100_000,
) -> np.ndarray:
    """
    Q* of every (state, action) of the map for one goal, by value iteration.

    :param graph: The map with its current closures
    :param goal: The goal node
    :param gamma: Discount factor, in [0, 1)
    :param goal_reward: Reward of the move that arrives at the goal
    :param step_penalty: Reward of any other move
    :param collision_penalty: Reward of a blocked move (the agent stays where it is)
    :param tolerance: Stop when no value changes by more than this
    :param max_iterations: Give up (with an error) after this many sweeps
    :return: ``(S, A)`` float64 array indexed like ``graph.transition_table``; rows of states at the goal are 0
    :raises ValueError: on a discount outside [0, 1) or a goal out of range
    :raises RuntimeError: if the values have not converged within ``max_iterations`` sweeps
    """
    if not 0.0 <= gamma < 1.0:
        raise ValueError(f"gamma must be in [0, 1) for value iteration to converge, got {gamma}")
    goal = graph.map.check_node(goal, "goal")
    n_states, n_actions = graph.n_states, graph.map.n_actions
    states = np.arange(n_states)
    next_states, blocked = graph.move(states[:, None], np.arange(n_actions)[None, :])
    at_goal = graph.map.state_nodes == goal
    arrives = ~blocked & at_goal[next_states]
    rewards = np.where(arrives, goal_reward, np.where(blocked, collision_penalty, step_penalty))
    continues = gamma * ~arrives  # no value after arriving
    q = np.zeros((n_states, n_actions))
    for _ in range(max_iterations):
        values = q.max(axis=1)
        values[at_goal] = 0.0
        updated = rewards + continues * values[next_states]
        updated[at_goal] = 0.0
        change = np.abs(updated - q).max(initial=0.0)
        q = updated
        if change <= tolerance:
            return q
    raise RuntimeError(f"value iteration did not converge to {tolerance} within {max_iterations} sweeps")
