"""What every benchmark script does with its results: the results folder, the machine they were measured on, Markdown
tables, the command that made them, atomic writes, and the JSON-lines files of finished runs with the loop that fills
them (:func:`run_missing`: the runs not there yet, each appended as it finishes)."""

from __future__ import annotations

import json
import os
import platform
import shlex
import sys
import time
from collections.abc import Callable, Hashable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from benchmarks.workers import run_in_workers
from campusnav_env.atomic_files import write_text_atomic

# Every script's results files (and their runs files) go here unless --out / --runs-file say otherwise
RESULTS_DIR = Path(__file__).resolve().parent / "results"
CPUINFO = Path("/proc/cpuinfo")
Job = TypeVar("Job")


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


def described(docstring: str | None) -> str:
    """A script's docstring's second paragraph (what it measures, before ``Usage::``) as one line of a results file."""
    return " ".join((docstring or "").split("Usage::")[0].split("\n\n")[1].split())


def first_paragraph(docstring: str | None) -> str:
    """A script's docstring's first paragraph (what it is) as one line: a results file's opening line."""
    return (docstring or "").split("\n\n")[0].replace("\n", " ")


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


# ------------------------------------------------------------------------------------------------ the runs loop
@dataclass
class Runs:
    """
    A benchmark's runs: the records of its runs file made with the settings asked for (read back, then the new ones
    in the order they finished), and what this invocation ran.

    :param records: The records, stored and new
    :param ran: Runs this invocation ran
    :param seconds: Wall time of those runs (all of them, from the first start to the last finish)
    """

    records: list[dict[str, Any]]
    ran: int = 0
    seconds: float = 0.0

    def machine(self, out: Path, default: str) -> str:
        """The ``Machine:`` line: this machine's when this invocation ran something, else the one of ``out``."""
        return default if self.ran else measured_on(out, default)

    def invocation_text(self, verb: str = "ran") -> str:
        """The end of a results file's time line: how many runs this invocation made, and in how long."""
        return (
            f"this invocation {verb} {self.ran} of them in {self.seconds:.0f} s."
            if self.ran
            else ("all read from the runs file.")
        )


def run_missing(
    runs_file: Path,
    jobs: Iterable[Job],
    run: Callable[[Job], dict[str, Any]],
    key: Callable[[dict[str, Any]], Hashable],
    *,
    job_key: Callable[[Job], Hashable] | None = None,
    settings: dict[str, Any] | None = None,
    workers: int = 1,
    describe: Callable[[dict[str, Any]], str] | None = None,
    noun: str = "runs",
) -> Runs:
    """
    The loop of every benchmark that keeps its runs in a JSON-lines file: read the runs already there, run the jobs
    that have none (in ``workers`` processes, :func:`benchmarks.workers.run_in_workers`), append each record as it
    finishes (an interrupted benchmark keeps what it finished, a rerun skips it), and return them all.

    :param runs_file: The JSON-lines file of finished runs
    :param jobs: Every job asked for, done or not
    :param run: Runs one job and returns its record (module-level, to be pickled to workers, if ``workers > 1``)
    :param key: What tells a record's run apart from the others with the same settings
    :param job_key: The key of a job's record, from the job (default: the job is its key)
    :param settings: Fields every record kept must have with these values (others are runs of other settings)
    :param workers: Worker processes; 1 runs the jobs here, in order
    :param describe: A progress line for a finished record (default: none)
    :param noun: What a run is called in the progress line ("runs", "agents", "stages")
    :return: the records with ``settings`` (stored, then new), and what this invocation ran
    """
    wanted = settings or {}
    stored = [r for r in read_runs(runs_file) if all(r.get(name) == value for name, value in wanted.items())]
    done = {key(record) for record in stored}
    todo = [job for job in jobs if (job if job_key is None else job_key(job)) not in done]
    workers_text = f" with {workers} workers" if workers > 1 and todo else ""
    print(f"{len(done)} {noun} already in {runs_file}, {len(todo)} to do{workers_text}", flush=True)
    started = time.perf_counter()
    for record in run_in_workers(run, todo, workers):
        append_run(runs_file, record)
        stored.append(record)
        if describe is not None:
            print(describe(record), flush=True)
    return Runs(stored, len(todo), time.perf_counter() - started)
