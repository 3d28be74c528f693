"""Which replay variants combine, and the buffer class of a combination: the one place that decides.

A combination is a base (``"Box"``: :class:`~sb3_dcqn.replay.base.DCQNReplayBuffer`, ``"Dict"``:
:class:`~sb3_dcqn.replay.base.DCQNDictReplayBuffer`, ``"Her"``: :class:`~sb3_dcqn.replay.her.DCQNHerReplayBuffer`)
and a set of variants, each a mix-in with its own arguments (``replay_buffer_kwargs``):

=============== ========================= ================================ ==========================================
variant         class name part           mix-in                           its arguments
=============== ========================= ================================ ==========================================
``lean``        ``Lean``                  :class:`LeanReplay`              none (Dict observations only)
``nstep``       ``NStep``                 :class:`NStepReplay`             ``n_steps``, ``gamma`` (DCQN passes its own)
``revision``    ``Revision``              :class:`RevisionReplay`          none
``prioritized`` ``Prioritized``           :class:`PrioritizedReplay`       ``alpha``, ``beta``, ``priority_eps``
``count_bonus`` ``CountBonus``            :class:`CountBonusReplay`        ``count_bonus`` (> 0)
=============== ========================= ================================ ==========================================

The class of a combination is named by its parts in that order and its base: ``LeanNStepDictReplayBuffer``,
``RevisionPrioritizedReplayBuffer`` (Box), ``LeanRevisionHerReplayBuffer``; every such name can be imported from
:mod:`sb3_dcqn.replay` (and pickled), and :func:`replay_buffer_class` builds it from variant names.
"""

from __future__ import annotations

import re
from typing import Any

from stable_baselines3.common.buffers import DictReplayBuffer, NStepReplayBuffer, ReplayBuffer
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

from sb3_dcqn.replay.base import DCQNDictReplayBuffer, DCQNReplayBuffer
from sb3_dcqn.replay.count_bonus import CountBonusReplay
from sb3_dcqn.replay.her import DCQNHerReplayBuffer
from sb3_dcqn.replay.lean import LeanReplay
from sb3_dcqn.replay.n_step import NStepReplay
from sb3_dcqn.replay.prioritized import PrioritizedReplay
from sb3_dcqn.replay.revision import RevisionReplay

__all__ = [
    "BASES",
    "VARIANTS",
    "all_replay_buffer_classes",
    "check_combination",
    "class_name",
    "class_of_name",
    "dcqn_buffer_class",
    "replay_buffer_class",
    "resolve_replay_buffer",
    "variants_of",
    "with_variants",
]

# Variant name -> (class name part, mix-in), in the order of the class names and of the MRO (outermost first)
VARIANTS: dict[str, tuple[str, type]] = {
    "lean": ("Lean", LeanReplay),
    "nstep": ("NStep", NStepReplay),
    "revision": ("Revision", RevisionReplay),
    "prioritized": ("Prioritized", PrioritizedReplay),
    "count_bonus": ("CountBonus", CountBonusReplay),
}
# Base name -> DCQN's base class (its class name ends a combination's name: "", "Dict", "Her" + "ReplayBuffer")
BASES: dict[str, type[ReplayBuffer]] = {
    "Box": DCQNReplayBuffer,
    "Dict": DCQNDictReplayBuffer,
    "Her": DCQNHerReplayBuffer,
}
_BASE_WORD = {"Box": "", "Dict": "Dict", "Her": "Her"}
# SB3's buffers, as DCQN serves them when a variant is added (and HerReplayBuffer always, see DCQNHerReplayBuffer)
_SB3_BASES: dict[type, tuple[str, frozenset[str]]] = {
    ReplayBuffer: ("Box", frozenset()),
    NStepReplayBuffer: ("Box", frozenset({"nstep"})),
    DictReplayBuffer: ("Dict", frozenset()),
    HerReplayBuffer: ("Her", frozenset()),
}

# What does not combine, and why: the one table (DCQN's ``blocked_action_target`` is the option ``blocked``)
_CONFLICTS: dict[frozenset[str], str] = {
    frozenset({"nstep", "revision"}): "a revised transition is one step, rewritten with its new outcome alone",
    frozenset({"nstep", "prioritized"}): "a priority is one transition's TD error, not an n-step window's",
    frozenset({"Her", "prioritized"}): (
        "a stored transition stands for every goal it is relabelled with, its TD error for none of them"
    ),
    frozenset({"Her", "nstep"}): "a relabelled goal changes the rewards along the window",
    frozenset({"Her", "count_bonus"}): "relabelled rewards are the env's compute_reward, with no room for a bonus",
    frozenset({"Box", "lean"}): "lean storage interns each Dict key's vectors: Dict observations only",
    # DCQN's options last: what the buffer itself cannot be is named first
    frozenset({"nstep", "blocked"}): (
        "an unchanged observation after n steps does not mean the first action was blocked"
    ),
}
_WHAT = {
    "lean": "lean storage (lean)",
    "nstep": "n-step returns (nstep)",
    "revision": "experience revision (revision)",
    "prioritized": "prioritized replay (prioritized)",
    "count_bonus": "the count bonus (count_bonus)",
    "blocked": "blocked_action_target (blocked)",
    "Her": "hindsight relabelling (HerReplayBuffer)",
    "Box": "Box observations (ReplayBuffer)",
    "Dict": "Dict observations (DictReplayBuffer)",
}
_CLASSES: dict[str, type[ReplayBuffer]] = {}


