"""benchmarks/view_build.py runs and writes its table and its plan (a smoke run; the figures are not asserted)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def test_view_build_quick_run_writes_the_table_and_the_plan(tmp_path: Path) -> None:
    out = tmp_path / "view_build.md"
    options = ["--quick", "--paths", "pool", "--workers", "2", "--out", str(out)]
    command = [sys.executable, str(BENCHMARKS / "view_build.py"), *options]
    subprocess.run(command, check=True, timeout=600, capture_output=True)
    text = out.read_text()
    assert "| serial | 1 |" in text  # the reference, measured whatever --paths says
    assert "| pool | 2 |" in text
    assert "## Plan: 56,000 intersections" in text
    assert "Command: `python benchmarks/view_build.py --quick --paths pool --workers 2 --out" in text
