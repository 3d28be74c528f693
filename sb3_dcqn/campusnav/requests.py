"""What a ``dcqn-campusnav`` command line asks for: its flags read once into a frozen :class:`Request`.

The parsed ``argparse.Namespace`` is read here and nowhere else; what is decided later (the levers a run trains with,
the folder it writes to) belongs to the run (:mod:`sb3_dcqn.campusnav.runs`), not to the request. Importing this
module is cheap (no torch, no CampusNav).
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass, fields
from typing import Any

__all__ = ["Request"]


def _tuple(value: Any) -> tuple[Any, ...] | None:
    return None if value is None else tuple(value)


@dataclass(frozen=True)
class Request:
    """
    Every flag of every subcommand (a subcommand's own flags set, the others at their defaults).

    :param command: The subcommand (``demo``, ``train``, ``evaluate``, ``readapt``, ``draw``, ``roads``)
    :param goals: The env's goals (``--goals``; for ``draw --map`` the ``--goal`` drawn, for ``roads --map`` node 0:
        an env on one's own map needs a goal on it, and which one changes neither the map nor its roads)
    :param levers: ``--levers`` as given (``None``: not given, the subcommand's default)
    :param params: ``-params key:value`` overrides, as given (text)
    """

    command: str
    # env and machine
    env: str | None = None
    conf: str | None = None
    map: str | None = None
    map_coords: str | None = None
    encoder: str | None = None
    encoder_weights: str | None = None
    encoder_random_init: bool = False
    render_size: tuple[int, int] | None = None
    threads: int = 1
    device: str | None = None
    verbose: int = 0
    goals: tuple[str, ...] | None = None
    # training
    seed: int = 0
    eval_freq: int = 1_000
    recovery_eval_freq: int = 5
    keep_training: bool = False
    no_progress: bool = False
    force: bool = False
    timesteps: int | None = None
    recovery_budget: int | None = None
    n_closures: int = 2
    n_envs: int | None = None
    no_replay_buffer: bool = False
    out: str | None = None
    levers: tuple[str, ...] | None = None
    default_levers: tuple[str, ...] = ()
    trained_agent: str | None = None
    save_freq: int | None = None
    params: tuple[str, ...] = ()
    # closures
    closures: str | None = None
    close: tuple[tuple[int, int], ...] = ()
    close_random: int | None = None
    close_on_route: tuple[str | int, ...] = ()
    close_at: int | None = None
    # a saved model
    model: str | None = None
    replay_buffer: str | None = None
    in_place: bool = False
    open_map: bool = False
    # goal, start and picture
    goal: str | None = None
    start: int | None = None
    heading: int | None = None
    picture: str | None = None
    size: int = 1000
    node_ids: bool = False
    node: int | None = None

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> Request:
        """The request of a parsed command line (:func:`sb3_dcqn.campusnav.cli.build_parser`)."""
        given = vars(args)
        values = {f.name: given[f.name] for f in fields(cls) if f.name in given and given[f.name] is not None}
        for name in ("render_size", "levers", "default_levers", "params", "close_on_route"):
            if name in values:
                values[name] = _tuple(values[name])
        if "close" in values:
            values["close"] = tuple((int(u), int(v)) for u, v in values["close"])
        if "goals" in values:
            values["goals"] = tuple(values["goals"])
        elif args.command == "draw" and given.get("model") is None and given.get("map") and given.get("goal"):
            values["goals"] = (given["goal"],)  # a map of one's own: the goal drawn is the env's goal
        elif args.command == "roads" and given.get("map"):
            values["goals"] = ("0",)
        return cls(**values)

    @property
    def progress(self) -> bool:
        return not self.no_progress

    @property
    def closure_flags_given(self) -> bool:
        return bool(self.close or self.close_random or self.close_on_route)
