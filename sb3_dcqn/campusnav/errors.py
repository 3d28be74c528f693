"""How ``dcqn-campusnav`` reports: bad input (:class:`CommandError`), Ctrl-C (:class:`Interrupted`), notes and warnings.

Each is one line on stderr, written by the command line (:mod:`sb3_dcqn.campusnav.cli`); the modules that check its
input (:mod:`~sb3_dcqn.campusnav.checks`, :mod:`~sb3_dcqn.campusnav.entries`) raise these and import nothing else of
each other for them. Importing this module is cheap.
"""

from __future__ import annotations

import sys
from typing import Any

__all__ = ["PROG", "CommandError", "Interrupted", "note", "one_line_warning"]

PROG = "dcqn-campusnav"


class CommandError(Exception):
    """Bad input to the command line (a flag, a file, a road); the message names it."""


class Interrupted(Exception):
    """Training stopped by Ctrl-C; the message says what was saved and how to go on (the command line exits 130)."""


def note(text: str) -> None:
    """A line on stderr, as the command line's notes are written."""
    print(f"{PROG}: {text}", file=sys.stderr)


def one_line_warning(message: Warning | str, category: type[Warning], *_: Any, **__: Any) -> str:
    """A library's warning as the command line writes its notes (``warnings.formatwarning``): one line, no source."""
    return f"{PROG}: warning: {message}\n"
