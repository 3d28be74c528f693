"""A memory that routes: one graph of the agent's own transitions for every goal.

In a deterministic world with discrete actions whose observations repeat exactly (CampusNav: the same intersection
seen at the same heading gives the same bytes), every transition ``(o, a) -> o'`` the agent makes is an exact, 1-hop
edge of the world's graph. :class:`RouteMemory` keeps those edges over **states that leave the goal out**: a state is
the digest of the observation without its goal keys (CampusNav: the views and the heading; a goal env's
``achieved_goal`` and ``desired_goal`` are left out), so that one graph serves every goal. A goal is a set of states:

- the states whose ``achieved_goal`` shows it (SB3's goal-env convention: ``achieved_goal`` equals ``desired_goal``
  at the goal), exactly, or through a **place matcher** where the goal's pictures differ from every remembered one
  (another time of day, passing cars: :mod:`sb3_dcqn.place_recognition`), or "not in memory";
- the states that a terminated transition with a reward above ``success_reward`` reached under that goal (envs
  without ``achieved_goal``: CampusNav-v0's ``goal_views``, FrozenLake's single goal).

A goal never trained on is then a place already in memory: reaching it is a search, not a generalisation of weights.
Each ``(state, action)`` keeps one outcome, the latest, so a collision (the observation did not change: a closed road)
turns that edge into a self-loop **for every goal at once**, and a move where the agent used to collide (a reopened
road) restores it (in a goal env, an episode's end is its goal's, and the move stays a move). The other remembered moves
into the state the lost move led to become untried again (:meth:`RouteMemory._suspect_moves_into`): where the state
after a move tells the road taken (CampusNav: the place and the heading away from the road), they are the same road from
the other headings, so one bump closes it for all. A terminated transition that is no success (FrozenLake's holes) is a
dead end: tried, never routed through.

What it holds (its own store, not the replay buffer's contents): per state a 16-byte digest and a row of
``n_actions`` int32 outcomes; per distinct ``achieved_goal`` picture its vector (for the place matcher) and the states
it was seen at; per goal given by success transitions its states. It grows with the distinct observations, not with
the steps, and stops taking new states at ``max_states`` (transitions between remembered states still update it).
It pickles, so it is saved inside the model's zip file (DCQN's ``route_memory``).

Queries (batched, as SB3's ``predict``):

- :meth:`route_actions`: the first action of a shortest remembered route to each observation's goal (-1: no route);
  hops per goal come from one backward breadth-first search over all edges as arrays, kept until the memory changes;
- :meth:`explore_actions` / :meth:`path_to_untried`: the first action towards the nearest untried ``(state,
  action)`` (Go-Explore's return-then-explore; the experience-graph floor's rule).

After *Semi-parametric Topological Memory* (SPTM, Savinov et al. 2018: a graph of observations, the goal found from
its picture, then graph search), *Search on the Replay Buffer* (SoRB, Eysenbach et al. 2019; here no critic is needed
for the edges: observations repeat, so stored transitions are exact, one hop long) and Dyna-Q+'s lesson that one model
update re-routes every goal.
"""

from __future__ import annotations

import hashlib
from collections import deque
from collections.abc import Mapping, Sequence
from typing import Any, Protocol

import numpy as np
from gymnasium import spaces

__all__ = [
    "DEAD_END",
    "NO_ROUTE",
    "UNTRIED",
    "PlaceMatcher",
    "RouteMemory",
    "UntriedExplorer",
    "batch_of_one",
    "default_goal_keys",
    "select_rows",
]

UNTRIED = -1  # outcome of a (state, action) never tried
DEAD_END = -2  # outcome of a (state, action) whose episode ended without success
NO_ROUTE = -1  # hops of a state with no remembered route
ACHIEVED_GOAL_KEY = "achieved_goal"
_NEVER = np.iinfo(np.int64).max
_MAX_CACHED_GOALS = 512


