"""The figures of the docs' Results page (``docs/results.md``): every row names the command that made it and the
results file it wrote; README's few headline rows come from those files too.

The table is the one place the docs state measured figures (README repeats a handful of its rows). A row with no
command, a command whose script does not exist, a results file that does not exist, or a results file written by
another script (its ``Command:`` line) fails here; so does a machine that the results file does not name, and a
README row whose results file is not one of the table's.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from importlib.metadata import distribution
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
RESULTS = ROOT / "docs" / "results.md"
COLUMNS = ("measure", "figure", "memory", "machine", "results file", "command")  # the long commands last
MEMORY = {"yes", "no", "floor", "matcher only", "-"}
# How a results file's Machine line spells the CPUs the table names
CPU_SPELLINGS = {"AMD EPYC": ("AMD EPYC",), "Intel Xeon": ("Intel(R) Xeon(R)", "Intel Xeon"), "x86_64": ("x86_64",)}


@dataclass(frozen=True)
class Row:
    cells: dict[str, str]

    @property
    def commands(self) -> list[str]:
        return re.findall(r"`([^`]+)`", self.cells["command"])

    @property
    def results_files(self) -> list[str]:
        return re.findall(r"`([^`]+)`", self.cells["results file"])


def split_row(line: str) -> list[str]:
    """A Markdown table row's cells (a ``|`` inside backticks is text, not a border)."""
    cells, current, in_code = [], "", False
    for char in line.strip()[1:-1]:
        if char == "`":
            in_code = not in_code
        if char == "|" and not in_code:
            cells.append(current.strip())
            current = ""
        else:
            current += char
    cells.append(current.strip())
    return cells


def results_table(text: str, columns: tuple[str, ...] = COLUMNS) -> list[Row]:
    """The rows of the table under a ``## Results`` heading (README), or of a page's first table (the Results page)."""
    section = text.split("\n## Results\n", 1)[1].split("\n## ", 1)[0] if "\n## Results\n" in text else text
    lines = [line for line in section.splitlines() if line.startswith("|")]
    header = tuple(split_row(lines[0]))
    assert header == columns, f"the Results table has the columns {header}, expected {columns}"
    return [Row(dict(zip(columns, split_row(line), strict=True))) for line in lines[2:]]


def console_scripts() -> set[str]:
    return {entry.name for entry in distribution("sb3-dcqn").entry_points if entry.group == "console_scripts"}


def script_of(command: str) -> str:
    """The program a command runs: a file of the repository (``benchmarks/x.py``) or a console script."""
    words = [word for word in command.split() if not re.match(r"^[A-Z_]+=", word)]  # environment variables apart
    files = [word for word in words if word.endswith(".py")]
    if files:
        return files[0]
    assert words, f"no program in {command!r}"
    return words[0].removeprefix(".venv/bin/")


ROWS = results_table(RESULTS.read_text())
HEADLINE_COLUMNS = ("measure", "figure", "memory", "results file")
HEADLINES = results_table(README.read_text(), HEADLINE_COLUMNS)


def test_readme_has_a_results_table_with_rows() -> None:
    assert len(ROWS) >= 20


@pytest.mark.parametrize("row", ROWS, ids=[row.cells["measure"][:60] for row in ROWS])
def test_every_figure_names_its_command_machine_memory_and_results_file(row: Row) -> None:
    assert row.cells["figure"], "a row without a figure"
    assert row.cells["memory"] in MEMORY, f"memory must be one of {sorted(MEMORY)}, got {row.cells['memory']!r}"
    assert row.cells["machine"] in CPU_SPELLINGS, f"machine must be one of {sorted(CPU_SPELLINGS)}"
    assert row.commands, "a figure without the command that made it"
    assert row.results_files, "a figure without its results file"
    scripts = {script_of(command) for command in row.commands}
    for script in scripts:
        assert script in console_scripts() or (ROOT / script).is_file(), f"the command runs {script}, which is missing"
    for name in row.results_files:
        path = ROOT / name
        assert path.is_file(), f"results file {name} does not exist"
        text = path.read_text()
        written_by = re.findall(r"Command: `(?:[A-Z_]+=\S+ )?(?:python |pytest )?([^\s`]+)", text)
        benchmark_scripts = {s for s in scripts if s.startswith("benchmarks/")}
        if written_by and benchmark_scripts:
            assert set(written_by) & benchmark_scripts, f"{name} was written by {written_by}, not by {scripts}"
        for command in row.commands:
            if script_of(command).startswith("benchmarks/"):
                # The file the command writes today: its --out, else the script's own name
                out = re.search(r"--out (\S+)", command)
                expected = out.group(1) if out else f"benchmarks/results/{Path(script_of(command)).stem}.md"
                assert expected == name, f"{command!r} writes {expected}, not {name}"
        machine = re.search(r"Machine: (.*)", text)
        if machine is not None:
            spellings = CPU_SPELLINGS[row.cells["machine"]]
            assert any(s in machine.group(1) for s in spellings), f"{name} was measured on: {machine.group(1)}"


def test_the_table_parser_sees_a_missing_command_and_a_pipe_inside_code() -> None:
    text = (
        "intro\n\n## Results\n\n| " + " | ".join(COLUMNS) + " |\n|---|---|---|---|---|---|\n"
        "| a | 1 | no | x86_64 | `benchmarks/results/scale.md` |  |\n"
        "| b | 2 | no | x86_64 | `benchmarks/results/scale.md` | `python benchmarks/scale.py --x 'a|b'` |\n"
        "\n## Layout\n"
    )
    first, second = results_table(text)
    assert first.commands == [] and second.commands == ["python benchmarks/scale.py --x 'a|b'"]
    assert script_of(second.commands[0]) == "benchmarks/scale.py"
    assert script_of("SOAK_REPORT=x.md pytest -m slow -s tests/test_soak.py") == "tests/test_soak.py"
    assert script_of(".venv/bin/dcqn-campusnav") == "dcqn-campusnav"


def test_readmes_headline_figures_come_from_the_results_pages_files() -> None:
    assert 3 <= len(HEADLINES) <= 10, "README shows a handful of headline rows"
    files = {name for row in ROWS for name in row.results_files}
    for row in HEADLINES:
        assert row.results_files, f"README's row {row.cells['measure']!r} names no results file"
        for name in row.results_files:
            assert (ROOT / name).is_file() and name in files, f"README quotes {name}, not a file of docs/results.md"
