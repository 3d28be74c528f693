"""The benchmarks package: scripts run as ``python -m benchmarks.NAME`` and as ``python benchmarks/NAME.py``, one
results folder, one machine line read from the machine, and no import circle among the scripts."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
sys.path.insert(0, str(ROOT))  # the benchmarks package, as `python -m benchmarks.NAME` imports it

from benchmarks import report  # noqa: E402

SCRIPTS = sorted(path for path in BENCHMARKS.glob("*.py") if path.name != "__init__.py")
# Still imports its neighbours as top-level modules (another change is under way there); it runs as a file only
NOT_YET_IN_THE_PACKAGE: set[str] = set()


def package_imports(path: Path) -> set[str]:
    """The benchmark modules a script imports, at the top or inside functions (``from benchmarks.X``, ``from
    benchmarks import X``)."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module == "benchmarks":
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and (node.module or "").startswith("benchmarks."):
            names.add(node.module.split(".")[1])
        elif isinstance(node, ast.Import):
            names |= {alias.name.split(".")[1] for alias in node.names if alias.name.startswith("benchmarks.")}
    return names


def test_no_script_imports_one_that_imports_it_back() -> None:
    graph = {path.stem: package_imports(path) for path in SCRIPTS}
    assert graph["scale"] >= {"scale_stages", "scale_common", "report"}

    def reaches(start: str, target: str, seen: set[str]) -> bool:
        following = graph.get(start, set()) - seen
        return any(name == target or reaches(name, target, seen | {name}) for name in following)

    circles = sorted(name for name in graph if reaches(name, name, set()))
    assert circles == [], f"benchmark scripts in an import circle: {circles}"


def test_the_results_folder_and_the_machine_line_are_defined_once() -> None:
    for path in SCRIPTS:
        if path.name in NOT_YET_IN_THE_PACKAGE | {"report.py"}:
            continue
        text = path.read_text()
        assert "RESULTS_DIR =" not in text, f"{path.name} defines its own RESULTS_DIR (report.RESULTS_DIR is the one)"
        assert '"Machine: ' not in text, f"{path.name} builds its own Machine line (report.machine_line builds it)"
        assert not {"report", "workers", "campusnav_runs", "scale_common"} & _top_level_imports(path), path.name
    assert report.RESULTS_DIR == BENCHMARKS / "results"


def _top_level_imports(path: Path) -> set[str]:
    """Modules a script imports by a bare name (``from report import ...``): a neighbour outside the package."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module)
        elif isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
    return names


def test_the_machine_line_reads_the_cores_and_the_cpu_from_the_machine(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text("processor\t: 0\nmodel name\t: Test   CPU 9000\n\nprocessor\t: 1\nmodel name\t: Test CPU 9000\n")
    monkeypatch.setattr(report, "CPUINFO", cpuinfo)
    monkeypatch.setattr(report.platform, "machine", lambda: "x86_64")
    monkeypatch.setattr(report.os, "cpu_count", lambda: 16)
    monkeypatch.setattr(report.os, "sched_getaffinity", lambda pid: {0, 1}, raising=False)
    line = report.machine_line("2 runs in parallel", torch_threads=4)
    assert line.startswith("Machine: ") and line.endswith(", 4 torch threads; 2 runs in parallel.")
    assert "Test CPU 9000 (x86_64), 2 of 16 cores (shared with other jobs)" in line
    # Every core usable, a quiet machine, words for the threads; no /proc/cpuinfo: what platform knows
    monkeypatch.setattr(report.os, "sched_getaffinity", lambda pid: set(range(16)), raising=False)
    monkeypatch.setattr(report, "CPUINFO", tmp_path / "missing")
    monkeypatch.setattr(report.platform, "processor", lambda: "")
    line = report.machine_line(torch_threads="1 torch thread per run", shared=False)
    assert ", x86_64, 16 cores, 1 torch thread per run; runs one after another in one process." in line


@pytest.mark.parametrize("form", ["module", "file"])
def test_a_script_runs_both_as_a_module_and_as_a_file(form: str, tmp_path: Path) -> None:
    # From elsewhere than the repository root as a file (its folder is then first on sys.path, not the root)
    command = ["-m", "benchmarks.long_routes"] if form == "module" else [str(BENCHMARKS / "long_routes.py")]
    env = {**os.environ, "PYTHONPATH": str(ROOT) if form == "module" else ""}
    result = subprocess.run(
        [sys.executable, *command, "--help"],
        cwd=ROOT if form == "module" else tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert "--rows" in result.stdout and "--max-steps" in result.stdout


def _square(job: int) -> dict[str, int]:
    return {"n": job, "square": job * job, "quick": 0}


def test_the_runs_loop_runs_only_what_the_runs_file_lacks_and_appends_each_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs_file = tmp_path / "runs.jsonl"
    report.append_run(runs_file, {"n": 2, "square": 4, "quick": 0})
    report.append_run(runs_file, {"n": 3, "square": 9, "quick": 1})  # another setting: not one of these runs
    runs = report.run_missing(
        runs_file, [1, 2, 3], _square, key=lambda r: r["n"], settings={"quick": 0}, describe=lambda r: f"n={r['n']}"
    )
    assert [r["n"] for r in runs.records] == [2, 1, 3] and runs.ran == 2
    assert "1 runs already in" in capsys.readouterr().out
    assert [r["n"] for r in report.read_runs(runs_file)] == [2, 3, 1, 3]
    # A second call finds everything done: it runs nothing, and the results keep the machine that measured them
    again = report.run_missing(runs_file, [1, 2, 3], _square, key=lambda r: r["n"], settings={"quick": 0})
    assert again.ran == 0 and len(again.records) == 3
    assert again.invocation_text() == "all read from the runs file."
    (tmp_path / "out.md").write_text("# x\n\nMachine: the one that ran them\n")
    assert again.machine(tmp_path / "out.md", "Machine: this one") == "Machine: the one that ran them"
    assert runs.machine(tmp_path / "out.md", "Machine: this one") == "Machine: this one"
    # Jobs of another shape than their records name their key
    by_job = report.run_missing(
        runs_file, [(4, "x")], lambda job: _square(job[0]), key=lambda r: r["n"], job_key=lambda job: job[0]
    )
    assert by_job.ran == 1 and by_job.records[-1]["square"] == 16


def test_the_runs_loop_runs_jobs_in_worker_processes(tmp_path: Path) -> None:
    runs = report.run_missing(tmp_path / "runs.jsonl", [5, 6], _square, key=lambda r: r["n"], workers=2)
    assert sorted(r["square"] for r in runs.records) == [25, 36]
    assert sorted(r["n"] for r in report.read_runs(tmp_path / "runs.jsonl")) == [5, 6]
