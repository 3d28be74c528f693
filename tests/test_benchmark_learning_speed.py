"""benchmarks/learning_speed.py runs and writes its results (a smoke run: the figures themselves are not asserted)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def test_quick_run_records_each_run_and_writes_the_table_and_picture(tmp_path: Path, shared_cache_dir: Path) -> None:
    runs, out = tmp_path / "runs.jsonl", tmp_path / "learning_speed.md"
    command = [sys.executable, str(BENCHMARKS / "learning_speed.py"), "--tasks", "quick", "--variants", "DCQN", "DQN"]
    command += ["--seeds", "0", "--runs-file", str(runs), "--out", str(out)]
    env = {**os.environ, "CAMPUSNAV_CACHE": str(shared_cache_dir)}  # the session's (conftest.py)
    subprocess.run(command, check=True, timeout=300, env=env, cwd=tmp_path)
    records = [json.loads(line) for line in runs.read_text().splitlines()]
    assert sorted(r["variant"] for r in records) == ["DCQN", "DQN"]
    for record in records:
        # Solved or not (600 steps rarely solve it), a run says how far it got: its last evaluation
        assert record["steps"] <= 600
        assert record["final_success"] == record["curve"][-1]["success"]
    text = out.read_text()
    assert "| task | world | agent | solved | median time to solved (s) |" in text
    for variant in ("DCQN", "DQN"):
        assert f"| smoke run (CampusNav-v0, 64x48 pixel features) | fixed | {variant} | " in text
    assert (tmp_path / "learning_speed.png").stat().st_size > 0
    # A second call finds both runs done and only rewrites the results
    again = subprocess.run(command, check=True, timeout=300, env=env, cwd=tmp_path, capture_output=True, text=True)
    assert "2 runs already in" in again.stdout and "0 to do" in again.stdout


def _run(variant: str, seed: int, steps: int | None, world: str = "harder") -> dict:
    """A recorded run as learning_speed.py writes it: solved at ``steps``, or a miss (``None``) at 60,000."""
    return {"task": "multi", "world": world, "variant": variant, "seed": seed, "solved": steps is not None,
            "steps": steps or 60_000}  # fmt: skip


def test_the_memory_is_judged_against_the_critics_alone_seed_by_seed_a_miss_as_infinitely_slow() -> None:
    sys.path.insert(0, str(BENCHMARKS.parent))
    from benchmarks.learning_speed import memory_against_critics_table

    runs = [_run("DCQN", 1, 20_000), _run("DCQN", 2, 24_000), _run("DCQN", 3, None)]
    runs += [_run("DCQN, critics alone", 1, 30_000), _run("DCQN, critics alone", 2, 36_000)]
    runs += [_run("DCQN, critics alone", 3, 40_000), _run("DCQN", 1, 500, world="fixed")]  # no twin: no row
    (row,) = memory_against_critics_table(runs, ["multi"])[2:]
    cells = [cell.strip() for cell in row.strip("|").split("|")]
    assert cells[1:5] == ["harder", "1 2 3", "24,000 (miss)", "20,000, 24,000, miss"]
    assert cells[5] == "36,000 (40,000)"
    # The medians are within 1.1x (0.67), but the worst seed is not: the worst is judged beside the median
    assert cells[7:] == ["0.67", "inf (memory missed)", "median only"]
    runs[2] = _run("DCQN", 3, 42_000)  # 1.05x the critics' on its seed: met everywhere
    assert memory_against_critics_table(runs, ["multi"])[2].endswith("| 0.67 | 1.05 | met |")
    only_critics = memory_against_critics_table([_run("DCQN, critics alone", 1, 9)], ["multi"])
    assert only_critics == []
