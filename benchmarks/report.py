"""What every benchmark script does with its results: the results folder, the machine they were measured on, Markdown
tables, the command that made them, atomic writes, and the JSON-lines files of finished runs."""

from __future__ import annotations

import json
import os
import platform
import shlex
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from campusnav_env.atomic_files import write_text_atomic

# Every script's results files (and their runs files) go here unless --out / --runs-file say otherwise
RESULTS_DIR = Path(__file__).resolve().parent / "results"
CPUINFO = Path("/proc/cpuinfo")


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo`` on Linux, else what :mod:`platform` knows) and its architecture."""
    model = ""
    try:
        for line in CPUINFO.read_text().splitlines():
            key, _, value = line.partition(":")
            if key.strip() == "model name" and value.strip():
                model = " ".join(value.split())
                break
    except OSError:  # no /proc (macOS, Windows)
        pass
    model = model or platform.processor()
    return f"{model} ({platform.machine()})" if model and model != platform.machine() else platform.machine()


def core_count() -> str:
    """The cores this process may run on, and the machine's when that is fewer (a CPU affinity mask, a container)."""
    machine = os.cpu_count() or 1
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else machine
    return f"{usable} cores" if usable == machine else f"{usable} of {machine} cores"


def machine_line(
    runs: str = "runs one after another in one process", *, torch_threads: int | str = 1, shared: bool = True
) -> str:
    """
    The ``Machine:`` line of a results file, read from the machine: OS, CPU model, cores, torch threads, and how the
    runs used them.

    :param runs: How the runs were laid out (one after another, in N workers, ...), the end of the line
    :param torch_threads: Torch threads of a run: a number, or words (``"1 torch thread per run"``)
    :param shared: Whether other jobs ran on the same cores (the timings are then noisier and pessimistic)
    :return: the line, ``"Machine: ..."``
    """
    threads = torch_threads if isinstance(torch_threads, str) else f"{torch_threads} torch thread"
    threads += "s" if isinstance(torch_threads, int) and torch_threads != 1 else ""
    sharing = " (shared with other jobs)" if shared else ""
    return f"Machine: {platform.platform()}, {cpu_model()}, {core_count()}{sharing}, {threads}; {runs}."


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    """
    The lines of a Markdown table: the header, the separator, one line per row (cells already formatted as text).

    :param header: Column titles
    :param rows: Rows, each with one cell per column
    :return: the table's lines (no blank line before or after)
    """
    lines = [table_row(header), "|" + "---|" * len(header)]
    for row in rows:
        if len(row) != len(header):
            raise ValueError(f"a table row has {len(row)} cells for {len(header)} columns: {list(row)}")
        lines.append(table_row(row))
    return lines


def table_row(cells: Sequence[Any]) -> str:
    """One Markdown table line: ``| a | b | c |``."""
    return "| " + " | ".join(str(cell) for cell in cells) + " |"


def command_line(script: str, argv: list[str] | None) -> str:
    """The Markdown line naming the command that produced a results file."""
    words = ["python", f"benchmarks/{script}", *(sys.argv[1:] if argv is None else argv)]
    return f"Command: `{shlex.join(words)}`"


def measured_on(path: Path, default: str) -> str:
    """
    The ``Machine:`` line of an existing results file, else ``default``: tables rebuilt from stored runs keep naming
    the machine that measured them.
    """
    if path.is_file():
        for line in path.read_text().splitlines():
            if line.startswith("Machine: "):
                return line
    return default


def write_results(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically, so an interrupted run never leaves half a file."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, text if text.endswith("\n") else text + "\n")


def publish(path: Path, lines: list[str], script: str, argv: list[str] | None) -> None:
    """Print a results file's lines, followed by the command that made them, and write them to ``path``."""
    text = "\n".join([*lines, "", command_line(script, argv)])
    print(text)
    write_results(path, text)
    print(f"wrote {path}")


def read_runs(path: Path) -> list[dict[str, Any]]:
    """The runs recorded so far in a JSON-lines file (none if it does not exist)."""
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def append_run(path: Path, run: dict[str, Any]) -> None:
    """Record one finished run: one JSON line, appended, so an interrupted benchmark keeps what it finished."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as file:
        file.write(json.dumps(run) + "\n")
