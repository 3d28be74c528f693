"""A memory that routes: one graph of the agent's own transitions, over recognised places, for every goal.

Every transition ``(o, a) -> o'`` the agent makes is a 1-hop edge of the world's graph once ``o`` and ``o'`` are known
as places. :class:`RouteMemory` keeps those edges over **states that leave the goal out**, so that one graph serves
every goal, and answers with the first action of the shortest remembered route, or -1 where it has none (an unknown
or unsure place, a goal it cannot place): the caller's own policy (the critics) acts there.

Its parts, one concern each:

- :mod:`~sb3_dcqn.route_memory.places`: which state a picture shows (bit identity, then similarity with thresholds
  calibrated on the agent's own pictures; known, new or unsure);
- :mod:`~sb3_dcqn.route_memory.edges`: per ``(state, slot)`` the latest outcome (:class:`Outcome`), where it led, when;
- :mod:`~sb3_dcqn.route_memory.goals`: where each goal is (successes, goal pictures);
- :mod:`~sb3_dcqn.route_memory.planner`: shortest routes, and the one bounded cache;
- :mod:`~sb3_dcqn.route_memory.explorer`: the way to the nearest untried move.

**Places, where the env declares its frame** (:mod:`sb3_dcqn.place_frame`; CampusNav does): a state is a *place*,
recognised from the keys that picture it (CampusNav: the four views in compass order), not from the heading; a move
is kept in **compass slots**, ``slot = (frame + action) mod n``, so a move tried at one heading is known at every
heading, and a route's slot is turned back into the action for the current heading. With two-way roads declared, a
driven road also records its way back (inferred), and a bump on a driven road closes its way back too, for every goal
at once. Pictures that vary between visits (light, cars, noise) are recognised by similarity; where they do not
separate places at all, the memory says so once and steps aside (:attr:`RouteMemory.stepped_aside`). Two states
that moves from two places lead to by turns are one place remembered twice (its pictures vary more than the
thresholds): they are merged into one (:attr:`RouteMemory.merged` counts them), moves and goals included; one state
whose slot led to two places by turns, pictured otherwise in a view on each side, is two look-alike places: it is
split in two (:attr:`RouteMemory.split` counts them; see the recogniser's siblings). **Poses, where
the env declares nothing**: a state is the exact observation without its goal keys (no similarity: an observation
that carries a heading or a position is compared bit for bit), and slots are the actions.

**Until its first calibration** (the first ``min_calibration`` distinct pictures of places) the memory holds the
transitions it is given, then remembers them in order: it never guesses a place before it knows what "the same place"
looks like in this world. **A guard**: where states grow like transitions (more than ``GROWTH_GUARD`` new states per
transition over ``GUARD_WINDOW`` transitions), recognition is failing: the memory warns once and steps aside for good
(every answer -1): the critics act alone from then on; so does a memory none of whose first ``NEVER_AGAIN_WINDOW``
transitions met a state seen before (observations that never repeat). Unsure pictures alone are no failure (its
predictions judge what it recognises). **Its evidence**
(:mod:`~sb3_dcqn.route_memory.evidence`): each move it knows predicts a state, scored against the state recognised
after it; where those predictions fail it stands aside (:attr:`RouteMemory.speaks` false: no routes, no exploration,
no place merged or split) until they hold again. **Stochastic moves** (poses: see
:mod:`~sb3_dcqn.route_memory.edges`) are planned on their outcome counts by value iteration.

**Success** is the env's ``info["is_success"]`` (the ``successes`` flags of :meth:`RouteMemory.add_batch`); where the
env gives none, a terminated transition with a reward above ``success_reward`` reached its goal, if that is set (else
none did: a CartPole fall is no goal). A terminated transition that is no success is a dead end (FrozenLake's holes),
except in a goal env, where an episode's end belongs to its goal.

Queries (batched, as SB3's ``predict``): :meth:`RouteMemory.route_actions`, :meth:`RouteMemory.explore_actions`,
:meth:`RouteMemory.path_to_untried`, :meth:`RouteMemory.route_from`.

After *Semi-parametric Topological Memory* (SPTM, Savinov et al. 2018), PlaceNav (Suomela et al. 2024: place
recognition and a prior over the graph), *Search on the Replay Buffer* (Eysenbach et al. 2019), MDP homomorphisms
(van der Pol et al. 2020: the headings of a place folded into one state), Dyna-Q+ and D* Lite (a closed road retried
as it ages; one model update re-routes every goal).
"""

from __future__ import annotations

import warnings
from collections import deque
from collections.abc import Hashable, Mapping, Sequence
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_dcqn.place_frame import PlaceFrame, place_frame_of
from sb3_dcqn.place_recognition import AlignedNearestPlace
from sb3_dcqn.route_memory.edges import CLOSED, DEAD, ROUTES, EdgeStore, Outcome
from sb3_dcqn.route_memory.evidence import PredictionRecord
from sb3_dcqn.route_memory.explorer import UntriedExplorer, path_to
from sb3_dcqn.route_memory.goals import ACHIEVED_GOAL_KEY, GoalIndex, PlaceMatcher
from sb3_dcqn.route_memory.places import Answer, PlaceRecogniser
from sb3_dcqn.route_memory.planner import NO_ROUTE, BoundedCache, Planner

