"""The re-adaptation levers: the one table of what each lever switches on, in DCQN and in the env.

Each lever is off in DCQN's and CampusNav's defaults (the paper's algorithm). A run takes any combination of them, as a
tuple of their names (``("revision", "blocked")``: the demo's); the command line's ``--levers`` and the closure
benchmarks' :class:`LeverSet` rows read this table, so an option is written once. Importing this module is cheap (no
torch, no CampusNav).

A lever that is a replay variant (``revision``, ``prioritized``) adds it to the entry's replay buffer class
(:func:`sb3_dcqn.replay.with_variants`: ``HerReplayBuffer`` becomes ``RevisionHerReplayBuffer``, no class
``RevisionDictReplayBuffer``); whether it combines with the entry's buffer, ``n_steps`` and DCQN options is decided
where every combination is (:mod:`sb3_dcqn.replay.combine`). Revision (and the boost it triggers) runs with hindsight
relabelling, as ``CampusNavGoal-v0``'s entry has; prioritized replay does not: a stored transition stands for every
goal it is relabelled with, its TD error for none of them. :func:`check_levers` refuses such a combination, naming
the lever and why; :func:`usable_levers` leaves those levers out (the command line's default levers on a goal env:
the demo's ``revision`` and ``blocked`` both stay).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from stable_baselines3.common.callbacks import BaseCallback

    from sb3_dcqn.zoo_entry import ZooEntry

__all__ = [
    "DEMO_LEVERS",
    "LEVERS",
    "Lever",
    "LeverSet",
    "check_levers",
    "lever_callbacks",
    "lever_options",
    "options_text",
    "replay_buffer_with_levers",
    "replay_variants",
    "unusable_levers",
    "usable_levers",
    "with_levers",
]


@dataclass(frozen=True)
class Lever:
    """
    A re-adaptation lever.

    :param name: What it is, in words (tables, help)
    :param replay_variants: Replay variants it adds to the replay buffer class (:data:`sb3_dcqn.replay.VARIANTS`)
    :param dcqn_options: DCQN keyword arguments it sets
    :param env_options: Env keyword arguments it sets
    :param boost_options: Keyword arguments of an :class:`~sb3_dcqn.adaptation_boost.AdaptationBoost` callback it
        adds to training (``None``: none)
    """

    name: str
    replay_variants: tuple[str, ...] = ()
    dcqn_options: dict[str, Any] = field(default_factory=dict)
    env_options: dict[str, Any] = field(default_factory=dict)
    boost_options: dict[str, Any] | None = None


LEVERS: dict[str, Lever] = {
    "revision": Lever("experience revision", replay_variants=("revision",)),
    "blocked": Lever("blocked-action target", dcqn_options={"blocked_action_target": True}),
    "prioritized": Lever("prioritized replay", replay_variants=("prioritized",)),
    "visible": Lever("visible closures", env_options={"visible_closures": True}),
    # The route memory: a collision removes its road from every goal's remembered routes at once. A layer, not DCQN's
    # own option: an entry with route_memory is built as DCQN wearing it (sb3_dcqn.route_memory.algorithm_class_for)
    "route_memory": Lever(
        "route memory (greedy actions plan, exploration seeks the untried)", dcqn_options={"route_memory": True}
    ),
    # An SB3 callback, not a DCQN option; alone it cannot be triggered by revisions: longer episodes are the sign
    "boost": Lever("adaptation boost (episode-length trigger)", boost_options={"trigger": "episode_length"}),
    # Triggered by the replay buffer's count of revised transitions: it needs revision, and switches it on
    "boost_on_revision": Lever(
        "adaptation boost (revision trigger)", replay_variants=("revision",), boost_options={"trigger": "revision"}
    ),
}
# The demo's: the levers that re-adapted fastest together in benchmarks/closures_one_at_a_time.py (see its results)
DEMO_LEVERS = ("revision", "blocked")


def lever_options(levers: Sequence[str]) -> tuple[dict[str, Any], dict[str, Any]]:
    """
    The DCQN options and env options of a combination of levers (replay variants not included: see
    :func:`with_levers`).

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


