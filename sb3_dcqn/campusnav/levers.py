"""The re-adaptation levers: the one table of what each lever switches on, in DCQN and in the env.

Each lever is off in DCQN's and CampusNav's defaults (the paper's algorithm). A run takes any combination of them, as a
tuple of their names (``("revision", "blocked")``: the demo's); the command line's ``--levers`` and the closure
benchmarks' :class:`LeverSet` rows read this table, so an option is written once. Importing this module is cheap (no
torch, no CampusNav).

Levers that work on DCQN's own replay buffers cannot run with another ``replay_buffer_class``
(``needs_own_replay_buffer``). Revision (and the boost it triggers) also runs with hindsight relabelling
(``HerReplayBuffer``, as ``CampusNavGoal-v0``'s entry has: DCQN serves it with ``DCQNHerReplayBuffer``, which revises
stored transitions with the goal left out of the match); prioritised replay does not: a stored transition stands for
every goal it is relabelled with, its TD error for none of them. :func:`check_levers` refuses such a combination,
naming the lever and why; :func:`usable_levers` leaves those levers out (the command line's default levers on a goal
env: the demo's ``revision`` and ``blocked`` both stay).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
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
    "check_levers",
    "lever_callbacks",
    "lever_options",
    "options_text",
    "replay_buffer_conflict",
    "unusable_levers",
    "usable_levers",
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
    :param needs_own_replay_buffer: It works on DCQN's own replay buffer (``DCQNReplayBuffer`` or
        ``DCQNDictReplayBuffer``), so not with another ``replay_buffer_class``
    :param runs_with_her: ... except ``HerReplayBuffer`` (DCQN's HER buffer does it too: experience revision)
    """

    name: str
    dcqn_options: dict[str, Any] = field(default_factory=dict)
    env_options: dict[str, Any] = field(default_factory=dict)
    boost_options: dict[str, Any] | None = None
    needs_own_replay_buffer: bool = False
    runs_with_her: bool = False


LEVERS: dict[str, Lever] = {
    "revision": Lever(
        "experience revision", {"experience_revision": True}, needs_own_replay_buffer=True, runs_with_her=True
    ),
    "blocked": Lever("blocked-action target", {"blocked_action_target": True}),
    "per": Lever("prioritised replay", {"prioritized_replay": True}, needs_own_replay_buffer=True),
    "visible": Lever("visible closures", env_options={"visible_closures": True}),
    # An SB3 callback, not a DCQN option; alone it cannot be triggered by revisions: longer episodes are the sign
    "boost": Lever("adaptation boost (episode-length trigger)", boost_options={"trigger": "episode_length"}),
    # Triggered by the replay buffer's count of revised transitions
    "boost_on_revision": Lever(
        "adaptation boost (revision trigger)",
        boost_options={"trigger": "revision"},
        needs_own_replay_buffer=True,
        runs_with_her=True,
    ),
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


def replay_buffer_conflict(hyperparams: Mapping[str, Any]) -> str | None:
    """
    Why a lever that needs DCQN's own replay buffer cannot run with these hyperparameters (``None``: it can).

    :param hyperparams: Algorithm keyword arguments (``ZooEntry.hyperparams``), ``replay_buffer_class`` a class
    :return: the reason in words, or ``None`` without ``replay_buffer_class`` or with one of DCQN's own buffers
    """
    buffer_class = hyperparams.get("replay_buffer_class")
    if buffer_class is None:
        return None  # DCQN picks its own buffer
    from sb3_dcqn.buffers import DCQNDictReplayBuffer, DCQNReplayBuffer

    name = getattr(buffer_class, "__name__", repr(buffer_class))
    if _is_her(buffer_class):
        return (
            f"it needs DCQN's own replay buffer, and replay_buffer_class={name} relabels goals in hindsight: a stored "
            "transition stands for every goal it is relabelled with, so its TD error is no single experience's to "
            "prioritise"
        )
    if isinstance(buffer_class, type) and issubclass(buffer_class, (DCQNReplayBuffer, DCQNDictReplayBuffer)):
        return None
    return f"it needs DCQN's own replay buffer (DCQNReplayBuffer or DCQNDictReplayBuffer), not {name}"


def unusable_levers(levers: Sequence[str], hyperparams: Mapping[str, Any]) -> dict[str, str]:
    """
    The levers of a combination that cannot run with an entry's hyperparameters, each with why.

    :param levers: Lever names (keys of :data:`LEVERS`)
    :param hyperparams: Algorithm keyword arguments (``ZooEntry.hyperparams``)
    :return: lever name -> the reason, in the order of ``levers`` (empty: all can run)
    """
    lever_options(levers)  # unknown names fail here
    conflict = replay_buffer_conflict(hyperparams)
    if conflict is None:
        return {}
    her = _is_her(hyperparams.get("replay_buffer_class"))
    return {
        name: conflict
        for name in levers
        if LEVERS[name].needs_own_replay_buffer and not (her and LEVERS[name].runs_with_her)
    }


def _is_her(buffer_class: Any) -> bool:
    from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

    return isinstance(buffer_class, type) and issubclass(buffer_class, HerReplayBuffer)


def usable_levers(levers: Sequence[str], hyperparams: Mapping[str, Any]) -> tuple[tuple[str, ...], dict[str, str]]:
    """
    The levers of a combination that can run with an entry's hyperparameters, and those left out.

    :param levers: Lever names (keys of :data:`LEVERS`)
    :param hyperparams: Algorithm keyword arguments (``ZooEntry.hyperparams``)
    :return: ``(usable, left_out)``: the usable names in the order of ``levers``, and lever name -> why
    """
    left_out = unusable_levers(levers, hyperparams)
    return tuple(name for name in levers if name not in left_out), left_out


def check_levers(levers: Sequence[str], hyperparams: Mapping[str, Any]) -> None:
    """
    Check that every lever of a combination can run with an entry's hyperparameters.

    :param levers: Lever names (keys of :data:`LEVERS`)
    :param hyperparams: Algorithm keyword arguments (``ZooEntry.hyperparams``)
    :raises KeyError: on an unknown lever
    :raises ValueError: naming the first lever that cannot run, and why
    """
    for name, why in unusable_levers(levers, hyperparams).items():
        raise ValueError(f"lever {name!r} ({LEVERS[name].name}) cannot run here: {why}")


def with_levers(entry: ZooEntry, levers: Sequence[str]) -> ZooEntry:
    """
    A zoo entry with the levers' DCQN options added to its hyperparameters and their env options to its
    ``env_kwargs``.

    :raises ValueError: if a lever cannot run with the entry's replay buffer (:func:`check_levers`)
    """
    check_levers(levers, entry.hyperparams)
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
