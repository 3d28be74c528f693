"""Route evaluation: run a greedy policy from every start to every goal and score the routes.

Scores (Anderson et al. 2018 for SPL): success rate over (start node, heading) pairs, SPL = mean of
``S * l / max(p, l)`` with ``l`` the shortest path in hops over open roads and ``p`` the steps taken, mean steps,
coverage (share of start nodes from which every heading reaches the goal) and optimality gap (mean extra steps over the
shortest path, successful routes only). The starts run in batches of ``chunk_size`` pairs (16,384 by default), so
that a policy is queried once per step for a whole batch and memory stays bounded on a map of any size: per batch an
int32 array of ``chunk_size x max_steps`` for the loop check (the states each route visited, and some 8 bits a step
that mark them, so that most checks need not read the array) and, with ``keep_nodes``, one of the routes' nodes: some
40 MB each at 16,384 pairs and 600 steps. For a deterministic policy on fixed views the batches change nothing: the
routes are those of one batch.

A sampled evaluation (``sample=n``) runs ``n`` (start, heading) pairs per goal, drawn with a seeded rng uniformly
without replacement from the pairs that can reach the goal, so that a check during training costs as much on a city
as on a campus. Its scores estimate those of every pair. :meth:`RouteReport.success_interval` gives the Wilson score
interval of the success rate: a range that holds the success rate of every pair with about the confidence asked for
(over the draws of samples). It takes the draws as independent, which makes it a little wider than needed for draws
without replacement from a finite set of pairs, and it pools the goals, which fits where each goal has as many pairs
(a connected map: the same sample size is drawn for each). A report of every pair estimates nothing: its interval is
its success rate itself.

The policy is a function of a batch of observations, or an SB3-style predictor (a model: ``predict(observation,
state, episode_start, deterministic)``), asked for its deterministic action with ``episode_start`` set at each route's
first step and its ``state`` carried from step to step: a policy that remembers within an episode (the route memory
layer's place each route's last move leads to, and the moves that bumped) keeps it per route. The state's arrays hold
one row per route along their first axis (the rows of routes that end are dropped with them).

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

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any, Protocol, runtime_checkable

import gymnasium as gym
import numpy as np

from campusnav_env.env import CampusNavEnv
from campusnav_env.wrappers import any_wrapper_varies, wrapped_observations


@runtime_checkable
class Predictor(Protocol):
    """An SB3-style model: its deterministic actions, with a state carried per route and episode starts."""

    def predict(
        self, observation: Any, state: Any = None, episode_start: Any = None, deterministic: bool = False
    ) -> tuple[np.ndarray, Any]: ...


Policy = Callable[[Any], np.ndarray] | Predictor  # batched observations -> actions, or a model


# Why a route ended (Route.ended): at the goal, stuck on a blocked move (a closed road or no road that way, tried again
# and again), round a loop of moves, or at the step limit
ENDINGS = ("goal", "blocked", "loop", "step limit")
_GOAL, _BLOCKED, _LOOP, _STEP_LIMIT = range(len(ENDINGS))

# Pairs per batch of the policy (see the module docstring for the memory this takes)
DEFAULT_CHUNK_SIZE = 16_384


@dataclass(frozen=True)
class Route:
    """
    One evaluated route.

    :param nodes: The nodes it went through, from ``start`` on (one per move that was not blocked); only ``(start,)``
        where the evaluation did not keep them (``evaluate_routes(..., keep_nodes=False)``)
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
    """
    Scores of a set of routes (see the module docstring).

    :param routes: The routes
    :param population: Where the routes are a sample: how many (start, heading) pairs each goal has, of which they
        were drawn (``None``: the routes are every pair evaluated, nothing was left out)
    """

    routes: list[Route] = field(default_factory=list)
    population: dict[str, int] | None = None

    @property
    def evaluated_pairs(self) -> int:
        """How many (goal, start, heading) routes were run."""
        return len(self.routes)

    @property
    def total_pairs(self) -> int:
        """How many (goal, start, heading) pairs there are: :attr:`evaluated_pairs` unless the routes are a sample."""
        return len(self.routes) if self.population is None else sum(self.population.values())

    @property
    def is_sample(self) -> bool:
        """Whether some pairs were left out, so that the scores are estimates."""
        return self.evaluated_pairs < self.total_pairs

    def success_interval(self, confidence: float = 0.95) -> tuple[float, float]:
        """
        The Wilson score interval of the success rate (see the module docstring): where the success rate of every
        pair lies with about ``confidence``, judging by this sample. ``(rate, rate)`` where every pair was evaluated.

        :param confidence: In ``(0, 1)``
        :return: ``(low, high)``
        :raises ValueError: if ``confidence`` is outside ``(0, 1)``
        """
        if not 0.0 < confidence < 1.0:
            raise ValueError(f"confidence must lie in (0, 1), got {confidence}")
        rate, n = self.success_rate, self.evaluated_pairs
        if not self.is_sample:
            return rate, rate
        if n == 0:
            return 0.0, 1.0  # nothing observed: no bound
        z = NormalDist().inv_cdf(0.5 + confidence / 2)
        centre = rate + z * z / (2 * n)
        spread = z * math.sqrt(rate * (1 - rate) / n + z * z / (4 * n * n))
        scale = 1 + z * z / n
        # At a rate of 0 or 1 the bound is exactly 0 or 1 (the formula's rounding would leave 1 - 2e-16)
        low = 0.0 if rate == 0.0 else max(0.0, (centre - spread) / scale)
        high = 1.0 if rate == 1.0 else min(1.0, (centre + spread) / scale)
        return low, high

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
        return RouteReport([r for r in self.routes if r.goal == goal], self._population_of(goal))

    def _population_of(self, goal: str) -> dict[str, int] | None:
        return None if self.population is None else {goal: self.population.get(goal, 0)}

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
            if route.goal not in groups:
                groups[route.goal] = RouteReport(population=self._population_of(route.goal))
            groups[route.goal].routes.append(route)
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
    chunk_size: int | None = DEFAULT_CHUNK_SIZE,
    keep_nodes: bool = True,
    sample: int | None = None,
    seed: int | None = None,
) -> RouteReport:
    """
    Run ``policy`` greedily from every (node, heading) that can reach each goal and collect the routes.

    :param env: The environment (its current closures apply), or a wrapper of one whose observation wrappers the
        policy's observations pass through (see the module docstring); its episode state is not touched (on a varied
        world its rng is drawn from)
    :param policy: Maps a batch of observations to a batch of actions, e.g.
        ``lambda obs: model.predict(obs, deterministic=True)[0]``; or the model itself (a :class:`Predictor`), asked for
        its deterministic actions with episode starts and its state per route (see the module docstring)
    :param goals: Goals by name or node id (default: all of the env's goals; with ``CampusNavGoal`` any
        intersection); routes carry the goal's name
    :param max_steps: Step limit per route (default: the env's ``max_steps``)
    :param starts: Start states (rows of ``graph.transition_table``; repeats allowed, e.g. test episodes from random
        starts) instead of every state that can reach the goal; each must be able to reach every goal evaluated
    :param stop_loops: Stop a route that revisits a state, as failed: right for a deterministic policy that sees the
        same observation at every visit (it would loop until ``max_steps``, so the scores are the same), wrong for one
        that samples its actions or sees varied observations. None (default): stop loops unless the observations vary
        (see the module docstring)
    :param chunk_size: Routes run together, one batch of the policy per step (``None``: all of a goal's at once)
    :param keep_nodes: Keep each route's nodes (``Route.nodes``, for pictures of routes and closures on them);
        ``False``: ``Route.nodes`` is only ``(start,)`` and nothing per step is kept beyond the loop check
    :param sample: Run this many (start, heading) pairs per goal, drawn uniformly without replacement among those
        that can reach it (or among ``starts``); all of them where there are no more (``None``: all of them). The
        report then knows its :attr:`~RouteReport.total_pairs` and its :meth:`~RouteReport.success_interval`
    :param seed: Seed of the sample's draw: the same seed draws the same pairs for a goal, whichever goals come with
        it (``None``: a fresh draw)
    :return: the routes and their scores, in the order of the starts (a sample's in state order)
    :raises ValueError: if a start cannot reach a goal, or ``chunk_size`` or ``sample`` is below 1
    :raises TypeError: if ``env`` is not a CampusNav env or a wrapper of one
    """
    observed, env = env, env.unwrapped
    if not isinstance(env, CampusNavEnv):
        raise TypeError(f"route evaluation needs a CampusNavEnv (or a wrapper of one), got {type(env).__name__}")
    if chunk_size is not None and chunk_size < 1:
        raise ValueError(f"chunk_size must be at least 1 (or None), got {chunk_size}")
    if sample is not None and sample < 1:
        raise ValueError(f"sample must be at least 1 pair (or None), got {sample}")
    if stop_loops is None:
        stop_loops = not (env.observations_vary or any_wrapper_varies(observed))
    max_steps = env.max_steps if max_steps is None else max_steps
    state_nodes = env.graph.map.state_nodes
    # One entropy for the whole call, each goal's draw keyed by its node: a goal's sample does not depend on the others
    entropy = np.random.SeedSequence(seed).entropy
    report = RouteReport(population=None if sample is None else {})
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
        if report.population is not None:
            report.population[goal] = report.population.get(goal, 0) + goal_starts.size
        if sample is not None and sample < goal_starts.size:
            rng = np.random.default_rng(np.random.SeedSequence(entropy, spawn_key=(int(goal_node),)))
            goal_starts = goal_starts[np.sort(rng.choice(goal_starts.size, size=sample, replace=False))]
        size = max(goal_starts.size, 1) if chunk_size is None else chunk_size
        for begin in range(0, goal_starts.size, size):
            report.routes.extend(
                _run_batch(
                    observed,
                    env,
                    policy,
                    goal,
                    goal_node,
                    goal_starts[begin : begin + size],
                    distances,
                    max_steps,
                    stop_loops,
                    keep_nodes,
                )
            )
    return report