__all__ = [
    "BLOCKED",
    "DEAD_END",
    "DRIVEN",
    "INFERRED",
    "INFERRED_BLOCKED",
    "NO_ROUTE",
    "OUTSIDE",
    "RECOGNITION_MODES",
    "UNTRIED",
    "Outcome",
    "PlaceMatcher",
    "RouteMemory",
    "UntriedExplorer",
    "batch_of_one",
    "default_goal_keys",
    "select_rows",
]

UNTRIED, DRIVEN, INFERRED, BLOCKED, DEAD_END, OUTSIDE, INFERRED_BLOCKED = tuple(Outcome)
DEFAULT_RETRY_AFTER = 50  # transitions after which a closed road may be tried again where it shortens a route
DEFAULT_CACHE_BYTES = 64 * 2**20
RECOGNITION_MODES = ("auto", "similar", "exact")
GUARD_WINDOW = 1_000  # transitions over which the guard counts new states and unsure pictures
GROWTH_GUARD = 0.75  # new states per transition past which recognition is failing
# Transitions after which a memory none of whose pictures came twice steps aside (CartPole: every observation new):
# a memory of places the agent never sees again only biases its exploration
NEVER_AGAIN_WINDOW = 100


def default_goal_keys(observation_space: spaces.Space | None) -> tuple[str, ...]:
    """The keys of a Dict observation that name a goal: those with "goal" in their name (``desired_goal``,
    ``achieved_goal``, CampusNav's ``goal_views``); none for other spaces."""
    if not isinstance(observation_space, spaces.Dict):
        return ()
    return tuple(sorted(key for key in observation_space.spaces if "goal" in key))


