"""The docs a user reads (``docs/``, README.md) cannot drift from the code.

- The site builds with Sphinx with warnings as errors, fetching nothing (no page of it loads anything from the web).
- Every internal link and anchor of the built HTML resolves.
- The API reference documents every public class and function of ``sb3_dcqn`` and ``campusnav_env``, in the module
  that defines it.
- Every Python code block of the guides and of README.md runs as a script file of its own, on a small budget
  (``tests/docs_blocks_prelude.py``: ``learn()`` capped at ``DOCS_MAX_STEPS`` env steps, CampusNav on the cheap
  ``pixels`` encoder); a block marked ``:class: no-run`` is shown, not run, and must say why.
- Every ``dcqn-campusnav`` command of their shell blocks parses with the command line's own parser.
- README.md stays a page long and opens with the two commands, verbatim.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest
from docs_support import DOCS, ROOT, CodeBlock, all_blocks, build_docs, session_folder

BLOCK_SECONDS = 600  # a block on the small budget takes seconds (a cold feature cache: a minute); this is a hang
MAIN_JOB = "python3 -m venv .venv && .venv/bin/pip install torch==2.13.0 -e . && .venv/bin/dcqn-campusnav"
TEST_COMMAND = (
    'python3 -m venv .venv && .venv/bin/pip install torch==2.13.0 -e ".[test]" && .venv/bin/python -m pytest -q'
)


@pytest.fixture(scope="module")
def site(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return build_docs(session_folder(tmp_path_factory.getbasetemp()))


# ------------------------------------------------------------------------------------------------ the built HTML
class _Page(HTMLParser):
    """The ids a page defines and the links and resources it points at."""

    def __init__(self) -> None:
        super().__init__()
        self.ids: set[str] = set()
        self.links: list[str] = []
        self.resources: list[str] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        values = {name: value for name, value in attrs if value is not None}
        self.ids.update(values[name] for name in ("id", "name") if name in values)
        if "href" in values:
            (self.resources if tag == "link" else self.links).append(values["href"])
        if "src" in values:
            self.resources.append(values["src"])


def parsed(page: Path) -> _Page:
    parser = _Page()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser


def test_every_internal_link_and_anchor_of_the_site_resolves(site: Path) -> None:
    pages = {page.resolve(): parsed(page) for page in site.rglob("*.html")}
    assert len(pages) > 50, f"only {len(pages)} pages built"
    broken: list[str] = []
    for path, page in pages.items():
        for link in page.links + page.resources:
            parts = urlsplit(link)
            if parts.scheme or link.startswith("//"):
                continue  # an external link: not this site's to resolve
            target = (path.parent / unquote(parts.path)).resolve() if parts.path else path
            if target.is_dir():
                target = target / "index.html"
            if not target.is_file():
                broken.append(f"{path.relative_to(site)}: {link} (no file)")
            elif parts.fragment and target.suffix == ".html" and parts.fragment not in pages[target].ids:
                broken.append(f"{path.relative_to(site)}: {link} (no anchor #{parts.fragment})")
    assert not broken, f"{len(broken)} broken internal links:\n" + "\n".join(broken[:40])


def test_no_page_loads_anything_from_the_web(site: Path) -> None:
    remote = [
        f"{page.relative_to(site)}: {resource}"
        for page in site.rglob("*.html")
        for resource in parsed(page).resources
        if urlsplit(resource).scheme in ("http", "https") or resource.startswith("//")
    ]
    assert not remote, "pages load remote resources (the docs must work offline):\n" + "\n".join(remote[:20])


def test_every_api_name_a_guide_names_resolves(site: Path) -> None:
    # An unresolved {py:class} role renders as code without a link (Sphinx warns only when nitpicky)
    unresolved: list[str] = []
    for page in [*site.glob("*.html"), *(site / "guide").glob("*.html")]:
        html = page.read_text(encoding="utf-8")
        for match in re.finditer(r'<code class="xref py[^"]*"><span class="pre">([^<]*)', html):
            opening = html[html.rfind("<", 0, match.start() - 1) : match.start()]
            if not opening.startswith("<a "):
                unresolved.append(f"{page.relative_to(site)}: {match.group(1)}")
    assert not unresolved, "API names the guides name that resolve to no page: " + ", ".join(unresolved)


PUBLIC_MEMBERS = """
import importlib, inspect, json, pkgutil
members = {}
for package_name in ("sb3_dcqn", "campusnav_env"):
    package = importlib.import_module(package_name)
    names = [package_name] + [info.name for info in pkgutil.walk_packages(package.__path__, f"{package_name}.")]
    for name in names:
        if any(part.startswith("_") for part in name.split(".")):
            continue
        module = importlib.import_module(name)
        members[name] = [
            member
            for member, value in vars(module).items()
            if not member.startswith("_")
            and (inspect.isclass(value) or inspect.isfunction(value))
            and getattr(value, "__module__", None) == name
        ]
