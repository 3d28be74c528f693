"""Experience revision: stored transitions that the agent's new experience contradicts get the new outcome.

In a deterministic world the same action from the same observation always has the same outcome. When a new
transition ``(o, a) -> (r, o', done)`` disagrees with stored transitions of the same ``(o, a)`` (a collision where the
agent used to drive on: a road has closed; a move where it used to collide: a road has reopened), the stored
transitions are contradicted by the agent's own experience, and are rewritten with the new outcome. Without it, the
stale copies (hundreds in a large buffer) keep teaching the old route long after a closure.

Transitions are found by a digest of the observation's bytes and the action, so the lookup costs a dictionary access
per added transition; the buffer counts the transitions it revised (``revised``). What "the same observation" and
"the outcome" mean is the buffer's (``_transition_bytes``, ``_outcome_bytes``, ``_copy_outcome``): with hindsight
relabelling (``DCQNHerReplayBuffer``) the goal is left out of the match and rewards are computed anew for each
transition's own goal.
"""

from __future__ import annotations

import hashlib
from typing import Any

import numpy as np

__all__ = ["RevisionReplay", "digest", "index_transition"]


def digest(data: bytes) -> bytes:
    """The revision index's key of an (observation, action) or an outcome: 16 bytes of BLAKE2b."""
    return hashlib.blake2b(data, digest_size=16).digest()


def index_transition(
    slots_of: dict[bytes, set[int]],
    key_of: list[bytes | None],
    outcome_of: list[bytes | None],
    slot: int,
    key: bytes,
    outcome: bytes,
) -> list[int]:
    """
    Index the transition just written to ``slot`` in the revision index and find what it contradicts.

    :param slots_of: Key (observation and action digest) -> the slots holding it
    :param key_of: Each slot's key (``None``: empty)
    :param outcome_of: Each slot's outcome digest
    :param slot: The slot written (its previous transition, if any, leaves the index)
    :param key: The new transition's key
    :param outcome: The new transition's outcome
    :return: the other slots of the same key with another outcome: the caller rewrites them; their outcome is now
        ``outcome``
    """
    old = key_of[slot]
    if old is not None:
        holders = slots_of[old]
        holders.discard(slot)
        if not holders:
            del slots_of[old]
    stale = [other for other in slots_of.get(key, ()) if outcome_of[other] != outcome]
    for other in stale:
        outcome_of[other] = outcome
    slots_of.setdefault(key, set()).add(slot)
    key_of[slot] = key
    outcome_of[slot] = outcome
    return stale


class RevisionReplay:
    """
    Experience revision (see the module docstring) over any of DCQN's replay buffers. No arguments of its own.

    :ivar revised: How many stored transitions were rewritten so far
    """

    buffer_size: int
    n_envs: int
    pos: int

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.revised = 0
        slots = self.buffer_size * self.n_envs
        # (observation, action) digest -> slots holding it; each slot's digests, to unindex on overwrite
        self._slots_of: dict[bytes, set[int]] = {}
        self._key_of: list[bytes | None] = [None] * slots
        self._outcome_of: list[bytes | None] = [None] * slots

    def add(
        self,
        obs: Any,
        next_obs: Any,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        pos = self.pos
        super().add(obs, next_obs, action, reward, done, infos)  # type: ignore[misc]
        for env in range(self.n_envs):
            slot = pos * self.n_envs + env
            key = digest(self._transition_bytes(obs, action, env))  # type: ignore[attr-defined]
            outcome = digest(self._outcome_bytes(pos, env))  # type: ignore[attr-defined]
            stale = index_transition(self._slots_of, self._key_of, self._outcome_of, slot, key, outcome)
            if stale:
                self._copy_outcome(np.array(stale), pos, env)  # type: ignore[attr-defined]
                self.revised += len(stale)
