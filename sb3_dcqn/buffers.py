"""Replay buffers with the re-adaptation options of DCQN: experience revision and prioritised replay.

**Experience revision** (``revise_experience=True``). In a deterministic world the same action from the same
observation always has the same outcome. When a new transition ``(o, a) -> (r, o', done)`` disagrees with stored
transitions of the same ``(o, a)`` (a collision where the agent used to drive on: a road has closed; a move where it
used to collide: a road has reopened), the stored transitions are contradicted by the agent's own experience, and are
relabelled with the new outcome. Without it, the stale copies (hundreds in a large buffer) keep teaching the old route
long after a closure. Transitions are found by a hash of the observation's bytes and the action, so the lookup costs a
dictionary access per added transition; the buffer counts the transitions it revised (:attr:`revised`).

**Prioritised replay** (``prioritized=True``, Schaul et al. 2016, proportional variant). Transitions are sampled with
probability ``p_i ** alpha / sum_k p_k ** alpha``, ``p_i`` the last absolute TD error (plus ``priority_eps``), new and
revised transitions at the highest priority so far, so that what just surprised the agent is replayed at once. The
samples carry importance weights ``(N * P(i)) ** -beta / max_j (N * P(j)) ** -beta`` (``beta`` annealed towards 1 by
the algorithm) and their indices, with which the algorithm reports the new TD errors (:meth:`update_priorities`).

Both options work with Box and Dict observations (:class:`DCQNReplayBuffer`, :class:`DCQNDictReplayBuffer`) and
several envs; not with ``optimize_memory_usage`` (next observations must be stored to be relabelled).

:class:`DCQNDictReplayBuffer` has three more options:

**Lean storage** (``lean=True``, DCQN's ``lean_replay``). Each Dict key's distinct vectors are stored once, in a table
shared by the observations and the next observations (:class:`~sb3_dcqn.observation_table.ObservationTable`), and
transitions hold ``int32`` row indices, gathered at sample time; Discrete actions take the smallest integer dtype.
Samples are the same as with the plain arrays. For an env whose observations repeat (CampusNav's views, the goal in
every step) a transition costs a few tens of bytes instead of kilobytes; the tables hold the live distinct rows only.

**n-step returns** (``n_steps > 1``, ``gamma``), as SB3's ``NStepReplayBuffer`` computes them (which does not take
Dict observations): the discounted sum of up to ``n_steps`` rewards, cut at the first termination or time limit (and
at the newest transition), the next observation and done of the window's last step, and ``discounts`` (``gamma ** k``
for a window of ``k`` steps) for the target. Not with revision or prioritised replay.

**Count bonus** (``count_bonus=beta > 0``), an exploration lever in the style of count-based bonuses (Strehl &
Littman 2008; Bellemare et al. 2016): sampled rewards get ``beta / sqrt(n(o'))``, ``n(o')`` the number of times the
transition's next observation (all keys) has been added to the buffer so far. The counts are of visits: they grow
with every addition and are not decremented when slots are overwritten, so the bonus of a view shrinks as the agent
keeps arriving there and stays large where it has rarely been. Cost: a digest per added transition, one ``int32``
per transition and a count per distinct observation.
"""

from __future__ import annotations

import hashlib
from typing import Any, NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer, ReplayBuffer
from stable_baselines3.common.type_aliases import DictReplayBufferSamples, TensorDict
from stable_baselines3.common.vec_env import VecNormalize

from sb3_dcqn.observation_table import ObservationTable

__all__ = [
    "DCQNDictReplayBuffer",
    "DCQNReplayBuffer",
    "PrioritizedDictReplayBufferSamples",
    "PrioritizedReplayBufferSamples",
    "use_observation_tables",
]


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


class PrioritizedReplayBufferSamples(NamedTuple):
    """Replay samples with importance weights and the indices to update their priorities."""

    observations: th.Tensor
    actions: th.Tensor
    next_observations: th.Tensor
    dones: th.Tensor
    rewards: th.Tensor
    discounts: th.Tensor | None
    weights: th.Tensor
    indices: np.ndarray


