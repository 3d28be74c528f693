"""Embedding-fusion features extractor (Zhu et al., "Target-driven visual navigation", 2017).

The current views and the goal views go through one shared (siamese) linear layer into the same embedding space; the
two embeddings (plus any other observation keys, such as the heading) are concatenated and a fusion layer forms the
joint state representation that the critics read.

It reads CampusNav's keys (``"views"``, ``"goal_views"``) or SB3's goal-env convention (``"observation"``,
``"desired_goal"``; the ``"achieved_goal"`` is left out there: it pictures the current place, which the current views
already show, and it is what hindsight relabelling compares, not a policy input).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from torch import nn


class EmbeddingFusionExtractor(BaseFeaturesExtractor):
    """
    Siamese embedding of current and goal views, then a fusion layer.

    :param observation_space: A Dict space holding ``current_key`` and ``goal_key`` (same shape, e.g. ``(4, D)``
        features of the four views) and optionally other Box entries, which are flattened into the fusion input.
    :param embed_dim: Size of the shared embedding of each of current and goal views
    :param features_dim: Size of the fused state (output)
    :param current_key: Observation key of the current views (default: ``"views"``, or ``"observation"`` in a goal env)
    :param goal_key: Observation key of the goal views (default: ``"goal_views"``, or ``"desired_goal"``)
    :param ignored_keys: Observation keys left out of the fusion (default: ``"achieved_goal"`` in a goal env)
    :param goal_view_dropout: In training, hide each of the goal's ``n_views`` views (zero it) with this probability,
        keeping at least one: the critics learn goals from partial pictures (an augmentation for goals never
        trained on). Evaluation and target critics see every view
    :param n_views: Number of equal blocks (views) the goal vector is made of (CampusNav: four compass views)
    :param activation_fn: Activation after the embedding and the fusion layers
    """

    def __init__(
        self,
        observation_space: gym.spaces.Dict,
        embed_dim: int = 512,
        features_dim: int = 512,
        current_key: str | None = None,
        goal_key: str | None = None,
        activation_fn: type[nn.Module] = nn.ReLU,
        ignored_keys: tuple[str, ...] | None = None,
        goal_view_dropout: float = 0.0,
        n_views: int = 4,
    ) -> None:
        if not isinstance(observation_space, spaces.Dict):
            raise TypeError(f"EmbeddingFusionExtractor needs a Dict observation space, got {observation_space}")
        goal_env = "views" not in observation_space.spaces and "desired_goal" in observation_space.spaces
        current_key = current_key or ("observation" if goal_env else "views")
        goal_key = goal_key or ("desired_goal" if goal_env else "goal_views")
        ignored = set(("achieved_goal",) if goal_env and ignored_keys is None else (ignored_keys or ()))
        for key in (current_key, goal_key):
            if key not in observation_space.spaces:
                raise KeyError(
                    f"EmbeddingFusionExtractor: observation key {key!r} not in the observation space "
                    f"(keys: {sorted(observation_space.spaces)})"
                )
        current_space, goal_space = observation_space[current_key], observation_space[goal_key]
        if current_space.shape != goal_space.shape:
            raise ValueError(
                f"EmbeddingFusionExtractor: {current_key!r} {current_space.shape} and {goal_key!r} {goal_space.shape} "
                "must have the same shape to share the siamese embedding"
            )
        if not 0.0 <= goal_view_dropout < 1.0:
            raise ValueError(f"EmbeddingFusionExtractor: goal_view_dropout must be in [0, 1), got {goal_view_dropout}")
        if goal_view_dropout and int(np.prod(goal_space.shape)) % n_views:
            raise ValueError(f"EmbeddingFusionExtractor: {goal_key!r} {goal_space.shape} is not {n_views} equal views")
        super().__init__(observation_space, features_dim)
        self.goal_view_dropout = goal_view_dropout
        self.n_views = n_views
        self.current_key = current_key
        self.goal_key = goal_key
        self.extra_keys = sorted(k for k in observation_space.spaces if k not in {current_key, goal_key, *ignored})
        view_dim = int(np.prod(current_space.shape))
        extra_dim = sum(int(np.prod(observation_space[k].shape)) for k in self.extra_keys)
        self.embedding = nn.Sequential(nn.Flatten(), nn.Linear(view_dim, embed_dim), activation_fn())
        self.fusion = nn.Sequential(nn.Linear(2 * embed_dim + extra_dim, features_dim), activation_fn())

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        batch = observations[self.current_key].shape[0]
        goal = observations[self.goal_key].float()
        if self.training and self.goal_view_dropout > 0:
            goal = self._hide_goal_views(goal)
        # One pass of the shared layer over current and goal views stacked along the batch
        both = th.cat([observations[self.current_key].float(), goal])
        embedded = self.embedding(both)
        parts = [embedded[:batch], embedded[batch:]]
        parts += [observations[k].float().reshape(batch, -1) for k in self.extra_keys]
        return self.fusion(th.cat(parts, dim=1))

    def _hide_goal_views(self, goal: th.Tensor) -> th.Tensor:
        """Zero each goal view with probability ``goal_view_dropout``, never all of one goal's views."""
        batch = goal.shape[0]
        hidden = th.rand(batch, self.n_views, device=goal.device) < self.goal_view_dropout
        all_hidden = hidden.all(dim=1)
        keep = th.randint(self.n_views, (batch,), device=goal.device)
        hidden[all_hidden, keep[all_hidden]] = False
        views = goal.reshape(batch, self.n_views, -1) * (~hidden).unsqueeze(-1)
        return views.reshape(goal.shape)
