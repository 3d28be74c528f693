"""The embedding-fusion features extractor (Zhu et al.) and its use by DCQN."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_dcqn import DCQN
from sb3_dcqn.fusion import EmbeddingFusionExtractor

SPACE = spaces.Dict(
    {
        "views": spaces.Box(-1, 1, (12,), np.float32),
        "goal_views": spaces.Box(-1, 1, (12,), np.float32),
        "heading": spaces.Box(0, 1, (4,), np.float32),
    }
)


def test_current_and_goal_views_share_one_embedding_layer() -> None:
    extractor = EmbeddingFusionExtractor(SPACE, embed_dim=8, features_dim=6)
    obs = {k: th.as_tensor(np.stack([s.sample() for _ in range(5)])) for k, s in SPACE.items()}
    assert extractor(obs).shape == (5, 6)
    # Swapping current and goal views swaps the two embeddings in the fusion input: the layer is shared
    embed = extractor.embedding
    swapped = {**obs, "views": obs["goal_views"], "goal_views": obs["views"]}
    fused_input = th.cat([embed(obs["views"]), embed(obs["goal_views"]), obs["heading"]], dim=1)
    swapped_input = th.cat([embed(swapped["views"]), embed(swapped["goal_views"]), obs["heading"]], dim=1)
    # The layers applied here, and the extractor's own forward pass: float32 rounding only (default tolerances)
    assert th.allclose(fused_input[:, :8], swapped_input[:, 8:16])
    assert th.allclose(extractor(obs), extractor.fusion(fused_input))
    linear_layers = [m for m in extractor.modules() if isinstance(m, th.nn.Linear)]
    assert len(linear_layers) == 2  # one siamese embedding + one fusion layer


def test_extra_keys_feed_the_fusion_layer() -> None:
    extractor = EmbeddingFusionExtractor(SPACE, embed_dim=8, features_dim=6)
    assert extractor.extra_keys == ["heading"]
    assert extractor.fusion[0].in_features == 2 * 8 + 4


def test_rejects_spaces_it_cannot_fuse() -> None:
    with pytest.raises(KeyError, match="goal_views"):
        EmbeddingFusionExtractor(spaces.Dict({"views": spaces.Box(-1, 1, (3,))}))
    with pytest.raises(ValueError, match="same shape"):
        EmbeddingFusionExtractor(spaces.Dict({"views": spaces.Box(-1, 1, (3,)), "goal_views": spaces.Box(-1, 1, (4,))}))
    with pytest.raises(TypeError, match="Dict"):
        EmbeddingFusionExtractor(spaces.Box(-1, 1, (3,)))


class FusionEnv(gym.Env):
    """Random observations in the fused Dict space, one-step episodes."""

    observation_space = SPACE
    action_space = spaces.Discrete(4)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        return SPACE.sample(), {}

    def step(self, action):
        return SPACE.sample(), 0.0, False, True, {}


def test_dcqn_with_the_fusion_extractor_gives_each_critic_its_own_unless_shared() -> None:
    kwargs = dict(features_extractor_class=EmbeddingFusionExtractor, features_extractor_kwargs=dict(embed_dim=8))
    separate = DCQN("MultiInputPolicy", FusionEnv(), policy_kwargs=kwargs, learning_starts=10, batch_size=4)
    assert len(separate.q_net.extra_features_extractors) == 1
    shared = DCQN(
        "MultiInputPolicy", FusionEnv(), policy_kwargs={**kwargs, "share_features_extractor": True}, batch_size=4
    )
    assert shared.q_net.shares_features_extractor
    separate.learn(40)
    assert separate._n_updates > 0


def test_goal_view_dropout_hides_whole_views_in_training_only() -> None:
    space = spaces.Dict(
        {
            "observation": spaces.Box(-1, 1, (8,)),
            "achieved_goal": spaces.Box(-1, 1, (8,)),
            "desired_goal": spaces.Box(-1, 1, (8,)),
        }
    )
    extractor = EmbeddingFusionExtractor(space, embed_dim=4, features_dim=4, goal_view_dropout=0.5)
    assert extractor.current_key == "observation" and extractor.goal_key == "desired_goal"
    assert extractor.extra_keys == []  # the achieved goal is not a policy input
    goal = th.ones(2_000, 8)
    hidden = extractor._hide_goal_views(goal).reshape(2_000, 4, 2)
    blocks = hidden.sum(dim=2)
    assert set(blocks.unique().tolist()) == {0.0, 2.0}  # a view is hidden whole or kept whole
    assert (blocks > 0).any(dim=1).all()  # never every view of a goal
    assert 0.35 < (blocks == 0).float().mean() < 0.5  # about half, less the views kept so that one stays
    obs = {"observation": th.zeros(3, 8), "achieved_goal": th.zeros(3, 8), "desired_goal": th.ones(3, 8)}
    extractor.eval()
    th.testing.assert_close(extractor(obs), extractor(obs))  # evaluation sees every view: deterministic
