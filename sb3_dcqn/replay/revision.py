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

On a plain Dict buffer the goal is part of the observation (CampusNav-v0's ``goal_views``), so by default a collision
seen on the way to goal A revises goal A's copies only. ``goal_keys`` names the goal's keys to leave out of the match:

- "the same observation and action": the observation without the goal keys, and the action;
- "the same outcome": the next observation without the goal keys (whether the agent stayed follows from it, since the
  observation is in the key); the reward and termination are left out: they are the goal's own (reached or not);
- a new outcome where the agent stayed and the episode did not end (a collision) holds for every goal: every goal's
  stale copies get it (next observation: the copy's own observation, its own goal keys kept; the collision's reward;
  not done);
- a new move (a reopened road) carries its goal's own reward and termination: only the stale copies collected for
  the same goal (equal goal keys) get it, the other goals' copies are left as they are (they are rewritten when the
  agent next drives that road for them; a route memory without goal keys learns the reopening for every goal).

**By place, where a route memory knows the places.** Bytes match only where observations repeat exactly, and even
then a heading is part of them: a bump at one heading leaves the copies of the same road driven at another heading
as they were. A route memory (:mod:`sb3_dcqn.route_memory`) knows the *place* of an observation (whatever the
heading, and in a world whose pictures vary, whatever the picture) and the compass *slot* of a move. Its layer hands
``add`` the transitions' :class:`PlaceKeys` (``place * n_slots + slot``, the place arrived at, whether the agent
stayed); the buffer then matches on them instead of the bytes, and a stay's stale copies end where each of them
started (their own observation), not in the bump's picture. A transition whose place the memory does not know
(``-1``) is not indexed: it neither revises nor is revised.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import Any, NamedTuple

import numpy as np
import torch as th

from sb3_dcqn.replay.base import TransitionHooks

__all__ = ["PlaceKeys", "RevisionReplay", "digest", "index_transition", "unindex"]

# The goal key of SB3's goal-env observations, which the hindsight-relabelling base leaves out of the match itself
_HER_GOAL_KEY = "desired_goal"


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
    goal_of: list[bytes | None] | None = None,
    goal: bytes = b"",
    same_goal_only: bool = False,
) -> list[int]:
    """
    Index the transition just written to ``slot`` in the revision index and find what it contradicts.

    :param slots_of: Key (observation and action digest) -> the slots holding it
    :param key_of: Each slot's key (``None``: empty)
    :param outcome_of: Each slot's outcome digest
    :param slot: The slot written (its previous transition, if any, leaves the index)
    :param key: The new transition's key
    :param outcome: The new transition's outcome
    :param goal_of: Each slot's goal digest (``None``: goals are not told apart)
    :param goal: The new transition's goal digest (recorded in ``goal_of``)
    :param same_goal_only: Only the slots of the same goal (``goal_of``) are contradicted: the new outcome is the
        goal's own
    :return: the other slots of the same key (and goal, with ``same_goal_only``) with another outcome: the caller
        rewrites them; their outcome is now ``outcome``
    """
    unindex(slots_of, key_of, slot)
    stale = [other for other in slots_of.get(key, ()) if outcome_of[other] != outcome]
    if same_goal_only:
        if goal_of is None:
            raise ValueError("same_goal_only needs goal_of, each slot's goal digest")
        stale = [other for other in stale if goal_of[other] == goal]
    for other in stale:
        outcome_of[other] = outcome
    slots_of.setdefault(key, set()).add(slot)
    key_of[slot] = key
    outcome_of[slot] = outcome
    if goal_of is not None:
        goal_of[slot] = goal
    return stale


def unindex(slots_of: dict[bytes, set[int]], key_of: list[bytes | None], slot: int) -> None:
    """Take ``slot``'s transition (if any) out of the revision index (it is overwritten, or not to be matched)."""
    old = key_of[slot]
    if old is None:
        return
    holders = slots_of[old]
    holders.discard(slot)
    if not holders:
        del slots_of[old]
    key_of[slot] = None


class PlaceKeys(NamedTuple):
    """
    A route memory's identity of a batch of transitions, one per env (see the module docstring).

    :param moves: ``place * n_slots + slot`` of each transition's move (-1: the memory does not know the place)
    :param arrivals: The place each move led to (-1: unknown)
    :param stays: Whether each move left the agent where it was (a bump)
    """

    moves: np.ndarray
    arrivals: np.ndarray
    stays: np.ndarray


