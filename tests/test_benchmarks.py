"""The benchmark scripts run and write their results file (smoke runs; the figures themselves are not asserted).

The smoke runs read and write the session's feature cache (conftest.py): the views of the quick settings are rendered
and encoded once for all of them and for the other tests of the session."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.campusnav_runs import APPEARANCES
from campusnav_env.goal_env import held_out_split

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def test_throughput_quick_run_writes_a_markdown_table(tmp_path: Path) -> None:
    out = tmp_path / "throughput.md"
    subprocess.run(
        [sys.executable, str(BENCHMARKS / "throughput.py"), "--quick", "--out", str(out)], check=True, timeout=600
    )
    text = out.read_text()
    assert "| CartPole-v1, net [64, 64], batch 64 |" in text
    assert "Command: `python benchmarks/throughput.py --quick --out" in text


def _quick_run(script: str, tmp_path: Path, cache: Path, *options: str) -> str:
    """Run a benchmark script's smoke run (its results and runs files in tmp_path, its views in the feature cache
    ``cache``) and return its results file."""
    out = tmp_path / script.replace(".py", ".md")
    env = {**os.environ, "CAMPUSNAV_CACHE": str(cache)}
    command = [sys.executable, str(BENCHMARKS / script), "--quick", "--out", str(out)]
    command += ["--runs-file", str(tmp_path / "runs.jsonl"), *options]
    subprocess.run(command, check=True, timeout=600, env=env)
    return out.read_text()


def test_closures_one_at_a_time_quick_run_writes_its_tables(tmp_path: Path, shared_cache_dir: Path) -> None:
    text = _quick_run("closures_one_at_a_time.py", tmp_path, shared_cache_dir)
    assert "| lever | seeds | solved before the closures at (per seed) | closures recovered |" in text
    # The recovery is seen at evaluations every 2 episodes (the default): the tables say so
    assert "| closures recovered | median episodes (evaluated every 2) |" in text
    assert "| lever | seed | closure | road | routes affected | success right after |" in text
    assert "| success right after | recovery episodes (evaluated every 2) |" in text
    assert "Command: `python benchmarks/closures_one_at_a_time.py --quick --out" in text


def test_closures_eleven_quick_run_evaluates_after_every_episode_when_asked(
    tmp_path: Path, shared_cache_dir: Path
) -> None:
    text = _quick_run("closures_eleven.py", tmp_path, shared_cache_dir, "--eval-every", "1")
    assert "| lever | seeds | solved before the closure at (per seed) | recovered |" in text
    assert "| lever | seed | routes affected | success / SPL right after |" in text
    assert "| success / SPL right after | recovery episodes (evaluated every 1) |" in text
    assert "then every 1 training episode)" in text
    runs = [json.loads(line) for line in (tmp_path / "runs.jsonl").read_text().splitlines()]
    assert runs and {run["recovery_eval_freq"] for run in runs} == {1}


def test_paper_goals_quick_run_writes_its_tables(tmp_path: Path, shared_cache_dir: Path) -> None:
    text = _quick_run("paper_goals.py", tmp_path, shared_cache_dir)
    assert "| goal | agent | seed | test success | mean steps | mean shortest | SPL |" in text
    assert "| goal | agent | seed | routes | success | SPL | coverage (every heading) |" in text


# The unseen-goals smoke runs train 2 s per run (the figures are not asserted; the tables' every row is)
UNSEEN_GOALS_BUDGET = ("--budget", "2")


def test_unseen_goals_quick_run_writes_the_goals_and_ablation_tables(tmp_path: Path, shared_cache_dir: Path) -> None:
    # Every protocol as shipped, then the re-adaptation for every goal (the appearance change: the slow test below)
    _quick_run("unseen_goals.py", tmp_path, shared_cache_dir, "--after", "readapt", *UNSEEN_GOALS_BUDGET)
    # Into the same results: two ablation levers on one protocol (each protocol's run is not needed here), their
    # held-out goals drawn with a split seed of their own, not the run's
    levers = ("--protocols", "strict", "--levers", "relabel8", "critics_alone", "--split-seeds", "5")
    text = _quick_run("unseen_goals.py", tmp_path, shared_cache_dir, *levers, *UNSEEN_GOALS_BUDGET)
    split_runs = [
        r for r in map(json.loads, (tmp_path / "runs.jsonl").read_text().splitlines()) if r["lever"] != "shipped"
    ]
    assert [(r["seed"], r["split_seed"]) for r in split_runs] == [(0, 5), (0, 5)]
    assert all(r["held_out"] == held_out_split(101, 0.2, 5)[1] != held_out_split(101, 0.2, 0)[1] for r in split_runs)
    assert "| measure | median (worst) | goal | seeds | route memory |" in text
    rows = ("held-out goals (20%, strict)", "held-out goals, lenient", "every intersection as goal")
    rows += ("the paper's four goals", "one closure, every goal")
    for row in rows:
        assert f"| {row}" in text
    assert "| strict | 8 relabelled goals per transition | 0 x splits 5 |" in text
    # The shipped entry plans over the route memory; the critics-alone lever turns it off, and the rows say which
    shipped, critics = (next(line for line in text.splitlines() if line.startswith(f"| strict | {lever} |"))
                        for lever in ("as shipped", "critics alone (route memory off)"))  # fmt: skip
    assert shipped.endswith("| on |") and critics.endswith("| off |")


@pytest.mark.slow  # five evaluations of every goal, each after its goal pictures are rendered: about a minute
def test_unseen_goals_quick_run_measures_goals_pictured_otherwise(tmp_path: Path, shared_cache_dir: Path) -> None:
    options = ("--protocols", "strict", "--after", "appearance", "--split-seeds", "5", *UNSEEN_GOALS_BUDGET)
    text = _quick_run("unseen_goals.py", tmp_path, shared_cache_dir, *options)
    for appearance in APPEARANCES:
        row = f"| held-out goals (strict) pictured otherwise, {appearance} (as shipped)"
        assert f"{row}: success |" in text and f"{row}: worst goal's success |" in text
        assert "| 0 x splits 5 | on |" in text


def test_long_routes_quick_run_writes_the_ablation_table(tmp_path: Path, shared_cache_dir: Path) -> None:
    text = _quick_run("long_routes.py", tmp_path, shared_cache_dir, "--rows", "curriculum", "memory")
    assert "| intersections | map seed | features | row | step cap | seeds | solved |" in text
    assert "| 101 | 0 | pixels | + start curriculum (near to far) | 3,000 | 0 |" in text
    assert "| 101 | 0 | pixels | + route memory (plans greedy actions) | 3,000 | 0 |" in text
    assert "Command: `python benchmarks/long_routes.py --quick --out" in text


def test_long_routes_reads_the_floor_of_the_same_size_and_map_seed(tmp_path: Path) -> None:
    from benchmarks.long_routes import ablation_table, floor_steps
    from benchmarks.report import append_run

    floor_runs = tmp_path / "floor_runs.jsonl"
    # A record without a map seed is one of map seed 0 (the runs files written before --map-seed)
    for size, map_seed, steps in ((1_000, None, 100_000), (1_000, 23, 200_000), (101, 23, 5_000)):
        record = {"size": size, "quick": False, "solved": True, "env_steps": steps, "driven_solved_steps": steps // 10}
        append_run(floor_runs, record if map_seed is None else {**record, "map_seed": map_seed})
    assert floor_steps(1_000, map_seed=0, runs_file=floor_runs) == [100_000]
    assert floor_steps(1_000, map_seed=23, runs_file=floor_runs) == [200_000]
    assert floor_steps(1_000, "driven_solved_steps", map_seed=23, runs_file=floor_runs) == [20_000]
    assert floor_steps(1_000, map_seed=7, runs_file=floor_runs) == []

    run = {
        "row": "base", "size": 1_000, "map_seed": 23, "seed": 0, "encoder": "pixels", "max_steps": 2_000_000,
        "solved": True, "steps": 400_000, "seconds": 100.0, "final_steps": 400_000, "final_seconds": 100.0,
        "final_success": 1.0, "final_spl": 0.99, "ms_per_step": 0.25, "peak_rss_mb": 900.0,
        "replay_bytes_per_transition": 800.0,
    }  # fmt: skip
    (line,) = ablation_table([run], floor_runs)[2:]
    # 400k steps against the map-23 floor's 200k (not map 0's 100k), and against its exploration alone (20k)
    assert line.startswith("| 1,000 | 23 | pixels | CampusNav-v0's entry")
    assert "| 2.0 | 20.0 |" in line


def test_city_scale_quick_run_puts_the_floor_beside_dcqn_on_the_same_city(
    tmp_path: Path, shared_cache_dir: Path
) -> None:
    out = tmp_path / "city_scale.md"
    env = {**os.environ, "CAMPUSNAV_CACHE": str(shared_cache_dir)}
    command = [sys.executable, str(BENCHMARKS / "city_scale.py"), "--quick", "--out", str(out)]
    subprocess.run(command, check=True, timeout=600, env=env)
    text = out.read_text()
    assert "| 101 | pixels | 0 |" in text and (tmp_path / "city_scale.png").is_file()
    assert "Command: `python benchmarks/city_scale.py --quick --out" in text
    floor = [json.loads(line) for line in (tmp_path / "city_scale_floor_runs.jsonl").read_text().splitlines()]
    assert [(run["size"], run["map_seed"], run["memory"]) for run in floor] == [(101, 71, "places")]


def test_city_scale_fits_the_slope_of_a_log_log_line() -> None:
    from benchmarks.city_scale import slope

    assert slope([1_000, 10_000, 100_000], [4_000, 40_000, 400_000]) == pytest.approx(1.0)
    assert slope([1_000, 4_000], [1_000, 2_000]) == pytest.approx(0.5)
    assert slope([1_000], [4_000]) is None


def test_city_build_quick_run_measures_before_the_views_and_the_pool(tmp_path: Path) -> None:
    out = tmp_path / "city_build.md"
    command = [sys.executable, str(BENCHMARKS / "city_build.py"), "--quick", "--no-ray", "--out", str(out)]
    subprocess.run(command, check=True, timeout=600)
    text = out.read_text()
    assert "| 300 |" in text and "Command: `python benchmarks/city_build.py --quick --no-ray --out" in text
    run = json.loads((tmp_path / "city_build_runs.jsonl").read_text().splitlines()[0])
    assert run["world_s"] > 0 and run["pool_nodes_s"] > 0 and run["world_file_mb"] is None  # 300 < 2,000: no file
