"""The benchmark scripts run and write their results file (smoke runs; the figures themselves are not asserted)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def test_throughput_quick_run_writes_a_markdown_table(tmp_path: Path) -> None:
    out = tmp_path / "throughput.md"
    subprocess.run(
        [sys.executable, str(BENCHMARKS / "throughput.py"), "--quick", "--out", str(out)], check=True, timeout=600
    )
    text = out.read_text()
    assert "| CartPole-v1, net [64, 64], batch 64 |" in text
    assert "Command: `python benchmarks/throughput.py --quick --out" in text


def _quick_run(script: str, tmp_path: Path, *options: str) -> str:
    """Run a benchmark script's smoke run (views encoded into a fresh cache in tmp_path) and return its results file."""
    out = tmp_path / script.replace(".py", ".md")
    env = {**os.environ, "CAMPUSNAV_CACHE": str(tmp_path / "campusnav-cache")}
    command = [sys.executable, str(BENCHMARKS / script), "--quick", "--out", str(out)]
    command += ["--runs-file", str(tmp_path / "runs.jsonl"), *options]
    subprocess.run(command, check=True, timeout=600, env=env)
    return out.read_text()


def test_closures_one_at_a_time_quick_run_writes_its_tables(tmp_path: Path) -> None:
    text = _quick_run("closures_one_at_a_time.py", tmp_path)
    assert "| lever | seeds | solved before the closures at (per seed) | closures recovered |" in text
    assert "| lever | seed | closure | road | routes affected | success right after |" in text
    assert "Command: `python benchmarks/closures_one_at_a_time.py --quick --out" in text


def test_closures_eleven_quick_run_writes_its_tables(tmp_path: Path) -> None:
    text = _quick_run("closures_eleven.py", tmp_path)
    assert "| lever | seeds | solved before the closure at (per seed) | recovered |" in text
    assert "| lever | seed | routes affected | success / SPL right after |" in text


def test_paper_goals_quick_run_writes_its_tables(tmp_path: Path) -> None:
    text = _quick_run("paper_goals.py", tmp_path)
    assert "| goal | agent | seed | test success | mean steps | mean shortest | SPL |" in text
    assert "| goal | agent | seed | routes | success | SPL | coverage (every heading) |" in text


def test_unseen_goals_quick_run_writes_the_goals_and_ablation_tables(tmp_path: Path) -> None:
    text = _quick_run("unseen_goals.py", tmp_path, "--after", "--levers", "shipped", "relabel8")  # --after: both
    assert "| measure | median (worst) | goal | seeds |" in text
    rows = ("held-out goals (20%, strict)", "held-out goals, lenient", "every intersection as goal")
    rows += (
        "the paper's four goals",
        "goals pictured otherwise, night (19:30) (as shipped)",
        "one closure, every goal",
    )
    for row in rows:
        assert f"| {row}" in text
    assert "| strict | 8 relabelled goals per transition | 0 |" in text


def test_long_routes_quick_run_writes_the_ablation_table(tmp_path: Path) -> None:
    text = _quick_run("long_routes.py", tmp_path, "--rows", "curriculum", "memory")
    assert "| intersections | features | row | step cap | seeds | solved |" in text
    assert "| 101 | pixels | + start curriculum (near to far) | 3,000 | 0 |" in text
    assert "| 101 | pixels | + route memory (plans greedy actions) | 3,000 | 0 |" in text
    assert "Command: `python benchmarks/long_routes.py --quick --out" in text