def _running_rows(state: Any, running: np.ndarray) -> Any:
    """A predictor's state (``None`` or a tuple of arrays, one row per route) for the routes still running."""
    if state is None:
        return None
    rows = []
    for array in state:
        array = np.asarray(array)
        if array.ndim == 0 or array.shape[0] != running.size:
            raise ValueError(
                f"route evaluation keeps a predictor's state per route: each array of its state needs one row per "
                f"route along its first axis ({running.size} routes), got shape {array.shape}"
            )
        rows.append(array[running])
    return tuple(rows)


def _mark_bytes(max_steps: int) -> int:
    """
    Bytes of a route's state marks: at least 8 bits per state the route can visit, so that a state it has not seen
    finds its bit set (and the row of its states read) at most once in 8.
    """
    return 1 << max(3, int(max_steps).bit_length())


def _mark_of(states: np.ndarray, n_bytes: int) -> tuple[np.ndarray, np.ndarray]:
    """The byte and bit that mark each state (Fibonacci hashing: the top bits of a product spread nearby states)."""
    bits_used = (8 * n_bytes).bit_length() - 1  # n_bytes is a power of 2
    hashed = (states.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits_used)
    return (hashed >> np.uint64(3)).astype(np.int64), (np.uint8(1) << (hashed & np.uint64(7)).astype(np.uint8))