class PrioritizedDictReplayBufferSamples(NamedTuple):
    """Dict-observation replay samples with importance weights and the indices to update their priorities."""

    observations: TensorDict
    actions: th.Tensor
    next_observations: TensorDict
    dones: th.Tensor
    rewards: th.Tensor
    discounts: th.Tensor | None
    weights: th.Tensor
    indices: np.ndarray


class _ReadaptationMixin:
    """Experience revision and prioritised replay on top of an SB3 replay buffer (see the module docstring)."""

    buffer_size: int
    n_envs: int
    pos: int
    full: bool
    rewards: np.ndarray
    dones: np.ndarray
    timeouts: np.ndarray

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        revise_experience: bool = False,
        prioritized: bool = False,
        alpha: float = 0.6,
        beta: float = 0.4,
        priority_eps: float = 1e-3,
    ) -> None:
        # The one signature of both buffers: SB3's (ReplayBuffer or DictReplayBuffer, next in the MRO), then the levers
        super().__init__(  # type: ignore[call-arg]
            buffer_size,
            observation_space,
            action_space,
            device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
        )
        if getattr(self, "optimize_memory_usage", False):
            raise ValueError(f"{type(self).__name__} stores next observations to revise them: no optimize_memory_usage")
        if not 0.0 <= alpha <= 1.0 or not 0.0 <= beta <= 1.0 or priority_eps <= 0:
            raise ValueError(f"need 0 <= alpha, beta <= 1 and priority_eps > 0, got {alpha}, {beta}, {priority_eps}")
        self.revise_experience = revise_experience
        self.prioritized = prioritized
        self.alpha = alpha
        self.beta = beta
        self.priority_eps = priority_eps
        self.revised = 0
        slots = self.buffer_size * self.n_envs
        # Revision index: (observation, action) digest -> slots holding it; each slot's digests, to unindex on overwrite
        self._slots_of: dict[bytes, set[int]] = {}
        self._key_of: list[bytes | None] = [None] * slots
        self._outcome_of: list[bytes | None] = [None] * slots
        self.priorities = np.zeros((self.buffer_size, self.n_envs), dtype=np.float64)
        self._max_priority = 1.0

    # ------------------------------------------------------------------ adding and revising
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
        self.priorities[pos] = self._max_priority
        if not self.revise_experience:
            return
        for env in range(self.n_envs):
            slot = pos * self.n_envs + env
            key = self._digest(self._observation_bytes(obs, env) + np.asarray(action)[env].tobytes())
            outcome = self._outcome(pos, env)
            for other in index_transition(self._slots_of, self._key_of, self._outcome_of, slot, key, outcome):
                self._relabel(other, pos, env)

    @staticmethod
    def _digest(data: bytes) -> bytes:
        return digest(data)

    def _outcome(self, pos: int, env: int) -> bytes:
        # The world's answer: reward, real termination (not a time limit) and where the agent ended up
        terminated = self.dones[pos, env] * (1 - self.timeouts[pos, env])
        head = np.array([self.rewards[pos, env], terminated], dtype=np.float32).tobytes()
        return self._digest(head + self._stored_next_bytes(pos, env))

    def _relabel(self, slot: int, pos: int, env: int) -> None:
        """Overwrite the outcome of the stored transition in ``slot`` with that of ``(pos, env)``."""
        old_pos, old_env = divmod(slot, self.n_envs)
        self._copy_next_observation(old_pos, old_env, pos, env)
        self.rewards[old_pos, old_env] = self.rewards[pos, env]
        self.dones[old_pos, old_env] = self.dones[pos, env]
        self.timeouts[old_pos, old_env] = self.timeouts[pos, env]
        self.priorities[old_pos, old_env] = self._max_priority  # what contradicted the agent is replayed first
        self.revised += 1

    def _observation_bytes(self, obs: Any, env: int) -> bytes:
        raise NotImplementedError

    def _stored_next_bytes(self, pos: int, env: int) -> bytes:
        raise NotImplementedError

    def _copy_next_observation(self, to_pos: int, to_env: int, from_pos: int, from_env: int) -> None:
        raise NotImplementedError

    # ------------------------------------------------------------------ prioritised sampling
    def sample(self, batch_size: int, env: VecNormalize | None = None) -> Any:
        if not self.prioritized:
            return super().sample(batch_size, env=env)  # type: ignore[misc]
        upper = self.buffer_size if self.full else self.pos
        flat = self.priorities[:upper].reshape(-1) ** self.alpha
        total = flat.sum()
        # Inverse-CDF sampling on the cumulative priorities: O(N) per batch, a few tens of microseconds at 50k
        picks = np.searchsorted(np.cumsum(flat), np.random.random(batch_size) * total, side="right")
        picks = np.minimum(picks, flat.size - 1)
        probabilities = flat[picks] / total
        weights = (flat.size * probabilities) ** (-self.beta)
        weights /= weights.max()
        batch_inds, env_inds = np.divmod(picks, self.n_envs)
        samples = self._samples_at(batch_inds, env_inds, env)
        weights_tensor = self.to_torch(weights.astype(np.float32).reshape(-1, 1))  # type: ignore[attr-defined]
        return self._prioritized_type(*samples, weights_tensor, picks)

    def update_priorities(self, indices: np.ndarray, td_errors: np.ndarray) -> None:
        """
        Set the priorities of sampled transitions from their new absolute TD errors.

        :param indices: The ``indices`` of the samples
        :param td_errors: Their TD errors (any sign), same length
        """
        priorities = np.abs(np.asarray(td_errors, dtype=np.float64).reshape(-1)) + self.priority_eps
        self.priorities.reshape(-1)[np.asarray(indices)] = priorities
        self._max_priority = max(self._max_priority, float(priorities.max()))

    def _samples_at(self, batch_inds: np.ndarray, env_inds: np.ndarray, env: VecNormalize | None) -> tuple:
        raise NotImplementedError

    _prioritized_type: type


