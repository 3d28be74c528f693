"""Prioritized replay (Schaul et al. 2016, proportional variant) for DCQN's replay buffers.

Transitions are sampled with probability ``p_i ** alpha / sum_k p_k ** alpha``, ``p_i`` the last absolute TD error
(plus ``priority_eps``), new and revised transitions at the highest priority so far, so that what just surprised the
agent is replayed at once. The samples carry importance weights ``(N * P(i)) ** -beta / max_j (N * P(j)) ** -beta``
and their indices. The training step weights each sample's loss with them (:meth:`PrioritizedReplay.loss_weights`)
and, after each gradient step, hands back the batch's new TD errors and how far training has come
(:meth:`PrioritizedReplay.after_gradient_step`, :mod:`sb3_dcqn.replay.feedback`): they become the batch's priorities
(:meth:`PrioritizedReplay.update_priorities`) and ``beta`` moves from its initial value towards 1
(:meth:`PrioritizedReplay.anneal_beta`).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np
import torch as th
from stable_baselines3.common.type_aliases import TensorDict
from stable_baselines3.common.vec_env import VecNormalize

__all__ = ["PrioritizedDictReplayBufferSamples", "PrioritizedReplay", "PrioritizedReplayBufferSamples"]


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


class PrioritizedReplay:
    """
    Prioritized replay (see the module docstring) over DCQN's ``DCQNReplayBuffer`` or ``DCQNDictReplayBuffer``.

    :param alpha: Priority exponent (0: uniform)
    :param beta: Initial importance-weight exponent (1: full correction); annealed to 1 by the algorithm
    :param priority_eps: Added to the absolute TD error so that no transition gets probability 0
    """

    buffer_size: int
    n_envs: int
    pos: int
    full: bool

    def __init__(
        self, *args: Any, alpha: float = 0.6, beta: float = 0.4, priority_eps: float = 1e-3, **kwargs: Any
    ) -> None:
        for name, value in (("alpha", alpha), ("beta", beta)):
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"prioritized replay: {name} must be in [0, 1], got {value!r}")
        if not priority_eps > 0:
            raise ValueError(f"prioritized replay: priority_eps must be > 0, got {priority_eps!r}")
        super().__init__(*args, **kwargs)
        self.alpha = alpha
        self.initial_beta = beta
        self.beta = beta
        self.priority_eps = priority_eps
        self.priorities = np.zeros((self.buffer_size, self.n_envs), dtype=np.float64)
        self._max_priority = 1.0

    def add(
        self, obs: Any, next_obs: Any, action: np.ndarray, reward: np.ndarray, done: np.ndarray, infos: Any
    ) -> None:
        pos = self.pos
        super().add(obs, next_obs, action, reward, done, infos)  # type: ignore[misc]
        self.priorities[pos] = self._max_priority

    def _copy_outcome(self, slots: np.ndarray, pos: int, env: int) -> None:
        super()._copy_outcome(slots, pos, env)  # type: ignore[misc]
        rows, envs = np.divmod(slots, self.n_envs)
        self.priorities[rows, envs] = self._max_priority  # what contradicted the agent is replayed first

    def sample(self, batch_size: int, env: VecNormalize | None = None) -> Any:
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
        samples = self._samples_at(batch_inds, env_inds, env)  # type: ignore[attr-defined]
        weights_tensor = self.to_torch(weights.astype(np.float32).reshape(-1, 1))  # type: ignore[attr-defined]
        samples_type = (
            PrioritizedDictReplayBufferSamples
            if isinstance(samples.observations, dict)
            else PrioritizedReplayBufferSamples
        )
        return samples_type(*samples, weights_tensor, picks)

    def loss_weights(self, samples: Any) -> th.Tensor | None:
        """The batch's importance weights: each sample's loss is weighted by them."""
        return samples.weights

    def after_gradient_step(self, samples: Any, td_errors: th.Tensor, progress: float) -> dict[str, float]:
        """The batch's new TD errors become its priorities; the importance correction anneals with ``progress``."""
        self.update_priorities(samples.indices, td_errors.cpu().numpy())
        self.anneal_beta(progress)
        return super().after_gradient_step(samples, td_errors, progress)  # type: ignore[misc]

    def update_priorities(self, indices: np.ndarray, td_errors: np.ndarray) -> None:
        """
        Set the priorities of sampled transitions from their new absolute TD errors.

        :param indices: The ``indices`` of the samples
        :param td_errors: Their TD errors (any sign), same length
        """
        priorities = np.abs(np.asarray(td_errors, dtype=np.float64).reshape(-1)) + self.priority_eps
        self.priorities.reshape(-1)[np.asarray(indices)] = priorities
        self._max_priority = max(self._max_priority, float(priorities.max()))

    def anneal_beta(self, progress: float) -> None:
        """
        Move the importance correction from its initial ``beta`` towards full (1) as training progresses.

        :param progress: The share of training done, from 0 to 1
        """
        self.beta = self.initial_beta + (1.0 - self.initial_beta) * float(progress)
