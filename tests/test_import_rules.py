"""Which module may import which: the algorithm package stands on SB3 alone, and CampusNav's imports run down its flow.

Read from the source (every ``import`` statement, those inside functions and ``TYPE_CHECKING`` blocks included), so a
lazy import against the rules is caught as well as a top-level one.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# sb3_dcqn's algorithm modules work on any Gymnasium env with SB3 alone (as stable_baselines3/dqn does)
ALGORITHM_MODULES = (
    "dcqn",
    "policies",
    "replay/__init__",
    "replay/base",
    "replay/combine",
    "replay/count_bonus",
    "replay/feedback",
    "replay/her",
    "replay/lean",
    "replay/n_step",
    "replay/prioritized",
    "replay/revision",
    "observation_table",
    "route_memory/__init__",
    "route_memory/layer",
    "route_memory/memory",
    "place_recognition",
    "place_frame",
    "fusion",
    "targets",
    "adaptation_boost",
    "zoo_files",
    "zoo_entry",
    "zoo",
)
ALGORITHM_DEPENDENCIES = {"stable_baselines3", "torch", "gymnasium", "numpy"}
# The zoo's hyperparameter files are YAML, their strings read by rl_zoo3's own code where that optional extra is
# installed (lazily: the entry schema must read without it); the zoo glue also drives the RL Zoo and its plots
EXTRA_DEPENDENCIES = {
    "zoo_files": {"yaml", "rl_zoo3"},
    "zoo_entry": {"yaml"},
    "zoo": {"yaml", "rl_zoo3", "matplotlib"},
}

# CampusNav's stages, top to bottom: a module imports from its own stage and the stages above it, never below
STAGES = (
    ("maps", ("maps/",)),
    ("rendering", ("rendering/",)),
    ("features", ("features/",)),
    ("env", ("env.py", "goal_env.py", "city_env.py", "registration.py", "closures.py", "wrappers.py")),
    ("evaluation", ("route_evaluation.py", "optimal_values.py", "recovery.py")),
    ("callbacks/figures", ("callbacks.py", "figures.py")),
)
# Helpers every stage may use (atomic writes), and the package's front door (which imports every stage)
ANY_STAGE = ("atomic_files.py",)


def imported_modules(path: Path) -> set[str]:
    """Every module a source file of the tree imports."""
    return modules_imported_by(path.read_text(), package=path.relative_to(ROOT).parts[:-1])


def modules_imported_by(source: str, package: tuple[str, ...]) -> set[str]:
    """Every module some source imports, relative imports resolved against its package."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = ".".join(package[: len(package) - node.level + 1]) if node.level else ""
            module = ".".join(part for part in (base, node.module or "") if part)
            names.add(module)
            # `from package import module` imports the module
            names.update(f"{module}.{alias.name}" for alias in node.names)
    return names


def stage_of(relative: str) -> int | None:
    """The stage of a path inside campusnav_env (``None`` for the helpers and ``__init__``)."""
    if relative in ANY_STAGE or relative.endswith("__init__.py"):
        return None
    for index, (_, prefixes) in enumerate(STAGES):
        if any(relative == prefix or relative.startswith(prefix) for prefix in prefixes if prefix.endswith("/")):
            return index
        if relative in prefixes:
            return index
    raise AssertionError(f"campusnav_env/{relative} belongs to no stage: add it to STAGES in this test")


def module_stage(module: str) -> int | None:
    """The stage of an imported ``campusnav_env`` module (``None``: the package itself or a helper)."""
    parts = module.split(".")[1:]
    candidates = [ROOT / "campusnav_env" / Path(*parts[:n]) for n in range(len(parts), 0, -1)]
    for candidate in candidates:
        for path in (candidate.with_suffix(".py"), candidate / "__init__.py"):
            if path.is_file():
                return stage_of(path.relative_to(ROOT / "campusnav_env").as_posix())
    return None


