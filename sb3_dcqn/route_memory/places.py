"""Which remembered place a picture shows: the one recogniser behind every "same place?" the route memory asks.

A place is pictured by ``views`` equal blocks (CampusNav: four views in compass order). Two pictures of one place taken
on two visits differ (light, passing cars, a camera a little off, sensor noise); two places differ more. The
recogniser answers each picture with one of three :class:`Answer`\\ s:

- ``KNOWN``: a remembered place (its state);
- ``NEW``: no remembered place (a new state where the caller adds one);
- ``UNSURE``: neither clearly; the caller does not act on it (the critics act, nothing is recorded).

**The fast path** is bit identity: a picture seen before (its 16-byte digest) is its place at once. **Otherwise** the
picture is compared with every place's *prototypes* (the running mean of its pictures; a place has one, or more
where places were merged) view by view, and the *distance* to a prototype is the k-th smallest of the per-view L2
distances, ``k = views - 1`` from four views on: one view may differ wholly (a construction barrier in it, a bus in
front of the camera) and the place is still the place, while two places that share two of four views are never one.
A picture is ``KNOWN`` at distance ``<= known`` from one place when it is clearly the nearest: every other place
``>= new`` away, or ``RATIO`` times as far at least (Lowe's ratio test). It is ``NEW`` at ``>= new`` from every place,
unless some place is within ``known`` in ``k - 1`` views and not far beyond ``new`` (``PRIOR_REACH``) in ``k``: a
place pictured with two odd views, cars before two cameras, is no new place; anything else is ``UNSURE``. A ``NEW``
answer is checked against every state (the screen below may miss the place) up to ``VERIFY_ALL_STATES`` states.
**A query** (a picture recognised without remembering it: evaluation, a rollout's choice of action) also takes the
clearly nearest place short of ``new``, and the one place the picture matches but for two views: a wrong answer
there costs a step, not a place merged with another, and the algorithm's own guess would cost as much. A query's
answer is kept apart: never taken when the same picture is remembered (a rollout asks, then remembers it), nor once
a place was added or merged.

**The graph's prior.** The caller may name the place it expects (where a remembered place and slot led before:
localisation on the graph, as PlaceNav's filter). An expected place within ``known`` is taken without searching;
otherwise it is taken where the picture is within ``new`` of it or ``k - 1`` views are within ``known`` of it, unless
another place is clearly nearer (the ratio); a picture a little beyond ``new`` of it (``PRIOR_REACH``) is ``UNSURE``,
not ``NEW``: a place's odd picture, not a new place. Only a picture far from the expected place is new there (a road
that now leads elsewhere).

**Places merged.** Where the graph shows two states to be one place (:meth:`PlaceRecogniser.merge`: moves from two
places lead to both by turns), the place keeps both prototypes: either kind of picture is the place, and the other
state is never answered again.

**Places split.** Where the graph shows one state to be two places (a move from it led to two places by turns: two
look-alike intersections that share all views but one), the caller has shown the recogniser the pictures of each
side (:meth:`PlaceRecogniser.witness`) and :meth:`PlaceRecogniser.split` gives the second place a state of its own
where the two sides' mean pictures differ clearly in a view. The two are *siblings*: a picture near both (the views
they share) is answered by the view that tells them apart, where one is clearly nearer there (the ratio), else it is
unsure; and the graph's prior never settles a sibling without that look (it was the prior that kept them one).

**Calibration on the agent's own pictures.** The thresholds come from the pictures the memory is shown, not from a
setting: the latest distinct pictures (a window) and the count of exact repeats among them. The distance between two
pictures of the window is either that of two visits of one place (small: noise, light) or of two places (large), so the
distances of all pairs (of a sample of up to ``CALIBRATION_SAMPLE`` pictures) fall into two groups, split where their
sorted logarithms jump the most (exact repeats count as distance 0; views that two pictures share bit for bit are left
out of their distance, so a world of a few renders per view calibrates on the renders' differences). With ``g`` the 90th
percentile of the repeat group and ``i`` the 10th of the other, ``known`` and ``new`` split ``[g, i]`` into thirds on a
log scale, where ``i`` is the lower of that and the 10th percentile of each picture's nearest other place (look-alike
places lie there): the nearest picture not linked to it by a chain of repeat-group distances (a place pictured in
drifting light has visits far apart, reached through the visits between; they are its own, not another place).
Where the pairs' ``i < 1.5 g`` the pictures do not separate places: until they first do,
:attr:`PlaceRecogniser.separable` is ``False`` and every picture that is not an exact repeat of a remembered one is
``UNSURE`` (so no state is made before the first calibration, at ``min_calibration`` distinct pictures). The thresholds
are renewed each time the window's distinct pictures double until it is full (a first calibration on a few pictures
does not stand for long), then each time ``window`` new pictures have been shown, so they follow a world whose
pictures drift; a window that does not separate keeps the last thresholds.

Cost: a search screens every place by a sketch of its prototype (a seeded random projection to ``SKETCH_DIM``
numbers; a batch of pictures is one matrix product) and compares the ``SCREEN_CANDIDATES`` nearest exactly, view by
view; an expected place that matches costs one comparison. Bytes: per state a float32 prototype, an int32
count and a 16-byte digest for each of at most ``MAX_DIGESTS_PER_STATE`` pictures; the window's pictures.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from enum import IntEnum

import numpy as np

__all__ = ["MAX_DIGESTS_PER_STATE", "Answer", "PlaceRecogniser", "digest", "linked_groups", "widest_gap"]

MAX_DIGESTS_PER_STATE = 8  # exact pictures remembered per place: repeats are found at once, varied ones by search
SEARCH = -1  # _quick's word for "a search is needed"
SKETCH_DIM = 32  # numbers per picture in the screen
SCREEN_CANDIDATES = 32  # states the screen hands to the exact comparison (all of them where there are fewer)
SCREEN_CHUNK = 256  # pictures screened against every state at once
RECENT_PICTURES = 256  # beyond those, the latest pictures recognised (a transition's end is the next one's start)
PROTOTYPE_HORIZON = 32  # a prototype is the mean of a place's last pictures, about this many
KNOWN_SHARE = 1 / 3  # of the log gap between repeat visits and other places: KNOWN below, UNSURE up to NEW_SHARE
NEW_SHARE = 2 / 3
RATIO = 0.8  # Lowe's ratio test: a place is clearly the nearest at most this share of the next one's distance
VERIFY_ALL_STATES = 4_096  # up to this many states a "new" picture is checked against all (about a millisecond)
PRIOR_REACH = 1.25  # of "new": a picture this near a place that it matches in k - 1 views, or that the graph expects,
# is no new place (unsure at most)
SEPARATION = 1.5  # the other places' low quantile over the repeat visits' high one: below this, no two groups
GENUINE_QUANTILE = 90.0
IMPOSTOR_QUANTILE = 10.0
CALIBRATION_SAMPLE = 256  # pictures of the window whose every pair is measured (32,640 pairs)
MIN_GROUP = 3  # pairs on each side of the split, at least
MAX_WITNESSED_STATES = 256  # states whose sides' pictures are kept for a split (the oldest forgotten)
_EXACT_FLOOR = 1e-4  # an exact repeat's distance, relative to the median distance between places (for logarithms)
_IDENTICAL_VIEW = 1e-9  # a view's squared distance below this share of its squared norms: the same view, float error


class Answer(IntEnum):
    """The recogniser's answer for one picture."""

    KNOWN = 0
    NEW = 1
    UNSURE = 2