class RouteMemory:
    """
    One graph of remembered transitions for every goal (see the module docstring).

    :param n_actions: Number of discrete actions (and of slots)
    :param observation_space: The observations' space: arrays are cast to its dtypes (stored and fresh observations
        then agree), and its Dict keys give the default ``goal_keys``
    :param goal_keys: The Dict keys that name the goal, left out of a state (default: :func:`default_goal_keys`)
    :param success_reward: Where the env gives no success flag, a terminated transition with a reward above this
        reached its goal (``None``, the default: only the env's word counts)
    :param max_states: The most states remembered (then new places get no state: moves into them lead outside)
    :param place_matcher: For goal pictures the recogniser does not know (pictured in other light, say): ``"auto"``
        (the default), an :class:`~sb3_dcqn.place_recognition.AlignedNearestPlace` over the frame's views where the
        env declares goal pictures of places recognised by similarity, none elsewhere; ``None``: such goals have no
        route; or a :class:`PlaceMatcher`
    :param place_frame: The env's declared frame (:class:`~sb3_dcqn.place_frame.PlaceFrame`): states are places and
        moves slots; ``None``: states are poses
    :param retry_after: Transitions after a bump before a closed road may be tried again in training (doubling with
        each further bump)
    :param max_cache_bytes: Bound on everything the memory caches (routes, goals' places)
    :param goal_tolerance: Goal vectors that differ by at most this in every entry are one goal (as the env accepts)
    :param recognition: How places are told apart: ``"similar"`` (pictures compared by similarity, thresholds
        calibrated on the agent's own pictures), ``"exact"`` (bit identity), ``"auto"`` (``"similar"`` for places
        pictured by float arrays, else ``"exact"``); poses are always exact
    :param calibration_window: Distinct pictures the recogniser calibrates on (see
        :class:`~sb3_dcqn.route_memory.places.PlaceRecogniser`)
    """

    def __init__(
        self,
        n_actions: int,
        observation_space: spaces.Space | None = None,
        goal_keys: Sequence[str] | None = None,
        success_reward: float | None = None,
        max_states: int = 1_000_000,
        place_matcher: PlaceMatcher | str | None = "auto",
        place_frame: PlaceFrame | None = None,
        retry_after: int = DEFAULT_RETRY_AFTER,
        max_cache_bytes: int = DEFAULT_CACHE_BYTES,
        goal_tolerance: float = 1e-4,
        recognition: str = "auto",
        calibration_window: int = 512,
    ) -> None:
        if n_actions < 1:
            raise ValueError(f"n_actions must be at least 1, got {n_actions}")
        if int(max_states) < 1:
            raise ValueError(f"max_states must be at least 1, got {max_states}")
        if goal_tolerance < 0:
            raise ValueError(f"goal_tolerance must be >= 0, got {goal_tolerance}")
        if recognition not in RECOGNITION_MODES:
            raise ValueError(f"recognition must be one of {RECOGNITION_MODES}, got {recognition!r}")
        if isinstance(place_matcher, str) and place_matcher != "auto":
            raise ValueError(f"place_matcher must be 'auto', None or a PlaceMatcher, got {place_matcher!r}")
        keys = default_goal_keys(observation_space) if goal_keys is None else tuple(goal_keys)
        _check_goal_keys(keys, observation_space)
        if place_frame is not None and place_frame.n_slots != n_actions:
            raise ValueError(f"place_frame has {place_frame.n_slots} slots for {n_actions} actions")
        self.n_actions = n_actions
        self.observation_space = observation_space
        self.goal_keys = keys
        self.success_reward = None if success_reward is None else float(success_reward)
        self.place_frame = place_frame
        self.cache = BoundedCache(max_cache_bytes)
        self._state_keys = place_frame.place_keys if place_frame is not None else None
        width, views, similar = self._picture_layout(recognition)
        self.edges = EdgeStore(
            n_actions,
            None if place_frame is None else place_frame.reverse_action,
            retry_after,
            forget_moves_into_on_bump=place_frame is None,
            one_place_twice=similar,
            count_outcomes=place_frame is None,  # poses: a move that ends in two places by turns is the world's chance
        )
        self.planner = Planner(self.edges, self.cache)
        self.recogniser = PlaceRecogniser(
            width, views, similar=similar, max_states=max_states, window=calibration_window,
            min_calibration=min(8, calibration_window),
        )  # fmt: skip
        legacy = place_frame is None and ACHIEVED_GOAL_KEY in keys  # SB3's goal env without a frame: poses
        if isinstance(place_matcher, str):  # "auto"
            pictured = similar and place_frame is not None and place_frame.goal_key is not None
            place_matcher = AlignedNearestPlace(views=views) if pictured else None
        self.goals = GoalIndex(
            asked_keys=[key for key in keys if key != ACHIEVED_GOAL_KEY],
            picture_key=place_frame.goal_key if place_frame is not None else None,
            recogniser=self.recogniser,
            cache=self.cache,
            achieved_key=ACHIEVED_GOAL_KEY if legacy else None,
            goal_tolerance=goal_tolerance,
            place_matcher=place_matcher,
            picture_rows=self._goal_picture_rows,
        )
        self._pending: list[tuple[Any, ...]] = []  # transitions held until the first calibration
        self._exhausted: set[int] = set()  # states whose search for untried found nothing, at _exhausted_version
        self._exhausted_version = -1
        self.stepped_aside = False
        self.aside_reason = ""
        self.predictions = PredictionRecord()  # its moves' predictions, scored: where they fail it stands aside
        # What it has to say, for the caller to print: (whether it stands aside (else speaks again), the words)
        self.notices: list[tuple[Hashable, str]] = []  # (kind, words): said by the layer
        self.merged = 0  # pairs of states merged into one place
        self.split = 0  # states split into two places
        self._guard: deque[np.ndarray] = deque()  # per recorded batch: (transitions, new states, unsure pictures)
        self._guard_totals = np.zeros(3, dtype=np.int64)

    @classmethod
    def for_env(cls, env: Any, place_frame: PlaceFrame | str | None = "auto", **kwargs: Any) -> RouteMemory:
        """
        An empty memory for an env (or vec env) with a ``Discrete`` action space.

        :param place_frame: ``"auto"``: the frame the env declares (:func:`~sb3_dcqn.place_frame.place_frame_of`,
            ``None`` where it declares none or where the declaration does not fit its wrapped spaces); ``None``: pose
            states whatever it declares; or a frame
        :param kwargs: The constructor's other arguments
        """
        if not isinstance(env.action_space, spaces.Discrete):
            raise ValueError(f"a route memory needs a Discrete action space, got {env.action_space}")
        frame = place_frame_of(env) if isinstance(place_frame, str) and place_frame == "auto" else place_frame
        return cls(int(env.action_space.n), env.observation_space, place_frame=frame, **kwargs)  # type: ignore[arg-type]

    # ------------------------------------------------------------------ sizes
    @property
    def n_states(self) -> int:
        return self.recogniser.n_states

    @property
    def n_tried(self) -> int:
        """Number of (state, slot) pairs tried (inferred outcomes are not tries)."""
        return self.edges.n_tried()

    def __len__(self) -> int:
        return self.n_states

    @property
    def speaks(self) -> bool:
        """Whether the memory routes and explores: it has not stepped aside for good (places not recognised), and
        does not stand aside now (its predictions fail: :mod:`~sb3_dcqn.route_memory.evidence`)."""
        return not self.stepped_aside and not self.predictions.standing_aside

    @property
    def outcome(self) -> np.ndarray:
        return self.edges.outcome

    @property
    def target(self) -> np.ndarray:
        return self.edges.target

    @property
    def arrival(self) -> np.ndarray:
        return self.edges.arrival

    @property
    def last_tried(self) -> np.ndarray:
        return self.edges.last_tried

    @property
    def clock(self) -> int:
        """Transitions remembered (the age of a closed road is counted in them)."""
        return self.edges.clock

    @clock.setter
    def clock(self, value: int) -> None:
        self.edges.clock = int(value)

    @property
    def aliased(self) -> set[int]:
        return self.edges.aliased

    @property
    def retry_after(self) -> int:
        return self.edges.retry_after

    @property
    def max_states(self) -> int:
        return self.recogniser.max_states

    @property
    def version(self) -> int:
        """Counts changes of the memory's moves and of where its goals are."""
        return self.edges.version + self.goals.version

    @property
    def place_matcher(self) -> PlaceMatcher | None:
        return self.goals.place_matcher

    def nbytes(self) -> int:
        """Bytes of the memory's facts: states (prototypes, digests), moves, goals (caches apart: :meth:`cache_nbytes`;
        Python's per-object overhead not counted)."""
        return self.recogniser.nbytes() + self.edges.nbytes() + self.goals.nbytes()

    def cache_nbytes(self) -> int:
        """Bytes of everything cached (routes, goals' places): at most ``max_cache_bytes``."""
        return self.cache.nbytes()

    def statistics(self) -> dict[str, float]:
        """What a logger shows of the memory (``memory/...``)."""
        transitions, new, unsure = self._guard_totals.tolist()
        recogniser = self.recogniser
        return {
            "states": float(self.recogniser.live_states().size),
            "merged": float(self.merged),
            "split": float(self.split),
            "tried": float(self.n_tried),
            "aliased": float(len(self.aliased)),
            "new_states_per_transition": new / transitions if transitions else 0.0,
            "unsure_share": unsure / transitions if transitions else 0.0,
            "known_below": float("nan") if recogniser.known is None else recogniser.known,
            "new_above": float("nan") if recogniser.new is None else recogniser.new,
            "stepped_aside": float(self.stepped_aside),
            "prediction_accuracy": self.predictions.accuracy,
            "standing_aside": float(self.predictions.standing_aside),
            "stochastic_moves": float(self.edges.n_stochastic),
        }

    # ------------------------------------------------------------------ pictures of places
    def _picture_layout(self, recognition: str) -> tuple[int, int, bool]:
        """Numbers per state picture (floats compared by similarity; else bytes), views per picture, and whether
        places are recognised by similarity."""
        space = self.observation_space
        if self.place_frame is not None and isinstance(space, spaces.Dict):
            keys = self.place_frame.place_keys
            floats = all(np.issubdtype(space[key].dtype, np.floating) for key in keys)
            if recognition == "similar" or (recognition == "auto" and floats):
                width = sum(int(np.prod(space[key].shape)) for key in keys)
                return width, self.place_frame.views_per_place, True
            return sum(_nbytes(space[key]) for key in keys), 1, False
        if isinstance(space, spaces.Dict):
            return sum(_nbytes(sub) for key, sub in space.spaces.items() if key not in self.goal_keys), 1, False
        return (_nbytes(space) if space is not None else 0), 1, False  # 0: set by the first observation

    def _pictures(self, observations: Any) -> np.ndarray:
        """The state part of a batch: the place keys as float32 (places), or each observation's bytes (poses)."""
        if self.recogniser.similar:
            batch = _batch_size(observations)
            keys = self._state_keys
            return np.concatenate(
                [np.asarray(observations[key], dtype=np.float32).reshape(batch, -1) for key in keys], axis=1
            )
        rows = self._rows(observations)
        if self.recogniser.dim == 0:  # no space given: the first observation sets the size
            self.recogniser.dim = rows.shape[1]
        return rows

    def _goal_picture_rows(self, pictures: np.ndarray) -> np.ndarray:
        """Goal pictures (a batch, in the place key's format) as the recogniser's rows."""
        return self._pictures({self._state_keys[0]: pictures})  # type: ignore[index]

    def _rows(self, observations: Any) -> np.ndarray:
        """A batch's bytes per observation (the state's keys of a Dict), cast to the space's dtypes."""
        if isinstance(observations, Mapping):
            keys = self._state_keys or [key for key in sorted(observations) if key not in self.goal_keys]
            subspaces = self.observation_space.spaces if isinstance(self.observation_space, spaces.Dict) else {}
            arrays = [_as_rows(observations[key], subspaces.get(key)) for key in sorted(keys)]
            return np.concatenate(arrays, axis=1) if len(arrays) > 1 else arrays[0]
        return _as_rows(observations, self.observation_space)

    def states_of(self, observations: Any, *, add: bool = False, expected: np.ndarray | None = None) -> np.ndarray:
        """
        The states of a batch of observations (a dict of batches for Dict observations): -1 where unknown or unsure.

        :param add: Give new places new states
        :param expected: Per observation, the state the caller expects (-1: none), e.g. from
            :meth:`expected_states` of its last state and move: the graph's prior, which settles pictures the views
            alone leave unsure
        """
        states, _ = self._recognise(observations, add, expected)
        return states

    def state_of(self, observation: Any, *, add: bool = False) -> int:
        """The state of one observation (unbatched), -1 if unknown."""
        return int(self.states_of(batch_of_one(observation), add=add)[0])

    def _recognise(
        self, observations: Any, add: bool, expected: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.stepped_aside:
            size = _batch_size(observations)
            return np.full(size, -1, dtype=np.int64), np.full(size, Answer.UNSURE, dtype=np.int8)
        return self.recogniser.recognise(self._pictures(observations), add=add, expected=expected)

    # ------------------------------------------------------------------ frames and slots
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

    def slot_actions(self, observations: Any, slots: np.ndarray) -> np.ndarray:
        """The actions that take ``slots`` at each observation's frame (-1 stays -1)."""
        slots = np.asarray(slots, dtype=np.int64)
        if not self._relative():
            return slots
        return np.where(slots >= 0, (slots - self._frames(observations)) % self.n_actions, -1)

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
        :param successes: Whether each transition reached its goal (the env's ``info["is_success"]``; ``None``: a
            terminated transition with a reward above ``success_reward``, where that is set)
        :return: how many changes the batch made to the memory's moves
        """
        actions = np.asarray(actions).reshape(-1).astype(np.int64)
        rewards = np.asarray(rewards, dtype=np.float64).reshape(-1)
        terminated = np.asarray(terminated).reshape(-1).astype(bool)
        if actions.size != _batch_size(observations):
            raise ValueError(f"{actions.size} actions for {_batch_size(observations)} observations")
        bad = (actions < 0) | (actions >= self.n_actions)
        if bad.any():
            raise ValueError(f"action {int(actions[bad][0])} is out of range [0, {self.n_actions})")
        if successes is None:
            reached = rewards > self.success_reward if self.success_reward is not None else np.zeros_like(terminated)
        else:
            reached = np.asarray(successes).reshape(-1).astype(bool)
        if self.stepped_aside:
            self.edges.clock += actions.size
            return 0
        before = self.edges.version
        batch = (observations, actions, next_observations, rewards, terminated & reached, terminated)
        if self.recogniser.similar and not self.recogniser.calibrated:
            self.recogniser.show(self._pictures(next_observations))
            self._pending.append(batch)
            if not self.recogniser.calibrated:
                return 0
            pending, self._pending = self._pending, []
            for held in pending:
                self._remember(*held)
        else:
            if self.recogniser.similar:
                self.recogniser.show(self._pictures(next_observations))
            self._remember(*batch)
        self._check_recognition()
        return self.edges.version - before

    def _remember(
        self,
        observations: Any,
        actions: np.ndarray,
        next_observations: Any,
        rewards: np.ndarray,
        success: np.ndarray,
        terminated: np.ndarray,
    ) -> None:
        if self.stepped_aside:
            return
        before = self.n_states
        states, answers = self._recognise(observations, add=True)
        slots = self._slots(self._frames(observations), actions)
        next_states, next_answers = self._recognise(
            next_observations, add=True, expected=self.expected_states(states, slots)
        )
        if success.any():
            self.goals.add_reached(select_rows(next_observations, success), next_states[success])
        if self.goals.matched:  # where an episode went on, its goal is not (a goal env ends its episodes there)
            went_on = np.where(success | (next_answers != Answer.KNOWN), -1, next_states)
            self.goals.rule_out(self.goal_digests(next_observations), went_on)
        if self.goals.achieved_key is not None:
            self.goals.add_achieved(observations, states)
            self.goals.add_achieved(next_observations, next_states)
        # An end without success is a dead end of the world, except where episodes end at their goal's
        dead = terminated & ~success & (not self.goals.conditioned)
        arrivals = self._frames(next_observations)
        unsure = (answers == Answer.UNSURE) | (next_answers == Answer.UNSURE)
        disputed: set[int] = set()
        hits: list[bool] = []  # the moves' predictions, each scored before its move is recorded
        for index, (state, slot, following, arrival, is_dead, skip) in enumerate(zip(
            states.tolist(), slots.tolist(), next_states.tolist(), arrivals.tolist(), dead.tolist(), unsure.tolist(),
            strict=True,
        )):  # fmt: skip
            if state >= 0:
                self.edges.ensure(self.n_states)
                hit = self._came_true(state, slot, DEAD if is_dead else following, next_answers[index] != Answer.UNSURE)
                if hit is not None:
                    hits.append(hit)
            if skip or state < 0:  # an unsure picture: nothing is recorded (the clock still counts)
                self.edges.clock += 1
                continue
            self.edges.record(state, slot, following, arrival, is_dead, self.recogniser.alike)
            if self.edges.disputed:
                disputed |= self._witness_disputes(observations, next_observations, index, state)
        self._count(actions.size, self.n_states - before, int(unsure.sum()))
        self._judge(hits)
        if self.predictions.standing_aside:
            return  # its evidence does not hold: it changes no place on it (merging, splitting)
        self._merge_twins()
        self._split_aliases(disputed)

    def _witness_disputes(self, observations: Any, next_observations: Any, index: int, state: int) -> set[int]:
        """Show the recogniser the picture of each state whose move was just disputed, labelled by where the move led
        (a move's start, or its end where the way back was disputed); returns those states."""
        witnessed = set()
        for disputed, slot, led_to in self.edges.disputed if self.recogniser.similar else ():
            picture = self._pictures(select_rows(observations if disputed == state else next_observations, [index]))
            self.recogniser.witness(disputed, (slot, led_to), picture[0])
            witnessed.add(disputed)
        self.edges.disputed.clear()
        return witnessed

    def _split_aliases(self, states: set[int]) -> None:
        """
        Aliased states (among ``states``) whose two sides (the pictures witnessed each time the slot that led to two
        places led to one or the other) differ in a view by ``new`` or more were two look-alike intersections
        remembered as one: each becomes a place of its own. Sides alike in every view leave the state aliased (its
        slot's two places may be one place remembered twice, or a picture of one taken for the other: no evidence
        to merge them on).
        """
        for state in sorted(states & self.edges.aliased):
            alias = self.edges.alias_of(state, self.recogniser.alike)
            if alias is None:
                continue
            slot, kept, moved = alias
            sibling = self.recogniser.split(state, (slot, kept), (slot, moved))
            if sibling >= 0:
                self.edges.split(state, slot, sibling, moved)
                self.cache.clear()
                self.split += 1

    def _merge_twins(self) -> None:
        """States the moves showed to be one place (:attr:`EdgeStore.twins`) become one: the older keeps it."""
        while self.edges.twins:
            keep, drop = sorted(self.edges.twins.pop())
            if not (self.recogniser.live(keep) and self.recogniser.live(drop)):
                continue
            self.recogniser.merge(keep, drop)
            self.edges.merge(keep, drop)
            self.goals.merge(keep, drop)
            self.cache.clear()
            self.merged += 1

    def expected_states(self, states: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """Where each (state, slot) should lead, by the memory (-1: unknown): the prior that localises on the graph."""
        states, slots = np.asarray(states, dtype=np.int64).reshape(-1), np.asarray(slots, dtype=np.int64).reshape(-1)
        expected = np.full(states.size, -1, dtype=np.int64)
        known = (states >= 0) & (states < self.n_states) & (slots >= 0)
        if not known.any():
            return expected
        rows, columns = states[known], slots[known]
        self.edges.ensure(self.n_states)
        outcomes, targets = self.edges.outcome[rows, columns], self.edges.target[rows, columns]
        expected[known] = np.where(np.isin(outcomes, ROUTES), targets, np.where(np.isin(outcomes, CLOSED), rows, -1))
        return expected

    def deterministic(self, states: np.ndarray, slots: np.ndarray) -> np.ndarray:
        """Which moves (``states`` and their ``slots``) are of known states and not stochastic (their outcome so far
        one end at a time, as a deterministic world's with closures)."""
        states = np.asarray(states, dtype=np.int64).reshape(-1)
        slots = np.asarray(slots, dtype=np.int64).reshape(-1)
        known = (states >= 0) & (states < self.edges.n_rows) & (slots >= 0)
        known[known] = ~self.edges.stochastic[states[known], slots[known]]
        return known

    def _came_true(self, state: int, slot: int, end: int, sure: bool) -> bool | None:
        """Whether a remembered move predicted where it led (``end``: a state, or :data:`DEAD` for an end without
        success; ``sure``: the picture there was recognised): its target, the state itself for a closed road, one of
        its ends before for a stochastic move; ``None`` where it predicts nothing (untried, a dead end, outside)."""
        edges = self.edges
        if edges.stochastic[state, slot]:
            return sure and edges.explains(state, slot, end)
        outcome = edges.outcome[state, slot]
        predicted = int(edges.target[state, slot]) if outcome in ROUTES else state if outcome in CLOSED else -1
        if predicted < 0:
            return None
        return sure and end == predicted

    def _judge(self, hits: list[bool]) -> None:
        """Score the predictions just made, and say so where the memory now stands aside or speaks again."""
        record = self.predictions
        if hits and record.score(np.array(hits, dtype=bool)):
            held = f"{record.accuracy:.0%} of the last {len(record)}"
            if record.standing_aside:
                self.cache.clear()
                words = f"stands aside (its moves' predictions held for {held}): the algorithm acts alone, on data "
                self.notices.append((True, f"route memory: {words}the memory leaves as they are"))
            else:
                self.edges.forget_disputes()  # gathered while its pictures were not told apart: no evidence
                self.notices.append((False, f"route memory: speaks again (its moves' predictions hold for {held})"))

    # ------------------------------------------------------------------ the guard
    def _count(self, transitions: int, new: int, unsure: int) -> None:
        """The guard's counts over about the last ``GUARD_WINDOW`` transitions."""
        self._guard.append(np.array([transitions, new, unsure], dtype=np.int64))
        self._guard_totals += self._guard[-1]
        while self._guard and self._guard_totals[0] - self._guard[0][0] >= GUARD_WINDOW:
            self._guard_totals -= self._guard.popleft()

    def _check_recognition(self) -> None:
        """Step aside where recognition is failing (see the module docstring)."""
        transitions, new, _ = self._guard_totals.tolist()
        recogniser = self.recogniser
        if recogniser.calibrated and not recogniser.separable and recogniser.window_full:
            self._step_aside(
                f"its pictures do not separate places (the nearest other picture is as far for a repeat visit as for "
                f"another place, over {recogniser.window} distinct pictures)"
            )
        elif NEVER_AGAIN_WINDOW <= transitions < GUARD_WINDOW and new >= transitions:
            self._step_aside(
                f"none of the first {transitions} transitions met a state seen before: states never repeat"
            )
        elif transitions >= GUARD_WINDOW and new > GROWTH_GUARD * transitions:
            self._step_aside(f"{new} new states in the last {transitions} transitions: places are not recognised")
        # Pictures it is unsure of are no reason: a varied world's first thresholds leave most of them unsure for a
        # while, and the predictions judge what it does recognise (hours 9-17, seeds 31 33 35: stepped aside for good
        # at 0.90-0.95 of its predictions true, the critics then took 19,250 env steps or more than 30,000)

    def _step_aside(self, reason: str) -> None:
        if self.stepped_aside:
            return
        self.stepped_aside, self.aside_reason = True, reason
        self._pending.clear()
        self.cache.clear()
        warnings.warn(f"The route memory steps aside for good ({reason}): the agent's own policy acts", stacklevel=3)

    # ------------------------------------------------------------------ goals
    def goal_digests(self, observations: Any) -> list[bytes]:
        """The goal asked for by each observation (one shared goal where the observation names none)."""
        return self.goals.digests(observations, _batch_size(observations))

    def goal_states(self, observation: Any) -> np.ndarray:
        """The remembered states where one (unbatched) observation's goal is reached (empty: not in memory)."""
        batch = batch_of_one(observation)
        return self._goal_states(self.goal_digests(batch)[0], batch, 0)

    def _goal_states(self, goal: bytes, batch: Any, index: int) -> np.ndarray:
        return self.goals.states(goal, batch, index, _batch_size(batch))

    def _goal_search(self, goal: bytes, batch: Any, index: int, retry: bool = False) -> tuple[tuple[Any, ...], Any]:
        """The planner's key for the goal of observation ``index`` (its states in it: a search for where the goal
        was is never reused once it is placed elsewhere) and which moves reach it (a function of rows)."""
        return self._search_to(goal, self._goal_states(goal, batch, index), retry)

    def _search_to(self, goal: bytes, goal_states: np.ndarray, retry: bool = False) -> tuple[tuple[Any, ...], Any]:
        """:meth:`_goal_search` for a goal whose states are known."""
        arrived = np.zeros(self.edges.n_rows + 1, dtype=bool)
        arrived[goal_states] = True

        def is_target(rows: np.ndarray) -> np.ndarray:
            successors = self.edges.target[rows]
            return self.edges.moves(rows, retry) & arrived[np.where(successors >= 0, successors, -1)]

        return ("hops", goal, retry, goal_states.tobytes()), is_target

    # ------------------------------------------------------------------ routes
    def hops_to_goal(self, observation: Any) -> np.ndarray:
        """Hops from every state to one (unbatched) observation's goal over remembered moves (:data:`NO_ROUTE`)."""
        batch = batch_of_one(observation)
        goal = self.goal_digests(batch)[0]
        return self.planner.cached_hops(*self._goal_search(goal, batch, 0)).astype(np.int64)

    def route_actions(
        self, observations: Any, staleness: int = 0, retry: bool = False, states: np.ndarray | None = None
    ) -> np.ndarray:
        """
        The first action of a shortest remembered route from each observation to its goal (the lowest slot on
        ties): a batch (a dict of batches) in, int64 actions for each observation's own frame out, -1 where there is
        none (unknown or unsure place, goal not placed, not connected).

        :param staleness: Reuse a goal's search up to this many changes of the memory ago (training's rollouts: one
            search per many steps on a large map; the current moves are still read, so a road seen closed is never
            taken again unless ``retry``); 0: exact
        :param retry: Routes may go through closed roads whose retry is due, and a state next to such a road tries
            it (training's rollouts: a reopened road is found again; evaluation never drives a road seen closed)
        :param states: The observations' states where the caller has recognised them (:meth:`states_of`)
        """
        return self.routes(observations, staleness, retry, states)[0]

    def routes(
        self,
        observations: Any,
        staleness: int = 0,
        retry: bool = False,
        states: np.ndarray | None = None,
        not_goal: Sequence[frozenset[int]] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """
        :meth:`route_actions`, and whether each observation's state is one where the memory places its goal (an
        episode that goes on there says the goal is elsewhere).

        :param not_goal: Per observation, states its goal is known not to be at (an evaluation's episode went on
            there): routes lead to the goal's other states (none left: no route)
        """
        states = self.states_of(observations) if states is None else np.asarray(states, dtype=np.int64)
        slots = np.full(states.size, -1, dtype=np.int64)
        arrived = np.zeros(states.size, dtype=bool)
        if not self.speaks or self.n_states == 0:
            return slots, arrived
        self.edges.ensure(self.n_states)
        by_goal: dict[tuple[bytes, frozenset[int]], list[int]] = {}
        for index, goal in enumerate(self.goal_digests(observations)):
            by_goal.setdefault((goal, frozenset() if not_goal is None else not_goal[index]), []).append(index)
        for (goal, elsewhere), indices in by_goal.items():
            rows = np.array(indices)
            goal_states = self._goal_states(goal, observations, indices[0])
            if elsewhere:
                goal_states = goal_states[~np.isin(goal_states, list(elsewhere))]
            key, is_target = self._search_to(goal, goal_states, retry)
            if self.edges.n_stochastic:  # a slippery world: the surest route, not the fewest hops
                values = self.planner.cached_values(key, goal_states, staleness, retry)
                slots[rows] = self.planner.best_slots(states[rows], values)
            else:
                hops = self.planner.cached_hops(key, is_target, staleness, retry)
                slots[rows] = self.planner.first_slots(states[rows], hops, is_target, retry)
            arrived[rows] = np.isin(states[rows], goal_states) & (states[rows] >= 0)
        if retry:  # passing by a closed road whose retry is due: try it (one bump per backoff, where still closed)
            slots = np.where((aged := self._retry_due_roads(states)) >= 0, aged, slots)
        return self.slot_actions(observations, slots), arrived

    def _retry_due_roads(self, states: np.ndarray) -> np.ndarray:
        """Per state, the lowest closed slot whose road led somewhere and whose retry is due (-1: none)."""
        slots = np.full(states.size, -1, dtype=np.int64)
        known = states >= 0
        if not known.any():
            return slots
        rows = states[known]
        targets = self.edges.target[rows]
        due = self.edges.retry_due(rows) & (targets >= 0) & (targets != rows[:, None])
        slots[known] = np.where(due.any(axis=1), due.argmax(axis=1), -1)
        return slots

    def route_from(self, observation: Any, max_hops: int | None = None) -> list[int]:
        """The actions of a shortest remembered route from one observation to its goal (empty: none), each for the
        frame the agent will have when it takes it."""
        batch = batch_of_one(observation)
        goal = self.goal_digests(batch)[0]
        state = self.state_of(observation)
        if state < 0:
            return []
        key, is_target = self._goal_search(goal, batch, 0)
        hops = self.planner.cached_hops(key, is_target)
        frame = int(self._frames(batch)[0])
        actions: list[int] = []
        for _ in range(self.n_states if max_hops is None else max_hops):
            slot = int(self.planner.first_slots(np.array([state]), hops, is_target)[0])
            if slot < 0:
                return []
            actions.append((slot - frame) % self.n_actions if self._relative() else slot)
            if is_target(np.array([state]))[0, slot]:
                return actions
            state, frame = int(self.edges.target[state, slot]), int(self.edges.arrival[state, slot])
        return actions

    # ------------------------------------------------------------------ exploration
    def untried_slots(self, state: int) -> np.ndarray:
        """The slots never tried from ``state`` (inferred ones are known, not untried)."""
        return np.flatnonzero(self.edges.outcome[state] == Outcome.UNTRIED)

    def frontier(self) -> np.ndarray:
        """The states with at least one untried slot."""
        self.edges.ensure(self.n_states)
        return np.flatnonzero((self.edges.outcome[: self.n_states] == Outcome.UNTRIED).any(axis=1))

    def explore_actions(self, observations: Any) -> np.ndarray:
        """
        The first action towards the nearest untried ``(state, slot)`` from each observation, in hops over remembered
        moves (the untried slot itself where the state has one; the lowest on ties): one search for all states, kept
        until the memory changes.

        :return: the actions, -1 where a state is unknown or nothing untried can be reached
        """
        if not self.speaks or self.n_states == 0:
            return np.full(_batch_size(observations), -1, dtype=np.int64)
        self.edges.ensure(self.n_states)
        hops = self.planner.cached_hops(("explore",), self.edges.untried)
        slots = self.planner.first_slots(self.states_of(observations), hops, self.edges.untried)
        return self.slot_actions(observations, slots)

    def path_to_untried(
        self, state: int, exclude: set[tuple[int, int]] | frozenset = frozenset(), retry: bool = True
    ) -> list[int] | None:
        """
        The slots from ``state`` to the nearest untried ``(state, slot)`` (``exclude``'s pairs passed over), that slot
        last; where nothing untried can be reached, to the nearest closed slot whose retry is due (see
        :func:`~sb3_dcqn.route_memory.explorer.path_to`), unless ``retry`` is False. In a stochastic world (with
        ``retry``) the nearest of all three: untried, tried too few times to plan on
        (:meth:`~sb3_dcqn.route_memory.edges.EdgeStore.undersampled`) and closed with its retry due.

        :return: the slots, or ``None`` if nothing can be reached
        """
        if not 0 <= state < self.n_states:
            raise ValueError(f"state {state} is not one of the memory's {self.n_states} states")
        self.edges.ensure(self.n_states)
        if self.place_frame is None and (self.edges.outcome[state] == Outcome.UNTRIED).all():
            # A pose it knows nothing of (it may never come again: CartPole's) has no slot to prefer: no way to offer,
            # so the caller's own uniform draw acts (SB3's, from the same generator as without the memory)
            return None
        if retry and self.edges.n_stochastic:
            # A stochastic world's counts are the planner's model: a move tried only a few times is sought as an
            # untried one is, in one search with them (searched after them, the goal's never-tried moves, which no
            # episode outlives, would be sought for ever)
            rows = np.arange(self.n_states)
            wanted = self.edges.untried(rows) | self.edges.undersampled()[rows] | self.edges.retry_due(rows)
            return path_to(self.edges, state, lambda here: np.flatnonzero(wanted[here]).tolist(), exclude)
        if self._exhausted_version != self.edges.version:
            self._exhausted, self._exhausted_version = set(), self.edges.version
        if state not in self._exhausted:
            path = path_to(self.edges, state, lambda here: self.untried_slots(here).tolist(), exclude)
            if path is not None:
                return path
            if not exclude:
                self._exhausted.add(state)
        if not retry:
            return None
        due = self.edges.retry_due(np.arange(self.n_states))  # once for every state: the search visits many
        if not due.any():
            return None
        return path_to(self.edges, state, lambda here: np.flatnonzero(due[here]).tolist(), exclude)

    # ------------------------------------------------------------------ saving
    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        state.update(_exhausted=set(), _exhausted_version=-1)
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        state.setdefault("merged", 0)  # saved before states were merged
        state.setdefault("split", 0)  # saved before states were split
        state.setdefault("predictions", PredictionRecord())  # saved before predictions were scored
        state.setdefault("notices", [])
        if "edges" not in state:  # saved by an earlier release: its facts carried over, recognised bit for bit
            from sb3_dcqn.route_memory.legacy import load_earlier_memory

            load_earlier_memory(self, state)
            return
        self.__dict__.update(state)


def _check_goal_keys(keys: tuple[str, ...], observation_space: spaces.Space | None) -> None:
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


def _as_rows(batch: Any, space: spaces.Space | None) -> np.ndarray:
    """A batch as a C-contiguous (batch, bytes) uint8 array (cast to the space's dtype first, where known)."""
    array = np.asarray(batch) if space is None or space.dtype is None else np.asarray(batch, dtype=space.dtype)
    if array.ndim == 0 or (space is not None and space.shape is not None and array.shape == tuple(space.shape)):
        array = array[None]  # one unbatched observation of a Discrete or Box space
    array = np.ascontiguousarray(array)
    return array.reshape(array.shape[0], -1).view(np.uint8).reshape(array.shape[0], -1)


def _nbytes(space: spaces.Space) -> int:
    """Bytes of one observation of a space (0 where its shape or dtype is not fixed)."""
    if space.shape is None or space.dtype is None:
        return 0
    return int(np.prod(space.shape, dtype=np.int64)) * np.dtype(space.dtype).itemsize


def _batch_size(observations: Any) -> int:
    first = next(iter(observations.values())) if isinstance(observations, Mapping) else observations
    array = np.asarray(first)
    return int(array.shape[0]) if array.ndim else 1


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
