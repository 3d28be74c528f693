"""A graph of experience over exact observations, and replay search: routes planned over stored transitions.

**The experience graph** (:class:`ExperienceGraph`). In a deterministic world with discrete actions whose observations
repeat exactly (CampusNav: the same intersection seen at the same heading gives the same bytes), every stored
transition ``(o, a) -> (r, o', terminated)`` is an exact, 1-hop edge of the world's graph. Observations are keyed by a
digest of their bytes (:func:`sb3_dcqn.replay.revision.digest`; a Dict observation's keys in sorted order, nothing
else: the key holds only what the agent sees). Each ``(o, a)`` has one outcome, the latest: a new outcome replaces
the old one, so a road seen closed (a collision: ``o' == o``) removes the edge it used to be. The graph answers, from an
observation:

- the shortest route in hops to a **success**: a terminated transition with a reward above ``success_reward`` (the
  goal in CampusNav), and the first action of that route. Distances come from a backward breadth-first search from the
  success transitions, kept in one int array: new edges that shorten routes update it in place (a backward search
  from the changed state only); a replaced outcome recomputes it on the next query (level-synchronous BFS over all
  edges as arrays, a few milliseconds at 40,000 states x 4 actions);
- the nearest observation with an **untried** action (for exploration), and the actions that lead there.

It is built incrementally (:meth:`ExperienceGraph.add`, :meth:`ExperienceGraph.add_batch`) or from an SB3 replay
buffer's stored contents (:meth:`ExperienceGraph.add_replay_buffer`: ``ReplayBuffer``, ``DictReplayBuffer``, DCQN's
buffers, or any buffer whose ``observations``, ``next_observations``, ``actions``, ``rewards``, ``dones`` and
``timeouts`` index as ``[pos, env]``).

**Replay search** (:class:`ReplaySearchPolicy`), after *Search on the Replay Buffer* (SoRB, Eysenbach et al. 2019):
act by planning over the states in the replay buffer. SoRB's observations are continuous and never repeat, so its
graph's nodes are sampled buffer states and its edges are distances predicted by a goal-conditioned critic. Here
observations repeat exactly, so no critic is needed for the edges: the stored transitions themselves are the edges,
exact and one hop long. What remains of the critic's role is the fallback: where the graph has no route from an
observation (unseen, or not yet connected to the goal), the policy takes the model's own greedy action.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Mapping
from typing import Any

import numpy as np
from gymnasium import spaces

from sb3_dcqn.replay.revision import digest

__all__ = ["ExperienceGraph", "ReplaySearchPolicy", "observation_digests"]

UNTRIED = -1  # ``next_state`` of an (observation, action) never tried
UNKNOWN = -1  # distance of a state with no known route to a success


def observation_digests(observations: Any, observation_space: spaces.Space | None = None) -> list[bytes]:
    """
    The digests of a batch of observations: 16 bytes each, of the observation's bytes (a Dict's keys in sorted order).

    :param observations: A batch (first axis), a dict of batches for Dict observations
    :param observation_space: Where given, each array is cast to its space's dtype first, so that observations read
        back from a replay buffer (stored in that dtype) and fresh ones from the env have the same digest
    :return: one digest per observation
    """
    if isinstance(observations, Mapping):
        keys = sorted(observations)
        subspaces = observation_space.spaces if isinstance(observation_space, spaces.Dict) else {}
        arrays = [_as_rows(observations[key], subspaces.get(key)) for key in keys]
        rows = np.concatenate(arrays, axis=1) if len(arrays) > 1 else arrays[0]
    else:
        rows = _as_rows(observations, observation_space)
    return [digest(row.tobytes()) for row in rows]


def _as_rows(batch: Any, space: spaces.Space | None) -> np.ndarray:
    """A batch as a C-contiguous (batch, bytes) uint8 array."""
    array = np.asarray(batch) if space is None or space.dtype is None else np.asarray(batch, dtype=space.dtype)
    array = np.ascontiguousarray(array)
    return array.reshape(array.shape[0], -1).view(np.uint8).reshape(array.shape[0], -1)


class ExperienceGraph:
    """
    The transitions seen so far as a graph over exact observations (see the module docstring).

    States are numbered in the order their observations were first seen; ``next_state[s, a]`` is the state the action
    led to (``s`` itself for a collision, :data:`UNTRIED` if never tried).

    :param n_actions: Number of discrete actions
    :param observation_space: The observations' space (optional): arrays are cast to its dtypes before digesting
    :param success_reward: A terminated transition with a reward above this is a success (a route's end)
    :param capacity: Initial number of state rows (grows by doubling)
    """

    def __init__(
        self,
        n_actions: int,
        observation_space: spaces.Space | None = None,
        success_reward: float = 0.0,
        capacity: int = 1024,
    ) -> None:
        if n_actions < 1:
            raise ValueError(f"n_actions must be at least 1, got {n_actions}")
        self.n_actions = n_actions
        self.observation_space = observation_space
        self.success_reward = success_reward
        self._state_of: dict[bytes, int] = {}
        self.next_state = np.full((capacity, n_actions), UNTRIED, dtype=np.int64)
        self.rewards = np.zeros((capacity, n_actions), dtype=np.float32)
        self.terminated = np.zeros((capacity, n_actions), dtype=bool)
        # The states each state is reached from, as p * n_actions + a: for the backward search after a new edge
        self._predecessors: list[set[int]] = []
        self._distance = np.full(capacity, UNKNOWN, dtype=np.int64)
        self._distances_stale = False  # a replaced outcome may have lengthened routes: recompute on the next query
        self.version = 0  # counts changes of any outcome
        self._explore_hops = np.zeros(0, dtype=np.int64)
        self._explore_version = -1
        # States from which path_to_untried found nothing, valid while the graph is at _exhausted_version
        self._exhausted: set[int] = set()
        self._exhausted_version = -1

    @classmethod
    def for_env(cls, env: Any, success_reward: float = 0.0) -> ExperienceGraph:
        """An empty graph for an env (or vec env) with a ``Discrete`` action space."""
        if not isinstance(env.action_space, spaces.Discrete):
            raise ValueError(f"an experience graph needs a Discrete action space, got {env.action_space}")
        return cls(int(env.action_space.n), env.observation_space, success_reward)

    # ------------------------------------------------------------------ sizes
    @property
    def n_states(self) -> int:
        return len(self._state_of)

    @property
    def n_tried(self) -> int:
        """Number of (observation, action) pairs tried."""
        return int((self.next_state[: self.n_states] != UNTRIED).sum())

    def __len__(self) -> int:
        return self.n_states

    # ------------------------------------------------------------------ states
    def states_of(self, observations: Any, *, add: bool = False) -> np.ndarray:
        """
        The states of a batch of observations.

        :param observations: A batch (a dict of batches for Dict observations)
        :param add: Give unseen observations new states (else they are -1)
        :return: int64 states, one per observation
        """
        keys = observation_digests(observations, self.observation_space)
        if add:
            return np.array([self._state_for(key) for key in keys], dtype=np.int64)
        return np.array([self._state_of.get(key, -1) for key in keys], dtype=np.int64)

    def state_of(self, observation: Any, *, add: bool = False) -> int:
        """The state of one observation (unbatched), -1 if unseen and not ``add``."""
        return int(self.states_of(_batch_of_one(observation), add=add)[0])

    def _state_for(self, key: bytes) -> int:
        state = self._state_of.get(key)
        if state is None:
            state = self._state_of[key] = len(self._state_of)
            if state == self.next_state.shape[0]:
                self._grow()
            self._predecessors.append(set())
        return state

    def _grow(self) -> None:
        rows = self.next_state.shape[0]
        self.next_state = np.concatenate([self.next_state, np.full_like(self.next_state, UNTRIED)])
        self.rewards = np.concatenate([self.rewards, np.zeros_like(self.rewards)])
        self.terminated = np.concatenate([self.terminated, np.zeros_like(self.terminated)])
        self._distance = np.concatenate([self._distance, np.full(rows, UNKNOWN, dtype=np.int64)])

    # ------------------------------------------------------------------ adding transitions
    def add(self, obs: Any, action: int, next_obs: Any, reward: float, terminated: bool) -> bool:
        """
        Record one transition (unbatched observations); it replaces any earlier outcome of ``(obs, action)``.

        :param terminated: A real end of the episode (not a time limit)
        :return: whether the graph changed
        """
        states = self.states_of(_batch_of_one(obs), add=True)
        next_states = self.states_of(_batch_of_one(next_obs), add=True)
        return self._set_outcome(int(states[0]), int(action), int(next_states[0]), float(reward), bool(terminated))

    def add_batch(self, observations: Any, actions: Any, next_observations: Any, rewards: Any, terminated: Any) -> int:
        """
        Record a batch of transitions in order (a later one of the same ``(obs, action)`` wins). Distances are
        recomputed once, on the next query (cheaper than keeping them up to date edge by edge for a large batch).

        :return: how many changed the graph
        """
        states = self.states_of(observations, add=True)
        next_states = self.states_of(next_observations, add=True)
        actions = np.asarray(actions).reshape(-1)
        rewards = np.asarray(rewards, dtype=np.float64).reshape(-1)
        terminated = np.asarray(terminated).reshape(-1).astype(bool)
        changed = 0
        for i in range(states.size):
            changed += self._set_outcome(
                int(states[i]),
                int(actions[i]),
                int(next_states[i]),
                float(rewards[i]),
                bool(terminated[i]),
                shorten=False,
            )
        if changed:  # one search over the whole graph on the next query, not one backward search per edge
            self._distances_stale = True
        return changed

    def add_replay_buffer(self, buffer: Any, positions: np.ndarray | None = None) -> int:
        """
        Record the transitions stored in an SB3 replay buffer, oldest first (so the latest outcome wins).

        :param buffer: ``ReplayBuffer``, ``DictReplayBuffer``, DCQN's buffers, or any buffer whose arrays index as
            ``[pos, env]`` (``observations``, ``next_observations``, ``actions``, ``rewards``, ``dones``, optionally
            ``timeouts``; Dict observations: dicts of such arrays)
        :param positions: Buffer positions to read, in this order (default: every stored one, oldest first)
        :return: how many transitions changed the graph
        :raises ValueError: for a buffer that does not store next observations (``optimize_memory_usage``)
        """
        if getattr(buffer, "optimize_memory_usage", False):
            raise ValueError("the buffer stores no next observations (optimize_memory_usage=True): nothing to read")
        if positions is None:
            positions = stored_positions(buffer)
        positions = np.asarray(positions, dtype=np.int64).reshape(-1)
        if positions.size == 0:
            return 0
        n_envs = int(getattr(buffer, "n_envs", 1))
        pos = np.repeat(positions, n_envs)
        env = np.tile(np.arange(n_envs), positions.size)
        terminated = np.asarray(buffer.dones[pos, env], dtype=bool)
        timeouts = getattr(buffer, "timeouts", None)
        if timeouts is not None:
            terminated &= ~np.asarray(timeouts[pos, env], dtype=bool)
        return self.add_batch(
            _rows(buffer.observations, pos, env),
            np.asarray(buffer.actions[pos, env]).reshape(-1),
            _rows(buffer.next_observations, pos, env),
            buffer.rewards[pos, env],
            terminated,
        )

    def _set_outcome(
        self, state: int, action: int, next_state: int, reward: float, terminated: bool, *, shorten: bool = True
    ) -> bool:
        """Set the outcome of ``(state, action)``; ``shorten``: bring the distances up to date at once."""
        if not 0 <= action < self.n_actions:
            raise ValueError(f"action {action} is out of range [0, {self.n_actions})")
        old = int(self.next_state[state, action])
        if old == next_state and self.rewards[state, action] == reward and self.terminated[state, action] == terminated:
            return False
        edge = state * self.n_actions + action
        if old != UNTRIED:
            # A replaced outcome: the old edge may have carried routes, so distances are recomputed from scratch
            if self._is_route_edge(state, old, self.terminated[state, action]):
                self._predecessors[old].discard(edge)
            self._distances_stale = True
        self.next_state[state, action] = next_state
        self.rewards[state, action] = reward
        self.terminated[state, action] = terminated
        if self._is_route_edge(state, next_state, terminated):
            self._predecessors[next_state].add(edge)
        self.version += 1
        if shorten and not self._distances_stale:
            self._shorten_from(state)
        return True

    @staticmethod
    def _is_route_edge(state: int, next_state: int, terminated: bool) -> bool:
        """Edges that routes go along: a move to another state that does not end the episode."""
        return next_state != state and not terminated

    # ------------------------------------------------------------------ routes to a success
    def _is_success(self, states: np.ndarray | slice) -> np.ndarray:
        """Whether each (state, action) of the rows is a success transition."""
        return self.terminated[states] & (self.rewards[states] > self.success_reward)

    def _shorten_from(self, state: int) -> None:
        """After a new outcome of ``state``: its distance may have dropped; pass the drop on backwards."""
        best = self._row_distance(state)
        if best == UNKNOWN or (UNKNOWN < self._distance[state] <= best):
            return
        self._distance[state] = best
        queue = deque([state])
        while queue:
            here = queue.popleft()
            through = int(self._distance[here]) + 1
            for edge in self._predecessors[here]:
                before = edge // self.n_actions
                if self._distance[before] == UNKNOWN or self._distance[before] > through:
                    self._distance[before] = through
                    queue.append(before)

    def _row_distance(self, state: int) -> int:
        """Hops to a success from ``state`` through its own outcomes and its successors' current distances."""
        best = UNKNOWN
        for action in range(self.n_actions):
            following = int(self.next_state[state, action])
            if following == UNTRIED:
                continue
            if self.terminated[state, action]:
                hops = 1 if self.rewards[state, action] > self.success_reward else UNKNOWN
            elif following != state and self._distance[following] != UNKNOWN:
                hops = int(self._distance[following]) + 1
            else:
                hops = UNKNOWN
            if hops != UNKNOWN and (best == UNKNOWN or hops < best):
                best = hops
        return best

    def _recompute_distances(self) -> None:
        """Backward BFS from every success transition."""
        self._distance = self._hops_to(self._is_success(slice(0, self.n_states)))
        self._distances_stale = False

    def _hops_to(self, targets: np.ndarray) -> np.ndarray:
        """
        Hops from every state to one of the target (state, action) pairs, that action included: a backward BFS level
        by level over all route edges as arrays (no per-state Python loop).

        :param targets: ``(n_states, n_actions)`` bool
        :return: int64 hops per state row of the arrays (:data:`UNKNOWN`: no target reachable)
        """
        n = self.n_states
        hops = np.full(self._distance.shape[0], UNKNOWN, dtype=np.int64)
        successors = self.next_state[:n]
        route = (successors >= 0) & ~self.terminated[:n] & (successors != np.arange(n)[:, None])
        sources = np.broadcast_to(np.arange(n)[:, None], successors.shape)[route]
        ends = successors[route]
        level = np.flatnonzero(targets.any(axis=1))
        count = 1
        hops[level] = count
        while level.size:
            frontier = np.zeros(n, dtype=bool)
            frontier[level] = True
            reached = sources[frontier[ends]]
            count += 1
            level = np.unique(reached[hops[reached] == UNKNOWN])
            hops[level] = count
        return hops

    def distances(self) -> np.ndarray:
        """Hops from every state to a success over the stored transitions (:data:`UNKNOWN`: no known route)."""
        if self._distances_stale:
            self._recompute_distances()
        return self._distance[: self.n_states]

    def distance_of(self, observation: Any) -> int:
        """Hops from one observation to a success (:data:`UNKNOWN` if unseen or without a known route)."""
        state = self.state_of(observation)
        return UNKNOWN if state < 0 else int(self.distances()[state])

    def route_actions(self, states: np.ndarray) -> np.ndarray:
        """
        The first action of a shortest stored route to a success from each state (the lowest such action on ties).

        :param states: States (-1 allowed: unseen)
        :return: the actions, -1 where a state is unseen or has no known route
        """
        return self._first_actions(states, self.distances(), self._is_success)

    def explore_actions(self, states: np.ndarray) -> np.ndarray:
        """
        The first action towards the nearest untried action from each state, in hops over stored route edges (the
        untried action itself where the state has one; the lowest such action on ties). The hops are computed for all
        states at once and kept until the graph changes: for evaluating many observations, where
        :meth:`path_to_untried` would search once per observation.

        :param states: States (-1 allowed: unseen)
        :return: the actions, -1 where a state is unseen or no untried action can be reached
        """
        if self._explore_version != self.version:
            self._explore_hops = self._hops_to(self.next_state[: self.n_states] == UNTRIED)
            self._explore_version = self.version
        return self._first_actions(states, self._explore_hops, lambda rows: self.next_state[rows] == UNTRIED)

    def _first_actions(self, states: np.ndarray, hops: np.ndarray, is_target: Any) -> np.ndarray:
        """The action of each state that starts a fewest-hops way to a target pair (-1: unseen or none)."""
        states = np.asarray(states, dtype=np.int64).reshape(-1)
        actions = np.full(states.size, -1, dtype=np.int64)
        known = states >= 0
        if not known.any():
            return actions
        rows = states[known]
        successors = self.next_state[rows]
        via = np.where(successors >= 0, hops[np.maximum(successors, 0)], UNKNOWN)
        moves = (successors >= 0) & (successors != rows[:, None]) & ~self.terminated[rows] & (via != UNKNOWN)
        never = np.iinfo(np.int64).max
        cost = np.where(is_target(rows), 1, np.where(moves, via + 1, never))
        best = cost.argmin(axis=1)
        actions[known] = np.where(cost[np.arange(rows.size), best] != never, best, -1)
        return actions

    def route_action(self, observation: Any) -> int:
        """The first action of a shortest stored route from one observation (-1: unseen or no known route)."""
        return int(self.route_actions(np.array([self.state_of(observation)]))[0])

    def route_from(self, state: int, max_hops: int | None = None) -> list[int]:
        """
        The actions of a shortest stored route from ``state`` to a success (empty if there is none).

        :param max_hops: Stop after this many actions (default: the number of states, more than any route needs)
        """
        actions: list[int] = []
        for _ in range(self.n_states if max_hops is None else max_hops):
            action = int(self.route_actions(np.array([state]))[0])
            if action < 0:
                return []
            actions.append(action)
            if self._is_success(np.array([state]))[0, action]:
                return actions
            state = int(self.next_state[state, action])
        return actions

    # ------------------------------------------------------------------ exploration
    def untried_actions(self, state: int) -> np.ndarray:
        """The actions never tried from ``state``."""
        return np.flatnonzero(self.next_state[state] == UNTRIED)

    def path_to_untried(self, state: int) -> list[int] | None:
        """
        The actions from ``state`` to the nearest state (in hops over stored route edges) with an untried action,
        that action last (the lowest untried one there; ties between states: the first found, in action order).

        :return: the actions, or ``None`` if no untried action can be reached
        """
        if not 0 <= state < self.n_states:
            raise ValueError(f"state {state} is not one of the graph's {self.n_states} states")
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
            ends = self.terminated[here].tolist()
            for action, following in enumerate(row):
                if following not in parent and following != here and not ends[action]:
                    parent[following] = (here, action)
                    queue.append(following)
        self._exhausted.update(parent)  # every state searched reaches nothing untried either
        return None

    def frontier(self) -> np.ndarray:
        """The states with at least one untried action."""
        return np.flatnonzero((self.next_state[: self.n_states] == UNTRIED).any(axis=1))


def stored_positions(buffer: Any) -> np.ndarray:
    """A replay buffer's filled positions, oldest first."""
    pos, size = int(buffer.pos), int(buffer.buffer_size)
    if getattr(buffer, "full", False):
        return np.concatenate([np.arange(pos, size), np.arange(0, pos)])
    return np.arange(pos)


def _rows(stored: Any, pos: np.ndarray, env: np.ndarray) -> Any:
    """Stored observations at ``[pos, env]`` (a dict of them for Dict observations)."""
    if isinstance(stored, Mapping):
        return {key: np.asarray(array[pos, env]) for key, array in stored.items()}
    return np.asarray(stored[pos, env])


def _batch_of_one(observation: Any) -> Any:
    if isinstance(observation, Mapping):
        return {key: np.asarray(value)[None] for key, value in observation.items()}
    return np.asarray(observation)[None]


class ReplaySearchPolicy:
    """
    Replay search: the first action of the shortest stored route to the goal, where the replay buffer has one; the
    model's own greedy action elsewhere (see the module docstring for how this relates to SoRB).

    Usable as a batch policy for :func:`campusnav_env.route_evaluation.evaluate_routes` (``policy(obs) -> actions``)
    and through SB3's ``predict`` signature.

    :param model: An SB3 algorithm with a ``Discrete`` action space (its ``predict`` is the fallback)
    :param experience: An :class:`ExperienceGraph` (used as is, :meth:`refresh` does nothing), or a replay buffer to
        read (default: ``model.replay_buffer``, read again by :meth:`refresh`)
    :param success_reward: A terminated transition with a reward above this ends a route (a new graph only)
    :param fallback: The ``predict`` used where the graph has no route (default: ``model.predict``; DCQN passes its
        policy's own, so that its ``replay_search`` option does not call itself)
    """

    def __init__(self, model: Any, experience: Any = None, success_reward: float = 0.0, fallback: Any = None) -> None:
        self.model = model
        self._fallback = model.predict if fallback is None else fallback
        if isinstance(experience, ExperienceGraph):
            self.graph, self._buffer = experience, None
        else:
            self.graph = ExperienceGraph(int(model.action_space.n), model.observation_space, success_reward)
            self._buffer = model.replay_buffer if experience is None else experience
        self._read_steps: int | None = None  # the model's num_timesteps when the buffer was last read
        self.refresh()

    def refresh(self) -> int:
        """
        Read the replay buffer's transitions added since the last refresh (all of it the first time, or when more
        were added than it holds). Added transitions are counted with the model's ``num_timesteps`` when the buffer is
        the model's own (one buffer position per vector-env step); any other buffer is read in full.

        :return: how many transitions changed the graph
        """
        buffer = self._buffer
        if buffer is None:
            return 0
        steps = int(getattr(self.model, "num_timesteps", 0))
        positions = None  # everything stored
        own = buffer is getattr(self.model, "replay_buffer", None)
        if own and self._read_steps is not None:
            added = (steps - self._read_steps) // max(int(getattr(buffer, "n_envs", 1)), 1)
            if 0 <= added < int(buffer.buffer_size):
                positions = (int(buffer.pos) - added + np.arange(added)) % int(buffer.buffer_size)
        self._read_steps = steps
        return self.graph.add_replay_buffer(buffer, positions)

    def predict(
        self,
        observation: Any,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """
        The replay-search action for each observation (SB3's ``predict`` signature; batched or single).

        :param deterministic: Passed to the model's ``predict`` where the graph has no route
        :return: the actions and the (unused) recurrent state
        """
        batched = _is_batched(observation, self.model.observation_space)
        batch = observation if batched else _batch_of_one(observation)
        actions = self.graph.route_actions(self.graph.states_of(batch))
        fallback = actions < 0
        if fallback.any():
            if isinstance(batch, Mapping):
                rest = {key: np.asarray(value)[fallback] for key, value in batch.items()}
            else:
                rest = np.asarray(batch)[fallback]
            greedy, _ = self._fallback(rest, state, episode_start, deterministic)
            actions[fallback] = np.asarray(greedy).reshape(-1)
        return (actions if batched else actions[0]), state

    def __call__(self, observations: Any) -> np.ndarray:
        """A batch of observations -> actions (the batch-policy form ``evaluate_routes`` calls)."""
        return self.predict(observations, deterministic=True)[0]


def _is_batched(observation: Any, space: spaces.Space) -> bool:
    if isinstance(observation, Mapping) and isinstance(space, spaces.Dict):
        key = next(iter(space.spaces))
        return np.asarray(observation[key]).shape != space.spaces[key].shape
    return np.asarray(observation).shape != space.shape
