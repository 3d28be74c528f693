"""A count bonus for DCQN's replay buffers: exploration towards rarely seen observations.

In the style of count-based bonuses (Strehl & Littman 2008; Bellemare et al. 2016): sampled rewards get
``count_bonus / sqrt(n(o'))``, ``n(o')`` the number of times the transition's next observation (all keys) has been
added to the buffer so far. The counts are of visits: they grow with every addition and are not decremented when
slots are overwritten, so the bonus of a view shrinks as the agent keeps arriving there and stays large where it has
rarely been. Cost: a digest per added transition, one ``int32`` per transition and a count per distinct observation.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecNormalize

from sb3_dcqn.replay.base import observation_bytes
from sb3_dcqn.replay.revision import digest

__all__ = ["CountBonusReplay"]


class CountBonusReplay:
    """
    A count bonus (see the module docstring) over DCQN's ``DCQNReplayBuffer`` or ``DCQNDictReplayBuffer``.

    :param count_bonus: Scale of the intrinsic reward ``count_bonus / sqrt(n(next observation))`` (> 0)
    """

    buffer_size: int
    n_envs: int
    pos: int
    observations: Any

    def __init__(self, *args: Any, count_bonus: float | None = None, **kwargs: Any) -> None:
        if count_bonus is None or not count_bonus > 0:
            raise ValueError(
                f"a count-bonus replay buffer needs replay_buffer_kwargs=dict(count_bonus=...) > 0, got {count_bonus!r}"
            )
        super().__init__(*args, **kwargs)
        self.count_bonus = float(count_bonus)
        # Each slot's next observation as a visit id; visits per distinct observation (never decremented)
        self.next_visits = np.zeros((self.buffer_size, self.n_envs), dtype=np.int32)
        self.visit_counts = np.zeros(16, dtype=np.int64)
        self._visit_of: dict[bytes, int] = {}

    def add(
        self, obs: Any, next_obs: Any, action: np.ndarray, reward: np.ndarray, done: np.ndarray, infos: Any
    ) -> None:
        # Before the rest of add: a revision of older slots copies the new slot's visit id
        self.next_visits[self.pos] = [self._visit(next_obs, env) for env in range(self.n_envs)]
        super().add(obs, next_obs, action, reward, done, infos)  # type: ignore[misc]

    def _visit(self, next_obs: Any, env: int) -> int:
        """Count one arrival at ``next_obs[env]``; its visit id."""
        visit = self._visit_of.setdefault(
            digest(observation_bytes(next_obs, env, self.observations)), len(self._visit_of)
        )
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
        return self.visit_counts[self.next_visits[batch_inds, env_inds]]

    def _rewards_at(self, batch_inds: np.ndarray, env_inds: np.ndarray, env: VecNormalize | None) -> np.ndarray:
        rewards = super()._rewards_at(batch_inds, env_inds, env)  # type: ignore[misc]
        return rewards + (self.count_bonus / np.sqrt(self.visits(batch_inds, env_inds))).astype(np.float32)

    def _copy_outcome(self, slots: np.ndarray, pos: int, env: int) -> None:
        super()._copy_outcome(slots, pos, env)  # type: ignore[misc]
        rows, envs = np.divmod(slots, self.n_envs)
        self.next_visits[rows, envs] = self.next_visits[pos, env]
