"""Shortest remembered routes: hops from every state to a set of target moves, and the first slot of each route.

Hops are one backward breadth-first search over every move edge at once (numpy arrays, level by level, no per-state
Python loop; each level reads only the moves into its states, so a search reads every move once). Searches are kept
in one cache bounded in bytes (:class:`BoundedCache`, least recently used first out; a result larger than the whole
bound is not kept), shared with the goal index's answers, so that :meth:`Planner.cache_nbytes` is everything the
memory keeps beside its facts.

**Where some moves are stochastic** (:attr:`~sb3_dcqn.route_memory.edges.EdgeStore.stochastic`: a slippery world),
fewest hops is no longer the best route: :meth:`Planner.values_to` solves the empirical model by value iteration
(the discounted chance of reaching the goal by each move, then the best moves; R-max's and Dyna-Q's model of observed
counts), and :meth:`Planner.best_slots` takes the move of highest value. A deterministic graph is its one-outcome
case: with every move certain, the best move is the first of a fewest-hops route.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Callable, Hashable
from typing import Any

import numpy as np

from sb3_dcqn.route_memory.edges import EdgeStore

__all__ = ["MAX_SWEEPS", "NO_ROUTE", "PLAN_DISCOUNT", "BoundedCache", "Planner"]

NO_ROUTE = -1  # hops of a state with no remembered route
# Value iteration's discount: a surer route beats a shorter one (0.99^20 = 0.82 is worth a 20-hop detour round a 20%
# risk), and of two equally sure routes the shorter wins
PLAN_DISCOUNT = 0.99
MAX_SWEEPS = 2_000  # value iteration's bound (a sweep reads every counted move once); it stops at convergence first
_CONVERGED = 1e-9
_NEVER = np.iinfo(np.int64).max
TargetTest = Callable[[np.ndarray], np.ndarray]  # rows -> (rows, slots) bool: which moves reach the target


class BoundedCache:
    """Entries ``key -> (version, array)`` whose arrays take at most ``max_bytes`` together (LRU eviction)."""

    def __init__(self, max_bytes: int) -> None:
        if max_bytes < 0:
            raise ValueError(f"max_cache_bytes must be >= 0, got {max_bytes}")
        self.max_bytes = int(max_bytes)
        self._entries: OrderedDict[Hashable, tuple[int, np.ndarray]] = OrderedDict()
        self._bytes = 0

    def get(self, key: Hashable) -> tuple[int, np.ndarray] | None:
        entry = self._entries.get(key)
        if entry is not None:
            self._entries.move_to_end(key)
        return entry

    def put(self, key: Hashable, version: int, value: np.ndarray) -> None:
        self.pop(key)
        if value.nbytes > self.max_bytes:
            return  # larger than the whole bound: not kept
        self._entries[key] = (version, value)
        self._bytes += value.nbytes
        while self._bytes > self.max_bytes:
            _, (_, evicted) = self._entries.popitem(last=False)
            self._bytes -= evicted.nbytes

    def pop(self, key: Hashable) -> None:
        entry = self._entries.pop(key, None)
        if entry is not None:
            self._bytes -= entry[1].nbytes

    def clear(self) -> None:
        self._entries.clear()
        self._bytes = 0

    def nbytes(self) -> int:
        return self._bytes

    def __len__(self) -> int:
        return len(self._entries)

    def __getstate__(self) -> dict[str, Any]:  # caches are rebuilt on use
        return {"max_bytes": self.max_bytes, "_entries": OrderedDict(), "_bytes": 0}


class Planner:
    """
    Routes over an :class:`~sb3_dcqn.route_memory.edges.EdgeStore`.

    :param edges: The moves
    :param cache: Where searches are kept
    """

    def __init__(self, edges: EdgeStore, cache: BoundedCache) -> None:
        self.edges = edges
        self.cache = cache

    def hops_to(self, targets: np.ndarray, retry: bool = False) -> np.ndarray:
        """
        Hops from every state to one of the target ``(state, slot)`` pairs, that move included.

        :param targets: ``(n_states, n_slots)`` bool
        :param retry: Closed roads whose retry is due count as moves
        :return: int32 hops per state (:data:`NO_ROUTE`: no target reachable)
        """
        n = self.edges.n_rows
        hops = np.full(n, NO_ROUTE, dtype=np.int32)
        moves = self.edges.moves(np.arange(n), retry)
        successors = self.edges.target[:n]
        sources = np.broadcast_to(np.arange(n)[:, None], successors.shape)[moves]
        ends = successors[moves].astype(np.int64)
        # The moves grouped by the state they end at: each level reads only its own states' in-moves, so a search
        # reads every move once (a level over all moves costs levels x moves: 300 x 170k at 56,000 places)
        order = np.argsort(ends, kind="stable")
        into = sources[order]
        first_into = np.concatenate([[0], np.cumsum(np.bincount(ends, minlength=n))])
        level = np.flatnonzero(targets.any(axis=1))
        count = 1
        hops[level] = count
        while level.size:
            starts, counts = first_into[level], first_into[level + 1] - first_into[level]
            offsets = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
            reached = into[np.repeat(starts, counts) + offsets]
            count += 1
            level = np.unique(reached[hops[reached] == NO_ROUTE])
            hops[level] = count
        return hops

    def cached_hops(self, key: Hashable, is_target: TargetTest, staleness: int = 0, retry: bool = False) -> np.ndarray:
        """
        :meth:`hops_to` for a named target, reused while at most ``staleness`` changes old and no move was lost since
        (a route never goes through a road seen closed because of a stale search).
        """
        return self._kept(key, staleness, lambda: self.hops_to(is_target(np.arange(self.edges.n_rows)), retry))

    def _kept(self, key: Hashable, staleness: int, search: Callable[[], np.ndarray]) -> np.ndarray:
        """The cache's answer for ``key`` while at most ``staleness`` changes old and no move was lost since, else
        ``search()``'s, kept."""
        entry = self.cache.get(key)
        version = self.edges.version
        if entry is not None and entry[0] >= self.edges.lost_move_version and version - entry[0] <= staleness:
            return entry[1]
        answer = search()
        self.cache.put(key, version, answer)
        return answer

    def first_slots(
        self, states: np.ndarray, hops: np.ndarray, is_target: TargetTest, retry: bool = False
    ) -> np.ndarray:
        """The slot of each state that starts a fewest-hops way to a target pair (-1: unknown state, or none)."""
        states = np.asarray(states, dtype=np.int64).reshape(-1)
        slots = np.full(states.size, -1, dtype=np.int64)
        known = states >= 0
        if not known.any() or hops.size == 0:
            return slots
        rows = states[known]
        if hops.size < self.edges.n_rows:  # stale hops: states added since have no known route yet
            hops = np.concatenate([hops, np.full(self.edges.n_rows - hops.size, NO_ROUTE, dtype=hops.dtype)])
        successors = self.edges.target[rows].astype(np.int64)
        via = np.where(successors >= 0, hops[np.maximum(successors, 0)], NO_ROUTE).astype(np.int64)
        moves = self.edges.moves(rows, retry) & (via != NO_ROUTE)
        cost = np.where(is_target(rows), 1, np.where(moves, via + 1, _NEVER))
        best = cost.argmin(axis=1)
        slots[known] = np.where(cost[np.arange(rows.size), best] != _NEVER, best, -1)
        return slots

    def values_to(self, goal_states: np.ndarray, retry: bool = False) -> np.ndarray:
        """
        Value iteration on the empirical model (:meth:`~sb3_dcqn.route_memory.edges.EdgeStore.outcome_model`): per
        ``(state, slot)``, the discounted chance (:data:`PLAN_DISCOUNT`) of reaching one of ``goal_states`` by that
        move and the best moves after it. Arriving at a goal state pays 1 and ends; a dead end pays 0 and ends.

        :return: ``(n_states, n_slots)`` float64 values, ``-inf`` where a slot is no move (untried, closed, a dead end)
        """
        n, n_slots = self.edges.n_rows, self.edges.n_slots
        states, slots, ends, probabilities = self.edges.outcome_model(retry)
        goal = np.zeros(n + 1, dtype=bool)  # the extra row: DEAD and outside, no goal
        goal[np.asarray(goal_states, dtype=np.int64)] = True
        ends = np.where(ends >= 0, ends, n)
        pays = probabilities * goal[ends]
        goes_on = probabilities * PLAN_DISCOUNT * (~goal[ends] & (ends < n))
        flat = states * n_slots + slots
        is_move = np.zeros(n * n_slots, dtype=bool)
        is_move[flat] = True
        values = np.zeros(n + 1)
        q = np.full(n * n_slots, -np.inf)
        for _ in range(MAX_SWEEPS):
            q[is_move] = np.bincount(flat, weights=pays + goes_on * values[ends], minlength=n * n_slots)[is_move]
            best = np.maximum(q.reshape(n, n_slots).max(axis=1, initial=0.0), 0.0)
            converged = np.abs(best - values[:n]).max(initial=0.0) < _CONVERGED
            values[:n] = best
            if converged:
                break
        return q.reshape(n, n_slots)

    def cached_values(
        self, key: Hashable, goal_states: np.ndarray, staleness: int = 0, retry: bool = False
    ) -> np.ndarray:
        """:meth:`values_to` for a named goal, kept as :meth:`cached_hops` keeps its searches."""
        return self._kept(("values", key), staleness, lambda: self.values_to(goal_states, retry))

    @staticmethod
    def best_slots(states: np.ndarray, values: np.ndarray) -> np.ndarray:
        """The slot of highest value of each state (the lowest on ties; -1: unknown state, or no move with a chance of
        the goal)."""
        states = np.asarray(states, dtype=np.int64).reshape(-1)
        slots = np.full(states.size, -1, dtype=np.int64)
        known = (states >= 0) & (states < len(values))
        if known.any():
            rows = values[states[known]]
            best = rows.argmax(axis=1)
            slots[known] = np.where(rows[np.arange(best.size), best] > 0, best, -1)
        return slots