class DCQNReplayBuffer(_ReadaptationMixin, ReplayBuffer):
    """
    SB3's ``ReplayBuffer`` with experience revision and prioritised replay (see the module docstring).

    :param buffer_size: Max number of elements in the buffer
    :param observation_space: Observation space
    :param action_space: Action space
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Not supported (must be False)
    :param handle_timeout_termination: Handle timeout termination (due to a time limit) separately
    :param revise_experience: Relabel stored transitions that a new transition of the same observation and action
        contradicts
    :param prioritized: Sample in proportion to the TD error (importance-weighted)
    :param alpha: Priority exponent (0: uniform)
    :param beta: Importance-weight exponent (1: full correction); the algorithm may anneal it
    :param priority_eps: Added to the absolute TD error so that no transition gets probability 0
    """

    _prioritized_type = PrioritizedReplayBufferSamples

    def _observation_bytes(self, obs: Any, env: int) -> bytes:
        return np.ascontiguousarray(np.asarray(obs)[env], dtype=self.observations.dtype).tobytes()

    def _stored_next_bytes(self, pos: int, env: int) -> bytes:
        return self.next_observations[pos, env].tobytes()

    def _copy_next_observation(self, to_pos: int, to_env: int, from_pos: int, from_env: int) -> None:
        self.next_observations[to_pos, to_env] = self.next_observations[from_pos, from_env]

    def _samples_at(self, batch_inds: np.ndarray, env_inds: np.ndarray, env: VecNormalize | None) -> tuple:
        data = (
            self._normalize_obs(self.observations[batch_inds, env_inds, :], env),
            self.actions[batch_inds, env_inds, :],
            self._normalize_obs(self.next_observations[batch_inds, env_inds, :], env),
            (self.dones[batch_inds, env_inds] * (1 - self.timeouts[batch_inds, env_inds])).reshape(-1, 1),
            self._normalize_reward(self.rewards[batch_inds, env_inds].reshape(-1, 1), env),
        )
        return (*map(self.to_torch, data), None)


