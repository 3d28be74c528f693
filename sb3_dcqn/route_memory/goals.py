"""Where each goal is, among the memory's states.

A goal is asked for by the observation's goal keys (CampusNav's ``goal_views``, a goal env's ``desired_goal``; none:
one goal for every observation). It is *at* a set of states:

- the states a success reached under that goal (the env's ``info["is_success"]``): every env, pictures or not; goal
  vectors within ``goal_tolerance`` in every entry are one goal (as the env accepts them);
- where the env declares that a goal key pictures a place (:mod:`sb3_dcqn.place_frame`), the state the recogniser
  names for the goal's picture (``KNOWN``); a picture it does not know (new or unsure: pictured in other light, say)
  is handed to a :class:`PlaceMatcher` where there is one (the memory's default: an
  :class:`~sb3_dcqn.place_recognition.AlignedNearestPlace`), with the places' prototypes as references and the most
  recent such pictures as its sample of their light; no answer: no place, and the critics act. A matcher that names
  candidates where it cannot name one place (a :class:`~sb3_dcqn.place_recognition.CandidateMatcher`, as the default
  is) places the goal at each of them: routes lead to the nearest. A place the matcher named where an episode for
  that goal then went on is ruled out for it (the env ends an episode at its goal), and the matcher is asked again
  without it;
- for pose states of an SB3 goal env without a declared frame, the states whose ``achieved_goal`` equals the goal's
  ``desired_goal`` (SB3's goal-env convention).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from typing import Any

import numpy as np

from sb3_dcqn.place_recognition import CandidateMatcher, PlaceMatcher
from sb3_dcqn.route_memory.places import Answer, PlaceRecogniser, digest
from sb3_dcqn.route_memory.planner import BoundedCache

__all__ = ["ACHIEVED_GOAL_KEY", "GoalIndex", "PlaceMatcher"]

ACHIEVED_GOAL_KEY = "achieved_goal"
MAX_GOALS_ASKED = 64  # the most recent distinct goal pictures kept for a place matcher (a sample of their conditions)
REASK_GROWTH = 1.02  # a goal's matcher answer stands until the places grew by this factor (or its inputs changed)
MAX_GOALS_PLACED = 4_096  # goals whose matched and ruled-out places are kept (the oldest forgotten: one more trip)


class GoalIndex:
    """
    The states each goal is at (see the module docstring).

    :param asked_keys: The keys that name the asked goal (sorted; none: one goal)
    :param picture_key: The goal key whose pictures show a place (``None``: goals by successes only)
    :param recogniser: The memory's recogniser (states of places)
    :param cache: Where answers are kept (shared with the planner)
    :param achieved_key: SB3's ``achieved_goal`` key, for pose states without a frame (``None``: never read)
    :param goal_tolerance: Goal vectors within this in every entry are one goal
    :param place_matcher: For goal pictures the recogniser does not know
    :param picture_rows: Goal pictures (a batch) as the recogniser's rows (default: flattened float32)
    """

    def __init__(
        self,
        asked_keys: Sequence[str],
        picture_key: str | None,
        recogniser: PlaceRecogniser,
        cache: BoundedCache,
        achieved_key: str | None = None,
        goal_tolerance: float = 1e-4,
        place_matcher: PlaceMatcher | None = None,
        picture_rows: Callable[[np.ndarray], np.ndarray] | None = None,
    ) -> None:
        self.asked_keys = tuple(sorted(asked_keys))
        self.picture_key = picture_key
        self.recogniser = recogniser
        self.cache = cache
        self.achieved_key = achieved_key
        self.goal_tolerance = float(goal_tolerance)
        self.place_matcher = place_matcher
        self.picture_rows = picture_rows
        self.version = 0  # counts changes of what goals attach to
        self._reached: dict[bytes, set[int]] = {}
        self._vectors: dict[bytes, np.ndarray] = {}  # goal vectors reached (within the tolerance: one goal)
        self._achieved: dict[bytes, tuple[np.ndarray, set[int]]] = {}  # achieved_goal picture -> states at it
        self._asked: dict[bytes, np.ndarray] = {}  # goal pictures asked about, oldest first (the matcher's sample)
        self._asked_count = 0  # pictures ever added to it: a matcher's answers may change with each
        self._matched: dict[bytes, tuple[int, ...]] = {}  # goal -> the places the matcher answered for its picture
        self._ruled_out: dict[bytes, set[int]] = {}  # goal -> places where an episode for it went on
        # goal -> (places, sample count, places ruled out, answer) when the matcher was last asked
        self._matcher_answers: dict[bytes, tuple[int, int, int, tuple[int, ...]]] = {}

    def __setstate__(self, state: dict[str, Any]) -> None:
        # Memories saved before the matcher's sample was counted and its answers could be ruled out load without them;
        # those saved while the matcher named one place per goal (an int, -1: none) load it as a tuple of places
        state = {"_asked_count": 0, "_matched": {}, "_ruled_out": {}, "_matcher_answers": {}, **state}
        state["_matched"] = {goal: _places(answer) for goal, answer in state["_matched"].items()}
        state["_matcher_answers"] = {
            goal: (*asked[:3], _places(asked[3])) for goal, asked in state["_matcher_answers"].items()
        }
        self.__dict__.update(state)

    @property
    def conditioned(self) -> bool:
        """Whether episodes end at their own goal (a goal env): an end without success is then no dead end."""
        return self.picture_key is not None or self.achieved_key is not None

    def nbytes(self) -> int:
        vectors = sum(v.nbytes for v in self._vectors.values()) + sum(v.nbytes for v in self._asked.values())
        achieved = sum(vector.nbytes + 8 * len(states) for vector, states in self._achieved.values())
        links = sum(len(states) for states in [*self._reached.values(), *self._ruled_out.values()])
        keys = len(self._reached) + len(self._achieved) + len(self._asked) + len(self._matched) + len(self._ruled_out)
        return vectors + achieved + 8 * links + 16 * keys

    # ------------------------------------------------------------------ asked goals
    def digests(self, observations: Any, batch: int) -> list[bytes]:
        """The goal each observation asks for (one shared goal where it names none)."""
        rows = self.rows(observations, batch)
        if rows is None:
            return [b""] * batch
        return [digest(row.tobytes()) for row in rows]

    def rows(self, observations: Any, batch: int) -> np.ndarray | None:
        """The asked goal keys of a batch as float64 rows (``None`` where no key names the goal)."""
        if not self.asked_keys or not isinstance(observations, Mapping):
            return None
        return np.concatenate(
            [np.asarray(observations[key], dtype=np.float64).reshape(batch, -1) for key in self.asked_keys], axis=1
        )

    # ------------------------------------------------------------------ learning where goals are
    def add_reached(self, observations: Any, states: np.ndarray) -> None:
        """Goals reached by success transitions (their vectors kept: a goal given within the tolerance)."""
        rows = self.rows(observations, len(states))
        for index, state in enumerate(states.tolist()):
            if state < 0:
                continue
            row = None if rows is None else rows[index]
            goal = self._canonical(b"" if row is None else digest(row.tobytes()), row, add=True)
            if state not in self._reached.setdefault(goal, set()):
                self._reached[goal].add(int(state))
                self.version += 1

    def _canonical(self, goal: bytes, row: np.ndarray | None, add: bool = False) -> bytes:
        """The goal a vector within the tolerance of a reached one stands for (itself if new)."""
        if goal in self._vectors or row is None:
            return goal
        for known, vector in self._vectors.items():
            if vector.shape == row.shape and np.abs(vector - row).max() <= self.goal_tolerance:
                return known
        if add:
            self._vectors[goal] = np.array(row, dtype=np.float64)
        return goal

    def add_achieved(self, observations: Mapping[str, Any], states: np.ndarray) -> None:
        """Pose states of a goal env: attach each state to the picture its ``achieved_goal`` shows."""
        pictures = np.asarray(observations[self.achieved_key], dtype=np.float64).reshape(len(states), -1)
        for picture, state in zip(pictures, states.tolist(), strict=True):
            if state < 0:
                continue
            entry = self._achieved.setdefault(digest(picture.tobytes()), (picture.copy(), set()))
            if state not in entry[1]:
                entry[1].add(int(state))
                self.version += 1

    def merge(self, keep: int, drop: int) -> None:
        """Two states that are one place: goals at ``drop`` are at ``keep`` (and not at ``keep`` where they were ruled
        out at ``drop``)."""
        every = [*self._reached.values(), *(states for _, states in self._achieved.values()), *self._ruled_out.values()]
        for states in every:
            if drop in states:
                states.discard(drop)
                states.add(keep)
                self.version += 1
        for goal, places in list(self._matched.items()):
            if drop in places:
                self._matched[goal] = tuple(dict.fromkeys(keep if place == drop else place for place in places))

    # ------------------------------------------------------------------ where a goal is
    def states(self, goal: bytes, observations: Any, index: int, batch: int) -> np.ndarray:
        """The states where the goal of observation ``index`` of a batch is reached (empty: not in memory)."""
        key = ("goal", goal)
        version = hash((self.version, self.recogniser.version, self._asked_count))
        cached = self.cache.get(key)
        if cached is not None and cached[0] == version:
            return cached[1]
        rows = self.rows(observations, batch)
        row = None if rows is None else rows[index]
        found = set(self._reached.get(self._canonical(goal, row), ()))
        if self.picture_key is not None and isinstance(observations, Mapping):
            found |= self._pictured(goal, np.asarray(observations[self.picture_key])[index])
        if self.achieved_key is not None and row is not None:
            found |= self._achieved_states(row)
        states = np.array(sorted(found), dtype=np.int64)
        self.cache.put(key, version, states)
        return states

    def _pictured(self, goal: bytes, picture: np.ndarray) -> set[int]:
        """The states a goal picture shows: the recogniser's known place, else the matcher's answer (or candidates)
        among the places the goal was not ruled out at."""
        rows = np.asarray(picture, dtype=np.float32).reshape(1, -1)
        if self.picture_rows is not None:
            rows = self.picture_rows(np.asarray(picture)[None])
        self._matched.pop(goal, None)
        states, answers = self.recogniser.recognise(rows)
        if answers[0] == Answer.KNOWN:
            return {int(states[0])}
        if self.place_matcher is None or self.recogniser.n_states == 0:
            return set()
        self._ask(rows[0])
        # Asked again once the places grew by a share (a search over every place at each new one would cost the
        # square of the map), the matcher's sample grew, or a place was ruled out for the goal
        ruled_out = self._ruled_out.get(goal, set())
        last = self._matcher_answers.get(goal)
        n_states = self.recogniser.n_states
        standing = last is not None and last[1:3] == (self._asked_count, len(ruled_out))
        if standing and n_states < last[0] * REASK_GROWTH and all(self.recogniser.live(place) for place in last[3]):
            places = last[3]
        else:
            references, labels = self.recogniser.prototypes()
            allowed = ~np.isin(labels, list(ruled_out))
            references, labels = references[allowed], labels[allowed]
            places = self._matcher_places(rows, references, labels, len(ruled_out)) if labels.size else ()
            self._matcher_answers[goal] = (n_states, self._asked_count, len(ruled_out), places)
            _keep_newest(self._matcher_answers, MAX_GOALS_ASKED)
        if not places:
            return set()
        self._matched[goal] = places
        _keep_newest(self._matched, MAX_GOALS_PLACED)
        return set(places)

    def _matcher_places(
        self, rows: np.ndarray, references: np.ndarray, labels: np.ndarray, n_ruled_out: int
    ) -> tuple[int, ...]:
        """The places the matcher names for one goal picture (``rows``: ``(1, d)``), the likeliest first: its
        candidates where it names them, until as many places were ruled out for the goal as it names at most (one
        tour: a picture of a place never visited has candidates everywhere, and a search of every place would keep
        the agent from the untried), else its one clear answer."""
        assert self.place_matcher is not None
        asked = np.stack(list(self._asked.values()))
        if isinstance(self.place_matcher, CandidateMatcher):
            answer = np.asarray(self.place_matcher.candidates(rows, references, labels, asked))[0]
            if n_ruled_out >= answer.size and answer.size > 1 and answer[1] >= 0:
                answer = answer[:0]  # toured: candidates are no answer any more
        else:
            answer = np.asarray(self.place_matcher.match(rows, references, labels, asked))[:1]
        return tuple(dict.fromkeys(int(labels[row]) for row in answer.tolist() if row >= 0))

    def rule_out(self, goals: Sequence[bytes], states: np.ndarray) -> None:
        """
        Each goal's episode went on at each state (no success there): a goal the matcher placed at that state is not
        there (the env ends an episode at its goal), and the matcher is asked again without it.
        """
        for goal, state in zip(goals, states.tolist(), strict=True):
            if state >= 0 and state in self._matched.get(goal, ()):
                del self._matched[goal]  # asked again without it (and placed at the candidates left, if still named)
                self._ruled_out.setdefault(goal, set()).add(int(state))
                _keep_newest(self._ruled_out, MAX_GOALS_PLACED)
                self.version += 1

    @property
    def matched(self) -> dict[bytes, tuple[int, ...]]:
        """The places of each goal the matcher placed (and no place was ruled out since), the likeliest first."""
        return self._matched

    def _ask(self, picture: np.ndarray) -> None:
        """Keep a goal picture the recogniser does not know among the most recent ones (the matcher's sample)."""
        key = digest(picture.tobytes())
        if key in self._asked:
            return
        self._asked[key] = picture.copy()
        self._asked_count += 1
        _keep_newest(self._asked, MAX_GOALS_ASKED)

    def _achieved_states(self, row: np.ndarray) -> set[int]:
        entry = self._achieved.get(digest(row.tobytes()))
        if entry is not None:
            return set(entry[1])
        for vector, states in self._achieved.values():
            if vector.shape == row.shape and np.abs(vector - row).max() <= self.goal_tolerance:
                return set(states)
        return set()


def _places(answer: int | tuple[int, ...]) -> tuple[int, ...]:
    """A matcher's answer as saved before candidates (one place, -1: none) or after (a tuple of places)."""
    if isinstance(answer, tuple):
        return answer
    return () if answer < 0 else (int(answer),)


def _keep_newest(entries: dict[Any, Any], limit: int) -> None:
    """Drop the oldest entries (insertion order) beyond ``limit``."""
    while len(entries) > limit:
        del entries[next(iter(entries))]