@pytest.mark.parametrize("name", ALGORITHM_MODULES)
def test_the_algorithm_modules_import_only_sb3_torch_gymnasium_and_numpy(name: str) -> None:
    allowed = ALGORITHM_DEPENDENCIES | EXTRA_DEPENDENCIES.get(name, set())
    outside = set()
    for module in imported_modules(ROOT / "sb3_dcqn" / f"{name}.py"):
        top = module.split(".")[0]
        if top in sys.stdlib_module_names or top in allowed or top == "__future__":
            continue
        if top == "sb3_dcqn" and module.split(".")[1:2] in (
            [],
            *[[other.split("/")[0]] for other in ALGORITHM_MODULES],
        ):
            continue
        outside.add(module)
    assert not outside, f"sb3_dcqn/{name}.py imports {sorted(outside)}: the algorithm package must need SB3 alone"


def test_campusnav_env_never_imports_sb3_dcqn() -> None:
    for path in sorted((ROOT / "campusnav_env").rglob("*.py")):
        offending = sorted(m for m in imported_modules(path) if m.split(".")[0] == "sb3_dcqn")
        assert not offending, f"{path.relative_to(ROOT)} imports {offending}"


def test_campusnav_env_imports_run_down_the_flow() -> None:
    against = []
    for path in sorted((ROOT / "campusnav_env").rglob("*.py")):
        own = stage_of(path.relative_to(ROOT / "campusnav_env").as_posix())
        if own is None:
            continue
        for module in imported_modules(path):
            if module.split(".")[0] != "campusnav_env":
                continue
            theirs = module_stage(module)
            if theirs is not None and theirs > own:
                against.append(f"{path.relative_to(ROOT)} ({STAGES[own][0]}) imports {module} ({STAGES[theirs][0]})")
    assert not against, "imports against maps -> rendering -> features -> env -> evaluation -> callbacks/figures:\n" + (
        "\n".join(against)
    )


def test_the_rule_sees_a_lazy_import_against_the_flow() -> None:
    # The checker itself: an import of the env inside a function of a map module is found and ranked below maps
    source = "def f():\n    from ..env import CampusNavEnv\n    return CampusNavEnv\n"
    modules = modules_imported_by(source, package=("campusnav_env", "maps"))
    assert "campusnav_env.env" in modules
    assert module_stage("campusnav_env.env") == 3 > stage_of("maps/road_graph.py") == 0


def package_modules() -> dict[str, Path]:
    """Every module of the two packages, by dotted name (a package by its ``__init__``)."""
    modules = {}
    for package in ("campusnav_env", "sb3_dcqn"):
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def import_circles(imports: dict[str, set[str]]) -> list[list[str]]:
    """The circles of an import graph: its strongly connected components of more than one module (Tarjan's)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    circles: list[list[str]] = []

    def visit(module: str) -> None:
        index[module] = low[module] = len(index)
        stack.append(module)
        for other in imports[module]:
            if other not in index:
                visit(other)
                low[module] = min(low[module], low[other])
            elif other in stack:
                low[module] = min(low[module], index[other])
        if low[module] == index[module]:
            component = [stack.pop()]
            while component[-1] != module:
                component.append(stack.pop())
            if len(component) > 1:
                circles.append(sorted(component))

    for module in sorted(imports):
        if module not in index:
            visit(module)
    return circles


def test_the_packages_have_no_import_circles() -> None:
    # Every import counts, those for type hints and those inside functions too: a circle is a circle of knowledge
    modules = package_modules()
    imports = {name: (imported_modules(path) & modules.keys()) - {name} for name, path in modules.items()}
    assert not import_circles(imports), f"import circles: {import_circles(imports)}"


def test_the_circle_rule_finds_a_circle_and_only_circles() -> None:
    assert import_circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert import_circles({"a": {"b"}, "b": set(), "c": {"a", "b"}}) == []
