"""The aliased-places benchmark's counts: what the memory made of a map, each intersection's true identity checked."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the benchmarks package, as `python -m benchmarks.NAME` imports it

from benchmarks.aliased_places import PIXELS, explore, make_env, wrong_moves  # noqa: E402
from sb3_dcqn.route_memory import RouteMemory  # noqa: E402
from sb3_dcqn.route_memory.edges import Outcome  # noqa: E402


@pytest.mark.usefixtures("shared_feature_cache")
@pytest.mark.filterwarnings("ignore:view_dim 64 is more than")  # the town's 60 views span fewer axes
def test_a_remembered_move_that_ends_at_the_wrong_intersection_is_counted() -> None:
    town = make_env("town", 0, 15, PIXELS, None)  # the shipped 15-intersection town, fixed views
    memory = RouteMemory.for_env(town)
    explore(town, memory, seed=0, max_steps=600)
    nodes, headings = town.graph.map.state_nodes, town.graph.map.state_headings
    states = memory.states_of(town.observations_at(nodes, headings, town.goal_nodes[0]))
    node_of = dict(zip(states.tolist(), nodes.tolist(), strict=True))  # fixed views: each place one state
    assert len(node_of) == 15 and wrong_moves(memory, town, node_of) == 0
    driven = np.argwhere(memory.edges.outcome[: memory.n_states] == Outcome.DRIVEN)
    state, slot = (int(value) for value in driven[0])
    elsewhere = next(other for other in node_of if other not in (state, int(memory.edges.target[state, slot])))
    memory.edges.target[state, slot] = elsewhere  # as if a picture of another place had been taken for its end
    assert wrong_moves(memory, town, node_of) == 1