class PlaceMatcher(Protocol):
    """Finds the remembered place of goal pictures that match none exactly (see :mod:`sb3_dcqn.place_recognition`)."""

    def match(self, queries: np.ndarray, references: np.ndarray, labels: np.ndarray) -> np.ndarray:
        """
        :param queries: ``(m, d)`` goal pictures
        :param references: ``(n, d)`` the memory's place pictures
        :param labels: ``(n,)`` each reference's place (pictures seen at one state share a label)
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

    States are numbered in the order they were first seen; ``next_state[s, a]`` is where the action led (``s`` itself
    for a collision, :data:`UNTRIED`, :data:`DEAD_END`).

    :param n_actions: Number of discrete actions
    :param observation_space: The observations' space: arrays are cast to its dtypes before digesting (stored and
        fresh observations then agree), and its Dict keys give the default ``goal_keys``
    :param goal_keys: The Dict keys that name the goal, left out of the state (default: :func:`default_goal_keys`);
        ``achieved_goal`` among them attaches goals to states
    :param success_reward: A terminated transition with a reward above this reached its goal
    :param max_states: The most states remembered (then new observations are not added)
    :param place_matcher: Finds the place of goal pictures that match none exactly (``None``: exact matches only)
    """

    def __init__(
        self,
        n_actions: int,
        observation_space: spaces.Space | None = None,
        goal_keys: Sequence[str] | None = None,
        success_reward: float = 0.0,
        max_states: int = 1_000_000,
        place_matcher: PlaceMatcher | None = None,
    ) -> None:
        if n_actions < 1:
            raise ValueError(f"n_actions must be at least 1, got {n_actions}")
        if max_states < 1:
            raise ValueError(f"max_states must be at least 1, got {max_states}")
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
        self.n_actions = n_actions
        self.observation_space = observation_space
        self.goal_keys = keys
        self.success_reward = success_reward
        self.max_states = max_states
        self.place_matcher = place_matcher
        self._achieved_key = ACHIEVED_GOAL_KEY if ACHIEVED_GOAL_KEY in keys else None
        # The keys that say which goal is asked for (the achieved goal says where the agent is, not the goal)
        self._asked_keys = tuple(key for key in keys if key != self._achieved_key)
        self._state_of: dict[bytes, int] = {}
        self.next_state = np.full((1024, n_actions), UNTRIED, dtype=np.int32)
        # Goals given by success transitions: goal digest -> states reached
        self._reached: dict[bytes, set[int]] = {}
        # Places: distinct achieved-goal pictures, their vectors, and the states each was seen at
        self._place_of: dict[bytes, int] = {}
        self._place_vectors: list[np.ndarray] = []
        self._place_states: list[set[int]] = []
        self.version = 0  # counts changes of edges and goals
        self.suspected = 0  # moves made untried again by a collision on a move into the same state
        self._hops: dict[bytes, tuple[int, np.ndarray]] = {}  # goal digest -> (version, hops per state)
        self._lost_move_version = 0  # the last change that removed a move: older hops may route through it
        self._matched: dict[bytes, tuple[int, int]] = {}  # goal digest -> (places seen, matched place or -1)
        self._explore_hops = np.zeros(0, dtype=np.int64)
        self._explore_version = -1
        self._exhausted: set[int] = set()  # states whose search for untried found nothing, at _exhausted_version
        self._exhausted_version = -1

    @classmethod
    def for_env(cls, env: Any, **kwargs: Any) -> RouteMemory:
        """An empty memory for an env (or vec env) with a ``Discrete`` action space (``kwargs``: the constructor's)."""
        if not isinstance(env.action_space, spaces.Discrete):
            raise ValueError(f"a route memory needs a Discrete action space, got {env.action_space}")
        return cls(int(env.action_space.n), env.observation_space, **kwargs)

    # ------------------------------------------------------------------ sizes
    @property
    def n_states(self) -> int:
        return len(self._state_of)

    @property
    def n_tried(self) -> int:
        """Number of (state, action) pairs tried."""
        return int((self.next_state[: self.n_states] != UNTRIED).sum())

    @property
    def n_places(self) -> int:
        """Number of distinct achieved-goal pictures remembered."""
        return len(self._place_vectors)

    def __len__(self) -> int:
        return self.n_states

    def nbytes(self) -> int:
        """Bytes of the memory's arrays and digests (Python's per-object overhead not counted)."""
        places = sum(vector.nbytes for vector in self._place_vectors)
        links = sum(len(states) for states in self._place_states) + sum(len(s) for s in self._reached.values())
        return (
            self.n_states * (16 + self.n_actions * 4) + places + 16 * (self.n_places + len(self._reached)) + 8 * links
        )

    # ------------------------------------------------------------------ digests
    def _rows(self, observations: Any, keys: Sequence[str] | None) -> np.ndarray:
        """A batch's bytes per observation, ``keys`` (sorted) of a Dict, every key but the goal's when ``None``."""
        if isinstance(observations, Mapping):
            if keys is None:
                keys = [key for key in sorted(observations) if key not in self.goal_keys]
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

    # ------------------------------------------------------------------ states
    def states_of(self, observations: Any, *, add: bool = False) -> np.ndarray:
        """
        The states of a batch of observations (a dict of batches for Dict observations).

        :param add: Give unseen observations new states (else, and once ``max_states`` are held, they are -1)
        :return: int64 states, one per observation
        """
        keys = self._digests(observations)
        if add:
            return np.array([self._state_for(key) for key in keys], dtype=np.int64)
        return np.array([self._state_of.get(key, -1) for key in keys], dtype=np.int64)

    def state_of(self, observation: Any, *, add: bool = False) -> int:
        """The state of one observation (unbatched), -1 if unseen and not ``add``."""
        return int(self.states_of(batch_of_one(observation), add=add)[0])

    def _state_for(self, key: bytes) -> int:
        state = self._state_of.get(key)
        if state is None:
            if len(self._state_of) >= self.max_states:
                return -1
            state = self._state_of[key] = len(self._state_of)
            if state == self.next_state.shape[0]:
                self.next_state = np.concatenate([self.next_state, np.full_like(self.next_state, UNTRIED)])
        return state

    # ------------------------------------------------------------------ remembering
    def add(self, obs: Any, action: int, next_obs: Any, reward: float, terminated: bool) -> int:
        """Remember one transition (unbatched observations); ``terminated``: a real end, not a time limit."""
        return self.add_batch(
            batch_of_one(obs), np.array([action]), batch_of_one(next_obs), np.array([reward]), np.array([terminated])
        )

    def add_batch(self, observations: Any, actions: Any, next_observations: Any, rewards: Any, terminated: Any) -> int:
        """
        Remember a batch of transitions in order (a later outcome of the same ``(state, action)`` wins).

        :param terminated: Real ends of episodes (not time limits)
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
        success = terminated & (rewards > self.success_reward)
        if success.any():
            goals = self.goal_digests(select_rows(observations, success))
            for goal, state in zip(goals, next_states[success], strict=True):
                if state >= 0 and state not in self._reached.setdefault(goal, set()):
                    self._reached[goal].add(int(state))
                    self.version += 1
        if self._achieved_key is not None:
            self._add_places(observations, states)
            self._add_places(next_observations, next_states)
        # An end without success is a dead end of the world, except in a goal env: there the end is the goal's
        dead = terminated & ~success if self._achieved_key is None else np.zeros_like(terminated)
        outcomes = np.where(dead, DEAD_END, next_states)
        for state, action, outcome in zip(states.tolist(), actions.tolist(), outcomes.tolist(), strict=True):
            previous = int(self.next_state[state, action]) if state >= 0 else UNTRIED
            if state >= 0 and outcome != -1 and previous != outcome:
                self.next_state[state, action] = outcome
                self.version += 1
                if previous >= 0 and previous != state:  # a move lost (a closed road): routes may lengthen
                    if outcome == state:
                        self._suspect_moves_into(previous)
                    self._lost_move_version = self.version
        return self.version - before

    def _suspect_moves_into(self, lost: int) -> None:
        """
        A collision where a move into ``lost`` used to be: the other remembered moves into ``lost`` become untried
        again (routes avoid them until they are tried anew, and exploration tries them). Where the state after a move
        tells which road was taken (CampusNav: the place and the heading away from the road came along), those moves
        are the same road seen from the other headings at its start, so one bump closes it for all of them.
        """
        into = self.next_state[: self.n_states] == lost
        if into.any():
            self.next_state[: self.n_states][into] = UNTRIED
            self.suspected += int(into.sum())

    def _add_places(self, observations: Mapping[str, Any], states: np.ndarray) -> None:
        """Attach each state to the place its achieved goal pictures."""
        achieved = self._rows(observations, [self._achieved_key])  # type: ignore[list-item]
        vectors = np.asarray(observations[self._achieved_key]).reshape(len(states), -1)
        for row, vector, state in zip(achieved, vectors, states.tolist(), strict=True):
            if state < 0:
                continue
            key = _digest(row.tobytes())
            place = self._place_of.get(key)
            if place is None:
                place = self._place_of[key] = len(self._place_vectors)
                self._place_vectors.append(np.array(vector, dtype=np.float32))
                self._place_states.append(set())
            if state not in self._place_states[place]:
                self._place_states[place].add(state)
                self.version += 1

    # ------------------------------------------------------------------ goals
    def place_vectors(self) -> np.ndarray:
        """The remembered achieved-goal pictures, ``(n_places, d)`` float32."""
        if not self._place_vectors:
            return np.zeros((0, 0), dtype=np.float32)
        return np.stack(self._place_vectors)

    def place_labels(self) -> np.ndarray:
        """Each place picture's place: pictures seen at a common state share a label (int64, ``(n_places,)``)."""
        parent = list(range(self.n_places))

        def root(i: int) -> int:
            while parent[i] != i:
                parent[i] = parent[parent[i]]
                i = parent[i]
            return i

        first_place: dict[int, int] = {}
        for place, states in enumerate(self._place_states):
            for state in states:
                other = first_place.setdefault(state, place)
                parent[root(place)] = root(other)
        return np.array([root(place) for place in range(self.n_places)], dtype=np.int64)

    def goal_states(self, observation: Any) -> np.ndarray:
        """The remembered states where one (unbatched) observation's goal is reached (empty: not in memory)."""
        batch = batch_of_one(observation)
        return self._goal_states(self.goal_digests(batch)[0], batch, 0)

    def _goal_states(self, goal: bytes, batch: Any, index: int) -> np.ndarray:
        states = set(self._reached.get(goal, ()))
        if self._achieved_key is not None and "desired_goal" in self._asked_keys:
            place = self._place_of.get(goal)
            if place is None and self.place_matcher is not None and self._place_vectors:
                place = self._matched_place(goal, np.asarray(batch["desired_goal"])[index])
            if place is not None and place >= 0:
                states |= self._place_states[place]
        return np.array(sorted(states), dtype=np.int64)

    def _matched_place(self, goal: bytes, picture: np.ndarray) -> int:
        """The place matcher's answer for one goal picture, kept until more places are remembered."""
        seen = self._matched.get(goal)
        if seen is not None and seen[0] == self.n_places:
            return seen[1]
        vectors = self.place_vectors()
        query = np.asarray(picture, dtype=np.float32).reshape(1, -1)
        place = int(self.place_matcher.match(query, vectors, self.place_labels())[0])  # type: ignore[union-attr]
        self._matched[goal] = (self.n_places, place)
        return place

    # ------------------------------------------------------------------ routes
    def hops_to_goal(self, observation: Any) -> np.ndarray:
        """Hops from every state to one (unbatched) observation's goal over remembered edges (:data:`NO_ROUTE`)."""
        batch = batch_of_one(observation)
        return self._goal_hops(self.goal_digests(batch)[0], batch, 0)

    def _goal_hops(self, goal: bytes, batch: Any, index: int, staleness: int = 0) -> np.ndarray:
        cached = self._hops.get(goal)
        fresh_enough = cached is not None and cached[0] >= self._lost_move_version
        if fresh_enough and self.version - cached[0] <= staleness:  # type: ignore[index]
            return cached[1]
        if len(self._hops) >= _MAX_CACHED_GOALS:  # bounded: the goals asked for lately
            self._hops = {g: entry for g, entry in self._hops.items() if entry[0] == self.version}
        hops = self._hops_to(self._goal_targets(goal, batch, index)(np.arange(self.n_states)))
        self._hops[goal] = (self.version, hops)
        return hops

    def route_actions(self, observations: Any, staleness: int = 0) -> np.ndarray:
        """
        The first action of a shortest remembered route from each observation to its goal (the lowest such action on
        ties): a batch (a dict of batches) in, int64 actions out, -1 where there is none (unseen state, goal not in
        memory, or not connected).

        :param staleness: Reuse a goal's hops computed up to this many changes of the memory ago (training's
            rollouts: one search per many steps on a large map; the current edges are still read, so a road seen
            closed is never taken again); 0: exact
        """
        states = self.states_of(observations)
        goals = self.goal_digests(observations)
        actions = np.full(states.size, -1, dtype=np.int64)
        by_goal: dict[bytes, list[int]] = {}
        for index, goal in enumerate(goals):
            by_goal.setdefault(goal, []).append(index)
        for goal, indices in by_goal.items():
            rows = np.array(indices)
            hops = self._goal_hops(goal, observations, indices[0], staleness)
            actions[rows] = self._first_actions(states[rows], hops, self._goal_targets(goal, observations, indices[0]))
        return actions

    def _goal_targets(self, goal: bytes, batch: Any, index: int) -> Any:
        goal_states = self._goal_states(goal, batch, index)
        arrived = np.zeros(self.n_states + 1, dtype=bool)
        arrived[goal_states] = True

        def is_target(rows: np.ndarray) -> np.ndarray:
            successors = self.next_state[rows]
            return self._moves(rows) & arrived[np.where(successors >= 0, successors, self.n_states)]

        return is_target

    def route_from(self, observation: Any, max_hops: int | None = None) -> list[int]:
        """The actions of a shortest remembered route from one observation to its goal (empty: none)."""
        batch = batch_of_one(observation)
        goal = self.goal_digests(batch)[0]
        hops = self._goal_hops(goal, batch, 0)
        is_target = self._goal_targets(goal, batch, 0)
        state = self.state_of(observation)
        actions: list[int] = []
        for _ in range(self.n_states if max_hops is None else max_hops):
            if state < 0:
                return []
            action = int(self._first_actions(np.array([state]), hops, is_target)[0])
            if action < 0:
                return []
            actions.append(action)
            if is_target(np.array([state]))[0, action]:
                return actions
            state = int(self.next_state[state, action])
        return actions

    def _moves(self, rows: np.ndarray) -> np.ndarray:
        """Which (state, action) pairs of the rows lead to another state (routes go along them)."""
        successors = self.next_state[rows]
        return (successors >= 0) & (successors != rows[:, None])

    def _hops_to(self, targets: np.ndarray) -> np.ndarray:
        """
        Hops from every state to one of the target (state, action) pairs, that action included: a backward BFS level
        by level over all move edges as arrays (no per-state Python loop).

        :param targets: ``(n_states, n_actions)`` bool
        :return: int64 hops per state (:data:`NO_ROUTE`: no target reachable)
        """
        n = self.n_states
        hops = np.full(n, NO_ROUTE, dtype=np.int64)
        successors = self.next_state[:n]
        moves = self._moves(np.arange(n))
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

    def _first_actions(self, states: np.ndarray, hops: np.ndarray, is_target: Any) -> np.ndarray:
        """The action of each state that starts a fewest-hops way to a target pair (-1: unseen or none)."""
        states = np.asarray(states, dtype=np.int64).reshape(-1)
        actions = np.full(states.size, -1, dtype=np.int64)
        known = states >= 0
        if not known.any() or hops.size == 0:
            return actions
        rows = states[known]
        if hops.size < self.n_states:  # stale hops: states added since have no known route yet
            hops = np.concatenate([hops, np.full(self.n_states - hops.size, NO_ROUTE, dtype=np.int64)])
        successors = self.next_state[rows].astype(np.int64)
        via = np.where(successors >= 0, hops[np.maximum(successors, 0)], NO_ROUTE)
        moves = self._moves(rows) & (via != NO_ROUTE)
        cost = np.where(is_target(rows), 1, np.where(moves, via + 1, _NEVER))
        best = cost.argmin(axis=1)
        actions[known] = np.where(cost[np.arange(rows.size), best] != _NEVER, best, -1)
        return actions

    # ------------------------------------------------------------------ exploration
    def untried_actions(self, state: int) -> np.ndarray:
        """The actions never tried from ``state``."""
        return np.flatnonzero(self.next_state[state] == UNTRIED)

    def frontier(self) -> np.ndarray:
        """The states with at least one untried action."""
        return np.flatnonzero((self.next_state[: self.n_states] == UNTRIED).any(axis=1))

    def explore_actions(self, states: np.ndarray) -> np.ndarray:
        """
        The first action towards the nearest untried action from each state, in hops over remembered moves (the
        untried action itself where the state has one; the lowest on ties). Hops are computed for all states at once
        and kept until the memory changes: for many observations at one version, where :meth:`path_to_untried`
        would search once per observation.

        :param states: States (-1 allowed: unseen)
        :return: the actions, -1 where a state is unseen or no untried action can be reached
        """
        if self._explore_version != self.version:
            self._explore_hops = self._hops_to(self.next_state[: self.n_states] == UNTRIED)
            self._explore_version = self.version
        return self._first_actions(states, self._explore_hops, lambda rows: self.next_state[rows] == UNTRIED)

    def path_to_untried(self, state: int) -> list[int] | None:
        """
        The actions from ``state`` to the nearest state (in hops over remembered moves) with an untried action, that
        action last (the lowest untried one there; ties between states: the first found, in action order). A search
        from one state that stops at the first untried action: cheap on a large memory, where the nearest is close.

        :return: the actions, or ``None`` if no untried action can be reached
        """
        if not 0 <= state < self.n_states:
            raise ValueError(f"state {state} is not one of the memory's {self.n_states} states")
        if self._exhausted_version != self.version:
            self._exhausted, self._exhausted_version = set(), self.version
        if state in self._exhausted:  # searched in full since the last change: nothing untried from there
            return None
        parent: dict[int, tuple[int, int]] = {state: (-1, -1)}
        queue = deque([state])
        while queue:
            here = queue.popleft()
            row = self.next_state[here].tolist()
            if UNTRIED in row:
                path = [row.index(UNTRIED)]
                while parent[here][0] >= 0:
                    here, action = parent[here]
                    path.append(action)
                return path[::-1]
            for action, following in enumerate(row):
                if following >= 0 and following not in parent and following != here:
                    parent[following] = (here, action)
                    queue.append(following)
        self._exhausted.update(parent)  # every state searched reaches nothing untried either
        return None

    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        # Caches are rebuilt on use; the matcher's own state pickles with it
        state.update(_hops={}, _matched={}, _explore_version=-1, _exhausted=set(), _exhausted_version=-1)
        state["next_state"] = self.next_state[: self.n_states].copy()
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        rows = max(1024, self.next_state.shape[0])
        grown = np.full((rows, self.n_actions), UNTRIED, dtype=np.int32)
        grown[: self.next_state.shape[0]] = self.next_state
        self.next_state = grown


