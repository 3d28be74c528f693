"""What every benchmark script does with its results: name the command that made them and write them atomically."""

from __future__ import annotations

import sys
from pathlib import Path

from campusnav_env.atomic_files import write_text_atomic


def command_line(script: str, argv: list[str] | None) -> str:
    """The Markdown line naming the command that produced a results file."""
    words = ["python", f"benchmarks/{script}", *(sys.argv[1:] if argv is None else argv)]
    return f"Command: `{' '.join(words)}`"


def write_results(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically, so an interrupted run never leaves half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, text if text.endswith("\n") else text + "\n")
