"""The peer-env benchmark's exact FrozenLake success: the greedy policy's chance of the goal, from the env's model."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from benchmarks.peer_envs import exact_success


class Policy:
    """A model stand-in: the given action at every state (``predict``'s batch of every state)."""

    def __init__(self, actions: np.ndarray) -> None:
        self.actions = np.asarray(actions)

    def predict(self, observation: np.ndarray, deterministic: bool = False) -> tuple[np.ndarray, Any]:
        return self.actions[np.asarray(observation)], None


def test_the_exact_success_is_one_on_ice_for_a_path_and_none_for_standing_still() -> None:
    env = gym.make("FrozenLake-v1", is_slippery=False)  # SFFF / FHFH / FFFH / HFFG
    left, down, right = 0, 1, 2
    path = np.full(16, left)
    path[[0, 4, 8, 9, 13, 14]] = [down, down, right, down, right, right]  # 0, 4, 8, 9, 13, 14, the goal
    assert exact_success(Policy(path), env) == pytest.approx(1.0)
    assert exact_success(Policy(np.full(16, left)), env) == 0.0  # left at the start: against the wall for ever


def test_the_exact_success_on_slippery_ice_is_the_chance_episodes_estimate() -> None:
    env = gym.make("FrozenLake-v1", is_slippery=True)
    policy = Policy(np.array([0, 3, 3, 3, 0, 0, 0, 0, 3, 1, 0, 0, 0, 2, 1, 0]))  # the 4x4 lake's optimal policy
    chance = exact_success(policy, env)
    wins = 0.0
    for episode in range(2_000):
        observation, _ = env.reset(seed=episode)
        done = False
        while not done:
            observation, reward, terminated, truncated, _ = env.step(int(policy.actions[observation]))
            wins, done = wins + reward, terminated or truncated
    assert 0.5 < chance < 1.0 and abs(wins / 2_000 - chance) < 0.04
