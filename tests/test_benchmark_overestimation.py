"""benchmarks/overestimation.py: the error measurement on cases with a known answer, and a smoke run of the script."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.optimal_values import optimal_q_values

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
sys.path.insert(0, str(ROOT))  # the benchmarks package, as `python -m benchmarks.NAME` imports it
from benchmarks.overestimation import milestones, value_errors  # noqa: E402


@pytest.fixture()
def q_star() -> np.ndarray:
    """Q* of three intersections in a row (goal at the end), one state each: action 0 drives on, 1 hits a wall."""
    transitions = np.array([[1, -1], [2, -1], [-1, -1]])
    graph = RoadGraph.from_transitions(transitions, [0, 1, 2], [0, 0, 0], [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0]])
    return optimal_q_values(NavigationGraph(graph), goal=2, gamma=0.9)


def test_a_q_table_shifted_by_a_constant_has_that_signed_error_everywhere(q_star: np.ndarray) -> None:
    states = np.array([0, 1])  # not at the goal
    visited = np.array([[True, False], [False, False], [False, False]])
    errors = value_errors(q_star + 0.1, q_star, states, {"visited": visited})
    for key in ("signed_all", "abs_all", "greedy", "signed_visited", "abs_visited"):
        assert errors[key] == pytest.approx(0.1), key
    assert errors["fraction_visited"] == pytest.approx(0.25)
    under = value_errors(q_star - 0.1, q_star, states)
    assert under["signed_all"] == pytest.approx(-0.1) and under["abs_all"] == pytest.approx(0.1)


def test_errors_of_opposite_signs_cancel_in_the_signed_error_only(q_star: np.ndarray) -> None:
    q = q_star.copy()
    q[0, 0] += 0.2  # the best action of state 0 over-estimated
    q[1, 1] -= 0.2  # a blocked action of state 1 under-estimated (not its best: the greedy value stays exact)
    nothing = np.zeros_like(q, dtype=bool)
    errors = value_errors(q, q_star, np.array([True, True, False]), {"visited": nothing})
    assert errors["signed_all"] == pytest.approx(0.0)
    assert errors["abs_all"] == pytest.approx(0.1)
    assert errors["greedy"] == pytest.approx(0.1)  # (0.2 + 0) / 2 states
    assert errors["signed_visited"] is None and errors["fraction_visited"] == 0.0


def test_the_table_shows_the_phase_quarters_and_the_first_steps_after_the_closure() -> None:
    measured = list(range(0, 20_001, 1_000))
    assert milestones(measured, 20_000, "before") == [2_000, 5_000, 10_000, 20_000]
    assert milestones(list(range(0, 10_001, 1_000)), 10_000, "after") == [0, 1_000, 2_000, 5_000, 10_000]


def test_quick_run_writes_its_tables_picture_and_runs(tmp_path: Path, shared_cache_dir: Path) -> None:
    out, runs = tmp_path / "overestimation.md", tmp_path / "runs.jsonl"
    env = {**os.environ, "CAMPUSNAV_CACHE": str(shared_cache_dir)}  # the session's (conftest.py)
    command = [sys.executable, str(BENCHMARKS / "overestimation.py"), "--quick", "--out", str(out)]
    command += ["--runs-file", str(runs)]
    subprocess.run(command, check=True, timeout=600, env=env)
    text = out.read_text()
    assert "| agent | seeds | end of training (400 steps): success | Q - Q*, all | Q - Q*, visited |" in text
    assert "| agent | phase | step | seeds | greedy success | Q - Q*, all pairs | Q - Q*, visited pairs |" in text
    assert "| DCQN, single-critic target | after the closure | 0 | 1 |" in text
    assert "Command: `python benchmarks/overestimation.py --quick --out" in text
    assert out.with_suffix(".png").stat().st_size > 0
    records = [json.loads(line) for line in runs.read_text().splitlines()]
    assert sorted(r["agent"] for r in records) == ["DCQN", "DCQN, single-critic target", "DQN"]
    for record in records:
        phases = [(p["phase"], p["step"]) for p in record["points"]]
        assert ("before", 400) in phases and ("after", 0) in phases and ("after", 200) in phases
        # The buffer's transitions were mapped back to states: some pairs are visited
        assert record["points"][-1]["fraction_visited"] > 0
    # A second call finds the runs done and only rewrites the results
    again = subprocess.run(command, check=True, timeout=600, env=env, capture_output=True, text=True)
    assert "3 runs already in" in again.stdout and "0 to do" in again.stdout
