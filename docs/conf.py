"""Sphinx configuration of the sb3-dcqn docs: guides in MyST Markdown, the API reference from the docstrings.

Built with warnings as errors (``python -m sphinx -W --keep-going -b html docs docs/_build/html``, as ``.ci/run``
does). Nothing is fetched at build time: no intersphinx (it downloads other projects' inventories), no remote images.
"""

from __future__ import annotations

import os
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout's packages, also where they are not installed
os.environ.setdefault("MPLBACKEND", "Agg")

import sb3_dcqn  # noqa: E402

project = "sb3-dcqn"
author = "the sb3-dcqn developers"
copyright = "2026, the sb3-dcqn developers"
release = sb3_dcqn.__version__
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.viewcode",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
templates_path = ["_templates"]

# The API reference: one page per module of sb3_dcqn and campusnav_env, every public member in the module that
# defines it (a name re-exported by a package is documented once, where it is defined)
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {
    "members": True,
    "undoc-members": True,
    "show-inheritance": True,
    "ignore-module-all": True,
    "member-order": "bysource",
}
autodoc_typehints = "description"
autodoc_typehints_description_target = "documented_params"
autodoc_class_signature = "separated"
autodoc_preserve_defaults = True
# Docstrings are reST with :param:/:ivar: fields, as SB3's are. No napoleon: it reads a property's first line
# "text: more" as "type: description" (Google style), and ours are prose with colons
add_module_names = False

myst_enable_extensions = ["colon_fence", "deflist"]
myst_heading_anchors = 3

# Furo, the theme of Gymnasium's docs: see docs/index.md ("About these docs") for why
html_theme = "furo"
html_title = f"sb3-dcqn {release}"
html_static_path: list[str] = []
html_show_sourcelink = False

# ------------------------------------------------------------------------------------------------ Markdown docstrings
# The envs' class docstrings are written as Gymnasium writes its envs' (Markdown: "## Observation Space", ```python
# fences, lists right under a paragraph), so that `help(env)` reads well; autodoc reads reST, so they are turned into
# reST here, only where a docstring has a Markdown heading.
_FENCE = re.compile(r"^(\s*)```(\w*)\s*$")
_HEADING = re.compile(r"^#{2,4} (.+)$")
_ITEM = re.compile(r"^[-*] ")


def _markdown_to_rest(lines: list[str]) -> list[str]:
    out: list[str] = []
    in_fence, in_list = False, False
    for line in lines:
        fence = _FENCE.match(line)
        if in_fence:
            if fence:
                in_fence = False
                out.append("")
            else:
                out.append("   " + line if line.strip() else "")
            continue
        if fence:
            in_fence, in_list = True, False
            out += ["", f".. code-block:: {fence.group(2) or 'text'}", ""]
            continue
        heading = _HEADING.match(line)
        if heading:
            in_list = False
            out += ["", f".. rubric:: {heading.group(1)}", ""]
            continue
        if _ITEM.match(line):
            if not in_list and out and out[-1].strip():
                out.append("")  # Markdown lets a list follow its paragraph; reST wants a blank line
            in_list = True
        elif in_list and line.strip() and not line.startswith(" "):
            out.append("")  # the paragraph after a list
            in_list = False
        elif not line.strip():
            in_list = False
        out.append(line)
    return out


def _inherited_from_gymnasium(what: str, name: str, obj: object) -> str | None:
    """The Gymnasium class whose docstring a method without its own inherits (Gymnasium writes them in Markdown)."""
    if what != "method" or getattr(obj, "__doc__", None) is not None:
        return None
    owner_name, _, attribute = name.rpartition(".")
    module_name, _, class_name = owner_name.rpartition(".")
    owner = getattr(sys.modules.get(module_name), class_name, None)
    for base in getattr(owner, "__mro__", ())[1:]:
        method = base.__dict__.get(attribute)
        if method is not None and getattr(method, "__doc__", None):
            return f"{base.__module__}.{base.__qualname__}" if base.__module__.startswith("gymnasium") else None
    return None


def _markdown_docstrings(app: object, what: str, name: str, obj: object, options: object, lines: list[str]) -> None:
    gymnasium_class = _inherited_from_gymnasium(what, name, obj)
    if gymnasium_class is not None:
        attribute = name.rpartition(".")[2]
        lines[:] = [f"As Gymnasium's ``{gymnasium_class}.{attribute}`` (its docstring: ``help``, or Gymnasium's docs)."]
    elif any(_HEADING.match(line) for line in lines):
        lines[:] = _markdown_to_rest(lines)


def _drop_modules_without_source(app: object) -> list[object]:
    """viewcode's index links every module it looked at, also those whose source it found none of (the methods of a
    ``NamedTuple`` claim a module ``namedtuple_<name>``): links to pages never written. Drop those first."""
    modules = getattr(app.env, "_viewcode_modules", {})  # type: ignore[attr-defined]
    for name in [name for name, entry in modules.items() if entry is False]:
        del modules[name]
    return []


def setup(app: object) -> None:
    app.connect("autodoc-process-docstring", _markdown_docstrings)  # type: ignore[attr-defined]
    app.connect("html-collect-pages", _drop_modules_without_source, priority=400)  # type: ignore[attr-defined]
