"""Refused inputs that carry what was refused and how to fix it as values, not only as text.

A :class:`Refusal` (an error or a warning) holds the setting that was given (``given``: a :class:`Setting`, e.g.
``coords='lonlat'``), what is wrong (``reason``), the setting that fixes it (``fix``, e.g. ``coords='projected'``) and
the advice around it (``advice``). ``reason`` and ``advice`` are templates whose ``{given}`` and ``{fix}`` name the
settings: ``str()`` names them as this package's keyword arguments, and a caller with other words for them (the
command line's flags: ``--map-coords projected``) names them its own way with :meth:`Refusal.say`, so that it never
edits the text::

    try:
        import_networkx(graph, coords="lonlat")
    except CoordinatesError as error:
        print(error.say(lambda setting: f"--map-coords {setting.value}"))
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

__all__ = ["Refusal", "RefusedInput", "Setting"]


@dataclass(frozen=True)
class Setting:
    """
    A keyword argument and its value: one that was given, or one that fixes a refused input.

    :param keyword: The argument's name, e.g. ``"coords"``
    :param value: Its value, e.g. ``"projected"``
    :param note: Said after it in this package's words, e.g. ``"the env's map_coords"``
    """

    keyword: str
    value: Any
    note: str = ""

    def __str__(self) -> str:
        return f"{self.keyword}={self.value!r}" + (f" ({self.note})" if self.note else "")


class Refusal(Exception):
    """
    What an error or a warning refused, as values (see the module docstring); mixed into the exception class the
    caller expects (``ValueError``, ``KeyError``, ``UserWarning``).

    :ivar where: What was being read or done (a file, a schedule's event), or ``""``
    :ivar reason: What is wrong, a template that may name ``{given}``
    :ivar advice: How to fix it, a template that may name ``{fix}`` (``""``: none)
    :ivar given: The setting that led to the refusal, if one did
    :ivar fix: The setting that fixes it, if one does
    :ivar separator: Between the reason and the advice
    """

    where: str
    reason: str
    advice: str
    given: Setting | None
    fix: Setting | None
    separator: str

    def _refuse(
        self,
        reason: str,
        advice: str = "",
        *,
        given: Setting | None = None,
        fix: Setting | None = None,
        where: str = "",
        separator: str = "; ",
    ) -> str:
        """Keep the values; return the message in this package's words (for the exception's ``args``)."""
        self.reason, self.advice, self.given, self.fix = reason, advice, given, fix
        self.where, self.separator = where, separator
        return self.say()

    def because(self, name: Callable[[Setting], str] = str) -> str:
        """What is wrong, without ``where`` and the advice, the given setting named by ``name``."""
        return self.reason.format(given="" if self.given is None else name(self.given))

    def say(self, name: Callable[[Setting], str] = str, advice: str | None = None, where: str | None = None) -> str:
        """
        The whole message, its settings named by ``name`` (default: as this package's keyword arguments).

        :param advice: Advice of the caller's own instead (e.g. where the fix is no option of the caller's), after
            ``"; "``; ``""``: none
        :param where: What to say it happened in instead of :attr:`where` (``""``: nothing)
        """
        where = self.where if where is None else where
        text = (f"{where}: " if where else "") + self.because(name)
        if advice is not None:
            return f"{text}; {advice}" if advice else text
        if not self.advice:
            return text
        return text + self.separator + self.advice.format(fix="" if self.fix is None else name(self.fix))

    def within(self, where: str) -> Refusal:
        """Say that this refusal happened within ``where`` (e.g. a schedule's event) and return it, to raise again."""
        self.where = f"{where}: {self.where}" if self.where else where
        self.args = (self.say(),)
        return self

    def __str__(self) -> str:
        return self.say()


class RefusedInput(Refusal, ValueError):
    """
    A ``ValueError`` that carries what it refused (:class:`Refusal`).

    :param reason: What is wrong (may name ``{given}``)
    :param advice: How to fix it (may name ``{fix}``)
    :param values: ``given``, ``fix``, ``where`` and ``separator``, as :class:`Refusal` keeps them
    """

    def __init__(self, reason: str, advice: str = "", **values: Any) -> None:
        super().__init__(self._refuse(reason, advice, **values))
