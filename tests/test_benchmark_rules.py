"""How the benchmarks are put together: a script (a module with a ``__main__`` block) imports shared modules only,
never another script; no module of the package edits ``sys.path``; and ``python benchmarks/NAME.py`` still finds the
package, from any folder.

Read from the source (every ``import`` statement, those inside functions included), so a lazy import is caught as
well as a top-level one.
"""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BENCHMARKS = ROOT / "benchmarks"
MODULES = sorted(path for path in BENCHMARKS.rglob("*.py") if "results" not in path.parts)


def module_name(path: Path) -> str:
    """``benchmarks.x`` (``benchmarks.scale_stages.replay``) of a file of the package."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def is_script(tree: ast.Module) -> bool:
    """Whether a module runs as a script: a top-level ``if __name__ == "__main__":``."""
    for node in tree.body:
        if isinstance(node, ast.If) and isinstance(node.test, ast.Compare):
            names = [node.test.left, *node.test.comparators]
            if any(isinstance(n, ast.Name) and n.id == "__name__" for n in names):
                return True
    return False


def benchmark_imports(tree: ast.Module) -> set[str]:
    """The modules of the package a source imports: ``import benchmarks.x``, ``from benchmarks.x import y`` (as
    ``benchmarks.x``, and ``benchmarks.x.y`` in case ``y`` is a module), ``from benchmarks import x``."""
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names if alias.name.startswith("benchmarks.")}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "benchmarks":
            names.add(node.module)
            names |= {f"{node.module}.{alias.name}" for alias in node.names}
    return names


def touches_sys_path(tree: ast.Module) -> list[int]:
    """The lines that read or change ``sys.path``."""
    return [
        node.lineno
        for node in ast.walk(tree)
        if isinstance(node, ast.Attribute)
        and node.attr == "path"
        and isinstance(node.value, ast.Name)
        and node.value.id == "sys"
    ]


TREES = {module_name(path): ast.parse(path.read_text()) for path in MODULES}
SCRIPTS = {name for name, tree in TREES.items() if is_script(tree)}


def test_the_package_has_scripts_and_shared_modules() -> None:
    # The rules below read which modules are scripts: make sure that reading sees both kinds
    assert {"benchmarks.closures_eleven", "benchmarks.scale", "benchmarks.scale_replay"} <= SCRIPTS
    shared = set(TREES) - SCRIPTS
    assert {"benchmarks.report", "benchmarks.workers", "benchmarks.closure_runs", "benchmarks.campusnav_runs"} <= shared
    assert "benchmarks.scale_stages.replay" in shared


def test_no_benchmark_script_imports_another() -> None:
    offenders = {
        name: sorted(benchmark_imports(tree) & SCRIPTS)
        for name, tree in TREES.items()
        if benchmark_imports(tree) & SCRIPTS
    }
    assert offenders == {}, f"scripts importing scripts (move what they share into a shared module): {offenders}"


def test_no_benchmark_module_edits_sys_path() -> None:
    offenders = {name: touches_sys_path(tree) for name, tree in TREES.items() if touches_sys_path(tree)}
    assert offenders == {}, f"sys.path in the benchmarks (benchmarks/benchmarks.py finds the package): {offenders}"


def test_the_rules_catch_what_they_forbid() -> None:
    source = (
        "import sys\nsys.path[0] = 'x'\n"
        "from benchmarks.closures_one_at_a_time import busiest_closures\n"
        "from benchmarks import scale\n"
        "if __name__ == '__main__':\n    pass\n"
    )
    tree = ast.parse(source)
    assert is_script(tree) and touches_sys_path(tree) == [2]
    assert benchmark_imports(tree) & SCRIPTS == {"benchmarks.closures_one_at_a_time", "benchmarks.scale"}
    assert not is_script(ast.parse("def main() -> None:\n    pass\n"))


def test_run_as_files_every_module_loads_from_the_package_folder(tmp_path: Path) -> None:
    # `python benchmarks/NAME.py` puts the benchmarks folder first on sys.path, not the repository root: a process
    # with that folder as its current directory (sys.path[0] == "") imports every module of the package as a file
    # run does, and each comes from the package's folder under its package name
    names = sorted(name for name in TREES if name not in {"benchmarks", "benchmarks.benchmarks"})
    program = (
        "import importlib, sys\n"
        f"names = {names!r}\n"
        "for name in names:\n"
        "    module = importlib.import_module(name)\n"
        "    print(name, module.__file__)\n"
        "print('package', sys.modules['benchmarks'].__path__)\n"
    )
    env = {**os.environ, "PYTHONPATH": "", "MPLCONFIGDIR": str(tmp_path)}
    result = subprocess.run(
        [sys.executable, "-c", program], cwd=BENCHMARKS, env=env, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stderr
    lines = dict(line.split(" ", 1) for line in result.stdout.splitlines())
    assert lines.pop("package") == repr([str(BENCHMARKS)])
    for name in names:
        assert Path(lines[name]).resolve().is_relative_to(BENCHMARKS), name