def replay_variants(levers: Sequence[str]) -> tuple[str, ...]:
    """The replay variants a combination of levers adds, once each, in the order of ``levers``."""
    lever_options(levers)  # unknown names fail here
    return tuple(dict.fromkeys(v for name in levers for v in LEVERS[name].replay_variants))


def replay_buffer_with_levers(levers: Sequence[str], hyperparams: Mapping[str, Any]) -> type | None:
    """
    The replay buffer class an entry's hyperparameters get with the levers' variants (``None``: none added, the
    entry's own), checked with the entry's ``n_steps`` and the levers' DCQN options (CampusNav's observations are
    Dicts).

    :raises ValueError: if they do not combine, naming both sides (:mod:`sb3_dcqn.replay.combine`)
    """
    from sb3_dcqn.replay.combine import resolve_replay_buffer, with_variants

    variants = replay_variants(levers)
    buffer_class = hyperparams.get("replay_buffer_class")
    if variants:
        buffer_class = with_variants(buffer_class, *variants, base="Dict")
    dcqn_options, _ = lever_options(levers)
    options = {**hyperparams, **dcqn_options}
    resolve_replay_buffer(
        buffer_class,
        dict(hyperparams.get("replay_buffer_kwargs") or {}),
        is_dict=True,
        n_steps=int(options.get("n_steps", 1)),
        gamma=float(options.get("gamma", 0.99)),
        blocked_action_target=bool(options.get("blocked_action_target", False)),
    )
    return buffer_class if variants else None


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
    """A combination's options as the results files write them: ``"replay variants revision, blocked_action_target=True,
    ..."`` or ``"as shipped"``."""
    dcqn_options, env_options = lever_options(levers)
    variants = replay_variants(levers)
    words = [f"replay variants {', '.join(variants)}"] if variants else []
    words += [f"{key}={value}" for key, value in {**dcqn_options, **env_options}.items()]
    for name in levers:
        if (boost := LEVERS[name].boost_options) is not None:
            words.append("callback AdaptationBoost(" + ", ".join(f"{k}={v!r}" for k, v in boost.items()) + ")")
    return ", ".join(words) or "as shipped"


def unusable_levers(levers: Sequence[str], hyperparams: Mapping[str, Any]) -> dict[str, str]:
    """
    The levers of a combination that cannot run with an entry's hyperparameters, each with why.

    :param levers: Lever names (keys of :data:`LEVERS`)
    :param hyperparams: Algorithm keyword arguments (``ZooEntry.hyperparams``)
    :return: lever name -> the reason, in the order of ``levers`` (empty: all can run)
    """
    lever_options(levers)  # unknown names fail here
    left_out: dict[str, str] = {}
    for name in levers:
        try:
            replay_buffer_with_levers([name], hyperparams)
        except ValueError as error:
            left_out[name] = str(error)
    return left_out


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
    A zoo entry with the levers' replay variants added to its replay buffer class, their DCQN options to its
    hyperparameters and their env options to its ``env_kwargs``.

    :raises ValueError: if a lever cannot run with the entry's replay buffer (:func:`check_levers`)
    """
    check_levers(levers, entry.hyperparams)
    try:
        buffer_class = replay_buffer_with_levers(levers, entry.hyperparams)
    except ValueError as error:  # each lever runs with the entry, but not all of them together
        raise ValueError(f"levers {', '.join(levers)} cannot run together: {error}") from None
    dcqn_options, env_options = lever_options(levers)
    replay = {} if buffer_class is None else {"replay_buffer_class": buffer_class}
    return replace(
        entry,
        hyperparams={**entry.hyperparams, **replay, **dcqn_options},
        env_kwargs={**entry.env_kwargs, **env_options},
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