def digest(data: bytes) -> bytes:
    """The memory's one digest: 16 bytes of BLAKE2b."""
    return hashlib.blake2b(data, digest_size=16).digest()


def widest_gap(values: np.ndarray, min_group: int, above: float = -np.inf, below: float = np.inf) -> int | None:
    """
    The index ``j`` where sorted ``values`` jump the most from ``values[j - 1]`` to ``values[j]``, with at least
    ``min_group`` values on either side, ``values[j] > above`` and ``values[j - 1] < below`` (``None``: no such index).
    """
    if len(values) < 2 * min_group:
        return None
    gaps = np.diff(values)[min_group - 1 : len(values) - min_group]
    upper, lower = values[min_group : len(values) - min_group + 1], values[min_group - 1 : len(values) - min_group]
    gaps = np.where((upper > above) & (lower < below), gaps, -np.inf)
    if not np.isfinite(gaps).any():
        return None
    return int(np.argmax(gaps)) + min_group


def linked_groups(linked: np.ndarray) -> np.ndarray:
    """The connected components of a symmetric boolean adjacency matrix: per node, the smallest node of its group."""
    groups = np.arange(len(linked))
    itself_or_linked = linked | np.eye(len(linked), dtype=bool)
    while groups.size:
        # every node takes the smallest group among itself and its neighbours, until no group changes
        reached = np.where(itself_or_linked, groups[None, :], len(linked)).min(axis=1)
        reached = reached[reached]  # jump along the chain: halves the rounds
        if np.array_equal(reached, groups):
            break
        groups = reached
    return groups


