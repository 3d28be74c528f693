"""benchmarks/view_variation.py runs and writes its table of the K-fold cost (a smoke run; figures not asserted)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def test_view_variation_quick_run_writes_the_fixed_and_the_k_fold_build(tmp_path: Path) -> None:
    out = tmp_path / "view_variation.md"
    command = [sys.executable, str(BENCHMARKS / "view_variation.py"), "--quick", "--out", str(out)]
    subprocess.run(command, check=True, timeout=600, capture_output=True)
    text = out.read_text()
    assert "| pixels | fixed | 404 |" in text and "| pixels | 2 | 808 |" in text  # the campus's views, then twice
    assert "Command: `python benchmarks/view_variation.py --quick --out" in text
