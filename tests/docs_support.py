"""What the docs' tests share: the built site (one Sphinx build per test module, warnings as errors) and the code
blocks of the guides and README.md.

``DOCS_HTML`` names a site already built with warnings as errors (CI's ``.ci/run`` builds it once, and its
integration stage opens it in a browser); without it the first test that asks builds one for the whole session, in
the folder above pytest's worker folders, under a file lock: test files run in two worker processes, and two builds
at once would write the same generated API pages (``docs/api/generated``) together.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
# The pages whose code blocks are the user's: every Markdown page of the docs, and README.md
PAGES = [*sorted(DOCS.rglob("*.md")), ROOT / "README.md"]
BUILD_SECONDS = 900  # a build on a loaded 2-core machine takes well under a minute; this is a hang, not a slow build


def build_docs(session_temp: Path) -> Path:
    """
    The HTML site built with warnings as errors (once per test session), its folder; the build's own output on
    failure.

    :param session_temp: The folder all of the session's workers share (:func:`session_folder`)
    """
    from filelock import FileLock

    prebuilt = os.environ.get("DOCS_HTML")
    if prebuilt:
        return Path(prebuilt)
    out, built = session_temp / "docs-html", session_temp / "docs-html.built"
    with FileLock(str(session_temp / "docs-html.lock")):
        if not built.is_file():
            command = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-E", "-b", "html"]
            command += ["-d", str(session_temp / "docs-doctrees"), str(DOCS), str(out)]
            env = {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
            result = subprocess.run(command, capture_output=True, text=True, timeout=BUILD_SECONDS, env=env)
            assert result.returncode == 0, f"the docs do not build with warnings as errors:\n{result.stderr[-6000:]}"
            built.touch()
    return out


def session_folder(base_temp: Path) -> Path:
    """The folder every worker of this test session shares: pytest-xdist gives each worker a folder of its own
    inside the session's; without workers the session's own folder (its parent is shared by past sessions)."""
    return base_temp.parent if os.environ.get("PYTEST_XDIST_WORKER") else base_temp


@dataclass(frozen=True)
class CodeBlock:
    """A fenced code block of a page: its language, its text, where it starts, and whether it is shown, not run."""

    page: Path
    line: int
    language: str
    text: str
    no_run: bool

    @property
    def name(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"


_FENCE = re.compile(r"^(\s*)```(\{code-block\}\s*)?(\w+)?\s*$")


def code_blocks(page: Path) -> list[CodeBlock]:
    """The fenced blocks of a Markdown page (```python, ```bash, or MyST's ```{code-block} python with options)."""
    blocks: list[CodeBlock] = []
    lines = page.read_text().splitlines()
    index = 0
    while index < len(lines):
        fence = _FENCE.match(lines[index])
        if fence is None or fence.group(3) is None:
            index += 1
            continue
        indent, start = fence.group(1), index + 1
        body: list[str] = []
        no_run = False
        index += 1
        while index < len(lines) and lines[index].strip() != "```":
            line = lines[index][len(indent) :] if lines[index].startswith(indent) else lines[index].lstrip()
            if line.startswith(":") and not body:  # a MyST directive option (":class: no-run")
                no_run = no_run or bool(re.match(r":class:.*\bno-run\b", line))
            else:
                body.append(line)
            index += 1
        blocks.append(CodeBlock(page, start, fence.group(3), "\n".join(body).strip("\n") + "\n", no_run))
        index += 1
    return blocks


def all_blocks(language: str) -> list[CodeBlock]:
    return [block for page in PAGES for block in code_blocks(page) if block.language == language]
