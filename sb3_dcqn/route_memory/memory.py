"""A memory that routes: one graph of the agent's own transitions, over places, for every goal.

In a deterministic world with discrete actions whose observations repeat exactly, every transition ``(o, a) -> o'``
the agent makes is an exact, 1-hop edge of the world's graph. :class:`RouteMemory` keeps those edges over **states
that leave the goal out**, so that one graph serves every goal.

**Places, where the env declares its frame** (:mod:`sb3_dcqn.place_frame`; CampusNav does): a state is a *place*,
the digest of the keys that picture it (CampusNav: the four views in compass order), not of the heading; a move is
kept in **compass slots**, ``slot = (frame + action) mod n``, so a move tried at one heading is known at every heading,
and ``predict`` turns a route's slot back into the action for the current heading. With two-way roads declared, a
driven road also records its **reverse** (marked inferred until driven or bumped into: inferred moves route, and are
not untried), and a bump closes the slot for every heading **and the reverse direction**, for every goal at once. A
place whose views change in a few of its blocks (a closure's barrier in one view) is still the same place: unseen
pictures are matched by their per-view digests (at least half of the views equal and one place alone voting). Two
places that picture the same (aliasing) are detected, a slot that led to two different places, each at least twice,
counted in :attr:`RouteMemory.aliased`, and never routed from. **Poses, where it declares nothing**: a state is the
observation without its goal keys, and slots are the actions (the memory before places).

**Goals** are sets of states: the states a terminated success (``info["is_success"]`` where the env gives it, else a
reward above ``success_reward``) reached under that goal, and, where the env declares goal pictures (CampusNav's
``goal_views``, the goal env's ``desired_goal``), the place the goal's pictures show, matched against the agent's
**own** views: exactly, then within ``goal_tolerance``, then by per-view vote, then through a **place matcher** where
the goal's pictures differ from every remembered one (another time of day: :mod:`sb3_dcqn.place_recognition`).
The goal env's ``achieved_goal`` (the env's rendering of the agent's location under the goal's conditions) is never
read when a frame is declared; without one, ``achieved_goal`` pictures attach goals as SB3's goal-env convention says.

**A closed road is a fact with an age.** Each ``(state, slot)`` keeps its latest outcome and when it was last tried
(the memory's clock counts transitions). Evaluation never drives a road seen closed; training's rollouts may route
through a road blocked ``retry_after`` transitions ago or more when that route is shorter, and try it when passing by
(Dyna-Q+'s bonus for time since last tried, D* Lite's replanning after one failed traversal): a reopened road is found
again, for every goal at once. A terminated
transition that is no success (FrozenLake's holes) is a dead end: tried, never routed through.

What it holds (its own store, not the replay buffer's): per state a 16-byte digest, per (state, slot) an int32 target,
an int32 time of the last try and two int8 codes (outcome, arrival frame); per view of a place a 16-byte digest; per
place its picture where goals are matched by pictures; per goal reached its states. It stops taking new states at
``max_states`` (a move into a state past the cap is tried and leads outside: never explored again). The cache of
hops per goal is bounded by ``max_cache_bytes`` (least recently used first out). It pickles, inside the model's file.

Queries (batched, as SB3's ``predict``): :meth:`RouteMemory.route_actions` (the first action of a shortest remembered
route to each observation's goal, -1: none), :meth:`RouteMemory.explore_actions` and
:meth:`RouteMemory.path_to_untried` (towards the nearest untried ``(state, slot)``: Go-Explore's return-then-explore,
the depth-first bound's one try per road end).

After *Semi-parametric Topological Memory* (SPTM, Savinov et al. 2018), *Search on the Replay Buffer* (SoRB,
Eysenbach et al. 2019; here the edges are exact, one hop long), MDP homomorphisms (van der Pol et al. 2020: the
headings of a place folded into one state) and Dyna-Q+'s lesson that one model update re-routes every goal.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict, deque
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np
from gymnasium import spaces

from sb3_dcqn.place_frame import PlaceFrame, place_frame_of

__all__ = [
    "BLOCKED",
    "DEAD_END",
    "DRIVEN",
    "INFERRED",
    "NO_ROUTE",
    "OUTSIDE",
    "UNTRIED",
    "PlaceMatcher",
    "RouteMemory",
    "UntriedExplorer",
    "batch_of_one",
    "default_goal_keys",
    "select_rows",
]

# Outcome of a (state, slot)
UNTRIED = 0  # never tried
DRIVEN = 1  # driven: leads to its target
INFERRED = 2  # the reverse of a driven road (two-way roads): routes use it, exploration does not seek it
BLOCKED = 3  # bumped into: no road, or a closed one (its target kept when it was driven before)
DEAD_END = 4  # its episode ended without success
OUTSIDE = 5  # led to a state past max_states
NO_ROUTE = -1  # hops of a state with no remembered route
ACHIEVED_GOAL_KEY = "achieved_goal"
DEFAULT_RETRY_AFTER = 50  # transitions after which a blocked road may be tried again where it shortens a route
DEFAULT_CACHE_BYTES = 64 * 2**20
MAX_GOALS_SHOWN = 20_000  # distinct goal pictures kept for a place matcher (their conditions' statistics)
_NEVER = np.iinfo(np.int64).max
_ROUTES = (DRIVEN, INFERRED)
_SLOT_ARRAYS = {"outcome": UNTRIED, "target": -1, "arrival": -1, "last_tried": 0}  # fill of untried rows


class PlaceMatcher(Protocol):
    """Finds the remembered place of goal pictures that match none exactly (see :mod:`sb3_dcqn.place_recognition`)."""

    def match(
        self, queries: np.ndarray, references: np.ndarray, labels: np.ndarray, goal_pictures: np.ndarray | None = None
    ) -> np.ndarray:
        """
        :param queries: ``(m, d)`` goal pictures
        :param references: ``(n, d)`` the memory's place pictures
        :param labels: ``(n,)`` each reference's place (pictures of one state share a label)
        :param goal_pictures: ``(k, d)`` the distinct goal pictures the memory was shown (no place named)
        :return: ``(m,)`` the matched reference row of each query, -1: not in memory
        """
        ...


def default_goal_keys(observation_space: spaces.Space | None) -> tuple[str, ...]:
    """The keys of a Dict observation that name a goal: those with "goal" in their name (``desired_goal``,
    ``achieved_goal``, CampusNav's ``goal_views``); none for other spaces."""
    if not isinstance(observation_space, spaces.Dict):
        return ()
    return tuple(sorted(key for key in observation_space.spaces if "goal" in key))


def _digest(data: bytes) -> bytes:
    return hashlib.blake2b(data, digest_size=16).digest()


class RouteMemory:
    """
    One graph of remembered transitions for every goal (see the module docstring).

    States are numbered in the order they were first seen. Per ``(state, slot)``: :attr:`outcome` (:data:`UNTRIED`,
    :data:`DRIVEN`, :data:`INFERRED`, :data:`BLOCKED`, :data:`DEAD_END`, :data:`OUTSIDE`), :attr:`target` (the state
    it leads to, -1 unknown) and :attr:`last_tried` (the clock at the last try).

    :param n_actions: Number of discrete actions (and of slots)
    :param observation_space: The observations' space: arrays are cast to its dtypes before digesting (stored and
        fresh observations then agree), and its Dict keys give the default ``goal_keys``
    :param goal_keys: The Dict keys that name the goal, left out of a pose state (default: :func:`default_goal_keys`)
    :param success_reward: Where the env gives no ``info["is_success"]``, a terminated transition with a reward above
        this reached its goal
    :param max_states: The most states remembered (then new observations are not added)
    :param place_matcher: Finds the place of goal pictures that match none exactly (``None``: exact matches only)
    :param place_frame: The env's declared frame (:class:`~sb3_dcqn.place_frame.PlaceFrame`): states are places and
        moves slots; ``None``: states are poses
    :param retry_after: Training's rollouts may route through a road blocked at least this many transitions ago
    :param max_cache_bytes: Bound on the cached hops per goal
    :param goal_tolerance: Goal vectors that differ by at most this in every entry are one goal (as the env accepts)
    """

    def __init__(
        self,
        n_actions: int,
        observation_space: spaces.Space | None = None,
        goal_keys: Sequence[str] | None = None,
        success_reward: float = 0.0,
        max_states: int = 1_000_000,
        place_matcher: PlaceMatcher | None = None,
        place_frame: PlaceFrame | None = None,
        retry_after: int = DEFAULT_RETRY_AFTER,
        max_cache_bytes: int = DEFAULT_CACHE_BYTES,
        goal_tolerance: float = 1e-4,
    ) -> None:
        if n_actions < 1:
            raise ValueError(f"n_actions must be at least 1, got {n_actions}")
        for name, value in (("max_states", max_states), ("retry_after", retry_after)):
            if int(value) < 1:
                raise ValueError(f"{name} must be at least 1, got {value}")
        if max_cache_bytes < 0 or goal_tolerance < 0:
            raise ValueError(f"max_cache_bytes and goal_tolerance must be >= 0: {max_cache_bytes}, {goal_tolerance}")
        keys = default_goal_keys(observation_space) if goal_keys is None else tuple(goal_keys)
        if keys and isinstance(observation_space, spaces.Dict):
            unknown = sorted(set(keys) - set(observation_space.spaces))
            if unknown:
                raise ValueError(
                    f"goal_keys {unknown} are not keys of the observation space {sorted(observation_space.spaces)}"
                )
            if set(keys) == set(observation_space.spaces):
                raise ValueError(f"goal_keys {sorted(keys)} leave nothing of the observation for the state")
        elif keys:
            raise ValueError(f"goal_keys {list(keys)} need a Dict observation space, got {observation_space}")
        if place_frame is not None and place_frame.n_slots != n_actions:
            raise ValueError(f"place_frame has {place_frame.n_slots} slots for {n_actions} actions")
        self.n_actions = n_actions
        self.observation_space = observation_space
        self.goal_keys = keys
        self.success_reward = success_reward
        self.max_states = int(max_states)
        self.place_matcher = place_matcher
        self.place_frame = place_frame
        self.retry_after = int(retry_after)
        self.max_cache_bytes = int(max_cache_bytes)
        self.goal_tolerance = float(goal_tolerance)
        # Pictures of goals: declared goal pictures of places, else SB3's achieved_goal (attached to the states seen)
        legacy = place_frame is None and ACHIEVED_GOAL_KEY in keys
        self._achieved_key = ACHIEVED_GOAL_KEY if legacy else None
        self._picture_key = place_frame.goal_key if place_frame is not None else ("desired_goal" if legacy else None)
        # The keys that say which goal is asked for (the achieved goal says where the agent is, not the goal)
        self._asked_keys = tuple(key for key in keys if key != ACHIEVED_GOAL_KEY)
        self._state_keys = place_frame.place_keys if place_frame is not None else None
        self._picture_dtype = np.dtype(np.float32)
        if self._picture_key is not None and isinstance(observation_space, spaces.Dict):
            self._picture_dtype = np.dtype(observation_space[self._picture_key].dtype)
        self._goal_conditioned = legacy or self._picture_key is not None
        self._state_of: dict[bytes, int] = {}  # picture digest -> state (a place may have several pictures)
        self._size = 0  # states numbered so far
        self._view_places: dict[bytes, int] = {}  # digest of (view block index, view) -> state, -2: several
        capacity = 1024
        self.outcome = np.zeros((capacity, n_actions), dtype=np.int8)
        self.target = np.full((capacity, n_actions), -1, dtype=np.int32)
        self.arrival = np.full((capacity, n_actions), -1, dtype=np.int8)  # the frame on arrival (-1 unknown)
        self.last_tried = np.zeros((capacity, n_actions), dtype=np.int32)
        self.clock = 0  # transitions remembered
        self.aliased: set[int] = set()  # states that led to two different states through one slot, each twice
        self._disputes: dict[tuple[int, int], dict[int, int]] = {}  # (state, slot) -> times each outcome was seen
        # Goals given by success transitions: goal digest -> states reached, and the goal vectors seen
        self._reached: dict[bytes, set[int]] = {}
        self._goal_vectors: dict[bytes, np.ndarray] = {}
        # Pictures that show a goal's place: their vectors, and the states each was seen at
        self._picture_of: dict[bytes, int] = {}
        self._pictures: list[np.ndarray] = []
        self._picture_states: list[set[int]] = []
        self._goals_shown: dict[bytes, np.ndarray] = {}  # distinct goal pictures asked for (a matcher's domain sample)
        self.version = 0  # counts changes of edges and goals
        self._goal_version = 0  # counts changes of what goals attach to (pictures, places, goals reached)
        self.suspected = 0  # pose states only: moves made untried again by a collision on a move into the same state
        self._lost_move_version = 0  # the last change that removed a move: older hops may route through it
        self._hops: OrderedDict[tuple[bytes, bool], tuple[int, np.ndarray]] = OrderedDict()
        self._goal_cache: dict[bytes, tuple[int, np.ndarray]] = {}  # goal digest -> (version, its states)
        self._explore_hops = np.zeros(0, dtype=np.int32)
        self._explore_version = -1
        self._exhausted: set[int] = set()  # states whose search for untried found nothing, at _exhausted_version
        self._exhausted_version = -1

    @classmethod
    def for_env(cls, env: Any, place_frame: PlaceFrame | str | None = "auto", **kwargs: Any) -> RouteMemory:
        """
        An empty memory for an env (or vec env) with a ``Discrete`` action space.

        :param place_frame: ``"auto"``: the frame the env declares (:func:`~sb3_dcqn.place_frame.place_frame_of`,
            ``None`` where it declares none); ``None``: pose states whatever it declares; or a frame
        :param kwargs: The constructor's other arguments
        """
        if not isinstance(env.action_space, spaces.Discrete):
            raise ValueError(f"a route memory needs a Discrete action space, got {env.action_space}")
        frame = place_frame_of(env) if isinstance(place_frame, str) and place_frame == "auto" else place_frame
        return cls(int(env.action_space.n), env.observation_space, place_frame=frame, **kwargs)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ sizes
    @property
    def n_states(self) -> int:
        return self._size

    @property
    def n_tried(self) -> int:
        """Number of (state, slot) pairs tried (inferred reverses are not tried)."""
        outcomes = self.outcome[: self._size]
        return int(((outcomes != UNTRIED) & (outcomes != INFERRED)).sum())

    @property
    def n_places(self) -> int:
        """Number of distinct goal pictures of places remembered."""
        return len(self._pictures)

    def __len__(self) -> int:
        return self.n_states

    def nbytes(self) -> int:
        """Bytes of the memory's arrays, digests and pictures (the hops cache apart: :meth:`cache_nbytes`; Python's
        per-object overhead not counted)."""
        per_slot = 4 + 4 + 1 + 1  # target, last tried, outcome, arrival frame
        pictures = sum(vector.nbytes for vector in self._pictures)
        goals = sum(vector.nbytes for vector in (*self._goal_vectors.values(), *self._goals_shown.values()))
        links = sum(len(states) for states in self._picture_states) + sum(len(s) for s in self._reached.values())
        digests = 16 * (len(self._state_of) + len(self._view_places) + self.n_places + len(self._reached))
        return self._size * self.n_actions * per_slot + digests + pictures + goals + 8 * links

    def cache_nbytes(self) -> int:
        """Bytes of the cached hops per goal (at most ``max_cache_bytes``)."""
        return sum(hops.nbytes for _, hops in self._hops.values()) + self._explore_hops.nbytes

    # ------------------------------------------------------------------ digests
    def _rows(self, observations: Any, keys: Sequence[str] | None) -> np.ndarray:
        """A batch's bytes per observation, ``keys`` (sorted) of a Dict, the state's keys when ``None``."""
        if isinstance(observations, Mapping):
            if keys is None:
                keys = self._state_keys or [key for key in sorted(observations) if key not in self.goal_keys]
            subspaces = self.observation_space.spaces if isinstance(self.observation_space, spaces.Dict) else {}
            arrays = [_as_rows(observations[key], subspaces.get(key)) for key in sorted(keys)]
            return np.concatenate(arrays, axis=1) if len(arrays) > 1 else arrays[0]
        return _as_rows(observations, self.observation_space)

    def _digests(self, observations: Any, keys: Sequence[str] | None = None) -> list[bytes]:
        return [_digest(row.tobytes()) for row in self._rows(observations, keys)]

    def goal_digests(self, observations: Any) -> list[bytes]:
        """The goal asked for by each observation (one shared goal where the observation names none)."""
        if not self._asked_keys or not isinstance(observations, Mapping):
            return [b""] * _batch_size(observations)
        return self._digests(observations, self._asked_keys)

    def _view_digests(self, row: np.ndarray) -> list[bytes]:
        """The digest of each view block of a place picture (its index in it)."""
        blocks = row.reshape(self.place_frame.views_per_place, -1)  # type: ignore[union-attr]
        return [_digest(bytes([index]) + block.tobytes()) for index, block in enumerate(blocks)]

    # ------------------------------------------------------------------ states
    def states_of(self, observations: Any, *, add: bool = False) -> np.ndarray:
        """
        The states of a batch of observations (a dict of batches for Dict observations).

        :param add: Give unseen observations new states (else, and once ``max_states`` are held, they are -1)
        :return: int64 states, one per observation
        """
        rows = self._rows(observations, None)
        return np.array([self._state_for(row, add) for row in rows], dtype=np.int64)

    def state_of(self, observation: Any, *, add: bool = False) -> int:
        """The state of one observation (unbatched), -1 if unseen and not ``add``."""
        return int(self.states_of(batch_of_one(observation), add=add)[0])

    def _state_for(self, row: np.ndarray, add: bool) -> int:
        key = _digest(row.tobytes())
        state = self._state_of.get(key)
        if state is not None:
            return state
        views = self._view_digests(row) if self._splits_views else []
        state = self._voted_state(views)
        if state >= 0:  # the same place with some views changed (a barrier): remember this picture of it too
            if add:
                self._state_of[key] = state
            return state
        if not add or self._size >= self.max_states:
            return -1
        state = self._size
        self._size += 1
        self._goal_version += 1  # a new place may be the one a goal's pictures vote for
        self._state_of[key] = state
        for view in views:
            self._view_places[view] = state if self._view_places.get(view, state) == state else -2
        if self._picture_key is not None and self._achieved_key is None:
            self._add_picture(key, row.view(self._picture_dtype), state)  # the place pictures its own goal
        if state == self.outcome.shape[0]:
            self._resize(2 * state)
        return state

    @property
    def _splits_views(self) -> bool:
        return self.place_frame is not None and self.place_frame.views_per_place > 1

    def _voted_state(self, views: list[bytes]) -> int:
        """The one remembered state that at least half of the views belong to (-1: none, or several)."""
        if not views:
            return -1
        votes: dict[int, int] = {}
        for view in views:
            state = self._view_places.get(view, -1)
            if state >= 0:
                votes[state] = votes.get(state, 0) + 1
        best = [state for state, count in votes.items() if 2 * count >= len(views)]
        return best[0] if len(best) == 1 else -1

    def _resize(self, rows: int) -> None:
        """The per-(state, slot) arrays with room for ``rows`` states (the used rows kept)."""
        for name, fill in _SLOT_ARRAYS.items():
            array = getattr(self, name)
            grown = np.full((rows, self.n_actions), fill, dtype=array.dtype)
            kept = min(len(array), rows)
            grown[:kept] = array[:kept]
            setattr(self, name, grown)

    def _frames(self, observations: Any) -> np.ndarray:
        """The frame of each observation of a batch (zeros where the env declares none)."""
        if self.place_frame is None or self.place_frame.frame_key is None or not isinstance(observations, Mapping):
            return np.zeros(_batch_size(observations), dtype=np.int64)
        frames = np.asarray(observations[self.place_frame.frame_key]).reshape(_batch_size(observations), -1)
        return frames.argmax(axis=1).astype(np.int64)

    def _relative(self) -> bool:
        return self.place_frame is not None and self.place_frame.frame_key is not None

    def _slots(self, frames: np.ndarray, actions: np.ndarray) -> np.ndarray:
        return (frames + actions) % self.n_actions if self._relative() else actions

    def _actions(self, frames: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """The actions that take ``slots`` at ``frames`` (-1 stays -1)."""
        if not self._relative():
            return slots
        return np.where(slots >= 0, (slots - frames) % self.n_actions, -1)

    # ------------------------------------------------------------------ remembering
    def add(
        self, obs: Any, action: int, next_obs: Any, reward: float, terminated: bool, success: bool | None = None
    ) -> int:
        """Remember one transition (unbatched observations); ``terminated``: a real end, not a time limit;
        ``success``: the env's ``info["is_success"]`` where it gives one."""
        return self.add_batch(
            batch_of_one(obs),
            np.array([action]),
            batch_of_one(next_obs),
            np.array([reward]),
            np.array([terminated]),
            None if success is None else np.array([success]),
        )

    def add_batch(
        self,
        observations: Any,
        actions: Any,
        next_observations: Any,
        rewards: Any,
        terminated: Any,
        successes: Any = None,
    ) -> int:
        """
        Remember a batch of transitions in order (a later outcome of the same ``(state, slot)`` wins).

        :param terminated: Real ends of episodes (not time limits)
        :param successes: Whether each terminated transition reached its goal (the env's ``info["is_success"]``;
            ``None``: a reward above ``success_reward``)
        :return: how many changed the memory
        """
        states = self.states_of(observations, add=True)
        next_states = self.states_of(next_observations, add=True)
        actions = np.asarray(actions).reshape(-1).astype(np.int64)
        rewards = np.asarray(rewards, dtype=np.float64).reshape(-1)
        terminated = np.asarray(terminated).reshape(-1).astype(bool)
        if actions.size != states.size:
            raise ValueError(f"{actions.size} actions for {states.size} observations")
        bad = (actions < 0) | (actions >= self.n_actions)
        if bad.any():
            raise ValueError(f"action {int(actions[bad][0])} is out of range [0, {self.n_actions})")
        before = self.version
        reached = rewards > self.success_reward if successes is None else np.asarray(successes).reshape(-1) > 0
        success = terminated & reached
        if success.any():
            self._add_reached(select_rows(observations, success), next_states[success])
        if self._picture_key is not None and self.place_matcher is not None:
            self._add_goals_shown(observations)
        if self._achieved_key is not None:
            self._add_achieved(observations, states)
            self._add_achieved(next_observations, next_states)
        # An end without success is a dead end of the world, except where episodes end at their goal's
        dead = terminated & ~success & (not self._goal_conditioned)
        slots = self._slots(self._frames(observations), actions)
        arrivals = self._frames(next_observations)
        for state, slot, following, arrival, is_dead in zip(
            states.tolist(), slots.tolist(), next_states.tolist(), arrivals.tolist(), dead.tolist(), strict=True
        ):
            self.clock += 1
            if state >= 0:
                self._record(state, slot, following, arrival, is_dead)
        return self.version - before

    def _record(self, state: int, slot: int, following: int, arrival: int, dead: bool) -> None:
        """One tried (state, slot): where it led (``following``, -1 past ``max_states``) and the frame there."""
        self.last_tried[state, slot] = self.clock
        if following < 0:
            self._set(state, slot, OUTSIDE if self.outcome[state, slot] == UNTRIED else self.outcome[state, slot])
        elif dead:
            self._set(state, slot, DEAD_END, following)
        elif following == state:
            self._collide(state, slot)
        else:
            self._drive(state, slot, following, arrival)

    def _set(self, state: int, slot: int, outcome: int, target: int | None = None, arrival: int | None = None) -> None:
        """Change one (state, slot), counting a change and a lost move."""
        was_move = self.outcome[state, slot] in _ROUTES and self.target[state, slot] >= 0
        changed = self.outcome[state, slot] != outcome or (target is not None and self.target[state, slot] != target)
        self.outcome[state, slot] = outcome
        if target is not None:
            self.target[state, slot] = target
        if arrival is not None:
            self.arrival[state, slot] = arrival
        if changed:
            self.version += 1
            if was_move and outcome not in _ROUTES:
                self._lost_move_version = self.version

    def _collide(self, state: int, slot: int) -> None:
        """A bump: the slot is blocked; with two-way roads its known reverse too; with pose states, the other moves
        into the state it led to become untried again."""
        previous = int(self.target[state, slot]) if self.outcome[state, slot] in _ROUTES else -1
        self._set(state, slot, BLOCKED)
        back = self._back_slot(state, slot)
        if back is not None:
            far = int(self.target[state, slot])
            self.last_tried[far, back] = self.clock
            if self.outcome[far, back] in _ROUTES and self.target[far, back] == state:
                self._set(far, back, BLOCKED)
        elif self.place_frame is None and previous >= 0:
            self._suspect_moves_into(previous)

    def _back_slot(self, state: int, slot: int) -> int | None:
        """The slot at the far end of a known road that leads back (two-way roads), else ``None``."""
        reverse = None if self.place_frame is None else self.place_frame.reverse_action
        if reverse is None or self.target[state, slot] < 0 or self.arrival[state, slot] < 0:
            return None
        return (int(self.arrival[state, slot]) + reverse) % self.n_actions

    def _drive(self, state: int, slot: int, following: int, arrival: int) -> None:
        """A move; with two-way roads the way back is inferred; a slot that led elsewhere before marks an alias."""
        known = int(self.target[state, slot])
        contradicts = known >= 0 and known != following and self.outcome[state, slot] in (*_ROUTES, BLOCKED)
        if contradicts or (state, slot) in self._disputes:
            self._dispute(state, slot, known, following)
        self._set(state, slot, DRIVEN, following, arrival)
        back = self._back_slot(state, slot)
        if back is None:
            return
        far_outcome, far_target = int(self.outcome[following, back]), int(self.target[following, back])
        if far_target >= 0 and far_target != state and far_outcome in (*_ROUTES, BLOCKED):
            self._dispute(following, back, far_target, state)  # the way back led elsewhere
        elif far_outcome in (UNTRIED, BLOCKED, OUTSIDE):
            # Arriving back here the agent would face away from the road, so that "back" again leads along it
            reverse = self.place_frame.reverse_action  # type: ignore[union-attr]
            self._set(following, back, INFERRED, state, (slot - reverse) % self.n_actions)

    def _dispute(self, state: int, slot: int, known: int, following: int) -> None:
        """
        A slot that led to ``known`` now leads to ``following``. Two places that picture the same make it flip between
        them again and again: once two outcomes were each seen at least twice, the state is aliased. One odd
        transition (a glitch: a step the caller skipped) leaves it alone, and the latest outcome wins.
        """
        counts = self._disputes.setdefault((state, slot), {known: 1} if known >= 0 else {})
        counts[following] = counts.get(following, 0) + 1
        if sum(count >= 2 for count in counts.values()) >= 2 and state not in self.aliased:
            self.aliased.add(state)
            self.version += 1

    def _suspect_moves_into(self, lost: int) -> None:
        """
        Pose states: a collision where a move into ``lost`` used to be makes the other remembered moves into ``lost``
        untried again. Where the state after a move tells which road was taken (the place and the heading away from
        the road), they are the same road seen from the other headings, so one bump closes it for all of them.
        """
        into = (self.target[: self._size] == lost) & np.isin(self.outcome[: self._size], _ROUTES)
        if into.any():
            self.outcome[: self._size][into] = UNTRIED
            self.suspected += int(into.sum())
            self.version += 1

    def _add_reached(self, observations: Any, states: np.ndarray) -> None:
        """Goals reached by success transitions (their goal vectors kept: a goal given within the tolerance)."""
        goals = self.goal_digests(observations)
        vectors = self._goal_rows(observations)
        for index, (goal, state) in enumerate(zip(goals, states.tolist(), strict=True)):
            if state < 0:
                continue
            goal = self._canonical_goal(goal, None if vectors is None else vectors[index])
            if state not in self._reached.setdefault(goal, set()):
                self._reached[goal].add(int(state))
                self.version += 1
                self._goal_version += 1

    def _goal_rows(self, observations: Any) -> np.ndarray | None:
        """The asked goal keys of a batch as float64 rows (``None`` where no key names the goal)."""
        if not self._asked_keys or not isinstance(observations, Mapping):
            return None
        batch = _batch_size(observations)
        return np.concatenate(
            [np.asarray(observations[key], dtype=np.float64).reshape(batch, -1) for key in sorted(self._asked_keys)],
            axis=1,
        )

    def _canonical_goal(self, goal: bytes, vector: np.ndarray | None) -> bytes:
        """The goal digest a goal vector within ``goal_tolerance`` of a remembered one stands for (itself if new)."""
        if goal in self._goal_vectors or vector is None:
            return goal
        for known, known_vector in self._goal_vectors.items():
            if known_vector.shape == vector.shape and np.abs(known_vector - vector).max() <= self.goal_tolerance:
                return known
        self._goal_vectors[goal] = np.array(vector, dtype=np.float64)
        return goal

    def _add_goals_shown(self, observations: Any) -> None:
        """Remember the distinct goal pictures of a batch (at most ``MAX_GOALS_SHOWN``: a sample of their domain)."""
        if len(self._goals_shown) >= MAX_GOALS_SHOWN or not isinstance(observations, Mapping):
            return
        pictures = np.asarray(observations[self._picture_key], dtype=np.float32)
        pictures = pictures.reshape(_batch_size(observations), -1)
        for picture in np.unique(pictures, axis=0):
            self._goals_shown.setdefault(_digest(picture.tobytes()), picture.copy())

    def goal_pictures(self) -> np.ndarray:
        """The distinct goal pictures shown to the memory so far, ``(k, d)`` float32 (with a place matcher)."""
        if not self._goals_shown:
            return np.zeros((0, 0), dtype=np.float32)
        return np.stack(list(self._goals_shown.values()))

    def _add_achieved(self, observations: Mapping[str, Any], states: np.ndarray) -> None:
        """Attach each state to the place its achieved goal pictures (pose states: SB3's goal-env convention)."""
        rows = self._rows(observations, [self._achieved_key])  # type: ignore[list-item]
        vectors = np.asarray(observations[self._achieved_key]).reshape(len(states), -1)
        for row, vector, state in zip(rows, vectors, states.tolist(), strict=True):
            if state >= 0:
                self._add_picture(_digest(row.tobytes()), vector, state)

    def _add_picture(self, key: bytes, vector: np.ndarray, state: int) -> None:
        picture = self._picture_of.get(key)
        if picture is None:
            picture = self._picture_of[key] = len(self._pictures)
            self._pictures.append(np.array(vector, dtype=np.float32).reshape(-1))
            self._picture_states.append(set())
        if state not in self._picture_states[picture]:
            self._picture_states[picture].add(state)
            self.version += 1
            self._goal_version += 1

    # ------------------------------------------------------------------ goals
    def place_vectors(self) -> np.ndarray:
        """The remembered pictures of places (a place matcher's references), ``(n_places, d)`` float32."""
        if not self._pictures:
            return np.zeros((0, 0), dtype=np.float32)
        return np.stack(self._pictures)

    def place_labels(self) -> np.ndarray:
        """Each picture's place: pictures seen at a common state share a label (int64, ``(n_places,)``)."""
        parent = list(range(self.n_places))

        def root(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        first_place: dict[int, int] = {}
        for place, states in enumerate(self._picture_states):
            for state in states:
                other = first_place.setdefault(state, place)
                parent[root(place)] = root(other)
        return np.array([root(place) for place in range(self.n_places)], dtype=np.int64)

    def goal_states(self, observation: Any) -> np.ndarray:
        """The remembered states where one (unbatched) observation's goal is reached (empty: not in memory)."""
        batch = batch_of_one(observation)
        return self._goal_states(self.goal_digests(batch)[0], batch, 0)

    def _goal_states(self, goal: bytes, batch: Any, index: int) -> np.ndarray:
        cached = self._goal_cache.get(goal)
        if cached is not None and cached[0] == self._goal_version:
            return cached[1]
        vectors = self._goal_rows(batch)
        states = set(self._reached.get(self._canonical_lookup(goal, vectors, index), ()))
        if self._picture_key is not None and isinstance(batch, Mapping):
            states |= self._pictured_states(np.asarray(batch[self._picture_key])[index])
        found = np.array(sorted(states), dtype=np.int64)
        self._goal_cache[goal] = (self._goal_version, found)
        if len(self._goal_cache) > 4096:  # bounded: the goals asked for lately
            self._goal_cache = {g: entry for g, entry in self._goal_cache.items() if entry[0] == self._goal_version}
        return found

    def _canonical_lookup(self, goal: bytes, vectors: np.ndarray | None, index: int) -> bytes:
        if goal in self._reached or vectors is None:
            return goal
        vector = vectors[index]
        for known, known_vector in self._goal_vectors.items():
            if known_vector.shape == vector.shape and np.abs(known_vector - vector).max() <= self.goal_tolerance:
                return known
        return goal

    def _pictured_states(self, picture: np.ndarray) -> set[int]:
        """The states a goal picture shows: the same picture, one within the tolerance, a per-view vote, or the place
        matcher's answer (empty: not in memory)."""
        space = self.observation_space
        subspace = space[self._picture_key] if isinstance(space, spaces.Dict) else None
        row = _as_rows(np.asarray(picture)[None], subspace)[0]
        found = self._picture_of.get(_digest(row.tobytes()))
        if found is None and self._pictures:
            vectors = self.place_vectors()
            query = np.asarray(picture, dtype=np.float32).reshape(1, -1)
            if vectors.shape[1] == query.shape[1]:
                distance = np.abs(vectors - query).max(axis=1)
                nearest = int(distance.argmin())
                if distance[nearest] <= self.goal_tolerance:
                    found = nearest
        if found is None and self._splits_views and self._achieved_key is None:
            voted = self._voted_state(self._view_digests(row))
            if voted >= 0:
                return {voted}
        if found is None and self.place_matcher is not None and self._pictures:
            vectors = self.place_vectors()
            query = np.asarray(picture, dtype=np.float32).reshape(1, -1)
            shown = self.goal_pictures() if self._goals_shown else None
            matched = int(self.place_matcher.match(query, vectors, self.place_labels(), shown)[0])
            found = matched if matched >= 0 else None
        return set() if found is None else set(self._picture_states[found])

    # ------------------------------------------------------------------ routes
    def hops_to_goal(self, observation: Any) -> np.ndarray:
        """Hops from every state to one (unbatched) observation's goal over remembered edges (:data:`NO_ROUTE`)."""
        batch = batch_of_one(observation)
        return self._goal_hops(self.goal_digests(batch)[0], batch, 0).astype(np.int64)

    def _goal_hops(self, goal: bytes, batch: Any, index: int, staleness: int = 0, retry: bool = False) -> np.ndarray:
        key = (goal, retry)
        cached = self._hops.get(key)
        fresh_enough = cached is not None and cached[0] >= self._lost_move_version
        if fresh_enough and self.version - cached[0] <= staleness:  # type: ignore[index]
            self._hops.move_to_end(key)
            return cached[1]  # type: ignore[index]
        is_target = self._goal_targets(goal, batch, index, retry)
        hops = self._hops_to(is_target(np.arange(self._size)), retry)
        self._hops[key] = (self.version, hops)
        self._hops.move_to_end(key)
        while self.cache_nbytes() > self.max_cache_bytes and len(self._hops) > 1:  # least recently used first out
            self._hops.popitem(last=False)
        return hops

    def route_actions(self, observations: Any, staleness: int = 0, retry: bool = False) -> np.ndarray:
        """
        The first action of a shortest remembered route from each observation to its goal (the lowest slot on
        ties): a batch (a dict of batches) in, int64 actions for each observation's own frame out, -1 where there is
        none (unseen state, goal not in memory, or not connected).

        :param staleness: Reuse a goal's hops computed up to this many changes of the memory ago (training's
            rollouts: one search per many steps on a large map; the current edges are still read, so a road seen
            closed is never taken again unless ``retry``); 0: exact
        :param retry: Routes may go through roads blocked ``retry_after`` transitions ago or more, and a state next to
            such a road tries it (training's rollouts: a reopened road is found again, a still closed one costs a
            bump per ``retry_after`` transitions; evaluation never drives a road seen closed)
        """
        states = self.states_of(observations)
        goals = self.goal_digests(observations)
        slots = np.full(states.size, -1, dtype=np.int64)
        by_goal: dict[bytes, list[int]] = {}
        for index, goal in enumerate(goals):
            by_goal.setdefault(goal, []).append(index)
        for goal, indices in by_goal.items():
            rows = np.array(indices)
            hops = self._goal_hops(goal, observations, indices[0], staleness, retry)
            is_target = self._goal_targets(goal, observations, indices[0], retry)
            slots[rows] = self._first_slots(states[rows], hops, is_target, retry)
        if retry:  # passing by a road blocked long enough ago: try it (one bump per retry_after, where still closed)
            aged = self._aged_blocked(states)
            slots = np.where(aged >= 0, aged, slots)
        return self._actions(self._frames(observations), slots)

    def _aged_blocked(self, states: np.ndarray) -> np.ndarray:
        """Per state, the lowest slot blocked ``retry_after`` transitions ago or more whose road led somewhere (-1)."""
        slots = np.full(states.size, -1, dtype=np.int64)
        known = states >= 0
        if not known.any():
            return slots
        rows = states[known]
        aged = (
            (self.outcome[rows] == BLOCKED)
            & (self.target[rows] >= 0)
            & (self.target[rows] != rows[:, None])
            & (self.clock - self.last_tried[rows] >= self.retry_after)
        )
        slots[known] = np.where(aged.any(axis=1), aged.argmax(axis=1), -1)
        return slots

    def _goal_targets(self, goal: bytes, batch: Any, index: int, retry: bool = False) -> Any:
        goal_states = self._goal_states(goal, batch, index)
        arrived = np.zeros(self._size + 1, dtype=bool)
        arrived[goal_states] = True

        def is_target(rows: np.ndarray) -> np.ndarray:
            successors = self.target[rows]
            return self._moves(rows, retry) & arrived[np.where(successors >= 0, successors, self._size)]

        return is_target

    def route_from(self, observation: Any, max_hops: int | None = None) -> list[int]:
        """The actions of a shortest remembered route from one observation to its goal (empty: none), each for the
        frame the agent will have when it takes it."""
        batch = batch_of_one(observation)
        goal = self.goal_digests(batch)[0]
        hops = self._goal_hops(goal, batch, 0)
        is_target = self._goal_targets(goal, batch, 0)
        state = self.state_of(observation)
        frame = int(self._frames(batch)[0])
        actions: list[int] = []
        for _ in range(self._size if max_hops is None else max_hops):
            if state < 0:
                return []
            slot = int(self._first_slots(np.array([state]), hops, is_target)[0])
            if slot < 0:
                return []
            actions.append(int(self._actions(np.array([frame]), np.array([slot]))[0]))
            if is_target(np.array([state]))[0, slot]:
                return actions
            state, frame = int(self.target[state, slot]), int(self.arrival[state, slot])
        return actions

    def _moves(self, rows: np.ndarray, retry: bool = False) -> np.ndarray:
        """Which (state, slot) pairs of the rows lead to another state (routes go along them); with ``retry`` also
        roads blocked long enough ago."""
        outcomes, successors = self.outcome[rows], self.target[rows]
        routable = (outcomes == DRIVEN) | (outcomes == INFERRED)
        if retry:
            aged = self.clock - self.last_tried[rows] >= self.retry_after
            routable |= (outcomes == BLOCKED) & aged
        moves = routable & (successors >= 0) & (successors != rows[:, None])
        if self.aliased:
            moves &= ~np.isin(rows, list(self.aliased))[:, None]
        return moves

    def _hops_to(self, targets: np.ndarray, retry: bool = False) -> np.ndarray:
        """
        Hops from every state to one of the target (state, slot) pairs, that move included: a backward BFS level by
        level over all move edges as arrays (no per-state Python loop).

        :param targets: ``(n_states, n_slots)`` bool
        :return: int32 hops per state (:data:`NO_ROUTE`: no target reachable)
        """
        n = self._size
        hops = np.full(n, NO_ROUTE, dtype=np.int32)
        successors = self.target[:n]
        moves = self._moves(np.arange(n), retry)
        sources = np.broadcast_to(np.arange(n)[:, None], successors.shape)[moves]
        ends = successors[moves]
        level = np.flatnonzero(targets.any(axis=1))
        count = 1
        hops[level] = count
        while level.size:
            frontier = np.zeros(n, dtype=bool)
            frontier[level] = True
            reached = sources[frontier[ends]]
            count += 1
            level = np.unique(reached[hops[reached] == NO_ROUTE])
            hops[level] = count
        return hops

    def _first_slots(self, states: np.ndarray, hops: np.ndarray, is_target: Any, retry: bool = False) -> np.ndarray:
        """The slot of each state that starts a fewest-hops way to a target pair (-1: unseen or none)."""
        states = np.asarray(states, dtype=np.int64).reshape(-1)
        slots = np.full(states.size, -1, dtype=np.int64)
        known = states >= 0
        if not known.any() or hops.size == 0:
            return slots
        rows = states[known]
        if hops.size < self._size:  # stale hops: states added since have no known route yet
            hops = np.concatenate([hops, np.full(self._size - hops.size, NO_ROUTE, dtype=hops.dtype)])
        successors = self.target[rows].astype(np.int64)
        via = np.where(successors >= 0, hops[np.maximum(successors, 0)], NO_ROUTE).astype(np.int64)
        moves = self._moves(rows, retry) & (via != NO_ROUTE)
        cost = np.where(is_target(rows), 1, np.where(moves, via + 1, _NEVER))
        best = cost.argmin(axis=1)
        slots[known] = np.where(cost[np.arange(rows.size), best] != _NEVER, best, -1)
        return slots

    # ------------------------------------------------------------------ exploration
    def untried_slots(self, state: int) -> np.ndarray:
        """The slots never tried from ``state`` (inferred reverses are known, not untried)."""
        return np.flatnonzero(self.outcome[state] == UNTRIED)

    def frontier(self) -> np.ndarray:
        """The states with at least one untried slot."""
        return np.flatnonzero((self.outcome[: self._size] == UNTRIED).any(axis=1))

    def explore_actions(self, observations: Any) -> np.ndarray:
        """
        The first action towards the nearest untried (state, slot) from each observation, in hops over remembered
        moves (the untried slot itself where the state has one; the lowest on ties). Hops are computed for all states
        at once and kept until the memory changes: for many observations at one version, where
        :meth:`path_to_untried` would search once per observation.

        :return: the actions, -1 where a state is unseen or nothing untried can be reached
        """
        if self._explore_version != self.version:
            self._explore_hops = self._hops_to(self.outcome[: self._size] == UNTRIED)
            self._explore_version = self.version
        states = self.states_of(observations)
        slots = self._first_slots(states, self._explore_hops, lambda rows: self.outcome[rows] == UNTRIED)
        return self._actions(self._frames(observations), slots)

    def path_to_untried(self, state: int, exclude: set[tuple[int, int]] | frozenset = frozenset()) -> list[int] | None:
        """
        The slots from ``state`` to the nearest state (in hops over remembered moves) with an untried slot, that slot
        last (the lowest untried one there, ``exclude``'s pairs passed over; ties between states: the first found, in
        slot order). A search from one state that stops at the first untried slot: cheap on a large memory.

        :param exclude: (state, slot) pairs not to seek (those other explorers are on their way to)
        :return: the slots, or ``None`` if no untried slot can be reached
        """
        if not 0 <= state < self._size:
            raise ValueError(f"state {state} is not one of the memory's {self._size} states")
        if self._exhausted_version != self.version:
            self._exhausted, self._exhausted_version = set(), self.version
        if state in self._exhausted:  # searched in full since the last change: nothing untried from there
            return None
        parent: dict[int, tuple[int, int]] = {state: (-1, -1)}
        queue = deque([state])
        while queue:
            here = queue.popleft()
            outcomes, targets = self.outcome[here].tolist(), self.target[here].tolist()
            untried = [slot for slot, code in enumerate(outcomes) if code == UNTRIED and (here, slot) not in exclude]
            if untried:
                path = [untried[0]]
                while parent[here][0] >= 0:
                    here, slot = parent[here]
                    path.append(slot)
                return path[::-1]
            if here in self.aliased:
                continue
            for slot, (code, following) in enumerate(zip(outcomes, targets, strict=True)):
                if code in _ROUTES and following >= 0 and following != here and following not in parent:
                    parent[following] = (here, slot)
                    queue.append(following)
        if not exclude:
            self._exhausted.update(parent)  # every state searched reaches nothing untried either
        return None

    def slot_actions(self, observations: Any, slots: np.ndarray) -> np.ndarray:
        """The actions that take ``slots`` at each observation's frame (-1 stays -1)."""
        return self._actions(self._frames(observations), np.asarray(slots, dtype=np.int64))

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        # Caches are rebuilt on use; the matcher's own state pickles with it
        state.update(_hops=OrderedDict(), _goal_cache={}, _explore_version=-1, _exhausted=set(), _exhausted_version=-1)
        state["_explore_hops"] = np.zeros(0, dtype=np.int32)
        for name in _SLOT_ARRAYS:
            state[name] = getattr(self, name)[: self._size].copy()
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        if "next_state" in state:  # saved before places (one next-state table over poses): loaded as poses
            self._load_pose_table(state)
            return
        self.__dict__.update(state)
        self._resize(max(1024, 2 * self._size))

    def _load_pose_table(self, state: dict[str, Any]) -> None:
        """A memory saved as one ``next_state`` table (-1 untried, -2 dead end, the state itself a collision)."""
        keys = ("n_actions", "observation_space", "goal_keys", "success_reward", "max_states", "place_matcher")
        self.__init__(*(state[key] for key in keys))  # type: ignore[misc]
        table = np.asarray(state["next_state"], dtype=np.int64)[: len(state["_state_of"])]
        self._state_of, self._size = dict(state["_state_of"]), len(table)
        self._resize(max(1024, 2 * self._size))
        rows = np.arange(self._size)[:, None]
        outcome = np.select([table == -1, table == -2, table == rows], [UNTRIED, DEAD_END, BLOCKED], DRIVEN)
        self.outcome[: self._size] = outcome
        self.target[: self._size] = np.where(outcome == DRIVEN, table, -1)
        self._reached = {goal: set(states) for goal, states in state["_reached"].items()}
        self._picture_of, self._pictures = dict(state["_place_of"]), list(state["_place_vectors"])
        self._picture_states = [set(states) for states in state["_place_states"]]


class UntriedExplorer:
    """
    Drives each env of a vector env to the nearest untried ``(state, slot)`` of a :class:`RouteMemory` and tries it
    (Go-Explore's return, then explore): the path is searched once and followed while the states met are the ones
    expected, searched anew otherwise. Envs do not chase the same untried pair: each seeks one no other env is on its
    way to.

    :param memory: The memory it reads
    :param n_envs: Number of envs (one path each)
    """

    def __init__(self, memory: RouteMemory, n_envs: int = 1) -> None:
        self.memory = memory
        self._paths: list[list[tuple[int, int]]] = [[] for _ in range(n_envs)]
        self._targets: list[tuple[int, int] | None] = [None] * n_envs  # the untried pair each env is on its way to

    def actions(self, observations: Any) -> np.ndarray:
        """The exploring action of each env's observation (a batch), -1 where the memory has none (unseen state, or
        nothing untried can be reached)."""
        return self.actions_at(self.memory.states_of(observations), observations)

    def actions_at(self, states: np.ndarray, observations: Any) -> np.ndarray:
        """:meth:`actions` for the envs' memory states (-1: unseen), where the caller has them already."""
        if states.size != len(self._paths):
            self._paths = [[] for _ in range(states.size)]
            self._targets = [None] * states.size
        slots = np.array([self._slot(env, int(state)) for env, state in enumerate(states)], dtype=np.int64)
        return self.memory.slot_actions(observations, slots)

    def _claimed(self, env: int) -> set[tuple[int, int]]:
        """The untried pairs the other envs are on their way to."""
        return {
            target
            for other, target in enumerate(self._targets)
            if other != env and target is not None and self.memory.outcome[target] == UNTRIED
        }

    def _slot(self, env: int, state: int) -> int:
        path, target = self._paths[env], self._targets[env]
        if state >= 0 and path and path[0][0] == state and self.memory.outcome[target] == UNTRIED:
            return path.pop(0)[1]
        path.clear()
        self._targets[env] = None
        if state < 0:
            return -1
        slots = self.memory.path_to_untried(state, self._claimed(env))
        if slots is None:
            slots = self.memory.path_to_untried(state)  # every reachable untried pair is claimed: share one
        if slots is None:
            return -1
        for slot in slots:
            path.append((state, slot))
            state = int(self.memory.target[state, slot])
        self._targets[env] = path[-1]
        return path.pop(0)[1]


def _as_rows(batch: Any, space: spaces.Space | None) -> np.ndarray:
    """A batch as a C-contiguous (batch, bytes) uint8 array (cast to the space's dtype first, where known)."""
    array = np.asarray(batch) if space is None or space.dtype is None else np.asarray(batch, dtype=space.dtype)
    if array.ndim == 0 or (space is not None and space.shape is not None and array.shape == tuple(space.shape)):
        array = array[None]  # one unbatched observation of a Discrete or Box space
    array = np.ascontiguousarray(array)
    return array.reshape(array.shape[0], -1).view(np.uint8).reshape(array.shape[0], -1)


def _batch_size(observations: Any) -> int:
    first = next(iter(observations.values())) if isinstance(observations, Mapping) else observations
    return int(np.asarray(first).shape[0])


def select_rows(observations: Any, mask: np.ndarray) -> Any:
    """The observations of a batch (a dict of batches) where ``mask`` is true."""
    if isinstance(observations, Mapping):
        return {key: np.asarray(value)[mask] for key, value in observations.items()}
    return np.asarray(observations)[mask]


def batch_of_one(observation: Any) -> Any:
    """One observation (a dict of arrays) as a batch of one."""
    if isinstance(observation, Mapping):
        return {key: np.asarray(value)[None] for key, value in observation.items()}
    return np.asarray(observation)[None]
