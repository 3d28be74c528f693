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