class PlaceRecogniser:
    """
    The states of a route memory and the pictures that show them (see the module docstring).

    :param dim: Length of a picture (all views; 0 with ``similar=False``: set by the caller before the first picture)
    :param views: Equal blocks of a picture, one per view
    :param similar: Recognise pictures by similarity; ``False``: by bit identity only (poses, integer observations)
    :param max_states: The most states remembered (then a new picture gets no state)
    :param window: Distinct pictures kept to calibrate on
    :param min_calibration: Distinct pictures needed before the first calibration
    """

    def __init__(
        self,
        dim: int,
        views: int = 1,
        similar: bool = True,
        max_states: int = 1_000_000,
        window: int = 512,
        min_calibration: int = 32,
    ) -> None:
        if views < 1 or (similar and (dim < 1 or dim % views)):
            raise ValueError(f"a picture of {dim} numbers does not split into {views} equal views")
        if window < min_calibration or min_calibration < 4:
            raise ValueError(f"window ({window}) must be >= min_calibration ({min_calibration}) >= 4")
        self.dim = int(dim)
        self.views = int(views)
        self.similar = bool(similar)
        self.max_states = int(max_states)
        self.window = int(window)
        self.min_calibration = int(min_calibration)
        # The k-th smallest per-view distance is a place's distance: one view may differ wholly from four views on
        self.kth = views - 1 if views >= 4 else views
        self.known: float | None = None  # thresholds, set by calibration
        self.new: float | None = None
        self.separable: bool | None = None  # None: not calibrated yet
        self.n_states = 0
        self.version = 0  # counts new states and calibrations: what a picture is recognised as may have changed
        self._exact: dict[bytes, int] = {}  # a picture's digest: the prototype it was recognised by
        self._owner = np.zeros(0, dtype=np.int64)  # per prototype: its place (itself, until merged into another)
        self._members: dict[int, list[int]] = {}  # a place with several prototypes (merged): all of them
        self._siblings: dict[int, set[int]] = {}  # places split from one state: each one's look-alikes
        # Per state, per side (the caller's label: where a move from it led), the sum and count of its pictures
        self._witnessed: OrderedDict[int, dict[object, tuple[np.ndarray, int]]] = OrderedDict()
        self._recent: OrderedDict[bytes, int] = OrderedDict()  # pictures recognised lately (past the digest cap)
        # A query's answers lately, with the version they were given at: a query is lenient (a wrong answer costs a
        # step), so its answer is never taken for a picture being remembered, nor once a place was added or merged or
        # the thresholds recalibrated
        self._queried: OrderedDict[bytes, tuple[int, int]] = OrderedDict()
        self._digests_of = np.zeros(0, dtype=np.int8)  # per state: exact pictures remembered
        self._prototypes = np.zeros((views, 0, max(dim, 1) // views), dtype=np.float32)  # (view, state, features)
        # The screen: each prototype projected to SKETCH_DIM numbers by one seeded Gaussian matrix
        self._projection = (
            np.random.default_rng(0)
            .normal(0.0, 1.0 / np.sqrt(SKETCH_DIM), (max(dim, 1), SKETCH_DIM))
            .astype(np.float32)
            if similar
            else np.zeros((0, SKETCH_DIM), dtype=np.float32)
        )
        self._sketches = np.zeros((0, SKETCH_DIM), dtype=np.float32)
        self._sketch_squares = np.zeros(0, dtype=np.float32)
        self._counts = np.zeros(0, dtype=np.int32)
        # Calibration: the latest distinct pictures (a ring), exact repeats among what was shown, and shown since
        self._window_rows = np.zeros((0, dim), dtype=np.float32)
        self._window_digests: dict[bytes, int] = {}
        self._next_slot = 0
        self._repeats = 0
        self._shown_since = 0
        self.calibrations = 0
        self.genuine: float | None = None  # the calibration's two quantiles
        self.impostor: float | None = None

    # ------------------------------------------------------------------ sizes
    @property
    def calibrated(self) -> bool:
        return self.separable is not None

    @property
    def window_full(self) -> bool:
        """Whether the window holds ``window`` distinct pictures (a failed calibration is then final)."""
        return len(self._window_rows) >= self.window

    def nbytes(self) -> int:
        """Bytes of the prototypes, counts, digests and the calibration window."""
        picture = (self.dim + SKETCH_DIM + 1) * 4 if self.similar else 0
        states = self.n_states * (picture + 4 + 1) + 16 * (len(self._exact) + len(self._recent) + len(self._queried))
        return states + self._window_rows.nbytes + 16 * len(self._window_digests)

    # ------------------------------------------------------------------ calibration
    def show(self, rows: np.ndarray) -> None:
        """Pictures the agent saw (every one it is fed, once): the sample thresholds are calibrated on."""
        if not self.similar:
            return
        rows = self._as_rows(rows)
        for row in rows:
            key = digest(row.tobytes())
            if key in self._window_digests:
                self._repeats += 1
                continue
            if len(self._window_rows) < self.window:
                self._window_rows = np.concatenate([self._window_rows, row[None]])
                slot = len(self._window_rows) - 1
            else:  # the oldest distinct picture makes room
                slot = self._next_slot
                self._next_slot = (slot + 1) % self.window
                old = digest(self._window_rows[slot].tobytes())
                self._window_digests.pop(old, None)
                self._window_rows[slot] = row
            self._window_digests[key] = slot
            self._shown_since += 1
            if self._due():
                self.calibrate()

    def _due(self) -> bool:
        distinct = len(self._window_rows)
        if self.separable and distinct >= self.window:
            return self._shown_since >= self.window
        # Until the window is full: at min_calibration distinct pictures, then each time their number doubles (a first
        # calibration on a few pictures is renewed as soon as there are twice as many)
        return distinct >= self.min_calibration and (distinct & (distinct - 1) == 0 or distinct == self.window)

    def calibrate(self) -> bool:
        """Set the thresholds from the window (see the module docstring); returns whether the pictures separate."""
        rows = self._window_rows
        self.calibrations += 1
        self.version += 1
        self._shown_since = 0
        if len(rows) < 2:
            return False
        if len(rows) > CALIBRATION_SAMPLE:  # every pair of a seeded sample of the window
            rows = rows[np.random.default_rng(self.calibrations).choice(len(rows), CALIBRATION_SAMPLE, replace=False)]
        matrix = self._pair_distances(rows)
        pairs = matrix[np.triu_indices(len(rows), k=1)]
        pairs = pairs[~np.isnan(pairs)]
        if len(pairs) < 2:
            return False
        zeros = np.zeros(min(self._repeats, len(pairs)), dtype=np.float64)
        self._repeats = 0
        scale = float(np.median(pairs)) if np.median(pairs) > 0 else 1.0
        logs = np.sort(np.log(np.maximum(np.concatenate([zeros, pairs]), _EXACT_FLOOR * scale)))
        # Each group holds a quarter as many pairs as pictures at least (a handful of pairs in the tail of one spread of
        # distances, pictures that never repeat a place, is no group of repeat visits); once places have separated, a
        # later split never puts the repeat visits seen then among the other places (a window of a few routes'
        # pictures has gaps inside the repeat visits too), nor the other places seen then among the repeat visits (a
        # window with a few odd pictures, far from everything, has a gap inside the other places too)
        above = -np.inf if self.genuine is None else float(np.log(self.genuine))
        below = np.inf if self.impostor is None else float(np.log(self.impostor))
        split = widest_gap(logs, max(MIN_GROUP, len(logs) // 1000, len(rows) // 4), above, below)
        separates = False
        if split is not None:
            genuine = float(np.exp(np.percentile(logs[:split], GENUINE_QUANTILE)))
            impostor = float(np.exp(np.percentile(logs[split:], IMPOSTOR_QUANTILE)))
            separates = impostor >= SEPARATION * genuine
        if separates:
            self.genuine, self.impostor = genuine, impostor
            # "New" means no remembered place is near, so the edge is the nearest other place of each picture (a low
            # quantile of those), not of a random pair: look-alike places lie there, and between known and new they
            # would stay unsure at every visit
            # A picture's repeat visits beyond the split are still linked to it by a chain of visits within it (the
            # place seen in between): the nearest other place is the nearest picture of another chain
            chains = linked_groups(matrix < np.exp(logs[split]))  # a pair left out (NaN) links nothing
            other = np.where(chains[:, None] != chains[None, :], matrix, np.nan)
            has_other = ~np.isnan(other).all(axis=1)
            if has_other.any():
                nearest = np.nanmin(other[has_other], axis=1)
                impostor = min(impostor, float(np.percentile(nearest, IMPOSTOR_QUANTILE)))
            gap = np.log(impostor) - np.log(genuine)
            self.known = float(np.exp(np.log(genuine) + KNOWN_SHARE * gap))
            self.new = float(np.exp(np.log(genuine) + NEW_SHARE * gap))
        # Once the pictures have separated places, a window that does not (look-alike places met together) keeps the
        # thresholds: whether recognition still works is the memory's guard's to say, from what it recognises
        self.separable = separates or bool(self.separable)
        return separates

    def _pair_distances(self, rows: np.ndarray) -> np.ndarray:
        """
        The place distance of every pair of rows, over the views in which the two differ: a symmetric matrix, NaN on
        the diagonal and for a pair left out.
        """
        blocks = rows.reshape(len(rows), self.views, -1).transpose(1, 0, 2).astype(np.float64)
        squares = (blocks**2).sum(axis=2)  # (view, row)
        sums = squares[:, :, None] + squares[:, None, :]
        per_view = np.maximum(sums - 2.0 * blocks @ blocks.transpose(0, 2, 1), 0.0)
        # A view pictured bit for bit as on another visit (a world of a few renders per view) says nothing of how far
        # repeat visits vary: a pair's distance is the same quantile (the k-th of the views) of the views that differ,
        # and a pair that differs in one view of several is left out (one view is no place's spread)
        identical = per_view <= _IDENTICAL_VIEW * sums
        per_view = np.sort(np.where(identical, np.inf, np.sqrt(per_view)), axis=0)
        differ = self.views - identical.sum(axis=0)
        rank = np.maximum(-(-self.kth * differ // self.views) - 1, 0)
        distance = np.take_along_axis(per_view, rank[None], axis=0)[0]
        distance[differ == 0] = 0.0
        if self.views > 1:
            distance[differ == 1] = np.nan
        np.fill_diagonal(distance, np.nan)
        return distance

    # ------------------------------------------------------------------ recognition
    def recognise(
        self, rows: np.ndarray, *, add: bool = False, expected: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """
        The state and :class:`Answer` of each picture.

        :param rows: ``(batch, dim)`` pictures
        :param add: A ``NEW`` picture becomes a new state (while fewer than ``max_states``), a ``KNOWN`` one updates its
            place's prototype
        :param expected: Per picture, the state the caller expects it to show (-1: none)
        :return: int64 states (-1: none) and int8 answers
        """
        rows = self._as_rows(rows)
        states = np.full(len(rows), -1, dtype=np.int64)
        answers = np.full(len(rows), Answer.UNSURE, dtype=np.int8)
        hints = np.full(len(rows), -1, dtype=np.int64) if expected is None else np.asarray(expected, dtype=np.int64)
        keys = [digest(row.tobytes()) for row in rows]
        if add:  # in order: each picture may make the state a later one is
            for index, (row, key) in enumerate(zip(rows, keys, strict=True)):
                states[index], answers[index] = self._recognise_one(row, key, add, int(hints[index]))
            return states, answers
        # Queries only (evaluation: many pictures at once): what needs a search is screened in one matrix product
        searched = []
        for index, (row, key) in enumerate(zip(rows, keys, strict=True)):
            states[index], answers[index] = self._quick(row, key, int(hints[index]), add)
            if answers[index] == SEARCH:
                searched.append(index)
        if searched:
            pools = self._candidates(rows[searched])
            for position, index in enumerate(searched):
                pool = None if pools is None else pools[position]
                states[index], answers[index] = self._search(rows[index], keys[index], add, int(hints[index]), pool)
        return states, answers

    def _recognise_one(self, row: np.ndarray, key: bytes, add: bool, expected: int) -> tuple[int, int]:
        state, answer = self._quick(row, key, expected, add)
        if answer != SEARCH:
            return state, answer
        pool = self._candidates(row[None])
        return self._search(row, key, add, expected, None if pool is None else pool[0])

    def _quick(self, row: np.ndarray, key: bytes, expected: int, add: bool) -> tuple[int, int]:
        """What needs no search: a picture seen before, the expected place, no calibration yet (else ``SEARCH``)."""
        found = self._exact.get(key, self._recent.get(key))
        if found is not None:
            return int(self._owner[found]), Answer.KNOWN
        asked = None if add else self._queried.get(key)
        if asked is not None and asked[1] == self.version:
            return int(self._owner[asked[0]]), Answer.KNOWN
        if not self.similar:
            return self._new(row, key, add), Answer.NEW
        if not self.separable:
            return -1, Answer.UNSURE
        if self.n_states == 0:
            return self._new(row, key, add), Answer.NEW
        assert self.known is not None
        if 0 <= expected < self.n_states and expected not in self._siblings:  # a sibling is told apart by search
            members = self.members(expected)
            distances = self._exact_distances(row, members)
            if distances.min() <= self.known:
                return self._known(row, key, int(members[distances.argmin()]), add), Answer.KNOWN
        return -1, SEARCH

    def _search(
        self, row: np.ndarray, key: bytes, add: bool, expected: int, pool: np.ndarray | None
    ) -> tuple[int, int]:
        """The answer from the nearest two states of the pool (every state where ``None``) and the expected place."""
        assert self.known is not None and self.new is not None
        candidates = np.arange(self.n_states) if pool is None else pool
        # Each candidate's per-view distances, sorted: read by every rule below (the k-th is the place distance)
        unsorted = self._per_view_distances(row, candidates)
        per_view = np.sort(unsorted, axis=0)
        nearest, first, second = self._two_nearest(candidates, per_view[self.kth - 1])
        told = self._told_apart(candidates, unsorted, per_view[self.kth - 1], self.known if add else self.new)
        if told is not None:  # look-alike siblings: the view that tells them apart decides, not the views they share
            if told >= 0:
                return self._known(row, key, told, add), Answer.KNOWN
        # Within "known" of one place and clearly nearer it than any other (no second within "new", or Lowe's ratio)
        elif first <= self.known and (second >= self.new or first <= RATIO * second):
            return self._known(row, key, nearest, add), Answer.KNOWN
        elif not add:
            # A query (nothing is remembered) takes the clearly nearest place short of "new", or the one place the
            # picture matches but for two odd views: a wrong answer costs a step, not a place merged with another
            if first < self.new and first <= RATIO * second:
                return self._known(row, key, nearest, add), Answer.KNOWN
            matching = candidates[self._matching_but_two_views(per_view)]
            if matching.size and (self._owner[matching] == self._owner[matching[0]]).all():
                return self._known(row, key, int(matching[0]), add), Answer.KNOWN
        if 0 <= expected < self.n_states:
            # The graph's prior settles what the picture leaves unsure: the expected place where the picture is within
            # "new" of it or two views agree with it (cars before the other two), unless another place is clearly
            # nearer; and a picture a little beyond "new" of it is its odd picture, not a new place
            per_view = np.sort(self._per_view_distances(row, self.members(expected)), axis=0)
            closest = int(per_view[self.kth - 1].argmin())
            views, prototype = per_view[:, closest], int(self.members(expected)[closest])
            to_expected = float(views[self.kth - 1])
            agrees = to_expected < self.new or (self.kth >= 2 and views[self.kth - 2] < self.known)
            if agrees and first >= RATIO * to_expected:
                return self._known(row, key, prototype, add), Answer.KNOWN
            if to_expected < PRIOR_REACH * self.new:
                return -1, Answer.UNSURE
        if first >= self.new and (not add or self._unlike_every_place(row, pool, per_view)):  # a query adds none
            return self._new(row, key, add), Answer.NEW
        return -1, Answer.UNSURE

    def _told_apart(
        self, candidates: np.ndarray, per_view: np.ndarray, distances: np.ndarray, reach: float
    ) -> int | None:
        """
        Where the two nearest places (place distances within ``new``) are look-alike siblings (split by the graph:
        their prototypes share all views but one, which is ``new`` apart or more), the one clearly nearer (the ratio)
        in that view and within ``reach``, else -1; ``None`` where they are no such pair.
        """
        assert self.new is not None
        if not self._siblings:  # nothing split yet: the common case costs nothing
            return None
        nearest = int(np.argmin(distances))
        owner = int(self._owner[candidates[nearest]])
        if owner not in self._siblings or distances[nearest] >= self.new:
            return None
        others = np.flatnonzero(self._owner[candidates] != owner)
        if not others.size:
            return None
        first, second = nearest, int(others[np.argmin(distances[others])])
        if distances[second] >= self.new or int(self._owner[candidates[second]]) not in self._siblings[owner]:
            return None
        apart = self._prototypes[:, candidates[first]] - self._prototypes[:, candidates[second]]
        apart_views = np.sqrt((apart.astype(np.float64) ** 2).sum(axis=1))
        view = int(np.argmax(apart_views))
        if np.sort(apart_views)[self.kth - 1] >= self.new or apart_views[view] < self.new:
            return None
        near, far = sorted((first, second), key=lambda index: per_view[view, index])
        if per_view[view, near] <= RATIO * per_view[view, far] and distances[near] <= reach:
            return int(candidates[near])
        return -1

    def _unlike_every_place(self, row: np.ndarray, pool: np.ndarray | None, pool_per_view: np.ndarray) -> bool:
        """
        Whether no remembered place is within ``new`` in ``kth`` views, nor matches the picture but for two odd views
        (:meth:`_matching_but_two_views`): a place pictured with cars before two cameras is no new place (unsure).
        Checked on every state up to ``VERIFY_ALL_STATES`` (the screen's pool may miss the place), on the pool beyond
        (``pool_per_view``: the pool's sorted per-view distances, already measured).
        """
        assert self.new is not None
        per_view = pool_per_view
        if pool is not None and self.n_states <= VERIFY_ALL_STATES:
            per_view = np.sort(self._per_view_distances(row, np.arange(self.n_states)), axis=0)
        return not (per_view[self.kth - 1] < self.new).any() and not self._matching_but_two_views(per_view).any()

    def _matching_but_two_views(self, per_view: np.ndarray) -> np.ndarray:
        """Per prototype (columns of sorted per-view distances): within ``known`` in ``kth - 1`` views and a little
        beyond ``new`` (``PRIOR_REACH``) in ``kth``."""
        assert self.known is not None and self.new is not None
        if self.kth < 2:
            return np.zeros(per_view.shape[1], dtype=bool)
        return (per_view[self.kth - 2] < self.known) & (per_view[self.kth - 1] < PRIOR_REACH * self.new)

    def alike(self, first: int, second: int) -> bool:
        """Whether two states' prototypes are nearer than ``new``: places the recogniser cannot tell apart (a place
        remembered twice, say); never for bit identity or before the thresholds are set."""
        if not self.similar or self.new is None:
            return False
        if int(self._owner[first]) == int(self._owner[second]):
            return True
        if first not in self._members and second not in self._members:  # one prototype each (most places): one reading
            return bool(self._exact_distances(self._prototypes[:, first].reshape(-1), np.array([second]))[0] < self.new)
        return any(
            self._exact_distances(self._prototypes[:, member].reshape(-1), self.members(second)).min() < self.new
            for member in self.members(first).tolist()
        )

    def distances(self, row: np.ndarray) -> np.ndarray:
        """The place distance of one picture to every state."""
        return self._exact_distances(self._as_rows(np.asarray(row)[None])[0], np.arange(self.n_states))

    def _exact_distances(self, row: np.ndarray, states: np.ndarray) -> np.ndarray:
        """The place distance of one picture to some states: the k-th smallest per-view L2 distance (float64)."""
        return np.partition(self._per_view_distances(row, states), self.kth - 1, axis=0)[self.kth - 1]

    def _per_view_distances(self, row: np.ndarray, states: np.ndarray) -> np.ndarray:
        """``(views, states)``: each view's L2 distance from one picture to some states' prototypes (float64)."""
        blocks = row.reshape(self.views, 1, -1).astype(np.float64)
        difference = self._prototypes[:, states].astype(np.float64) - blocks  # (view, state, features)
        return np.sqrt((difference**2).sum(axis=2))

    def _candidates(self, rows: np.ndarray) -> np.ndarray | None:
        """
        Per picture of a batch, the ``SCREEN_CANDIDATES`` states nearest in the sketch (a random projection of the whole
        picture to ``SKETCH_DIM`` numbers: distances kept to within a few tens of percent, at a tenth of the reading);
        ``None`` where there are few enough states to compare with all.
        """
        n = self.n_states
        if n <= SCREEN_CANDIDATES:
            return None
        sketches = rows @ self._projection
        chosen = np.empty((len(rows), SCREEN_CANDIDATES), dtype=np.int64)
        for start in range(0, len(rows), SCREEN_CHUNK):  # a chunk of queries against every state at once
            block = sketches[start : start + SCREEN_CHUNK]
            squared = self._sketch_squares[:n] - 2.0 * block @ self._sketches[:n].T
            chosen[start : start + SCREEN_CHUNK] = np.argpartition(squared, SCREEN_CANDIDATES - 1, axis=1)[
                :, :SCREEN_CANDIDATES
            ]
        return chosen

    def _two_nearest(self, pool: np.ndarray, distances: np.ndarray) -> tuple[int, float, float]:
        """The nearest prototype of a pool (given its place distances), its distance and that of the nearest prototype
        of another place (``inf``: none)."""
        nearest = int(distances.argmin())
        others = self._owner[pool] != self._owner[pool[nearest]]
        second = float(distances[others].min()) if others.any() else np.inf
        return int(pool[nearest]), float(distances[nearest]), second

    # ------------------------------------------------------------------ states
    def _new(self, row: np.ndarray, key: bytes, add: bool) -> int:
        if not add or self.n_states >= self.max_states:
            return -1
        state = self._add_state(row)
        self._remember_digest(key, state)
        return state

    def _add_state(self, row: np.ndarray) -> int:
        """A new state pictured by ``row`` (its first picture)."""
        state = self.n_states
        if state == len(self._counts):
            self._grow(max(64, 2 * state))
        if self.similar:  # bit identity needs no picture kept
            self._prototypes[:, state] = row.reshape(self.views, -1)
            self._sketch(state)
        self._counts[state] = 1
        self._owner[state] = state
        self.n_states += 1
        self.version += 1
        return state

    def _known(self, row: np.ndarray, key: bytes, state: int, add: bool) -> int:
        """A picture of prototype ``state``: with ``add`` its views move the prototype (all but a view that differs
        wholly). Returns its place."""
        if not add:
            self._remember_query(key, state)
            return int(self._owner[state])
        self._remember_digest(key, state)
        blocks = row.reshape(self.views, -1)
        difference = blocks - self._prototypes[:, state]
        per_view = np.sqrt((difference.astype(np.float64) ** 2).sum(axis=1))
        agreeing = per_view <= np.partition(per_view, self.kth - 1)[self.kth - 1]
        count = min(int(self._counts[state]) + 1, PROTOTYPE_HORIZON)
        self._prototypes[agreeing, state] += difference[agreeing] / count
        self._sketch(state)
        self._counts[state] = count
        return int(self._owner[state])

    def _sketch(self, state: int) -> None:
        sketch = self._prototypes[:, state].reshape(-1) @ self._projection
        self._sketches[state] = sketch
        self._sketch_squares[state] = sketch @ sketch

    def _remember_digest(self, key: bytes, state: int) -> None:
        if self._digests_of[state] < MAX_DIGESTS_PER_STATE:
            self._exact[key] = state
            self._digests_of[state] += 1
        else:
            self._remember_recent(key, state)

    def _remember_recent(self, key: bytes, state: int) -> None:
        """A picture met again within a few steps (an observation is the next one's start) is found at once."""
        _keep_latest(self._recent, key, state)

    def _remember_query(self, key: bytes, state: int) -> None:
        """A query's answer, found at once when the same picture is asked again (a rollout's step, then the next)."""
        _keep_latest(self._queried, key, (state, self.version))

    def _grow(self, capacity: int) -> None:
        old = len(self._counts)
        if self.similar:
            views, _, features = self._prototypes.shape
            prototypes = np.zeros((views, capacity, features), dtype=np.float32)
            prototypes[:, :old] = self._prototypes[:, :old]
            sketches = np.zeros((capacity, SKETCH_DIM), dtype=np.float32)
            sketches[:old] = self._sketches[:old]
            sketch_squares = np.zeros(capacity, dtype=np.float32)
            sketch_squares[:old] = self._sketch_squares[:old]
            self._prototypes, self._sketches, self._sketch_squares = prototypes, sketches, sketch_squares
        self._counts = np.concatenate([self._counts, np.zeros(capacity - old, dtype=np.int32)])
        self._digests_of = np.concatenate([self._digests_of, np.zeros(capacity - old, dtype=np.int8)])
        self._owner = np.concatenate([self._owner, np.arange(old, capacity, dtype=np.int64)])

    def merge(self, keep: int, drop: int) -> None:
        """
        Two places that are one (the caller's evidence: the graph): ``drop``'s prototypes become ``keep``'s. The place
        keeps each of them (a place pictured two ways, say by day and with a lorry parked before it, is recognised by
        either); no picture is answered as ``drop`` again.
        """
        if keep == drop or not (self.live(keep) and self.live(drop)):
            return
        members = [*self.members(keep).tolist(), *self.members(drop).tolist()]
        self._owner[members] = keep
        self._members[keep] = members
        self._members.pop(drop, None)
        self._witnessed.pop(drop, None)
        # The place keeps the look-alikes of both
        self._make_siblings((self._siblings.pop(drop, set()) | self._siblings.get(keep, set()) | {keep}) - {drop})
        self.version += 1

    def witness(self, state: int, side: object, row: np.ndarray) -> None:
        """
        A picture of ``state`` taken where a move from it led to ``side`` (the caller's label, say the slot and the
        state it led to): the sides' mean pictures are what :meth:`split` tells apart. Kept for the
        ``MAX_WITNESSED_STATES`` states witnessed last.
        """
        if not self.similar or not self.live(state):
            return
        sides = self._witnessed.setdefault(state, {})
        self._witnessed.move_to_end(state)
        total, count = sides.get(side, (np.zeros(self.dim, dtype=np.float64), 0))
        sides[side] = (total + self._as_rows(np.asarray(row)[None])[0], count + 1)
        while len(self._witnessed) > MAX_WITNESSED_STATES:
            self._witnessed.popitem(last=False)

    def split(self, state: int, kept: object, other: object) -> int:
        """
        One state found to be two places (the caller's evidence: the graph): the pictures witnessed on side ``other``
        become a new state, a sibling of ``state``, which keeps side ``kept``'s (their means are the two prototypes;
        the state's exact pictures are forgotten, as they may be of either). Returns the new state, or -1 where the
        two sides' mean pictures differ in no view by ``new`` or more (nothing to tell them apart by) or no state is
        left.
        """
        apart = self.sides_apart(state, kept, other)
        if apart is None or self.n_states >= self.max_states:
            return -1
        differ = apart >= self.new
        if not differ.any():
            return -1
        kept_mean, other_mean = (self._side_mean(state, side) for side in (kept, other))
        # The views the two share keep the state's prototype (the mean of many visits); those that tell them apart
        # are each side's own
        prototype = self._prototypes[:, state].copy()
        prototype[differ] = other_mean[differ]
        sibling = self._add_state(prototype.reshape(-1))
        self._prototypes[differ, state] = kept_mean[differ]
        self._sketch(state)
        self._exact = {key: owner for key, owner in self._exact.items() if owner != state}
        self._recent = OrderedDict((key, owner) for key, owner in self._recent.items() if owner != state)
        self._digests_of[state] = 0
        self._make_siblings(self._siblings.get(state, set()) | {state, sibling})
        del self._witnessed[state]
        return sibling

    def _make_siblings(self, family: set[int]) -> None:
        """Each place of ``family`` has the others for siblings (a family of one has none)."""
        for member in family:
            self._siblings[member] = family - {member}
            if not self._siblings[member]:
                del self._siblings[member]

    def sides_apart(self, state: int, first: object, second: object) -> np.ndarray | None:
        """Per view, the distance between the mean pictures witnessed on two sides of a state (``None``: a side not
        witnessed, or no thresholds yet)."""
        sides = self._witnessed.get(state, {})
        if first not in sides or second not in sides or self.new is None:
            return None
        return np.sqrt(((self._side_mean(state, first) - self._side_mean(state, second)) ** 2).sum(axis=1))

    def _side_mean(self, state: int, side: object) -> np.ndarray:
        """``(views, features)``: the mean picture witnessed on one side of a state."""
        total, count = self._witnessed[state][side]
        return (total / count).reshape(self.views, -1)

    def siblings(self, state: int) -> set[int]:
        """The places split from the same state as ``state`` (look-alikes the graph told apart)."""
        return set(self._siblings.get(state, ()))

    def live(self, state: int) -> bool:
        """Whether a state is a place (not merged into another)."""
        return 0 <= state < self.n_states and int(self._owner[state]) == state

    def live_states(self) -> np.ndarray:
        """The states that are places (not merged into another)."""
        return np.flatnonzero(self._owner[: self.n_states] == np.arange(self.n_states))

    def members(self, state: int) -> np.ndarray:
        """The prototypes of a place (itself, unless others were merged into it)."""
        return np.array(self._members.get(state, [state]), dtype=np.int64)

    def prototypes(self) -> tuple[np.ndarray, np.ndarray]:
        """Every prototype as a row ``(n, dim)`` float32, and the place each is of (a merged place has several)."""
        n = self.n_states
        rows = self._prototypes[:, :n].transpose(1, 0, 2).reshape(n, -1)
        return np.ascontiguousarray(rows), self._owner[:n].copy()

    def prototype(self, state: int) -> np.ndarray:
        """The mean picture of a state, ``(dim,)`` float32."""
        if not 0 <= state < self.n_states:
            raise ValueError(f"state {state} is not one of the {self.n_states} states")
        return self._prototypes[:, state].reshape(-1).copy()

    def _as_rows(self, rows: np.ndarray) -> np.ndarray:
        array = np.ascontiguousarray(rows, dtype=np.float32) if self.similar else np.ascontiguousarray(rows)
        if array.ndim != 2 or array.shape[1] != self.dim:
            raise ValueError(f"pictures must be (batch, {self.dim}), got shape {array.shape}")
        return array

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        n = self.n_states  # the used rows only
        state["_prototypes"] = self._prototypes[:, :n].copy()
        state["_sketches"] = self._sketches[:n].copy()
        state["_sketch_squares"] = self._sketch_squares[:n].copy()
        state["_counts"] = self._counts[:n].copy()
        state["_digests_of"] = self._digests_of[:n].copy()
        state["_owner"] = self._owner[:n].copy()
        return state

    def __setstate__(self, state: dict) -> None:
        if "_owner" not in state:  # saved before places could merge: each prototype its own place
            state["_owner"] = np.arange(len(state["_counts"]), dtype=np.int64)
            state["_members"] = {}
        state.setdefault("_siblings", {})  # saved before places could split
        state.setdefault("_witnessed", OrderedDict())
        state.setdefault("_queried", OrderedDict())  # saved when queries and remembering shared one cache
        self.__dict__.update(state)


def _keep_latest(cache: OrderedDict, key: bytes, value: object) -> None:
    """``cache[key] = value``, the oldest entry dropped past ``RECENT_PICTURES``."""
    cache[key] = value
    if len(cache) > RECENT_PICTURES:
        cache.popitem(last=False)