print(json.dumps(members))
"""


def public_members() -> dict[str, list[str]]:
    """
    Every public module of the two packages and the public classes and functions it defines, as a fresh import
    defines them. In a fresh interpreter: a module's names built on first access (the replay combinations of
    :mod:`sb3_dcqn.replay`, documented by their naming rule) are there only after some other test asked for them.
    """
    done = subprocess.run([sys.executable, "-c", PUBLIC_MEMBERS], capture_output=True, text=True, check=True, cwd=ROOT)
    return json.loads(done.stdout)


def test_the_api_reference_documents_every_public_class_and_function(site: Path) -> None:
    missing: list[str] = []
    for module, names in public_members().items():
        page = site / "api" / "generated" / f"{module}.html"
        if not page.is_file():
            missing.append(f"{module} (no page)")
            continue
        ids = parsed(page).ids
        missing += [f"{module}.{name}" for name in names if f"{module}.{name}" not in ids]
    assert not missing, f"{len(missing)} public names not in the API reference: {', '.join(missing[:30])}"


def test_a_property_reads_as_its_docstring_and_its_type_comes_from_its_annotation(site: Path) -> None:
    # A Google-style reader (napoleon) takes a first line "text: more" for "type: description": the prose then shows
    # as a "Type" field and its words as cross-references (ambiguous ones fail the build on Sphinx 9)
    misread: list[str] = []
    for page in (site / "api" / "generated").glob("*.html"):
        html = page.read_text(encoding="utf-8")
        for match in re.finditer(r'<dl class="py property">\s*<dt class="sig[^"]*" id="([^"]+)"', html):
            following = html.find('<dl class="py ', match.end())
            entry = html[match.end() : following if following > 0 else len(html)]
            if re.search(r'<dt class="field-\w+">Type<', entry):
                misread.append(match.group(1))
    assert not misread, "properties whose docstring is shown as their type: " + ", ".join(misread)


# ------------------------------------------------------------------------------------------------ code blocks
PYTHON_BLOCKS = all_blocks("python")


def test_the_guides_have_python_blocks_to_run() -> None:
    assert len([block for block in PYTHON_BLOCKS if not block.no_run]) >= 8
    for block in PYTHON_BLOCKS:
        if block.no_run:  # shown, not run: the block says why in its first line
            assert block.text.startswith("# "), f"{block.name}: a no-run block says why in its first line"


@pytest.mark.parametrize("block", [b for b in PYTHON_BLOCKS if not b.no_run], ids=lambda block: block.name)
def test_each_python_block_runs_as_a_script(
    block: CodeBlock, tmp_path: Path, shared_cache_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    script = tmp_path / "block.py"
    script.write_text(f"import docs_blocks_prelude  # noqa: F401  (small budgets)\n{block.text}")
    env = {
        **os.environ,
        "PYTHONPATH": os.pathsep.join([str(ROOT / "tests"), str(ROOT), os.environ.get("PYTHONPATH", "")]),
        "CAMPUSNAV_CACHE": str(shared_cache_dir),
        "OMP_NUM_THREADS": "1",
        "MPLBACKEND": "Agg",
    }
    result = subprocess.run(
        [sys.executable, str(script)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=BLOCK_SECONDS
    )
    assert result.returncode == 0, f"{block.name} failed:\n{result.stderr[-4000:]}"


def campusnav_commands(block: CodeBlock) -> list[list[str]]:
    """The ``dcqn-campusnav`` commands of a shell block, as argument lists (continuations joined, variables filled)."""
    text = block.text.replace("\\\n", " ").replace("$EXAMPLES", "/examples")
    commands: list[list[str]] = []
    for line in text.splitlines():
        if "dcqn-campusnav" not in line:
            continue
        words: list[str] = []
        for word in [*shlex.split(line, comments=True), "&&"]:  # commands chained by && or ; split apart
            if word not in ("&&", ";", "|"):
                words.append(word)
                continue
            if words and words[0].removeprefix(".venv/bin/") == "dcqn-campusnav":
                commands.append(words[1:])
            words = []
    return commands


SHELL_COMMANDS = [
    (f"{block.name}:{' '.join(words)[:50]}", words)
    for block in all_blocks("bash")
    for words in campusnav_commands(block)
]


def test_the_guides_show_dcqn_campusnav_commands() -> None:
    assert len(SHELL_COMMANDS) >= 15


@pytest.mark.parametrize("words", [words for _, words in SHELL_COMMANDS], ids=[name for name, _ in SHELL_COMMANDS])
def test_each_dcqn_campusnav_command_of_the_docs_parses(words: list[str], capsys: pytest.CaptureFixture[str]) -> None:
    from sb3_dcqn.campusnav.cli import build_parser

    try:
        build_parser().parse_args(words)
    except SystemExit:
        pytest.fail(f"dcqn-campusnav {' '.join(words)}: {capsys.readouterr().err.strip()}")


# ------------------------------------------------------------------------------------------------ README
def test_readme_is_a_page_long_and_opens_with_the_two_commands() -> None:
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    commands = [block.text.strip() for block in all_blocks("bash") if block.page.name == "README.md"]
    assert commands[:2] == [MAIN_JOB, TEST_COMMAND]
    ci = (ROOT / ".ci" / "run").read_text()  # CI runs the very command README shows (pip quiet there)
    assert TEST_COMMAND.replace("pip install torch", "pip install -q torch") in ci
    for link in re.findall(r"\]\((docs/[^)#]+)", readme):
        assert (ROOT / link).is_file(), f"README links to {link}, which does not exist"


def test_the_docs_ship_their_build_dependencies_in_an_extra() -> None:
    pyproject = (ROOT / "pyproject.toml").read_text()
    test_extra = re.search(r"^test = .*$", pyproject, re.M)
    assert re.search(r'^docs = \[.*"sphinx', pyproject, re.M) and test_extra and "docs" in test_extra[0]
    assert "sphinx.ext.intersphinx" not in (DOCS / "conf.py").read_text()  # it downloads inventories from the web
