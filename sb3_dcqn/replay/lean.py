"""Lean storage: each distinct observation vector stored once per Dict key, row indices per transition.

For an env whose observations repeat (CampusNav's views, the goal carried in every step) a replay buffer is mostly
copies of the same vectors, each stored twice per transition (``observations`` and ``next_observations``).
:class:`LeanReplay` replaces each key's two arrays by one interned table of distinct rows
(:class:`~sb3_dcqn.observation_table.ObservationTable`, shared by observations and next observations) and keeps
``int32`` row indices per transition, gathered at sample time; Discrete actions take the smallest integer dtype.
Samples are the same as with the plain arrays. The tables hold the live distinct rows only: a row that no slot holds
any more is reused, so memory stays bounded by the buffer's even where observations never repeat.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer

from sb3_dcqn.observation_table import ObservationTable

__all__ = ["LeanReplay", "use_observation_tables"]


def use_observation_tables(buffer: DictReplayBuffer) -> None:
    """
    Store a (new, empty) Dict replay buffer's observations in interned tables: one table of distinct rows per key,
    shared by its observations and next observations; Discrete actions in the smallest integer dtype that holds them.

    :param buffer: An SB3 Dict replay buffer (or a subclass: DCQN's, HER's) before anything was added
    """
    for key, array in buffer.observations.items():
        table = ObservationTable(array.shape, array.dtype)
        buffer.observations[key] = table  # type: ignore[assignment]
        buffer.next_observations[key] = ObservationTable(array.shape, array.dtype, rows=table.rows)  # type: ignore
    space = buffer.action_space
    if isinstance(space, spaces.Discrete):
        first, last = int(space.start), int(space.start + space.n - 1)
        dtype = np.promote_types(np.min_scalar_type(first), np.min_scalar_type(last))
        buffer.actions = np.zeros(buffer.actions.shape, dtype=dtype)


class LeanReplay:
    """
    Lean storage (see the module docstring) for a Dict replay buffer: DCQN's ``DCQNDictReplayBuffer`` or
    ``DCQNHerReplayBuffer``, with any other variant. No arguments of its own.
    """

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        if not isinstance(self.observations, dict):  # type: ignore[attr-defined]
            raise ValueError(
                f"{type(self).__name__}: lean storage interns each Dict key's vectors: Dict observations only"
            )
        use_observation_tables(self)  # type: ignore[arg-type]
