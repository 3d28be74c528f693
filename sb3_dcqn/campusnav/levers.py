"""The re-adaptation levers: the one table of what each lever switches on, in DCQN and in the env.

Each lever is off in DCQN's and CampusNav's defaults (the paper's algorithm). A run takes any combination of them, as a
tuple of their names (``("revision", "blocked")``: the demo's); the command line's ``--levers`` and the closure
benchmarks' :class:`LeverSet` rows read this table, so an option is written once. Importing this module is cheap (no
torch, no CampusNav).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stable_baselines3.common.callbacks import BaseCallback

    from sb3_dcqn.zoo import ZooEntry

__all__ = [
    "DEMO_LEVERS",
    "LEVERS",
    "Lever",
    "LeverSet",
    "lever_callbacks",
    "lever_options",
    "options_text",
    "with_levers",
]


@dataclass(frozen=True)
class Lever:
    """
    A re-adaptation lever.

    :param name: What it is, in words (tables, help)
    :param dcqn_options: DCQN keyword arguments it sets
    :param env_options: Env keyword arguments it sets
    :param boost_options: Keyword arguments of an :class:`~sb3_dcqn.adaptation_boost.AdaptationBoost` callback it
        adds to training (``None``: none)
    """

    name: str
    dcqn_options: dict[str, Any] = field(default_factory=dict)
    env_options: dict[str, Any] = field(default_factory=dict)
    boost_options: dict[str, Any] | None = None


LEVERS: dict[str, Lever] = {
    "revision": Lever("experience revision", {"experience_revision": True}),
    "blocked": Lever("blocked-action target", {"blocked_action_target": True}),
    "per": Lever("prioritised replay", {"prioritized_replay": True}),
    "visible": Lever("visible closures", env_options={"visible_closures": True}),
    # An SB3 callback, not a DCQN option; alone it cannot be triggered by revisions: longer episodes are the sign
    "boost": Lever("adaptation boost (episode-length trigger)", boost_options={"trigger": "episode_length"}),
    "boost_on_revision": Lever("adaptation boost (revision trigger)", boost_options={"trigger": "revision"}),
}
# The demo's: the levers that re-adapted fastest together in benchmarks/closures_one_at_a_time.py (median 8 episodes
# per closure over 3 seeds, 8 of 9 closures within 50 episodes; with prioritised replay added: 32, 5 of 9)
DEMO_LEVERS = ("revision", "blocked")


def lever_options(levers: Sequence[str]) -> tuple[dict[str, Any], dict[str, Any]]:
    """
    The DCQN options and env options of a combination of levers.

    :param levers: Lever names (keys of :data:`LEVERS`)
    :return: ``(dcqn_options, env_options)``, in the order of ``levers``
    :raises KeyError: on an unknown lever, naming it and the known ones
    """
    dcqn_options: dict[str, Any] = {}
    env_options: dict[str, Any] = {}
    for name in levers:
        if name not in LEVERS:
            raise KeyError(f"unknown lever {name!r} (levers: {', '.join(LEVERS)})")
        dcqn_options.update(LEVERS[name].dcqn_options)
        env_options.update(LEVERS[name].env_options)
    return dcqn_options, env_options


def lever_callbacks(levers: Sequence[str]) -> list[BaseCallback]:
    """
    The training callbacks of a combination of levers (the adaptation boost's), new objects for one run.

    :param levers: Lever names (keys of :data:`LEVERS`)
    :return: the callbacks, in the order of ``levers``
    """
    lever_options(levers)  # unknown names fail here
    boosts = [options for name in levers if (options := LEVERS[name].boost_options) is not None]
    if not boosts:
        return []
    from sb3_dcqn.adaptation_boost import AdaptationBoost

    return [AdaptationBoost(**options) for options in boosts]


def options_text(levers: Sequence[str]) -> str:
    """A combination's options as the results files write them: ``"experience_revision=True, ..."`` or
    ``"as shipped"``."""
    dcqn_options, env_options = lever_options(levers)
    words = [f"{key}={value}" for key, value in {**dcqn_options, **env_options}.items()]
    for name in levers:
        if (boost := LEVERS[name].boost_options) is not None:
            words.append("callback AdaptationBoost(" + ", ".join(f"{k}={v!r}" for k, v in boost.items()) + ")")
    return ", ".join(words) or "as shipped"


def with_levers(entry: ZooEntry, levers: Sequence[str]) -> ZooEntry:
    """A zoo entry with the levers' DCQN options added to its hyperparameters and their env options to its
    ``env_kwargs``."""
    dcqn_options, env_options = lever_options(levers)
    return replace(
        entry, hyperparams={**entry.hyperparams, **dcqn_options}, env_kwargs={**entry.env_kwargs, **env_options}
    )


@dataclass(frozen=True)
class LeverSet:
    """
    A named combination of levers (a row of the closure benchmarks).

    :param name: Name in tables
    :param levers: Lever names (keys of :data:`LEVERS`); none: DCQN as shipped
    """

    name: str
    levers: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        lever_options(self.levers)  # unknown names fail here, when the table is written

    def options_text(self) -> str:
        return options_text(self.levers)
