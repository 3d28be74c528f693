"""DCQN's replay buffers: SB3's buffers with variants that compose, chosen by ``replay_buffer_class``.

Each variant is a mix-in with its own arguments (given in ``replay_buffer_kwargs``, checked by the mix-in), over one of
DCQN's bases, which sample exactly as SB3's buffers do:

- :class:`DCQNReplayBuffer` (Box), :class:`DCQNDictReplayBuffer` (Dict), :class:`DCQNHerReplayBuffer` (hindsight
  relabelling; DCQN serves SB3's ``HerReplayBuffer`` with it: relabelled transitions that reach their new goal are
  terminal, ``terminal_relabels``);
- :class:`LeanReplay` (``lean``), :class:`NStepReplay` (``nstep``), :class:`RevisionReplay` (``revision``),
  :class:`PrioritizedReplay` (``prioritized``), :class:`CountBonusReplay` (``count_bonus``).

A combination's class is named by its parts (``LeanNStepDictReplayBuffer``, ``RevisionHerReplayBuffer``,
``PrioritizedReplayBuffer`` for Box observations) and can be imported from here by that name, or built with
:func:`replay_buffer_class` (``replay_buffer_class("lean", "revision", base="Her")``); :mod:`.combine` is the one place
that decides which variants combine (an error names both sides). For example::

    from sb3_dcqn import DCQN
    from sb3_dcqn.replay import RevisionDictReplayBuffer

    model = DCQN("MultiInputPolicy", env, replay_buffer_class=RevisionDictReplayBuffer)
"""

from __future__ import annotations

from typing import Any

from sb3_dcqn.replay.base import DCQNDictReplayBuffer, DCQNReplayBuffer
from sb3_dcqn.replay.combine import (
    BASES,
    VARIANTS,
    all_replay_buffer_classes,
    check_combination,
    class_of_name,
    dcqn_buffer_class,
    replay_buffer_class,
    variants_of,
    with_variants,
)
from sb3_dcqn.replay.count_bonus import CountBonusReplay
from sb3_dcqn.replay.her import DCQNHerReplayBuffer
from sb3_dcqn.replay.lean import LeanReplay
from sb3_dcqn.replay.n_step import NStepReplay
from sb3_dcqn.replay.prioritized import (
    PrioritizedDictReplayBufferSamples,
    PrioritizedReplay,
    PrioritizedReplayBufferSamples,
)
from sb3_dcqn.replay.revision import RevisionReplay

__all__ = [
    "BASES",
    "VARIANTS",
    "CountBonusReplay",
    "DCQNDictReplayBuffer",
    "DCQNHerReplayBuffer",
    "DCQNReplayBuffer",
    "LeanReplay",
    "NStepReplay",
    "PrioritizedDictReplayBufferSamples",
    "PrioritizedReplay",
    "PrioritizedReplayBufferSamples",
    "RevisionReplay",
    "all_replay_buffer_classes",
    "check_combination",
    "dcqn_buffer_class",
    "replay_buffer_class",
    "variants_of",
    "with_variants",
]


def __getattr__(name: str) -> Any:
    # Every combination's class by its name (PEP 562): imports, pickles and YAML entries name them
    cls = class_of_name(name)
    if cls is None:
        raise AttributeError(f"module 'sb3_dcqn.replay' has no attribute {name!r}")
    globals()[name] = cls
    return cls