def check_combination(base: str, variants: set[str] | frozenset[str], options: frozenset[str] = frozenset()) -> None:
    """
    Check that a base, variants and DCQN options combine.

    :param base: ``"Box"``, ``"Dict"`` or ``"Her"``
    :param variants: Variant names (keys of :data:`VARIANTS`)
    :param options: DCQN options that take part (``"blocked"``: ``blocked_action_target``)
    :raises ValueError: on an unknown name, or naming both sides of the first conflict and why
    """
    if base not in BASES:
        raise ValueError(f"unknown replay buffer base {base!r} (bases: {', '.join(BASES)})")
    unknown = sorted(set(variants) - set(VARIANTS))
    if unknown:
        raise ValueError(f"unknown replay variant {unknown[0]!r} (variants: {', '.join(VARIANTS)})")
    present = {base, *variants, *options}
    for pair, why in _CONFLICTS.items():
        if pair <= present:
            first, second = sorted(pair, key=_order)
            raise ValueError(f"{_WHAT[first]} does not combine with {_WHAT[second]}: {why}")


def _order(name: str) -> int:
    order = [*BASES, *VARIANTS, "blocked"]
    return order.index(name)


def class_name(base: str, variants: set[str] | frozenset[str]) -> str:
    """The name of a combination's class (``LeanNStepDictReplayBuffer``); a base alone keeps its own name."""
    if not variants:
        return BASES[base].__name__
    return "".join(VARIANTS[v][0] for v in VARIANTS if v in variants) + _BASE_WORD[base] + "ReplayBuffer"


def replay_buffer_class(*variants: str, base: str = "Dict") -> type[ReplayBuffer]:
    """
    DCQN's replay buffer class of a combination, for ``replay_buffer_class=`` (built once, then the same object).

    :param variants: Variant names (keys of :data:`VARIANTS`), any order
    :param base: ``"Box"``, ``"Dict"`` (default) or ``"Her"``
    :raises ValueError: if they do not combine (:func:`check_combination`)
    """
    chosen = frozenset(variants)
    check_combination(base, chosen)
    if not chosen:
        return BASES[base]
    if base == "Box" and chosen == {"nstep"}:
        return NStepReplayBuffer  # SB3's own (the same samples), not a second class of that name
    name = class_name(base, chosen)
    if name not in _CLASSES:
        mixins = tuple(mixin for variant, (_, mixin) in VARIANTS.items() if variant in chosen)
        parts = ", ".join(f"{mixin.__module__}.{mixin.__name__}" for mixin in mixins)
        doc = (
            f"{BASES[base].__name__} with {', '.join(_WHAT[v] for v in VARIANTS if v in chosen)}: the mix-ins "
            f"{parts} (their arguments are this class's, after the base's)."
        )
        cls = type(name, (*mixins, BASES[base]), {"__doc__": doc, "__module__": "sb3_dcqn.replay"})
        cls.__qualname__ = name
        _CLASSES[name] = cls
    return _CLASSES[name]


def all_replay_buffer_classes() -> list[type[ReplayBuffer]]:
    """Every base and every combination of variants that combines, built (for namespaces that list names)."""
    classes = []
    for base in BASES:
        for mask in range(2 ** len(VARIANTS)):
            chosen = [v for i, v in enumerate(VARIANTS) if mask >> i & 1]
            try:
                classes.append(replay_buffer_class(*chosen, base=base))
            except ValueError:
                continue  # does not combine
    return classes


def class_of_name(name: str) -> type[ReplayBuffer] | None:
    """The combination class a name stands for (``"LeanNStepDictReplayBuffer"``), or ``None`` if it names none."""
    match = re.fullmatch(
        r"((?:Lean)?(?:NStep)?(?:Revision)?(?:Prioritized)?(?:CountBonus)?)(Dict|Her|)ReplayBuffer", name
    )
    if match is None or not match.group(1):
        return None
    words = re.findall(r"Lean|NStep|Revision|Prioritized|CountBonus", match.group(1))
    by_word = {word: variant for variant, (word, _) in VARIANTS.items()}
    base = {"": "Box", "Dict": "Dict", "Her": "Her"}[match.group(2)]
    return replay_buffer_class(*(by_word[w] for w in words), base=base)


