"""Memories saved by earlier releases, loaded into today's parts.

Two layouts came before: one ``next_state`` table over poses (-1 untried, -2 dead end, the state itself a collision),
and one set of per-``(state, slot)`` arrays over places keyed by digests of their pictures. Neither kept what
similarity needs (a picture per place), so both load with ``recognition="exact"``: states are found by the same
digests as before, and what was learnt (moves, closures, goals reached) carries over.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from sb3_dcqn.route_memory.edges import Outcome

__all__ = ["load_earlier_memory"]


def load_earlier_memory(memory: Any, state: dict[str, Any]) -> None:
    """Fill an unpickled (bare) :class:`~sb3_dcqn.route_memory.memory.RouteMemory` from an earlier release's state."""
    settings = {
        "n_actions": state["n_actions"],
        "observation_space": state.get("observation_space"),
        "goal_keys": state.get("goal_keys"),
        "success_reward": state.get("success_reward"),
        "max_states": state.get("max_states", 1_000_000),
        "place_frame": state.get("place_frame"),
        "retry_after": state.get("retry_after", 50),
        "max_cache_bytes": state.get("max_cache_bytes", 64 * 2**20),
        "goal_tolerance": state.get("goal_tolerance", 1e-4),
        "recognition": "exact",
    }
    type(memory).__init__(memory, **settings)
    digests = dict(state["_state_of"])
    size = int(state.get("_size", len(state.get("next_state", ())) or len(set(digests.values()))))
    recogniser = memory.recogniser
    for digest, index in digests.items():
        if index < size:
            recogniser._exact[digest] = int(index)
    recogniser.n_states = size
    recogniser._grow(max(64, size))
    recogniser._digests_of[:size] = 1
    edges = memory.edges
    edges.ensure(size)
    if "next_state" in state:
        table = np.asarray(state["next_state"], dtype=np.int64)[:size]
        rows = np.arange(size)[:, None]
        outcome = np.select(
            [table == -1, table == -2, table == rows], [Outcome.UNTRIED, Outcome.DEAD_END, Outcome.BLOCKED],
            Outcome.DRIVEN,
        )  # fmt: skip
        edges.outcome[:size] = outcome
        edges.target[:size] = np.where(outcome == Outcome.DRIVEN, table, -1)
    else:
        for name in ("outcome", "target", "arrival", "last_tried"):
            getattr(edges, name)[:size] = np.asarray(state[name])[:size]
        edges.clock = int(state.get("clock", 0))
        edges.aliased = set(state.get("aliased", ()))
        edges._disputes = dict(state.get("_disputes", {}))
    edges.failures[:size] = np.where(edges.outcome[:size] == Outcome.BLOCKED, 1, 0)
    goals = memory.goals
    goals._reached = {goal: set(states) for goal, states in state.get("_reached", {}).items()}
    goals._vectors = dict(state.get("_goal_vectors", {}))
    if goals.achieved_key is not None:
        pictures = state.get("_pictures", state.get("_place_vectors", []))
        linked = state.get("_picture_states", state.get("_place_states", []))
        for picture, states in zip(pictures, linked, strict=True):
            vector = np.asarray(picture, dtype=np.float64).reshape(-1)
            goals._achieved[digest(vector.tobytes())] = (vector, set(states))