class RevisionReplay:
    """
    Experience revision (see the module docstring) over any of DCQN's replay buffers.

    :param goal_keys: Dict observation keys that name the goal (CampusNav-v0: ``("goal_views",)``), left out of the
        match: a collision revises every goal's stale copies, a reopened road the same goal's (see the module
        docstring). Default: none, every key is matched. The hindsight-relabelling base leaves its goal out itself
        (``()`` or ``("desired_goal",)`` there)
    :ivar revised: How many stored transitions were rewritten so far
    """

    buffer_size: int
    n_envs: int
    pos: int
    observations: Any

    def __init__(self, *args: Any, goal_keys: Sequence[str] = (), **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.goal_keys = self._checked_goal_keys(goal_keys)
        self.revised = 0
        slots = self.buffer_size * self.n_envs
        # (observation, action) digest -> slots holding it; each slot's digests, to unindex on overwrite
        self._slots_of: dict[bytes, set[int]] = {}
        self._key_of: list[bytes | None] = [None] * slots
        self._outcome_of: list[bytes | None] = [None] * slots
        # Each slot's goal digest, where goals are told apart (a plain Dict base with goal keys)
        self._goal_of: list[bytes | None] | None = (
            [None] * slots if self.goal_keys and isinstance(self, TransitionHooks) else None
        )

    def _checked_goal_keys(self, goal_keys: Sequence[str]) -> tuple[str, ...]:
        name = type(self).__name__
        if isinstance(goal_keys, str):
            raise ValueError(f"{name}: goal_keys is a sequence of keys, got the string {goal_keys!r}")
        keys = tuple(dict.fromkeys(goal_keys))
        if not keys:
            return keys
        if not isinstance(self.observations, dict):
            raise ValueError(f"{name}: goal_keys={keys} needs Dict observations, the observations are a Box")
        space_keys = list(self.observations)
        if not isinstance(self, TransitionHooks):  # hindsight relabelling: its hooks leave desired_goal out
            if keys != (_HER_GOAL_KEY,):
                raise ValueError(
                    f"{name}: with hindsight relabelling the goal left out of the match is {_HER_GOAL_KEY!r} "
                    f"(its rewards are computed for each goal), goal_keys={keys} cannot be chosen"
                )
            return keys
        for key in keys:
            if key not in self.observations:
                raise ValueError(f"{name}: goal key {key!r} is not in the observation space (keys: {space_keys})")
        if len(keys) == len(space_keys):
            raise ValueError(f"{name}: goal_keys={keys} leave no key of {space_keys} to tell observations apart")
        return keys

    def __setstate__(self, state: dict[str, Any]) -> None:
        # Buffers saved before goal_keys: every key matched
        state = {"goal_keys": (), "_goal_of": None, **state}
        parent = getattr(super(), "__setstate__", None)
        if parent is not None:
            parent(state)
        else:
            self.__dict__.update(state)

    def add(
        self,
        obs: Any,
        next_obs: Any,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
        places: PlaceKeys | None = None,
    ) -> None:
        """
        SB3's ``add``, then the new transitions revise the stored ones they contradict.

        :param places: The transitions' places and slots from a route memory: matched on them instead of the bytes
            (see the module docstring); ``None``: by the bytes
        """
        pos = self.pos
        super().add(obs, next_obs, action, reward, done, infos)  # type: ignore[misc]
        for env in range(self.n_envs):
            slot = pos * self.n_envs + env
            stayed = None
            if places is None:
                key = digest(self._transition_bytes(obs, action, env))  # type: ignore[attr-defined]
                outcome = digest(self._outcome_bytes(pos, env))  # type: ignore[attr-defined]
            elif places.moves[env] < 0 or places.arrivals[env] < 0:
                unindex(self._slots_of, self._key_of, slot)  # a place the memory does not know: not matched
                continue
            else:
                key = digest(b"place" + np.int64(places.moves[env]).tobytes())
                arrival = np.int64(places.arrivals[env]).tobytes()
                outcome = digest(self._outcome_bytes(pos, env, arrival))  # type: ignore[attr-defined]
                stayed = bool(places.stays[env])
            if self._goal_of is None:
                stale = index_transition(self._slots_of, self._key_of, self._outcome_of, slot, key, outcome)
            else:
                stale = index_transition(
                    self._slots_of,
                    self._key_of,
                    self._outcome_of,
                    slot,
                    key,
                    outcome,
                    goal_of=self._goal_of,
                    goal=digest(self._goal_bytes(obs, env)),  # type: ignore[attr-defined]
                    same_goal_only=not self._holds_for_every_goal(pos, env, stayed),  # type: ignore[attr-defined]
                )
            if stale:
                self._copy_outcome(np.array(stale), pos, env)  # type: ignore[attr-defined]
                if stayed:  # each copy was a move from its own picture and heading of the place: it ends there
                    self._stay_in_place(np.array(stale))  # type: ignore[attr-defined]
                self.revised += len(stale)

    def after_gradient_step(self, samples: Any, td_errors: th.Tensor, progress: float) -> dict[str, float]:
        """Reports how many stored transitions were rewritten so far (``train/revised_transitions``)."""
        statistics = super().after_gradient_step(samples, td_errors, progress)  # type: ignore[misc]
        return {**statistics, "revised_transitions": float(self.revised)}