class UntriedExplorer:
    """
    Drives each env of a vector env to the nearest untried ``(state, action)`` of a :class:`RouteMemory` and tries it
    (Go-Explore's return, then explore): the path is searched once and followed while the states met are the ones
    expected, searched anew otherwise.

    :param memory: The memory it reads
    :param n_envs: Number of envs (one path each)
    """

    def __init__(self, memory: RouteMemory, n_envs: int = 1) -> None:
        self.memory = memory
        self._paths: list[list[tuple[int, int]]] = [[] for _ in range(n_envs)]

    def actions(self, observations: Any) -> np.ndarray:
        """The exploring action of each env's observation (a batch), -1 where the memory has none (unseen state, or
        nothing untried can be reached)."""
        return self.actions_at(self.memory.states_of(observations))

    def actions_at(self, states: np.ndarray) -> np.ndarray:
        """:meth:`actions` for the envs' memory states (-1: unseen), where the caller has them already."""
        if states.size != len(self._paths):
            self._paths = [[] for _ in range(states.size)]
        return np.array([self._action(env, int(state)) for env, state in enumerate(states)], dtype=np.int64)

    def _action(self, env: int, state: int) -> int:
        path = self._paths[env]
        if state >= 0 and path and path[0][0] == state:
            return path.pop(0)[1]
        path.clear()
        actions = None if state < 0 else self.memory.path_to_untried(state)
        if actions is None:
            return -1
        for action in actions:
            path.append((state, action))
            state = int(self.memory.next_state[state, action])
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
