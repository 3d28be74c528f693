"""The equal-budget comparison: every agent gets the same training budget and the same evaluation."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
sys.path.insert(0, str(ROOT))  # the benchmarks package, as `python -m benchmarks.NAME` imports it

from benchmarks.compare import AGENTS, BudgetHarness, campus_goals, episode_starts  # noqa: E402
from campusnav_env import GOALS, CampusNavEnv  # noqa: E402
from campusnav_env.features.view_build import ViewBuild  # noqa: E402
from campusnav_env.rendering.street_view import RenderSettings  # noqa: E402

BUDGET = 1.0


@pytest.fixture(scope="module")
def env(shared_cache_dir: Path) -> CampusNavEnv:
    return CampusNavEnv(
        encoder="pixels",
        view_build=ViewBuild(
            render_settings=RenderSettings(width=32, height=24),
            cache_dir=shared_cache_dir,  # the session's (conftest.py)
            progress=False,
        ),
    )


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory, shared_cache_dir: Path) -> tuple[str, list[dict]]:
    """One smoke run of every agent on one goal, with a budget of one second each."""
    tmp_path = tmp_path_factory.mktemp("compare")
    out, runs_file = tmp_path / "compare.md", tmp_path / "runs.jsonl"
    command = [sys.executable, str(BENCHMARKS / "compare.py"), "--quick", "--goals", "1", "--budget", str(BUDGET)]
    command += ["--eval-every", "200", "--out", str(out), "--runs-file", str(runs_file)]
    env = {**os.environ, "CAMPUSNAV_CACHE": str(shared_cache_dir)}
    subprocess.run(command, check=True, timeout=600, env=env)
    return out.read_text(), [json.loads(line) for line in runs_file.read_text().splitlines()]


def test_every_agent_trains_for_the_same_budget(quick_run: tuple[str, list[dict]]) -> None:
    _, runs = quick_run
    assert sorted(run["agent"] for run in runs) == sorted(AGENTS)
    for run in runs:
        assert run["budget"] == BUDGET
        if run["agent"] == "oracle":
            assert run["train_seconds"] == 0.0 and run["env_steps"] == 0
        else:
            # the budget is checked after every (vector) step: it overshoots by at most a step and an update phase
            assert BUDGET <= run["train_seconds"] < BUDGET + 1.5, run["agent"]
            assert run["env_steps"] > 0


def test_every_agent_is_tested_from_the_same_starts_with_the_same_cap(quick_run: tuple[str, list[dict]]) -> None:
    _, runs = quick_run
    starts = {tuple(run["test_starts"]) for run in runs}
    assert len(starts) == 1 and len(next(iter(starts))) == 100
    for run in runs:
        assert run["curve"] or run["agent"] == "oracle"  # the same periodic route evaluations
        assert 1.0 <= run["test"]["steps"] <= 200
    oracle = next(run for run in runs if run["agent"] == "oracle")
    assert oracle["test"]["success"] == oracle["test"]["spl"] == oracle["route_spl"] == 1.0


def test_the_report_has_the_summary_the_step_ratio_and_the_goals(quick_run: tuple[str, list[dict]]) -> None:
    text, _ = quick_run
    assert "| agent | env steps in the budget | test success | test mean steps | test SPL |" in text
    assert "| A2C greedy / DCQN |" in text and "| 4.5 |" in text
    assert "| Dreese Lab |" in text
    assert "Command: `python benchmarks/compare.py --quick --goals 1" in text


def test_evaluation_time_does_not_count_as_training(env: CampusNavEnv) -> None:
    def slow_policy(observations: dict[str, np.ndarray]) -> np.ndarray:
        time.sleep(0.01)
        return np.zeros(len(observations["heading"]), dtype=np.int64)

    harness = BudgetHarness(env, seconds=0.05, eval_every=1)
    harness.start()
    assert harness.step(1, slow_policy)  # an evaluation of well over 0.05 s: the budget is not spent
    assert len(harness.evaluations) == 1 and harness.excluded_seconds > 0.05
    assert harness.train_seconds < 0.05
    time.sleep(0.06)
    assert not harness.step(1, slow_policy)  # not due again at the same step; the budget is spent


def test_the_fourteen_goals_start_with_the_paper_goals_and_are_distinct(env: CampusNavEnv) -> None:
    goals = campus_goals(env)
    assert len(goals) == 14 and list(goals[:4]) == list(GOALS)
    nodes = [env.graph.map.landmarks[g] if isinstance(g, str) else g for g in goals]
    assert len(set(nodes)) == 14


def test_episode_starts_depend_only_on_the_goal_and_the_seed(env: CampusNavEnv) -> None:
    first = episode_starts(env, "Dreese Lab", seed=0)
    np.testing.assert_array_equal(first, episode_starts(env, "Dreese Lab", seed=0))
    assert not np.array_equal(first, episode_starts(env, "Dreese Lab", seed=1))
    goal = env.graph.map.landmarks["Dreese Lab"]
    assert (env.graph.map.state_nodes[first] != goal).all()
