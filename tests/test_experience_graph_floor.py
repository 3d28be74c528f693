"""The experience-graph floor: an agent that remembers exact transitions solves the campus, and the CLI reports it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
sys.path.insert(0, str(ROOT))  # the benchmarks package, as `python -m benchmarks.NAME` imports it

from benchmarks.floor_runs import FloorAgent, floor_steps, make_env  # noqa: E402
from campusnav_env import CampusNavEnv  # noqa: E402
from sb3_dcqn.route_memory import RouteMemory  # noqa: E402


@pytest.fixture(scope="module")
def env() -> CampusNavEnv:
    return make_env(101)


def test_the_floor_solves_the_campus(env: CampusNavEnv) -> None:
    result = floor_steps(env, seed=0, eval_every=500)
    assert result.solved
    assert result.env_steps > 0 and result.env_steps % 500 == 0  # counted at the evaluation that found it solved
    assert result.episodes > 1 and result.evaluations == result.env_steps // 500
    assert result.success >= 0.99 and result.spl >= 0.98
    assert result.tried <= env.graph.transition_table.size


def test_the_floor_gives_up_at_its_step_cap(env: CampusNavEnv) -> None:
    result = floor_steps(env, seed=0, eval_every=50, max_env_steps=150)
    assert not result.solved and result.env_steps == 150 and result.evaluations == 3


def test_the_floor_over_places_needs_a_small_share_of_the_floor_over_poses(env: CampusNavEnv) -> None:
    places = floor_steps(env, seed=0, eval_every=50)
    poses = floor_steps(env, seed=0, eval_every=50, memory="poses")
    assert places.solved and poses.solved
    # A place's four headings are one state and a driven road's way back is known: about one try per slot
    assert places.states == env.graph.n_nodes - 1 <= poses.states / 3
    assert places.env_steps * 10 <= poses.env_steps


def test_the_agent_explores_untried_slots_before_it_plans(env: CampusNavEnv) -> None:
    agent = FloorAgent(RouteMemory.for_env(env, recognition="exact"))
    observation, _ = env.reset(seed=0)
    tried = []
    for _ in range(4):  # a new place: its compass slots are tried in order, collisions included
        action = agent.act(observation)
        tried.append((int(observation["heading"].argmax()) + action) % 4)
        next_observation, reward, terminated, _, _ = env.step(action)
        agent.graph.add(observation, action, next_observation, float(reward), terminated)
        if not np.array_equal(next_observation["views"], observation["views"]):
            break
        observation = next_observation
    assert tried == list(range(len(tried)))


def test_the_policy_takes_the_fixed_action_on_unseen_observations(env: CampusNavEnv) -> None:
    agent = FloorAgent(RouteMemory.for_env(env, recognition="exact"), fixed_action=2)
    observations = env.observations_at(np.array([0, 1]), np.array(env.graph.map.state_headings[:2]), "Dreese Lab")
    assert agent.policy(observations).tolist() == [2, 2]


def test_the_quick_run_writes_its_table_and_runs(tmp_path: Path) -> None:
    out, runs = tmp_path / "floor.md", tmp_path / "runs.jsonl"
    options = ["--quick", "--eval-every", "500", "--max-env-steps", "1000"]
    command = [sys.executable, str(BENCHMARKS / "experience_graph_floor.py"), *options]
    subprocess.run([*command, "--out", str(out), "--runs-file", str(runs)], check=True, timeout=120)
    text = out.read_text()
    header = "| memory | intersections | map seed | (node, heading, action) triples | start-only states | eval every |"
    assert header in text
    assert "| places | 101 | 0 | 1,616 | 94 | 500 | 0 | 1/1 | 500 |" in text
    assert "Command: `python benchmarks/experience_graph_floor.py --quick --eval-every 500 --max-env-steps 1000" in text
    (record,) = [json.loads(line) for line in runs.read_text().splitlines()]
    assert record["memory"] == "places" and record["size"] == 101 and record["env_steps"] == 500
    assert record["solved"] and record["tried"] > 0 and record["evaluations"] == 1
