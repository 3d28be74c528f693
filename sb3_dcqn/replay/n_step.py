"""n-step returns for DCQN's replay buffers, as SB3's ``NStepReplayBuffer`` computes them (which takes no Dict).

A sampled transition carries the discounted sum of up to ``n_steps`` rewards, cut at the first termination or time
limit (and at the newest transition stored), the next observation and done of the window's last step, and
``discounts`` (``gamma ** k`` for a window of ``k`` steps) for the algorithm's target.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecNormalize

__all__ = ["NStepReplay"]


class NStepReplay:
    """
    n-step returns (see the module docstring) over DCQN's ``DCQNReplayBuffer`` or ``DCQNDictReplayBuffer``.

    :param n_steps: Steps of the returns (>= 1; 1: one-step transitions)
    :param gamma: Discount of the returns (the algorithm's; DCQN passes its own when not given)
    """

    buffer_size: int
    pos: int
    dones: np.ndarray
    timeouts: np.ndarray

    def __init__(self, *args: Any, n_steps: int = 3, gamma: float = 0.99, **kwargs: Any) -> None:
        if int(n_steps) != n_steps or n_steps < 1:
            raise ValueError(f"n_steps must be an integer >= 1, got {n_steps!r}")
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"gamma must be in [0, 1], got {gamma!r}")
        super().__init__(*args, **kwargs)
        self.n_steps = int(n_steps)
        self.gamma = float(gamma)

    def _returns(
        self, batch_inds: np.ndarray, env_inds: np.ndarray, env: VecNormalize | None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """
        The n-step windows from the given transitions, as SB3's ``NStepReplayBuffer`` forms them: up to ``n_steps``
        steps, the last one the first that ends (termination or time limit) or the newest transition stored.

        :return: the position of each window's last step, the discounted sum of its rewards, and the discount of the
            bootstrap (``gamma ** steps``, shape ``(batch, 1)``)
        """
        if self.n_steps == 1:
            return super()._returns(batch_inds, env_inds, env)  # type: ignore[misc]
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
        rewards = self._rewards_at(indices.reshape(-1), np.repeat(env_inds, self.n_steps), env)  # type: ignore
        rewards = rewards.reshape(indices.shape) * self.gamma ** steps.astype(np.float32) * within
        discounts = (self.gamma ** within.sum(axis=1, keepdims=True)).astype(np.float32)
        return (batch_inds + last) % self.buffer_size, rewards.sum(axis=1).astype(np.float32), discounts
