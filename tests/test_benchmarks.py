"""The benchmark scripts run and write their results file (smoke runs; the figures themselves are not asserted)."""

from __future__ import annotations

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