class DCQNDictReplayBuffer(_ReadaptationMixin, DictReplayBuffer):
    """
    SB3's ``DictReplayBuffer`` with experience revision, prioritised replay, lean storage, n-step returns and a count
    bonus (see the module docstring).

    :param buffer_size: Max number of elements in the buffer
    :param observation_space: Observation space (a Dict)
    :param action_space: Action space
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Not supported (must be False)
    :param handle_timeout_termination: Handle timeout termination (due to a time limit) separately
    :param revise_experience: Relabel stored transitions that a new transition of the same observation and action
        contradicts
    :param prioritized: Sample in proportion to the TD error (importance-weighted)
    :param alpha: Priority exponent (0: uniform)
    :param beta: Importance-weight exponent (1: full correction); the algorithm may anneal it
    :param priority_eps: Added to the absolute TD error so that no transition gets probability 0
    :param lean: Store each key's distinct vectors once and row indices per transition
    :param n_steps: Steps of the returns (1: one-step transitions); not with revision or priorities
    :param gamma: Discount of the n-step returns (the algorithm's)
    :param count_bonus: Scale of the intrinsic reward ``count_bonus / sqrt(n(next observation))`` (0: none)
    """

    _prioritized_type = PrioritizedDictReplayBufferSamples
    observations: dict[str, np.ndarray]
    next_observations: dict[str, np.ndarray]

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Dict,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        revise_experience: bool = False,
        prioritized: bool = False,
        alpha: float = 0.6,
        beta: float = 0.4,
        priority_eps: float = 1e-3,
        lean: bool = False,
        n_steps: int = 1,
        gamma: float = 0.99,
        count_bonus: float = 0.0,
    ) -> None:
        super().__init__(
            buffer_size,
            observation_space,
            action_space,
            device,
            n_envs=n_envs,
            optimize_memory_usage=optimize_memory_usage,
            handle_timeout_termination=handle_timeout_termination,
            revise_experience=revise_experience,
            prioritized=prioritized,
            alpha=alpha,
            beta=beta,
            priority_eps=priority_eps,
        )
        if n_steps < 1:
            raise ValueError(f"n_steps must be >= 1, got {n_steps}")
        if n_steps > 1 and (revise_experience or prioritized):
            raise ValueError(
                "experience revision and prioritised replay do not support n-step returns (n_steps > 1): a revised "
                "or prioritised transition is one step"
            )
        if count_bonus < 0:
            raise ValueError(f"count_bonus must be >= 0, got {count_bonus}")
        self.lean = lean
        self.n_steps = n_steps
        self.gamma = gamma
        self.count_bonus = count_bonus
        if lean:
            use_observation_tables(self)
        # Count bonus: each slot's next observation as a visit id; visits per distinct observation (never decremented)
        self.next_visits = np.zeros((self.buffer_size, self.n_envs), dtype=np.int32) if count_bonus > 0 else None
        self.visit_counts = np.zeros(16 if count_bonus > 0 else 0, dtype=np.int64)
        self._visit_of: dict[bytes, int] = {}

    def add(  # type: ignore[override]
        self,
        obs: dict[str, np.ndarray],
        next_obs: dict[str, np.ndarray],
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        if self.next_visits is not None:  # before super().add: a revision copies the new slot's visit id
            self.next_visits[self.pos] = [self._visit(next_obs, env) for env in range(self.n_envs)]
        super().add(obs, next_obs, action, reward, done, infos)

    def _visit(self, next_obs: dict[str, np.ndarray], env: int) -> int:
        """Count one arrival at ``next_obs[env]``; its visit id."""
        visit = self._visit_of.setdefault(digest(self._observation_bytes(next_obs, env)), len(self._visit_of))
        if visit == len(self.visit_counts):
            self.visit_counts = np.concatenate([self.visit_counts, np.zeros_like(self.visit_counts)])
        self.visit_counts[visit] += 1
        return visit

    def visits(self, batch_inds: np.ndarray, env_inds: np.ndarray) -> np.ndarray:
        """
        How many times the next observations of the given transitions have been added so far.

        :param batch_inds: Positions in the buffer
        :param env_inds: Their envs
        :return: The counts (``int64``, at least 1 for a stored transition)
        """
        if self.next_visits is None:
            raise ValueError("visits are counted with count_bonus > 0 only")
        return self.visit_counts[self.next_visits[batch_inds, env_inds]]

    def _observation_bytes(self, obs: Any, env: int) -> bytes:
        return b"".join(
            np.ascontiguousarray(np.asarray(obs[key])[env], dtype=self.observations[key].dtype).tobytes()
            for key in sorted(self.observations)
        )

    def _stored_next_bytes(self, pos: int, env: int) -> bytes:
        return b"".join(self.next_observations[key][pos, env].tobytes() for key in sorted(self.next_observations))

    def _copy_next_observation(self, to_pos: int, to_env: int, from_pos: int, from_env: int) -> None:
        for array in self.next_observations.values():
            array[to_pos, to_env] = array[from_pos, from_env]
        if self.next_visits is not None:
            self.next_visits[to_pos, to_env] = self.next_visits[from_pos, from_env]

    def _get_samples(  # type: ignore[override]
        self, batch_inds: np.ndarray, env: VecNormalize | None = None
    ) -> DictReplayBufferSamples:
        # The env of each sample drawn as SB3's DictReplayBuffer draws it (same samples for the same seed)
        env_inds = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        return DictReplayBufferSamples(*self._samples_at(batch_inds, env_inds, env))

    def _rewards_at(self, batch_inds: np.ndarray, env_inds: np.ndarray, env: VecNormalize | None) -> np.ndarray:
        """The rewards of the given transitions (normalised), with the count bonus."""
        rewards = self._normalize_reward(self.rewards[batch_inds, env_inds], env)
        if self.next_visits is None:
            return rewards
        return rewards + (self.count_bonus / np.sqrt(self.visits(batch_inds, env_inds))).astype(np.float32)

    def _samples_at(self, batch_inds: np.ndarray, env_inds: np.ndarray, env: VecNormalize | None) -> tuple:
        if self.n_steps > 1:
            last_inds, rewards, discounts = self._n_step_windows(batch_inds, env_inds, env)
        else:
            last_inds, rewards, discounts = batch_inds, self._rewards_at(batch_inds, env_inds, env), None
        observations = self._normalize_obs({k: o[batch_inds, env_inds] for k, o in self.observations.items()}, env)
        next_observations = self._normalize_obs(
            {k: o[last_inds, env_inds] for k, o in self.next_observations.items()}, env
        )
        dones = self.dones[last_inds, env_inds] * (1 - self.timeouts[last_inds, env_inds])
        return (
            {k: self.to_torch(o) for k, o in observations.items()},  # type: ignore[union-attr]
            self.to_torch(self.actions[batch_inds, env_inds]),
            {k: self.to_torch(o) for k, o in next_observations.items()},  # type: ignore[union-attr]
            self.to_torch(dones).reshape(-1, 1),
            self.to_torch(rewards.reshape(-1, 1)),
            None if discounts is None else self.to_torch(discounts),
        )

    def _n_step_windows(
        self, batch_inds: np.ndarray, env_inds: np.ndarray, env: VecNormalize | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """
        The n-step windows from the given transitions, as SB3's ``NStepReplayBuffer`` forms them: up to ``n_steps``
        steps, the last one the first that ends (termination or time limit) or the newest transition stored.

        :return: the position of each window's last step, the discounted sum of its rewards, and the discount of the
            bootstrap (``gamma ** steps``, shape ``(batch, 1)``)
        """
        steps = np.arange(self.n_steps)
        indices = (batch_inds[:, None] + steps[None, :]) % self.buffer_size  # (batch, n_steps)
        envs = env_inds[:, None]
        dones = self.dones[indices, envs].astype(bool)
        # The newest transition ends a window unless it ended its episode: the slot after it is another episode's
        # (SB3 marks it as truncated for the duration of the sample; here without writing to the buffer)
        newest = indices == (self.pos - 1) % self.buffer_size
        ends = dones | self.timeouts[indices, envs].astype(bool) | (newest & ~dones)
        last = np.where(ends.any(axis=1), ends.argmax(axis=1), self.n_steps - 1)
        within = steps[None, :] <= last[:, None]
        rewards = self._rewards_at(indices.reshape(-1), np.repeat(env_inds, self.n_steps), env)
        rewards = rewards.reshape(indices.shape) * self.gamma ** steps.astype(np.float32) * within
        discounts = (self.gamma ** within.sum(axis=1, keepdims=True)).astype(np.float32)
        return (batch_inds + last) % self.buffer_size, rewards.sum(axis=1).astype(np.float32), discounts
