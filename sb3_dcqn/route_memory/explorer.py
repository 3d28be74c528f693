"""Exploration with the memory: drive to the nearest untried move and try it (Go-Explore's return, then explore).

Where nothing untried can be reached any more, the nearest closed move whose retry is due is sought instead (a road
bumped before it was ever driven is tried again after it may have reopened, ever more rarely: see
:meth:`~sb3_dcqn.route_memory.edges.EdgeStore.retry_due`). In a stochastic world a move tried too few times for its
outcome counts to be a model is sought as an untried one is
(:meth:`~sb3_dcqn.route_memory.edges.EdgeStore.is_undersampled`).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

import numpy as np

from sb3_dcqn.route_memory.edges import ROUTES, EdgeStore, Outcome

__all__ = ["UntriedExplorer", "path_to"]


def path_to(
    edges: EdgeStore, state: int, wanted: Callable[[int], list[int]], exclude: frozenset | set = frozenset()
) -> list[int] | None:
    """
    The slots from ``state`` to the nearest state (in hops over remembered moves, never out of an aliased state) with a
    wanted slot, that slot last (the first of ``wanted(state)`` not in ``exclude``; ties between states: the first
    found, in slot order). A search from one state that stops at the first wanted slot: cheap on a large memory.

    :return: the slots, or ``None`` if no wanted slot can be reached
    """
    parent: dict[int, tuple[int, int]] = {state: (-1, -1)}
    queue = deque([state])
    while queue:
        here = queue.popleft()
        found = [slot for slot in wanted(here) if (here, slot) not in exclude]
        if found:
            path = [found[0]]
            while parent[here][0] >= 0:
                here, slot = parent[here]
                path.append(slot)
            return path[::-1]
        if here in edges.aliased:
            continue
        outcomes, targets = edges.outcome[here].tolist(), edges.target[here].tolist()
        for slot, (code, following) in enumerate(zip(outcomes, targets, strict=True)):
            if code in ROUTES and following >= 0 and following != here and following not in parent:
                parent[following] = (here, slot)
                queue.append(following)
    return None


class UntriedExplorer:
    """
    Drives each env of a vector env to the nearest untried ``(state, slot)`` of a memory and tries it: the path is
    searched once and followed while the states met are the ones expected, searched anew otherwise. Envs do not chase
    the same pair: each seeks one no other env is on its way to.

    :param memory: The :class:`~sb3_dcqn.route_memory.memory.RouteMemory` it reads
    :param n_envs: Number of envs (one path each)
    """

    def __init__(self, memory: Any, n_envs: int = 1) -> None:
        self.memory = memory
        self._paths: list[list[tuple[int, int]]] = [[] for _ in range(n_envs)]
        self._targets: list[tuple[int, int] | None] = [None] * n_envs  # the pair each env is on its way to

    def actions(self, observations: Any) -> np.ndarray:
        """The exploring action of each env's observation (a batch), -1 where the memory has none."""
        return self.actions_at(self.memory.states_of(observations), observations)

    def actions_at(self, states: np.ndarray, observations: Any, untried_only: bool = False) -> np.ndarray:
        """
        :meth:`actions` for the envs' memory states (-1: unknown), where the caller has them already.

        :param untried_only: Seek untried pairs only, not closed ones whose retry is due (-1 where none is in reach)
        """
        if states.size != len(self._paths):
            self._paths = [[] for _ in range(states.size)]
            self._targets = [None] * states.size
        slots = np.array(
            [self._slot(env, int(state), untried_only) for env, state in enumerate(states)], dtype=np.int64
        )
        return self.memory.slot_actions(observations, slots)

    def driving(self, states: np.ndarray) -> np.ndarray:
        """Which envs are on their way to an untried pair: their path goes on from their state (-1: unknown) and its
        pair is still untried (or its retry still due)."""
        states = np.asarray(states, dtype=np.int64).reshape(-1)
        if states.size != len(self._paths):
            return np.zeros(states.size, dtype=bool)
        return np.array(
            [
                state >= 0 and bool(path) and path[0][0] == state and self._still_wanted(target)
                for state, path, target in zip(states.tolist(), self._paths, self._targets, strict=True)
            ],
            dtype=bool,
        )

    def _still_wanted(self, target: tuple[int, int] | None) -> bool:
        if target is None:
            return False
        edges = self.memory.edges
        if edges.outcome[target] == Outcome.UNTRIED or edges.is_undersampled(*target):
            return True
        return bool(edges.retry_due(np.array([target[0]]))[0, target[1]])

    def _claimed(self, env: int) -> set[tuple[int, int]]:
        return {
            target
            for other, target in enumerate(self._targets)
            if other != env and target is not None and self._still_wanted(target)
        }

    def _slot(self, env: int, state: int, untried_only: bool = False) -> int:
        path, target = self._paths[env], self._targets[env]
        wanted = target is not None and (self.memory.edges.outcome[target] == Outcome.UNTRIED or not untried_only)
        if state >= 0 and path and path[0][0] == state and wanted and self._still_wanted(target):
            return path.pop(0)[1]
        path.clear()
        self._targets[env] = None
        if state < 0:
            return -1
        retry = not untried_only
        slots = self.memory.path_to_untried(state, self._claimed(env), retry)
        if slots is None:
            slots = self.memory.path_to_untried(state, retry=retry)  # every reachable pair is claimed: share one
        if slots is None:
            return -1
        edges = self.memory.edges
        for slot in slots:
            path.append((state, slot))
            state = int(edges.target[state, slot])
        self._targets[env] = path[-1]
        return path.pop(0)[1]
