"""Shortest remembered routes and the one bounded cache (Planner's and BoundedCache's public API)."""

from __future__ import annotations

import numpy as np
import pytest

from sb3_dcqn.route_memory.edges import EdgeStore
from sb3_dcqn.route_memory.planner import NO_ROUTE, BoundedCache, Planner


def line(n: int) -> EdgeStore:
    """States 0..n-1 in a line: slot 0 forward, slot 1 back."""
    edges = EdgeStore(2)
    edges.ensure(n)
    for state in range(n - 1):
        edges.record(state, 0, following=state + 1, arrival=-1, dead=False)
        edges.record(state + 1, 1, following=state, arrival=-1, dead=False)
    return edges


def at_the_end(edges: EdgeStore, end: int):
    def is_target(rows: np.ndarray) -> np.ndarray:
        return edges.moves(rows) & (edges.target[rows] == end)

    return is_target


def test_hops_count_the_moves_to_a_target_and_first_slots_start_a_shortest_route() -> None:
    edges = line(6)
    planner = Planner(edges, BoundedCache(1 << 20))
    hops = planner.hops_to(at_the_end(edges, 5)(np.arange(6)))
    assert hops.tolist() == [5, 4, 3, 2, 1, 2]  # from the end itself: back one, and forward into it again
    assert planner.first_slots(np.array([0, 3, 5, -1]), hops, at_the_end(edges, 5)).tolist() == [0, 0, 1, -1]
    back = planner.hops_to(at_the_end(edges, 0)(np.arange(6)))
    assert planner.first_slots(np.array([5]), back, at_the_end(edges, 0)).tolist() == [1]
    edges.record(5, 1, following=5, arrival=-1, dead=False)  # the way back from the end is closed
    assert planner.hops_to(at_the_end(edges, 5)(np.arange(6)))[5] == NO_ROUTE


def breadth_first_hops(edges: EdgeStore, targets: np.ndarray) -> list[int]:
    """The hops of a plain breadth-first search, one state at a time (what ``hops_to`` must equal)."""
    n = edges.n_rows
    moves = edges.moves(np.arange(n))
    into: dict[int, list[int]] = {}
    for state, slot in zip(*np.nonzero(moves), strict=True):
        into.setdefault(int(edges.target[state, slot]), []).append(int(state))
    hops = [NO_ROUTE] * n
    level = [int(s) for s in np.flatnonzero(targets.any(axis=1))]
    for state in level:
        hops[state] = 1
    while level:
        following = []
        for state in level:
            for source in into.get(state, []):
                if hops[source] == NO_ROUTE:
                    hops[source] = hops[state] + 1
                    following.append(source)
        level = following
    return hops


@pytest.mark.parametrize("seed", range(5))
def test_hops_are_a_breadth_first_searchs_on_any_graph(seed: int) -> None:
    rng = np.random.default_rng(seed)
    edges = EdgeStore(4)
    edges.ensure(300)
    for _ in range(1_000):  # one-way moves, self-loops and states nothing leads to among them
        state, slot, following = int(rng.integers(300)), int(rng.integers(4)), int(rng.integers(300))
        edges.record(state, slot, following=following, arrival=-1, dead=False)
    moves = np.argwhere(edges.moves(np.arange(300)))
    targets = np.zeros((300, 4), dtype=bool)
    targets[tuple(moves[rng.choice(len(moves), size=3, replace=False)].T)] = True
    hops = Planner(edges, BoundedCache(1 << 20)).hops_to(targets)
    assert hops.tolist() == breadth_first_hops(edges, targets)
    assert (hops == NO_ROUTE).any() and (hops > 3).any()  # the graphs are not trivial


def test_the_lowest_slot_wins_a_tie() -> None:
    edges = EdgeStore(3)
    edges.ensure(3)
    edges.record(0, 2, following=1, arrival=-1, dead=False)
    edges.record(0, 1, following=1, arrival=-1, dead=False)
    planner = Planner(edges, BoundedCache(1 << 20))
    hops = planner.hops_to(at_the_end(edges, 1)(np.arange(3)))
    assert planner.first_slots(np.array([0]), hops, at_the_end(edges, 1)).tolist() == [1]


def test_a_cached_search_is_reused_within_its_staleness_but_never_after_a_lost_move() -> None:
    edges = line(4)
    planner = Planner(edges, BoundedCache(1 << 20))
    target = at_the_end(edges, 3)
    first = planner.cached_hops("goal", target, staleness=5)
    edges.record(3, 0, following=3, arrival=-1, dead=False)  # a change that loses no move (an empty slot)
    assert planner.cached_hops("goal", target, staleness=5) is first
    assert planner.cached_hops("goal", target, staleness=0) is not first
    fresh = planner.cached_hops("goal", target, staleness=5)
    edges.record(1, 0, following=1, arrival=-1, dead=False)  # the road 1 -> 2 is lost
    after = planner.cached_hops("goal", target, staleness=5)
    assert after is not fresh and after[0] == NO_ROUTE


def test_the_cache_evicts_the_least_recently_used_and_never_holds_more_than_its_bound() -> None:
    cache = BoundedCache(100)
    a, b, c = (np.zeros(10, dtype=np.int32) for _ in range(3))  # 40 bytes each
    cache.put("a", 0, a)
    cache.put("b", 0, b)
    cache.get("a")  # "a" is now the most recently used
    cache.put("c", 0, c)
    assert cache.get("b") is None and cache.get("a") is not None and cache.get("c") is not None
    assert cache.nbytes() == 80 <= cache.max_bytes
    cache.put("big", 0, np.zeros(26, dtype=np.int32))  # 104 bytes: larger than the whole bound, not kept
    assert cache.get("big") is None and cache.nbytes() == 80 and len(cache) == 2
    cache.put("a", 1, np.zeros(5, dtype=np.int32))  # replaced, counted once
    assert cache.nbytes() == 60 and cache.get("a")[0] == 1


def test_a_negative_bound_is_refused() -> None:
    with pytest.raises(ValueError, match="max_cache_bytes"):
        BoundedCache(-1)
