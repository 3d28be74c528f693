"""
The navigation core: a fixed :class:`~campusnav_env.maps.road_graph.RoadGraph` plus the roads closed now.

Everything that moves an agent or measures distances goes through :class:`NavigationGraph`: the environment's
``step``, the route evaluator, the map picture and the closure callbacks. It holds the only copy of

- the **move rule** (:meth:`NavigationGraph.move`): the transition table's entry, or stay put where it says -1;
- **closing and reopening** roads: a closed road's transitions (both directions, every heading) read -1 and the hop
  distances are recomputed; a closure that would cut a protected node off from a node that reaches it now is refused
  with :class:`RoadClosureError` unless forced;
- **hop distances** (:meth:`NavigationGraph.hops_to`): fewest actions to a goal over open roads, by one vectorised
  breadth-first search over the states (a node's distance is that of its best state). On a street network every road
  is one action away at every heading, so this equals the number of roads travelled.

The road graph is shared and never written; each environment owns its ``NavigationGraph``, so closures never leak
from one environment to another.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable

import numpy as np

from campusnav_env.maps.refusals import RefusedInput, Setting
from campusnav_env.maps.road_graph import RoadGraph

__all__ = ["NavigationGraph", "RoadClosureError", "RoadStateError"]


class RoadClosureError(RefusedInput):
    """
    A road closure refused because it would cut a protected node off from nodes that reach it now; its ``fix`` is
    ``force=True``.

    :param road: The road, as a canonical ``(min, max)`` pair
    :param node: The protected node it would cut off
    :param labels: The node's landmark names
    :param n_cut: How many nodes that reach it now would not
    """

    def __init__(self, road: tuple[int, int], node: int, labels: Iterable[str], n_cut: int) -> None:
        self.road, self.node, self.labels, self.n_cut = road, node, tuple(labels), n_cut
        label = f" ({', '.join(self.labels)})" if self.labels else ""
        super().__init__(
            f"closing road {road} would cut protected node {node}{label} off from {n_cut} node(s) that reach it now",
            "pass {fix} to close it anyway",
            fix=Setting("force", True),
        )


class RoadStateError(RefusedInput):
    """
    A road already as asked: closing a closed road, or reopening an open one.

    :param road: The road, as a canonical ``(min, max)`` pair
    :param closed: Whether it is closed
    """

    def __init__(self, road: tuple[int, int], closed: bool) -> None:
        self.road, self.closed = road, closed
        super().__init__(f"road {road} is {'already closed' if closed else 'not closed'}")


class _ReverseIndex:
    """The transitions of a table grouped by target state, for breadth-first search backwards from a goal."""

    def __init__(self, table: np.ndarray) -> None:
        source, action = np.nonzero(table >= 0)
        target = table[source, action]
        order = np.argsort(target, kind="stable")
        self.predecessors = source[order]
        self.starts = np.concatenate([[0], np.cumsum(np.bincount(target, minlength=table.shape[0]))])

    def state_hops(self, goal_states: np.ndarray) -> np.ndarray:
        """Fewest actions from every state to any of ``goal_states`` (-1 where unreachable), one hop per loop."""
        hops = np.full(self.starts.size - 1, -1, dtype=np.int64)
        hops[goal_states] = 0
        frontier = np.asarray(goal_states, dtype=np.int64)
        distance = 0
        while frontier.size:
            distance += 1
            begin, count = self.starts[frontier], self.starts[frontier + 1] - self.starts[frontier]
            # Concatenated ranges [begin, begin + count) without a Python loop
            offsets = np.repeat(begin - np.concatenate([[0], np.cumsum(count)[:-1]]), count)
            previous = self.predecessors[offsets + np.arange(int(count.sum()))]
            frontier = np.unique(previous[hops[previous] < 0])
            hops[frontier] = distance
        return hops


class NavigationGraph:
    """
    A road graph with closures: moves, hop distances and closing/reopening roads.

    :param road_graph: The fixed map (shared, never modified)
    :param closed_roads: Roads to start closed (no protection check: the caller asks for them explicitly)
    """

    def __init__(self, road_graph: RoadGraph, closed_roads: Iterable[tuple[int, int]] = ()) -> None:
        if not isinstance(road_graph, RoadGraph):
            raise TypeError(f"road_graph must be a RoadGraph, got {type(road_graph).__name__}")
        self.map = road_graph
        self._closed: set[int] = set()
        self._table = road_graph.transitions.copy()
        self.version = 0
        self._index: _ReverseIndex | None = None
        self._hops: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for u, v in closed_roads:
            self.close_road(u, v, force=True)

    # ------------------------------------------------------------------ facts of the fixed map
    @property
    def n_nodes(self) -> int:
        return self.map.n_nodes

    @property
    def n_states(self) -> int:
        return self.map.n_states

    @property
    def landmarks(self) -> dict[str, int]:
        return self.map.landmarks

    # ------------------------------------------------------------------ the changing part
    @property
    def transition_table(self) -> np.ndarray:
        """``(S, A)`` next state of each action with the current closures, -1 where blocked (a read-only view)."""
        view = self._table.view()
        view.flags.writeable = False
        return view

    @property
    def closed_roads(self) -> frozenset[tuple[int, int]]:
        """The closed roads as canonical ``(min, max)`` pairs."""
        return frozenset(self.map.roads[e] for e in self._closed)

    def is_closed(self, u: int, v: int) -> bool:
        """Whether the road between ``u`` and ``v`` is closed (``KeyError`` if there is none)."""
        return self.map.road_id(u, v) in self._closed

    def move(self, states: np.ndarray | int, actions: np.ndarray | int) -> tuple[np.ndarray, np.ndarray]:
        """
        Apply actions: the one move rule of CampusNav.

        :param states: Flat state indices (any shape)
        :param actions: Actions, broadcast against ``states``
        :return: ``(next_states, blocked)``: where the table says -1 the move is blocked and the state is unchanged
        :raises ValueError: if a state or an action is out of range
        """
        states, actions = np.broadcast_arrays(np.asarray(states, dtype=np.int64), np.asarray(actions, dtype=np.int64))
        if states.size and (states.min() < 0 or states.max() >= self.n_states):
            raise ValueError(f"states must be in [0, {self.n_states}), got {states.min()}..{states.max()}")
        if actions.size and (actions.min() < 0 or actions.max() >= self.map.n_actions):
            raise ValueError(f"actions must be in [0, {self.map.n_actions}), got {actions.min()}..{actions.max()}")
        target = self._table[states, actions]
        blocked = target < 0
        return np.where(blocked, states, target), blocked

    def state_hops_to(self, goal: int) -> np.ndarray:
        """
        Fewest actions from every state to any state at ``goal`` over open roads.

        Cached per goal until the next closure or reopening; the returned array is read-only.

        :return: Shape ``(S,)`` int64, ``-1`` where the goal is unreachable
        """
        return self._hops_entry(goal)[0]

    def hops_to(self, goal: int) -> np.ndarray:
        """
        Fewest actions from every node (its best state) to ``goal`` over open roads.

        Cached per goal until the next closure or reopening; the returned array is read-only.

        :return: Shape ``(N,)`` int64, ``-1`` where the goal is unreachable
        """
        return self._hops_entry(goal)[1]

    def _hops_entry(self, goal: int) -> tuple[np.ndarray, np.ndarray]:
        goal = self.map.check_node(goal, "goal")
        entry = self._hops.get(goal)
        if entry is None:
            if self._index is None:
                self._index = _ReverseIndex(self._table)
            state_hops = self._index.state_hops(self._states_at(goal))
            entry = (state_hops, self._node_hops(state_hops))
            for array in entry:
                array.flags.writeable = False
            self._hops[goal] = entry
        return entry

    def _states_at(self, node: int) -> np.ndarray:
        row = self.map.state_of[node]
        return row[row >= 0]

    def _node_hops(self, state_hops: np.ndarray) -> np.ndarray:
        unreachable = np.iinfo(np.int64).max
        node_hops = np.full(self.n_nodes, unreachable, dtype=np.int64)
        reached = state_hops >= 0
        np.minimum.at(node_hops, self.map.state_nodes[reached], state_hops[reached])
        node_hops[node_hops == unreachable] = -1
        return node_hops

    def shortest_path(self, start: int, goal: int) -> list[int]:
        """
        One shortest path over open roads, as the list of nodes visited from ``start`` to ``goal``.

        Starts from the start's best state and takes, at every step, the lowest action that gets one hop closer.
        Returns an empty list when the goal is unreachable.
        """
        start = self.map.check_node(start, "start")
        hops = self.state_hops_to(goal)
        states = self._states_at(start)
        if not (hops[states] >= 0).any():
            return []
        state = int(states[np.argmin(np.where(hops[states] >= 0, hops[states], np.iinfo(np.int64).max))])
        path = [start]
        while hops[state] > 0:
            row = self._table[state]
            state = int(next(t for t in row if t >= 0 and hops[t] == hops[state] - 1))
            node = int(self.map.state_nodes[state])
            if node != path[-1]:
                path.append(node)
        return path

    # ------------------------------------------------------------------ closures
    def close_road(self, u: int, v: int, *, protect: Iterable[int] | None = None, force: bool = False) -> None:
        """
        Close the road between ``u`` and ``v``: every transition along it, both ways, at every heading.

        :param protect: Nodes that must stay reachable from every node that reaches them now; defaults to all
            landmark nodes
        :param force: Close even if a protected node gets cut off
        :raises NoSuchRoadError: (a ``KeyError``) if there is no such road
        :raises RoadStateError: (a ``ValueError``) if the road is already closed
        :raises RoadClosureError: (a ``ValueError``) if the closure would cut a protected node off (and ``force`` is
            False)
        """
        road = self.map.road_id(u, v)
        a, b = self.map.roads[road]
        if road in self._closed:
            raise RoadStateError((int(a), int(b)), closed=True)
        if not force:
            cut = self._cut_protected(self._closed, road, self._protected_nodes(protect))
            if cut is not None:
                node, n_cut = cut
                labels = [label for label, n in self.map.landmarks.items() if n == node]
                raise RoadClosureError((int(a), int(b)), node, labels, n_cut)
        self._closed.add(road)
        self._refresh()

    def reopen_road(self, u: int, v: int) -> None:
        """
        Reopen a closed road, restoring both directions of the table exactly.

        :raises NoSuchRoadError: (a ``KeyError``) if there is no such road
        :raises RoadStateError: (a ``ValueError``) if the road is not closed
        """
        road = self.map.road_id(u, v)
        if road not in self._closed:
            a, b = self.map.roads[road]
            raise RoadStateError((int(a), int(b)), closed=False)
        self._closed.remove(road)
        self._refresh()

    def sample_closures(
        self, k: int, rng: np.random.Generator, *, protect: Iterable[int] | None = None
    ) -> list[tuple[int, int]]:
        """
        Draw ``k`` distinct open roads that can be closed together without cutting any protected node off.

        Greedy random selection with rejection: roads are tried in random order and kept when closing them (on top of
        those kept so far) leaves every protected node reachable from every node that reaches it now. The roads are
        returned (canonical pairs, in the order drawn), not closed.

        :param k: Number of roads
        :param rng: Source of randomness (the result is deterministic for a given generator state)
        :param protect: Protected nodes; defaults to all landmark nodes
        :raises ValueError: if ``k`` is negative or no such set of ``k`` roads exists
        """
        if k < 0:
            raise ValueError(f"k must be non-negative, got {k}")
        protected = self._protected_nodes(protect)
        candidates = [e for e in range(self.map.n_roads) if e not in self._closed]
        if k > len(candidates):
            raise ValueError(f"cannot close {k} roads: only {len(candidates)} are open")
        chosen: list[int] = []
        for index in rng.permutation(len(candidates)):
            if len(chosen) == k:
                break
            road = candidates[int(index)]
            # Greedy is exact on street networks: a road rejected now stays a bridge after further closures
            if self._cut_protected(self._closed | set(chosen), road, protected) is None:
                chosen.append(road)
        if len(chosen) < k:
            raise ValueError(
                f"cannot close {k} roads without cutting a protected node off: at most {len(chosen)} can be closed"
            )
        return [self.map.roads[e] for e in chosen]

    def copy(self) -> NavigationGraph:
        """An independent navigation graph over the same (shared) road graph, with the same closures."""
        return NavigationGraph(self.map, self.closed_roads)

    def _table_with(self, closed: set[int]) -> np.ndarray:
        table = self.map.transitions.copy()
        if closed:
            table[np.isin(self.map.transition_roads, list(closed))] = -1
        return table

    def _refresh(self) -> None:
        # In place, so that views handed out earlier (transition_table) see the closure too
        self._table[...] = self._table_with(self._closed)
        self.version += 1
        self._index = None
        self._hops.clear()

    def _protected_nodes(self, protect: Iterable[int] | None) -> list[int]:
        if protect is None:
            return sorted(set(self.map.landmarks.values()))
        return sorted({self.map.check_node(int(node), "protected node") for node in protect})

    def _cut_protected(self, closed: set[int], road: int, protected: list[int]) -> tuple[int, int] | None:
        """
        If closing ``road`` on top of ``closed`` (a set of closures that cuts no protected node off) disconnects some
        node from a protected node that it reaches now, return that protected node and the number of nodes cut off
        from it; otherwise ``None``.
        """
        if not protected:
            return None
        if self.map.slots is not None and self._ends_stay_connected(road, closed):
            # A street network is undirected: if the road's ends still reach each other, no route is lost
            return None
        index = _ReverseIndex(self._table_with(closed | {road}))
        for node in protected:
            reached_now = self.hops_to(node) >= 0
            reached_after = self._node_hops(index.state_hops(self._states_at(node))) >= 0
            cut = reached_now & ~reached_after
            if cut.any():
                return node, int(cut.sum())
        return None

    def _ends_stay_connected(self, road: int, closed: set[int]) -> bool:
        """Whether the two ends of ``road`` are joined by open roads other than itself (a search from one end that
        stops at the other: usually a nearby block, a few nodes)."""
        source, target = self.map.roads[road]
        # Roads and neighbours per compass slot: the transitions of each node's north-facing state
        neighbours = self.map.slots
        slot_roads = self.map.transition_roads[0::4]
        skip = closed | {road}
        seen = {source}
        frontier = deque([source])  # breadth first: the detour around a block is found before distant nodes
        while frontier:
            node = frontier.popleft()
            for nxt, via in zip(neighbours[node].tolist(), slot_roads[node].tolist(), strict=True):
                if nxt < 0 or via in skip or nxt in seen:
                    continue
                if nxt == target:
                    return True
                seen.add(nxt)
                frontier.append(nxt)
        return False

    def __repr__(self) -> str:
        return f"NavigationGraph({self.map!r}, closed={sorted(self.closed_roads)})"