def _run_batch(
    observed: gym.Env[Any, Any],
    env: CampusNavEnv,
    policy: Policy,
    goal: str,
    goal_node: int,
    starts: np.ndarray,
    distances: np.ndarray,
    max_steps: int,
    stop_loops: bool,
    keep_nodes: bool,
) -> list[Route]:
    """The routes from ``starts`` (state indices) to one goal, run together (see :func:`evaluate_routes`)."""
    graph = env.graph
    state_nodes, state_headings = graph.map.state_nodes, graph.map.state_headings
    n = starts.size
    current = starts.copy()
    arrival = np.zeros(n, dtype=np.int64)  # the step at which a route reached the goal
    ended = np.full(n, _STEP_LIMIT, dtype=np.int8)
    index = np.arange(n)  # the routes still running
    # Row i, columns 0..t: the states route i visited up to step t (all running routes are at the same step), and
    # a bit per hash of those states, which rules most states out at once: only where its bit is set is the row read
    seen = np.empty((n, max_steps + 1), dtype=np.int32) if stop_loops else None
    marks = np.zeros((n, _mark_bytes(max_steps)), dtype=np.uint8) if stop_loops else None
    if seen is not None and marks is not None:
        seen[:, 0] = starts
        byte, bit = _mark_of(starts, marks.shape[1])
        marks[np.arange(n), byte] = bit
    # Row i, columns below length[i]: the nodes route i went through
    path = np.empty((n, max_steps + 1), dtype=np.int32) if keep_nodes else None
    length = np.ones(n, dtype=np.int64)
    if path is not None:
        path[:, 0] = state_nodes[starts]
    carried: Any = None  # a predictor's state, one row per running route
    predictor = isinstance(policy, Predictor)
    for t in range(max_steps):
        if index.size == 0:
            break
        states = current[index]
        observations = env.observations_at(state_nodes[states], state_headings[states], goal)
        observations = wrapped_observations(observed, observations)
        if predictor:
            assert isinstance(policy, Predictor)
            starts_now = np.full(index.size, t == 0)
            actions, carried = policy.predict(observations, state=carried, episode_start=starts_now, deterministic=True)
        else:
            actions = policy(observations)
        actions = np.asarray(actions).reshape(-1)
        states, blocked = graph.move(states, actions)
        current[index] = states
        if path is not None:
            moved = index[~blocked]
            path[moved, length[moved]] = state_nodes[current[moved]]
            length[moved] += 1
        arrived = state_nodes[states] == goal_node
        arrival[index[arrived]] = t + 1
        ended[index[arrived]] = _GOAL
        running = ~arrived
        if seen is not None and marks is not None:
            # A deterministic policy that repeats a state loops forever: a blocked move repeats the state it is in
            byte, bit = _mark_of(states, marks.shape[1])
            maybe = np.flatnonzero(running & ((marks[index, byte] & bit) != 0))
            repeated = maybe[(seen[index[maybe], : t + 1] == states[maybe, None]).any(axis=1)]
            ended[index[repeated]] = np.where(blocked[repeated], _BLOCKED, _LOOP)
            running[repeated] = False
            seen[index, t + 1] = states
            marks[index, byte] |= bit
        index = index[running]
        carried = _running_rows(carried, running)
    success = ended == _GOAL
    steps = np.where(success, arrival, max_steps)  # a failed route counts the full budget
    start_nodes = state_nodes[starts]
    rows = zip(
        start_nodes.tolist(),
        state_headings[starts].tolist(),
        success.tolist(),
        steps.tolist(),
        distances[start_nodes].tolist(),
        ended.tolist(),
        strict=True,
    )
    return [
        Route(
            goal=goal,
            start=start,
            heading=heading,
            success=succeeded,
            steps=taken,
            shortest=shortest,
            nodes=tuple(path[i, : length[i]].tolist()) if path is not None else (start,),
            ended=ENDINGS[end],
        )
        for i, (start, heading, succeeded, taken, shortest, end) in enumerate(rows)
    ]
