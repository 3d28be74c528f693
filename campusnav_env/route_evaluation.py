"""Route evaluation: run a greedy policy from every start to every goal and score the routes.

Scores (Anderson et al. 2018 for SPL): success rate over (start node, heading) pairs, SPL = mean of
``S * l / max(p, l)`` with ``l`` the shortest path in hops over open roads and ``p`` the steps taken, mean steps,
coverage (share of start nodes from which every heading reaches the goal) and optimality gap (mean extra steps over the
shortest path, successful routes only). All starts run as one batch, so a policy is queried once per step for all of
them.

The policy sees what the agent sees: the env may come wrapped, and the batch of observations the env builds
(:meth:`~campusnav_env.env.CampusNavEnv.observations_at`) passes through the observation wrappers of its chain
(:func:`~campusnav_env.wrappers.wrapped_observations`: a noise wrapper's noise, fresh for every visit), and on a varied
world (``view_variation``) every visit draws its views among the K renders with the env's rng, as in an episode.

When a route stops: where a (node, heading) is always observed the same way (fixed views, no noise), a route that
revisits one has entered a loop under a deterministic policy and is stopped at once as failed (the step limit would
end it failed with the same scores). Where observations vary between visits (a variation of several renders, or a
wrapper whose ``observations_vary`` is true) a revisit is no proof of a loop: the policy may act otherwise on the next
picture of the same place, so a route runs until it reaches the goal or the step limit.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from campusnav_env.env import CampusNavEnv
from campusnav_env.wrappers import any_wrapper_varies, wrapped_observations

Policy = Callable[[Any], np.ndarray]  # batched observations -> actions


# Why a route ended (Route.ended): at the goal, stuck on a blocked move (a closed road or no road that way, tried again
# and again), round a loop of moves, or at the step limit
ENDINGS = ("goal", "blocked", "loop", "step limit")


@dataclass(frozen=True)
class Route:
    """
    One evaluated route.

    :param ended: Why it ended, one of :data:`ENDINGS` (``""``: not recorded, a route made elsewhere)
    """

    goal: str
    start: int
    heading: int
    success: bool
    steps: int
    shortest: int
    nodes: tuple[int, ...]
    ended: str = ""

    @property
    def spl(self) -> float:
        return float(self.success) * self.shortest / max(self.steps, self.shortest)


@dataclass
class RouteReport:
    """Scores of a set of routes (see the module docstring)."""

    routes: list[Route] = field(default_factory=list)

    @property
    def success_rate(self) -> float:
        return _mean([r.success for r in self.routes])

    @property
    def spl(self) -> float:
        return _mean([r.spl for r in self.routes])

    @property
    def mean_steps(self) -> float:
        return _mean([r.steps for r in self.routes])

    @property
    def mean_shortest(self) -> float:
        return _mean([r.shortest for r in self.routes])

    @property
    def coverage(self) -> float:
        """Share of (goal, start node) pairs from which the route succeeds at every heading."""
        by_start: dict[tuple[str, int], bool] = {}
        for r in self.routes:
            by_start[(r.goal, r.start)] = by_start.get((r.goal, r.start), True) and r.success
        return _mean(list(by_start.values()))

    @property
    def optimality_gap(self) -> float:
        """Mean extra steps over the shortest path, successful routes only (NaN if none succeeded)."""
        return _mean([r.steps - r.shortest for r in self.routes if r.success], empty=float("nan"))

    def for_goal(self, goal: str) -> RouteReport:
        return RouteReport([r for r in self.routes if r.goal == goal])

    def meets(self, success_threshold: float, spl_threshold: float, every_goal: bool = False) -> bool:
        """
        Whether success rate and SPL are both at or above the thresholds.

        :param every_goal: Also for each goal on its own (not only over all routes)
        """
        reports = [self, *self.by_goal().values()] if every_goal else [self]
        return all(r.success_rate >= success_threshold and r.spl >= spl_threshold for r in reports)

    def by_goal(self) -> dict[str, RouteReport]:
        """The routes per goal, in the order the goals first appear, in one pass (not one :meth:`for_goal` each)."""
        groups: dict[str, RouteReport] = {}
        for route in self.routes:
            groups.setdefault(route.goal, RouteReport()).routes.append(route)
        return groups

    def summary(self) -> dict[str, float]:
        return {
            "success_rate": self.success_rate,
            "spl": self.spl,
            "coverage": self.coverage,
            "mean_steps": self.mean_steps,
            "mean_shortest": self.mean_shortest,
            "optimality_gap": self.optimality_gap,
            "n_routes": float(len(self.routes)),
        }


def _mean(values: Sequence[float], empty: float = 0.0) -> float:
    return float(np.mean(values)) if len(values) else empty


def evaluate_routes(
    env: CampusNavEnv | gym.Env[Any, Any],
    policy: Policy,
    *,
    goals: Sequence[str | int] | None = None,
    max_steps: int | None = None,
    starts: Sequence[int] | np.ndarray | None = None,
    stop_loops: bool | None = None,
) -> RouteReport:
    """
    Run ``policy`` greedily from every (node, heading) that can reach each goal and collect the routes.

    :param env: The environment (its current closures apply), or a wrapper of one whose observation wrappers the
        policy's observations pass through (see the module docstring); its episode state is not touched (on a varied
        world its rng is drawn from)
    :param policy: Maps a batch of observations to a batch of actions, e.g.
        ``lambda obs: model.predict(obs, deterministic=True)[0]``
    :param goals: Goals by name or node id (default: all of the env's goals; with ``CampusNavGoal`` any
        intersection); routes carry the goal's name
    :param max_steps: Step limit per route (default: the env's ``max_steps``)
    :param starts: Start states (rows of ``graph.transition_table``; repeats allowed, e.g. test episodes from random
        starts) instead of every state that can reach the goal; each must be able to reach every goal evaluated
    :param stop_loops: Stop a route that revisits a state, as failed: right for a deterministic policy that sees the
        same observation at every visit (it would loop until ``max_steps``, so the scores are the same), wrong for one
        that samples its actions or sees varied observations. None (default): stop loops unless the observations vary
        (see the module docstring)
    :return: the routes and their scores
    :raises ValueError: if a start cannot reach a goal
    :raises TypeError: if ``env`` is not a CampusNav env or a wrapper of one
    """
    observed, env = env, env.unwrapped
    if not isinstance(env, CampusNavEnv):
        raise TypeError(f"route evaluation needs a CampusNavEnv (or a wrapper of one), got {type(env).__name__}")
    if stop_loops is None:
        stop_loops = not (env.observations_vary or any_wrapper_varies(observed))
    max_steps = env.max_steps if max_steps is None else max_steps
    graph = env.graph
    state_nodes, state_headings = graph.map.state_nodes, graph.map.state_headings
    report = RouteReport()
    for asked in env.goal_names if goals is None or len(goals) == 0 else goals:
        goal, goal_node = env.resolve_goal(asked)
        distances = env.node_distances(goal_node)
        if starts is None:
            goal_starts = np.flatnonzero((distances > 0)[state_nodes])  # state indices
        else:
            goal_starts = np.asarray(starts, dtype=np.int64).reshape(-1)
            unreachable = goal_starts[distances[state_nodes[goal_starts]] <= 0]
            if unreachable.size:
                nodes = sorted({int(state_nodes[s]) for s in unreachable})
                raise ValueError(f"starts at nodes {nodes} cannot reach goal {goal!r} (or are the goal)")
        current = goal_starts.copy()
        steps = np.zeros(goal_starts.size, dtype=np.int64)
        active = np.ones(goal_starts.size, dtype=bool)
        success = np.zeros(goal_starts.size, dtype=bool)
        ended = ["step limit"] * goal_starts.size
        visited: list[set[int]] = [{int(s)} for s in goal_starts]
        paths: list[list[int]] = [[int(state_nodes[s])] for s in goal_starts]
        for _ in range(max_steps):
            index = np.flatnonzero(active)
            if index.size == 0:
                break
            states = current[index]
            observations = env.observations_at(state_nodes[states], state_headings[states], goal)
            observations = wrapped_observations(observed, observations)
            actions = np.asarray(policy(observations)).reshape(-1)
            current[index], blocked = graph.move(states, actions)
            steps[index] += 1
            for i, state, was_blocked in zip(index.tolist(), current[index].tolist(), blocked.tolist(), strict=True):
                if not was_blocked:
                    paths[i].append(int(state_nodes[state]))
                if state_nodes[state] == goal_node:
                    success[i], active[i], ended[i] = True, False, "goal"
                elif stop_loops and state in visited[i]:
                    active[i] = False  # a deterministic policy that repeats a state loops forever
                    ended[i] = "blocked" if was_blocked else "loop"
                elif stop_loops:
                    visited[i].add(state)
        for i, start in enumerate(goal_starts):
            report.routes.append(
                Route(
                    goal=goal,
                    start=int(state_nodes[start]),
                    heading=int(state_headings[start]),
                    success=bool(success[i]),
                    steps=int(steps[i]) if success[i] else max_steps,  # a failed route counts the full budget
                    shortest=int(distances[state_nodes[start]]),
                    nodes=tuple(paths[i]),
                    ended=ended[i],
                )
            )
    return report
