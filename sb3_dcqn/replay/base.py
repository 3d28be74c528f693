"""DCQN's two replay-buffer bases: SB3's ``ReplayBuffer`` and ``DictReplayBuffer`` with the hooks the variants use.

On their own, :class:`DCQNReplayBuffer` and :class:`DCQNDictReplayBuffer` store and sample exactly as SB3's buffers do
(the same samples for the same seed). The variants of :mod:`sb3_dcqn.replay` are mix-ins over them, each overriding
one hook:

- ``_returns``: what a sampled transition bootstraps from (the n-step window's last step, its rewards, its discount);
- ``_rewards_at``: the rewards of stored transitions (plus a count bonus);
- ``_transition_bytes`` / ``_outcome_bytes`` / ``_copy_outcome`` (with ``_goal_bytes`` / ``_holds_for_every_goal``
  and the ``goal_keys`` they leave out): what "the same observation and action" and "the same outcome" mean, and how a
  stored transition gets a new outcome (experience revision);
- ``sample``: which slots are drawn (prioritized replay);
- ``loss_weights`` / ``after_gradient_step`` (:class:`~sb3_dcqn.replay.feedback.TrainingFeedback`): what the
  training step tells the buffer after each gradient step (prioritized replay's TD errors, revision's count).

Next observations are always stored (no ``optimize_memory_usage``): the variants revise, window or share them.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer, ReplayBuffer
from stable_baselines3.common.type_aliases import DictReplayBufferSamples, ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from sb3_dcqn.replay.feedback import TrainingFeedback

__all__ = ["DCQNDictReplayBuffer", "DCQNReplayBuffer", "TransitionHooks", "observation_bytes"]


def observation_bytes(observation: Any, env: int, storage: Any, keys: list[str] | None = None) -> bytes:
    """
    The bytes of one env's observation as the buffer stores it (its dtype), Dict keys in sorted order.

    :param observation: A batch of observations, one per env (an array, or a dict of arrays)
    :param env: The env
    :param storage: The buffer's ``observations`` (its dtypes; a dict for Dict observations)
    :param keys: The Dict keys to include (default: all)
    """
    if isinstance(storage, dict):
        keys = sorted(storage) if keys is None else keys
        return b"".join(
            np.ascontiguousarray(np.asarray(observation[key])[env], dtype=storage[key].dtype).tobytes() for key in keys
        )
    return np.ascontiguousarray(np.asarray(observation)[env], dtype=storage.dtype).tobytes()


class TransitionHooks(TrainingFeedback):
    """The hooks of DCQN's replay buffers, over SB3's ``ReplayBuffer`` or ``DictReplayBuffer`` (next in the MRO)."""

    buffer_size: int
    n_envs: int
    pos: int
    full: bool
    observations: Any
    next_observations: Any
    actions: np.ndarray
    rewards: np.ndarray
    dones: np.ndarray
    timeouts: np.ndarray
    device: th.device

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
    ) -> None:
        if optimize_memory_usage:
            raise ValueError(
                f"{type(self).__name__} stores next observations (its variants revise, window or share them): "
                "optimize_memory_usage=True is not supported"
            )
        super().__init__(  # type: ignore[call-arg]
            buffer_size,
            observation_space,
            action_space,
            device,
            n_envs=n_envs,
            optimize_memory_usage=False,
            handle_timeout_termination=handle_timeout_termination,
        )

    # ------------------------------------------------------------------ sampling
    def _get_samples(self, batch_inds: np.ndarray, env: VecNormalize | None = None) -> Any:  # type: ignore[override]
        # The env of each sample drawn as SB3's buffers draw it (same samples for the same seed)
        env_inds = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        return self._samples_at(batch_inds, env_inds, env)

    def _samples_at(
        self, batch_inds: np.ndarray, env_inds: np.ndarray, env: VecNormalize | None
    ) -> ReplayBufferSamples | DictReplayBufferSamples:
        """The samples of the stored transitions ``(batch_inds, env_inds)``, as SB3's ``_get_samples`` forms them."""
        last_inds, rewards, discounts = self._returns(batch_inds, env_inds, env)
        dones = self.dones[last_inds, env_inds] * (1 - self.timeouts[last_inds, env_inds])
        observations = self._normalize_obs(_gather(self.observations, batch_inds, env_inds), env)  # type: ignore
        next_observations = self._normalize_obs(_gather(self.next_observations, last_inds, env_inds), env)  # type: ignore
        samples_type = DictReplayBufferSamples if isinstance(observations, dict) else ReplayBufferSamples
        return samples_type(
            _to_torch(self, observations),  # type: ignore[arg-type]
            self.to_torch(self.actions[batch_inds, env_inds]),  # type: ignore[attr-defined]
            _to_torch(self, next_observations),  # type: ignore[arg-type]
            self.to_torch(dones.reshape(-1, 1)),  # type: ignore[attr-defined]
            self.to_torch(rewards.reshape(-1, 1)),  # type: ignore[attr-defined]
            None if discounts is None else self.to_torch(discounts),  # type: ignore[attr-defined]
        )

    def _returns(
        self, batch_inds: np.ndarray, env_inds: np.ndarray, env: VecNormalize | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """
        What the sampled transitions bootstrap from: one step.

        :return: the positions of their next observations and dones, their rewards, and the bootstrap's discount
            (``None``: the algorithm's ``gamma``)
        """
        return batch_inds, self._rewards_at(batch_inds, env_inds, env), None

    def _rewards_at(self, batch_inds: np.ndarray, env_inds: np.ndarray, env: VecNormalize | None) -> np.ndarray:
        """The (normalized) rewards of the given stored transitions."""
        return self._normalize_reward(self.rewards[batch_inds, env_inds], env)  # type: ignore[attr-defined]

    # ------------------------------------------------------------------ what a transition is (experience revision)
    # Observation keys that name the goal (``RevisionReplay(goal_keys=...)``, Dict observations): left out of "the same
    # observation" and of "the same outcome", kept in a stored transition that gets a new outcome
    goal_keys: tuple[str, ...] = ()

    def _place_keys(self) -> list[str] | None:
        """The Dict keys that say where the agent is: every key but the goal keys (``None``: every key)."""
        if not self.goal_keys:
            return None
        return sorted(key for key in self.observations if key not in self.goal_keys)

    def _transition_bytes(self, obs: Any, action: np.ndarray, env: int) -> bytes:
        """The bytes that make two transitions "the same observation and action" (the goal keys left out)."""
        return observation_bytes(obs, env, self.observations, self._place_keys()) + np.asarray(action)[env].tobytes()

    def _outcome_bytes(self, pos: int, env: int, arrival: bytes | None = None) -> bytes:
        """
        The world's answer to the transition at ``(pos, env)``: reward, real termination, where the agent ended.

        With goal keys, where the agent ended alone (every key but the goal keys): the reward and termination of a
        move are its goal's own (the goal reached or not), not the road's. Whether the agent stayed needs no byte of
        its own: the observation is in the key, so among one key's transitions a stay has one outcome digest.

        :param arrival: Where the agent ended, as a route memory names the place (``None``: the next observation)
        """
        place = self._place_keys()
        if arrival is None:
            if isinstance(self.next_observations, dict):
                keys = sorted(self.next_observations) if place is None else place
                arrival = b"".join(self.next_observations[k][pos, env].tobytes() for k in keys)
            else:
                arrival = self.next_observations[pos, env].tobytes()
        if place is not None:
            return arrival
        terminated = self.dones[pos, env] * (1 - self.timeouts[pos, env])
        return np.array([self.rewards[pos, env], terminated], dtype=np.float32).tobytes() + arrival

    def _goal_bytes(self, obs: Any, env: int) -> bytes:
        """The bytes of the goal a transition was collected for (its goal keys; empty without goal keys)."""
        if not self.goal_keys:
            return b""
        return observation_bytes(obs, env, self.observations, sorted(self.goal_keys))

    def _holds_for_every_goal(self, pos: int, env: int, stayed: bool | None = None) -> bool:
        """
        Whether the outcome of ``(pos, env)`` is the same whatever the goal: the agent stayed where it was (every key
        but the goal keys unchanged: a collision) and the episode did not end for real (an ending is the goal's).
        Without goal keys, every key is part of the observation: ``True`` (there is no other goal to tell apart).

        :param stayed: Whether the agent stayed, as a route memory knows it (``None``: the keys unchanged)
        """
        place = self._place_keys()
        if place is None:
            return True
        if self.dones[pos, env] * (1 - self.timeouts[pos, env]):
            return False
        if stayed is not None:
            return stayed
        return all(np.array_equal(self.next_observations[k][pos, env], self.observations[k][pos, env]) for k in place)

    def _copy_outcome(self, slots: np.ndarray, pos: int, env: int) -> None:
        """
        Give the stored transitions in ``slots`` (``pos * n_envs + env`` each) the outcome of ``(pos, env)``: its next
        observation (the goal keys of each slot's own kept), reward and dones.
        """
        rows, envs = np.divmod(slots, self.n_envs)
        if isinstance(self.next_observations, dict):
            storages = [self.next_observations[k] for k in self._place_keys() or self.next_observations]
        else:
            storages = [self.next_observations]
        for storage in storages:
            for row, row_env in zip(rows, envs, strict=True):
                storage[row, row_env] = storage[pos, env]
        for array in (self.rewards, self.dones, self.timeouts):
            array[rows, envs] = array[pos, env]

    def _stay_in_place(self, slots: np.ndarray) -> None:
        """The stored transitions in ``slots`` end where they started: their next observation is their own
        observation (the goal keys kept), as a bump's is."""
        rows, envs = np.divmod(slots, self.n_envs)
        if isinstance(self.next_observations, dict):
            for key in self._place_keys() or self.next_observations:
                self.next_observations[key][rows, envs] = self.observations[key][rows, envs]
        else:
            self.next_observations[rows, envs] = self.observations[rows, envs]


def _gather(storage: Any, batch_inds: np.ndarray, env_inds: np.ndarray) -> Any:
    if isinstance(storage, dict):
        return {key: array[batch_inds, env_inds] for key, array in storage.items()}
    return storage[batch_inds, env_inds, :]


def _to_torch(buffer: Any, observations: Any) -> Any:
    if isinstance(observations, dict):
        return {key: buffer.to_torch(value) for key, value in observations.items()}
    return buffer.to_torch(observations)


class DCQNReplayBuffer(TransitionHooks, ReplayBuffer):
    """
    SB3's ``ReplayBuffer`` (Box observations) with the hooks of DCQN's replay variants; alone, it samples as SB3's.

    :param buffer_size: Max number of elements in the buffer
    :param observation_space: Observation space
    :param action_space: Action space
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Not supported (must be False)
    :param handle_timeout_termination: Handle timeout termination (due to a time limit) separately
    """


class DCQNDictReplayBuffer(TransitionHooks, DictReplayBuffer):
    """
    SB3's ``DictReplayBuffer`` with the hooks of DCQN's replay variants; alone, it samples as SB3's.

    :param buffer_size: Max number of elements in the buffer
    :param observation_space: Observation space (a Dict)
    :param action_space: Action space
    :param device: PyTorch device
    :param n_envs: Number of parallel environments
    :param optimize_memory_usage: Not supported (must be False)
    :param handle_timeout_termination: Handle timeout termination (due to a time limit) separately
    """

    observations: dict[str, np.ndarray]
    next_observations: dict[str, np.ndarray]