def variants_of(buffer_class: type) -> tuple[str, frozenset[str]] | None:
    """
    The base and variants of a replay buffer class DCQN can extend (its own, or SB3's ``ReplayBuffer``,
    ``NStepReplayBuffer``, ``DictReplayBuffer``, ``HerReplayBuffer``), ``None`` for any other class.
    """
    if buffer_class in _SB3_BASES:
        return _SB3_BASES[buffer_class]
    for base, base_class in BASES.items():
        if isinstance(buffer_class, type) and issubclass(buffer_class, base_class):
            mro = buffer_class.__mro__
            variants = frozenset(v for v, (_, mixin) in VARIANTS.items() if mixin in mro)
            if buffer_class is replay_buffer_class(*variants, base=base):
                return base, variants
            return None  # a user's subclass: its own business
    return None


def with_variants(buffer_class: type | None, *variants: str, base: str = "Dict") -> type[ReplayBuffer]:
    """
    A replay buffer class with variants added: ``with_variants(HerReplayBuffer, "revision")`` is
    ``RevisionHerReplayBuffer``.

    :param buffer_class: The class to extend (``None``: ``base``'s, for an algorithm that would pick its own)
    :param variants: Variant names to add
    :param base: The base when ``buffer_class`` is ``None``
    :raises ValueError: if ``buffer_class`` cannot be extended, or the variants do not combine with it
    """
    if buffer_class is None:
        return replay_buffer_class(*variants, base=base)
    found = variants_of(buffer_class)
    if found is None:
        name = getattr(buffer_class, "__name__", repr(buffer_class))
        raise ValueError(
            f"{', '.join(variants)} need one of DCQN's replay buffers (or SB3's ReplayBuffer, DictReplayBuffer, "
            f"HerReplayBuffer, which DCQN extends), not replay_buffer_class={name}"
        )
    own_base, own = found
    return replay_buffer_class(*own, *variants, base=own_base)


def dcqn_buffer_class(buffer_class: type) -> type:
    """The class DCQN builds for ``replay_buffer_class=buffer_class``: ``HerReplayBuffer`` is served by
    :class:`~sb3_dcqn.replay.her.DCQNHerReplayBuffer` (terminal relabels), every other class is built as given."""
    return DCQNHerReplayBuffer if buffer_class is HerReplayBuffer else buffer_class


def resolve_replay_buffer(
    buffer_class: type[ReplayBuffer] | None,
    buffer_kwargs: dict[str, Any],
    is_dict: bool,
    n_steps: int,
    gamma: float,
    blocked_action_target: bool = False,
) -> tuple[type[ReplayBuffer] | None, dict[str, Any]]:
    """
    The replay buffer class and arguments DCQN builds for what it was given (``replay_buffer_class``,
    ``replay_buffer_kwargs``, ``n_steps``, ``blocked_action_target``).

    - None: SB3's choice, except n-step returns with Dict observations (SB3 has none): ``NStepDictReplayBuffer``;
    - SB3's ``HerReplayBuffer``: served by :class:`~sb3_dcqn.replay.her.DCQNHerReplayBuffer` (same arguments);
    - SB3's other buffers and a user's own classes: built as given (SB3 warns that ``n_steps`` goes unused);
    - DCQN's buffers: ``n_steps > 1`` adds the ``nstep`` variant;
    - a class with the ``nstep`` variant gets DCQN's ``n_steps`` and ``gamma`` unless its kwargs give them.

    :return: the class (``None``: SB3 picks it) and its keyword arguments
    :raises ValueError: where the variants and options do not combine (:func:`check_combination`)
    """
    blocked = frozenset({"blocked"}) if blocked_action_target else frozenset()
    wants_n_steps = frozenset({"nstep"}) if n_steps > 1 else frozenset()
    if buffer_class is None:
        base = "Dict" if is_dict else "Box"
        check_combination(base, wants_n_steps, blocked)  # SB3 builds NStepReplayBuffer for Box
        if not (is_dict and wants_n_steps):
            return None, buffer_kwargs
        variants = wants_n_steps
    else:
        given = dcqn_buffer_class(buffer_class)
        found = variants_of(given)
        if found is None or given in _SB3_BASES:  # SB3's own buffer or the user's: built as given
            if found is not None:
                check_combination(*found, blocked)
            return given, buffer_kwargs
        base, own = found
        variants = own | wants_n_steps
        check_combination(base, variants, blocked)
    kwargs = dict(buffer_kwargs)
    if "nstep" in variants:
        kwargs.setdefault("n_steps", n_steps)
        kwargs.setdefault("gamma", gamma)
    return replay_buffer_class(*variants, base=base), kwargs
