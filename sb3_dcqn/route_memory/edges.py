"""What the memory knows of each move: per ``(state, slot)``, its latest outcome, where it led and when it was tried.

Outcomes (:class:`Outcome`) are either **observed** (the agent made that move: ``DRIVEN``, ``BLOCKED``, ``DEAD_END``,
``OUTSIDE``) or **inferred** from a move at the road's other end, where the env declares two-way roads (``INFERRED``:
the way back of a driven road; ``INFERRED_BLOCKED``: the other end of a road seen closed). An observed outcome
outranks an inferred one: an inference never overwrites an observation, except that a road seen closed from one end
is believed closed from the other (closures close both ways) until it is driven again. Bumping into an inferred way
back (a one-way road) says the inference was wrong and closes nothing else.

A slot that led to two different states, each at least twice, marks its state *aliased* (two places that picture
the same): routes never go through it. One odd outcome (a glitch) leaves it alone and the latest outcome wins, and so
do two states that are one place remembered twice: the caller says they look alike, or another move has led to both
of them too (a place whose pictures vary more than the recogniser's thresholds; two twin places behind two sources
that each picture alike are far less likely). Each disputed outcome is listed in :attr:`EdgeStore.disputed` for the
caller (who knows the pictures), and an aliased state the caller can tell apart is :meth:`EdgeStore.split` in two.

**Stochastic moves.** Where states are poses (exact observations of an env that declares no place frame, with no
roads between places: ``count_outcomes``), a slot that led to two ends by turns is no alias of two places that look
alike: the world itself is random there (a slippery floor). Such a store keeps **outcome counts** per
``(state, slot)`` (where it ended: a state, or :data:`DEAD` for an end of the episode without success) and the number
of times the end changed from one try to the next. A deterministic world
with closures changes a move's end once per closure or reopening, and a pose's move leads to one state (or stays,
closed); a move whose end changed :data:`STOCHASTIC_CHANGES` times or more, or that led to two states, is
**stochastic** (:attr:`EdgeStore.stochastic`): its outcomes are never disputed (no alias), a stay
there closes nothing, and its remembered target is its most frequent end elsewhere (the explorer's way along it). Once
one move is stochastic the world is, and the counts of every move are the model the planner solves
(:meth:`EdgeStore.outcome_model`).

A closed slot is a fact with an age: ``last_tried`` (the memory's clock, in transitions) and ``failures`` (bumps in a
row) say when it may be tried again (:meth:`EdgeStore.retry_due`): ``retry_after`` transitions after the first bump,
twice that after the second, and so on (a slot that never had a road is tried ever more rarely).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from enum import IntEnum

import numpy as np

__all__ = ["CLOSED", "DEAD", "ROUTES", "STOCHASTIC_CHANGES", "UNDERSAMPLED_BELOW", "EdgeStore", "Outcome"]

MAX_BACKOFF = 16  # a closed slot is retried after at most retry_after * 2**16 transitions
# Changes of a move's end from one try to the next past which the move is the world's chance, not a closure: a closure
# changes it once, its reopening once more, a road closed again a third time is rare; a fair three-way slip changes
# it at two tries in three
STOCHASTIC_CHANGES = 3
DEAD = -2  # an outcome count's end: the episode ended without success (FrozenLake's hole)
# Tries of a move in a stochastic world below which its counts are a guess, not a model: exploration seeks it as it
# seeks an untried one (a three-way slip's shares are within about 0.15 after ten tries)
UNDERSAMPLED_BELOW = 10


class Outcome(IntEnum):
    """The latest outcome of a ``(state, slot)``."""

    UNTRIED = 0  # never tried
    DRIVEN = 1  # driven: leads to its target
    INFERRED = 2  # the way back of a driven road (two-way roads): routes use it, exploration does not seek it
    BLOCKED = 3  # bumped into: no road, or a closed one (its target kept where it was driven before)
    DEAD_END = 4  # its episode ended without success
    OUTSIDE = 5  # led to a state past the memory's size
    INFERRED_BLOCKED = 6  # the other end of a road seen closed: believed closed until driven or retried


ROUTES = (Outcome.DRIVEN, Outcome.INFERRED)
CLOSED = (Outcome.BLOCKED, Outcome.INFERRED_BLOCKED)
_FILL = {"outcome": Outcome.UNTRIED, "target": -1, "arrival": -1, "last_tried": 0, "failures": 0, "stochastic": False}
_DTYPES = {
    "outcome": np.int8,
    "target": np.int32,
    "arrival": np.int8,
    "last_tried": np.int64,
    "failures": np.int8,
    "stochastic": np.bool_,
}


def _never_alike(_a: int, _b: int) -> bool:
    return False


class EdgeStore:
    """
    The moves of a memory's states (see the module docstring).

    :param n_slots: Slots per state (the actions' number)
    :param reverse_action: Right after a move, the action that leads back (two-way roads; the slot at the far end is
        the arrival frame plus it); ``None``: nothing is inferred about ways back
    :param retry_after: Transitions after a bump before a closed slot may be tried again (doubling with each bump)
    :param forget_moves_into_on_bump: Pose states (see :meth:`forget_moves_into`): a bump where a move into a state
        used to be makes every other move into that state untried again
    :param one_place_twice: Whether two states can be one place remembered twice (places recognised by similarity;
        not states that are exact observations, where two states a move leads to by turns are a stochastic world's)
    :param count_outcomes: Count each move's ends and plan the moves found stochastic on their counts (pose states;
        see the module docstring); else a slot that led to two states by turns is an alias
    """

    def __init__(
        self,
        n_slots: int,
        reverse_action: int | None = None,
        retry_after: int = 50,
        forget_moves_into_on_bump: bool = False,
        one_place_twice: bool = True,
        count_outcomes: bool = False,
    ) -> None:
        if n_slots < 1 or retry_after < 1:
            raise ValueError(f"n_slots and retry_after must be at least 1, got {n_slots}, {retry_after}")
        self.n_slots = int(n_slots)
        self.reverse_action = reverse_action
        self.retry_after = int(retry_after)
        self.forget_moves_into_on_bump = forget_moves_into_on_bump
        self.one_place_twice = one_place_twice
        self.count_outcomes = count_outcomes
        self.forgotten = 0  # moves made untried again by a bump (forget_moves_into)
        self.clock = 0  # transitions recorded
        self.version = 0  # counts changes of moves
        self.lost_move_version = 0  # the last change that removed a move: routes computed before it are stale
        self.aliased: set[int] = set()
        self.twins: set[tuple[int, int]] = set()  # pairs of states shown to be one place, for the caller to merge
        self._disputes: dict[tuple[int, int], dict[int, int]] = {}
        # The disputed moves that led to each state (:meth:`_led_to`), kept as disputes grow; None: read anew when
        # asked (after a dispute was dropped)
        self._led_to_index: dict[int, set[tuple[int, int]]] | None = None
        # Disputed outcomes since the caller last took them: (state, slot, the state it led to)
        self.disputed: list[tuple[int, int, int]] = []
        # Exact states only: per (state, slot), how often it ended where (a state, or DEAD), its last end, and how many
        # times its end changed from one try to the next
        self.counts: dict[tuple[int, int], dict[int, int]] = {}
        self._last_end: dict[tuple[int, int], int] = {}
        self._changes: dict[tuple[int, int], int] = {}
        self.n_stochastic = 0
        self.n_rows = 0
        self.outcome = np.zeros((0, n_slots), dtype=np.int8)
        self.target = np.zeros((0, n_slots), dtype=np.int32)
        self.arrival = np.zeros((0, n_slots), dtype=np.int8)  # the frame on arrival (-1 unknown)
        self.last_tried = np.zeros((0, n_slots), dtype=np.int64)
        self.failures = np.zeros((0, n_slots), dtype=np.int8)
        self.stochastic = np.zeros((0, n_slots), dtype=np.bool_)  # moves planned on their outcome counts
        self._grow(1024)

    def ensure(self, states: int) -> None:
        """Rows for ``states`` states (the arrays double as they fill)."""
        self.n_rows = max(self.n_rows, states)
        if states > len(self.outcome):
            self._grow(max(states, 2 * len(self.outcome)))

    def _grow(self, capacity: int) -> None:
        kept = len(self.outcome)
        for name, fill in _FILL.items():
            grown = np.full((capacity, self.n_slots), fill, dtype=_DTYPES[name])
            grown[:kept] = getattr(self, name)
            setattr(self, name, grown)

    def nbytes(self) -> int:
        """Bytes per used row (int32 target, int64 last try, three int8 codes, a flag), and about 64 per counted end."""
        counted = sum(len(ends) for ends in self.counts.values())
        return self.n_rows * self.n_slots * (4 + 8 + 3 + 1) + 64 * counted

    # ------------------------------------------------------------------ recording
    def record(
        self,
        state: int,
        slot: int,
        following: int,
        arrival: int,
        dead: bool,
        alike: Callable[[int, int], bool] = _never_alike,
    ) -> None:
        """
        One tried ``(state, slot)``: where it led (``following``, -1: outside the memory) and the frame there.
        ``alike(a, b)``: whether two states picture places the caller cannot tell apart; a slot that led to two such
        states is one place remembered twice, not an alias (the latest target stands).
        """
        self.clock += 1
        self.last_tried[state, slot] = self.clock
        if self.count_outcomes and self._count(state, slot, DEAD if dead else following):
            return
        if following < 0:
            if self.outcome[state, slot] == Outcome.UNTRIED:
                self._set(state, slot, Outcome.OUTSIDE)
        elif dead:
            self._set(state, slot, Outcome.DEAD_END, following)
        elif following == state:
            self._bump(state, slot)
        else:
            self._drive(state, slot, following, arrival, alike)

    def _count(self, state: int, slot: int, end: int) -> bool:
        """Count one end of a move (exact states); returns whether the move is stochastic (then it is recorded here:
        its most frequent end elsewhere is its target, and nothing is disputed, closed or inferred)."""
        key = (state, slot)
        ends = self.counts.setdefault(key, {})
        ends[end] = ends.get(end, 0) + 1
        last = self._last_end.get(key)
        if last is not None and last != end:
            self._changes[key] = self._changes.get(key, 0) + 1
        self._last_end[key] = end
        if not self.stochastic[state, slot]:
            # Two ends elsewhere: a pose's move leads to one state, or stays where a road closed; another end is chance
            elsewhere = sum(1 for target in ends if target not in (state, DEAD, -1))
            if self._changes.get(key, 0) < STOCHASTIC_CHANGES and elsewhere < 2:
                return False
            self.stochastic[state, slot] = True
            self.n_stochastic += 1
            if self._disputes.pop(key, None) is not None:  # its two ends were chance, not two places
                self._led_to_index = None
                self._settle(_never_alike)
            self.version += 1
        elsewhere = {target: count for target, count in ends.items() if target not in (state, DEAD, -1)}
        if elsewhere:
            self._set(state, slot, Outcome.DRIVEN, max(elsewhere, key=lambda target: elsewhere[target]))
        elif DEAD in ends:
            self._set(state, slot, Outcome.DEAD_END)
        else:
            self._set(state, slot, Outcome.BLOCKED)
        return True

    def explains(self, state: int, slot: int, end: int) -> bool:
        """Whether a stochastic move has ended at ``end`` before (a state, or :data:`DEAD`)."""
        return bool(self.stochastic[state, slot]) and end in self.counts.get((state, slot), {})

    def outcome_model(self, retry: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """
        Every move as an empirical model: one row per (move, end) with its probability. Once any move is stochastic
        the world is, and every counted move is its counts (a stay or a dead end included: a move tried once is its one
        end so far); a move not counted (an inferred way back, or every move of a store that counts nothing) is its
        one end, where :meth:`moves` routes along it. Never out of an aliased state.

        :return: int64 states, slots, ends (a state, or :data:`DEAD`) and float64 probabilities
        """
        n = self.n_rows
        counted = np.zeros((n, self.n_slots), dtype=bool)
        chance = []
        if self.n_stochastic:
            for (state, slot), ends in self.counts.items():
                counted[state, slot] = True
                if state in self.aliased:
                    continue
                total = sum(ends.values())
                chance += [(state, slot, end, count / total) for end, count in ends.items() if end != -1]
        states, slots = np.nonzero(self.moves(np.arange(n), retry) & ~counted)
        parts = [(states, slots, self.target[states, slots].astype(np.int64), np.ones(states.size))]
        if chance:  # -1, outside the memory, has no value: left out
            columns = np.array(chance, dtype=np.float64).T
            parts.append((*(columns[:3].astype(np.int64)), columns[3]))
        return tuple(np.concatenate([part[index] for part in parts]) for index in range(4))  # type: ignore[return-value]

    def _set(
        self, state: int, slot: int, outcome: Outcome, target: int | None = None, arrival: int | None = None
    ) -> None:
        """Change one ``(state, slot)``, counting a change and a lost move."""
        was = int(self.outcome[state, slot])
        was_move = was in ROUTES and self.target[state, slot] >= 0
        changed = was != outcome or (target is not None and self.target[state, slot] != target)
        self.outcome[state, slot] = outcome
        if target is not None:
            self.target[state, slot] = target
        if arrival is not None:
            self.arrival[state, slot] = arrival
        if changed:
            self.version += 1
            if was_move and outcome not in ROUTES:
                self.lost_move_version = self.version

    def _bump(self, state: int, slot: int) -> None:
        """A collision: the slot is closed; where it was a driven road, its way back is believed closed too."""
        observed_road = self.outcome[state, slot] == Outcome.DRIVEN and self.target[state, slot] >= 0
        was_move = self.outcome[state, slot] in ROUTES and self.target[state, slot] >= 0
        self._set(state, slot, Outcome.BLOCKED)
        if self.forget_moves_into_on_bump and was_move:
            self.forgotten += self.forget_moves_into(int(self.target[state, slot]))
        self.failures[state, slot] = min(int(self.failures[state, slot]) + 1, MAX_BACKOFF + 1)
        back = self.back_slot(state, slot)
        if not observed_road or back is None:
            return  # an inferred way back that bumps is a one-way road: nothing else follows
        far = int(self.target[state, slot])
        self.last_tried[far, back] = self.clock
        if self.outcome[far, back] in ROUTES and self.target[far, back] == state:
            self._set(far, back, Outcome.INFERRED_BLOCKED)

    def _drive(self, state: int, slot: int, following: int, arrival: int, alike: Callable[[int, int], bool]) -> None:
        """A move; its way back is inferred where nothing was observed there."""
        known = int(self.target[state, slot])
        contradicts = known >= 0 and known != following and self.outcome[state, slot] in (*ROUTES, *CLOSED)
        if contradicts or (state, slot) in self._disputes:
            self._dispute(state, slot, known, following, alike)
        self._set(state, slot, Outcome.DRIVEN, following, arrival)
        self.failures[state, slot] = 0
        back = self.back_slot(state, slot)
        if back is None:
            return
        far_outcome, far_target = int(self.outcome[following, back]), int(self.target[following, back])
        if far_outcome == Outcome.DRIVEN and far_target >= 0 and far_target != state:
            self._dispute(following, back, far_target, state, alike)  # the way back was driven and led elsewhere
        elif far_outcome in (Outcome.UNTRIED, Outcome.INFERRED, Outcome.INFERRED_BLOCKED):
            # Arriving back here the agent would face away from the road, so that "back" again leads along it
            self._set(following, back, Outcome.INFERRED, state, (slot - self.reverse_action) % self.n_slots)

    def back_slot(self, state: int, slot: int) -> int | None:
        """The slot at the far end of a known move that leads back (two-way roads), else ``None``."""
        if self.reverse_action is None or self.target[state, slot] < 0 or self.arrival[state, slot] < 0:
            return None
        return (int(self.arrival[state, slot]) + self.reverse_action) % self.n_slots

    def _dispute(self, state: int, slot: int, known: int, following: int, alike: Callable[[int, int], bool]) -> None:
        """A slot that led to ``known`` now leads to ``following``: two states that are not one place, twice each, and
        the state is aliased; a state aliased before is cleared where its states have since shown to be one place."""
        counts = self._disputes.setdefault((state, slot), {known: 1} if known >= 0 else {})
        counts[following] = counts.get(following, 0) + 1
        if self._led_to_index is not None:
            for target in counts:
                self._led_to_index.setdefault(target, set()).add((state, slot))
        self.disputed.append((state, slot, following))
        # Each pair's look read once for every aliased state (the prototypes do not move meanwhile), and the moves that
        # led to each state kept (_led_to): scanning every dispute for each aliased state and pair made a dispute cost
        # the square of them (the hours 0-24 world, 62 aliased states: 30 ms a transition)
        alike = functools.cache(alike)
        self._settle(alike, but=state)
        if state not in self.aliased and self._splits((state, slot), alike):
            self.aliased.add(state)
            self.version += 1

    def _settle(self, alike: Callable[[int, int], bool], but: int = -1) -> None:
        """Aliased states (but ``but``) whose disputed moves have since shown their states to be one place (merged, or
        alike) are aliased no more."""
        if not self.aliased.difference((but,)):
            return
        keys_of: dict[int, list[tuple[int, int]]] = {}  # each state's disputed moves, read once
        for key in self._disputes:
            keys_of.setdefault(key[0], []).append(key)
        for aliased in [other for other in self.aliased if other != but]:
            if not any(self._splits(key, alike) for key in keys_of.get(aliased, ())):
                self.aliased.discard(aliased)
                self.version += 1

    def _led_to(self) -> dict[int, set[tuple[int, int]]]:
        """For each state, the disputed moves that led to it (the caller only reads it)."""
        if self._led_to_index is None:
            self._led_to_index = {}
            for key, counts in self._disputes.items():
                for target in counts:
                    self._led_to_index.setdefault(target, set()).add(key)
        return self._led_to_index

    def _splits(self, source: tuple[int, int], alike: Callable[[int, int], bool]) -> bool:
        """Whether a disputed move led to two states, twice each, that are not one place remembered twice."""
        return self._two_places(source, alike) is not None

    def _two_places(self, source: tuple[int, int], alike: Callable[[int, int], bool]) -> tuple[int, int] | None:
        """Two states a disputed move led to, twice each, that are not one place remembered twice (the most frequent
        first), else ``None``."""
        counts = self._disputes[source]
        frequent = sorted((target for target, count in counts.items() if count >= 2), key=lambda t: -counts[t])
        for index, first in enumerate(frequent):
            for second in frequent[index + 1 :]:
                if not alike(first, second) and not self._one_place(first, second, source):
                    return first, second
        return None

    def alias_of(self, state: int, alike: Callable[[int, int], bool]) -> tuple[int, int, int] | None:
        """Why an aliased state is aliased: a slot of it and two states that slot led to, twice each (the slot's more
        frequent first); ``None`` for a state not aliased."""
        if state not in self.aliased:
            return None
        for key in [key for key in self._disputes if key[0] == state]:
            places = self._two_places(key, alike)
            if places is not None:
                return key[1], places[0], places[1]
        return None

    def split(self, state: int, slot: int, sibling: int, moved: int) -> None:
        """
        An aliased ``state`` found to be two places: the one where ``slot`` led to ``moved`` is ``sibling`` (a new
        state). The slot leads to ``moved`` from the sibling and to its other place from ``state``, and ``moved``'s
        way back leads to the sibling. The state keeps its other moves (most were made from its more frequent side; a
        wrong one is disputed when driven again); the sibling's other slots are untried, to be explored, and so are the
        other moves into ``state`` (their end may have been either place).
        """
        self.ensure(max(state, sibling, moved) + 1)
        counts = self._disputes.pop((state, slot), {})
        self._led_to_index = None
        kept = max((target for target in counts if target != moved), key=lambda t: counts[t], default=-1)
        latest, arrival = int(self.target[state, slot]), int(self.arrival[state, slot])  # the frame at the latest end
        for name, fill in _FILL.items():
            getattr(self, name)[sibling] = fill
        self.outcome[state, slot] = Outcome.DRIVEN if kept >= 0 else Outcome.UNTRIED
        self.target[state, slot] = kept
        self.arrival[state, slot] = arrival if latest == kept else -1
        self.outcome[sibling, slot], self.target[sibling, slot] = Outcome.DRIVEN, moved
        self.arrival[sibling, slot] = arrival if latest == moved else -1
        self.last_tried[[state, sibling], slot] = self.clock
        back = self.back_slot(sibling, slot)
        if back is not None and self.target[moved, back] == state:
            self.target[moved, back] = sibling
        # Any other move into the state may have ended at either place (each was recognised as one): untried again,
        # but the way back from the slot's end that stays the state's
        self.forget_moves_into(state, but_from=kept)
        self.aliased.discard(state)
        self.version += 1
        self.lost_move_version = self.version

    def forget_disputes(self) -> None:
        """Forget every disputed move, alias and twin (evidence gathered from pictures that were not recognised
        reliably: while the memory stood aside); a move that still leads to two places by turns is disputed anew."""
        if self._disputes or self.aliased or self.twins:
            self.version += 1
        self._disputes.clear()
        self._led_to_index = None
        self.aliased.clear()
        self.twins.clear()
        self.disputed.clear()

    def _one_place(self, first: int, second: int, source: tuple[int, int]) -> bool:
        """Whether another move has led to both states too: one place remembered as two (its pictures vary more than
        the recogniser's thresholds), not two places that ``source``'s state pictures alike. Such pairs are kept in
        :attr:`twins` for the caller to merge (:meth:`merge`)."""
        if not self.one_place_twice:
            return False
        led_to = self._led_to()
        twins = bool(led_to.get(first, set()) & led_to.get(second, set()) - {source})
        if twins:
            self.twins.add((min(first, second), max(first, second)))
        return twins

    def merge(self, keep: int, drop: int) -> None:
        """
        Two states that are one place: ``drop``'s moves become ``keep``'s where ``keep`` has observed nothing there (the
        later try where both have), every move into ``drop`` leads into ``keep``, and ``drop`` keeps no move (its row
        is ``OUTSIDE``: neither a route nor untried).
        """
        if keep == drop or max(keep, drop) >= self.n_rows:
            return
        observed = (Outcome.DRIVEN, Outcome.BLOCKED, Outcome.DEAD_END, Outcome.OUTSIDE)
        theirs = np.isin(self.outcome[drop], observed)
        ours = np.isin(self.outcome[keep], observed)
        take = theirs & (~ours | (self.last_tried[drop] > self.last_tried[keep]))
        for name in _FILL:
            array = getattr(self, name)
            array[keep, take] = array[drop, take]
            array[drop] = _FILL[name]
        self.outcome[drop] = Outcome.OUTSIDE
        rows = slice(0, self.n_rows)
        self.target[rows][self.target[rows] == drop] = keep
        self._led_to_index = None
        for key in [key for key in self._disputes if key[0] == drop]:
            del self._disputes[key]
        for counts in self._disputes.values():
            if drop in counts:
                counts[keep] = counts.get(keep, 0) + counts.pop(drop)
        self.aliased.discard(drop)
        self.twins = {(a, b) for a, b in ((keep if a == drop else a, keep if b == drop else b) for a, b in self.twins)}
        self.twins = {(a, b) for a, b in self.twins if a != b}
        self.version += 1
        self.lost_move_version = self.version

    def forget_moves_into(self, lost: int, but_from: int = -1) -> int:
        """
        Every remembered move into ``lost`` (but those from state ``but_from``) becomes untried again, its end
        forgotten; returns how many. With pose states, where the state after a move tells which road was taken (the
        place and the heading away from it), they are the same road seen from the other headings, so one bump closes
        it for all of them; a split state's moves in may have ended at either of its places.
        """
        rows = slice(0, self.n_rows)
        into = (self.target[rows] == lost) & np.isin(self.outcome[rows], ROUTES) & ~self.stochastic[rows]
        if but_from >= 0:
            into[but_from] = False
        if into.any():
            self.outcome[rows][into] = Outcome.UNTRIED
            self.target[rows][into] = -1
            self.arrival[rows][into] = -1
            self.version += 1
            self.lost_move_version = self.version
        return int(into.sum())

    # ------------------------------------------------------------------ reading
    def retry_due(self, rows: np.ndarray) -> np.ndarray:
        """Which closed ``(state, slot)`` pairs of the rows may be tried again (their backoff has passed)."""
        failures = np.maximum(self.failures[rows].astype(np.int64), 1)
        wait = self.retry_after * 2 ** np.minimum(failures - 1, MAX_BACKOFF)
        closed = np.isin(self.outcome[rows], CLOSED)
        return closed & (self.clock - self.last_tried[rows] >= wait)

    def moves(self, rows: np.ndarray, retry: bool = False) -> np.ndarray:
        """Which ``(state, slot)`` pairs of the rows lead to another state (routes go along them); with ``retry`` also
        closed roads whose retry is due. Never out of an aliased state."""
        successors = self.target[rows]
        routable = np.isin(self.outcome[rows], ROUTES)
        if retry:
            routable |= self.retry_due(rows)
        moves = routable & (successors >= 0) & (successors != rows[:, None])
        if self.aliased:
            moves &= ~np.isin(rows, list(self.aliased))[:, None]
        return moves

    def is_undersampled(self, state: int, slot: int) -> bool:
        """Whether a move was tried, but fewer than :data:`UNDERSAMPLED_BELOW` times, in a world shown stochastic
        (never in a deterministic one: there a move tried once is known), out of a state that is not aliased."""
        tries = sum(self.counts.get((state, slot), {}).values())
        return bool(self.n_stochastic) and 0 < tries < UNDERSAMPLED_BELOW and state not in self.aliased

    def undersampled(self) -> np.ndarray:
        """:meth:`is_undersampled` of every ``(state, slot)`` of the used rows."""
        wanted = np.zeros((self.n_rows, self.n_slots), dtype=bool)
        if self.n_stochastic:
            for state, slot in self.counts:
                wanted[state, slot] = state < self.n_rows and self.is_undersampled(state, slot)
        return wanted

    def untried(self, rows: np.ndarray) -> np.ndarray:
        return self.outcome[rows] == Outcome.UNTRIED

    def n_tried(self) -> int:
        """Pairs tried (inferred outcomes are not tries)."""
        outcomes = self.outcome[: self.n_rows]
        return int(np.isin(outcomes, (Outcome.DRIVEN, Outcome.BLOCKED, Outcome.DEAD_END, Outcome.OUTSIDE)).sum())

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        for name in _FILL:
            state[name] = getattr(self, name)[: self.n_rows].copy()
        state["_led_to_index"] = None  # read anew from the disputes when asked
        return state

    def __setstate__(self, state: dict) -> None:
        state.setdefault("twins", set())  # saved before states were merged
        state.setdefault("disputed", [])  # saved before states were split
        state.setdefault("one_place_twice", False)
        for name in ("counts", "_last_end", "_changes"):  # saved before outcomes were counted
            state.setdefault(name, {})
        state.setdefault("n_stochastic", 0)
        state.setdefault("_led_to_index", None)  # saved before it was kept
        state.setdefault("count_outcomes", False)
        if "stochastic" not in state:
            state["stochastic"] = np.zeros_like(state["outcome"], dtype=np.bool_)
        self.__dict__.update(state)
        self._grow(max(1024, 2 * self.n_rows))
