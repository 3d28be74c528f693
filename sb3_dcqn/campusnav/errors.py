"""How ``dcqn-campusnav`` refuses and reports: bad input (:class:`CommandError`: one line, exit status 2), Ctrl-C
(:class:`Interrupted`: what was saved, exit status 130), notes and library warnings on stderr as one line each, and the
refusals of ``campusnav_env`` (:class:`~campusnav_env.maps.refusals.Refusal`) said with the flags that set what they
name (:func:`said`: ``coords='projected'`` is ``--map-coords projected``), from their values, never by editing their
text. The modules that check the command line's input (the ``*_checks`` modules, :mod:`~sb3_dcqn.campusnav.entries`)
raise these and import nothing else of each other for them.

Importing this module is cheap (no torch, no CampusNav).
"""

from __future__ import annotations

import sys
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from campusnav_env.maps.refusals import Refusal, Setting

__all__ = ["PROG", "CommandError", "Interrupted", "in_flags", "note", "one_line_warning", "said"]

PROG = "dcqn-campusnav"
# campusnav_env's keyword arguments that a flag sets, by name
_FLAGS = {"coords": "--map-coords"}
# What to do instead where a refusal's fix is a keyword argument no flag sets (the command line never forces a closure)
_ADVICE = {"force": "close another road instead"}


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


def in_flags(setting: Setting) -> str:
    """A keyword argument of ``campusnav_env`` as the flag that sets it (``coords='projected'``: ``--map-coords
    projected``), else as it is."""
    flag = _FLAGS.get(setting.keyword)
    return str(setting) if flag is None else f"{flag} {setting.value}"


def said(refusal: Refusal, where: str | None = None) -> str:
    """
    A refusal of ``campusnav_env`` in the command line's words: the settings it names as flags (:func:`in_flags`), and
    where its fix is no flag, the command line's own advice.

    :param where: What to say it happened in instead of the refusal's own ``where`` (``""``: nothing)
    """
    fix = refusal.fix
    advice = _ADVICE.get(fix.keyword, "") if fix is not None and fix.keyword not in _FLAGS else None
    return refusal.say(in_flags, advice=advice, where=where)
