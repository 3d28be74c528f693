"""Critics for heading-relative actions (``heading_key``): score absolute directions, rotate into the action frame."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces

from sb3_dcqn import DCQN
from sb3_dcqn.fusion import EmbeddingFusionExtractor


class HeadingEnv(gym.Env):
    """A stand-in with CampusNav's observation layout: views, goal views and a one-hot heading; 4 relative actions."""

    observation_space = spaces.Dict(
        {
            "views": spaces.Box(-3.0, 3.0, shape=(8,), dtype=np.float32),
            "goal_views": spaces.Box(-3.0, 3.0, shape=(8,), dtype=np.float32),
            "heading": spaces.Box(0.0, 1.0, shape=(4,), dtype=np.float32),
        }
    )
    action_space = spaces.Discrete(4)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        return self.observation_space.sample(), {}

    def step(self, action: int):
        return self.observation_space.sample(), 0.0, False, True, {}


def observations(heading: np.ndarray, seed: int = 0) -> dict[str, th.Tensor]:
    """The same views seen at the given headings."""
    rng = np.random.default_rng(seed)
    views, goal = rng.normal(size=8).astype(np.float32), rng.normal(size=8).astype(np.float32)
    n = len(heading)
    return {
        "views": th.as_tensor(np.tile(views, (n, 1))),
        "goal_views": th.as_tensor(np.tile(goal, (n, 1))),
        "heading": th.as_tensor(np.eye(4, dtype=np.float32)[heading]),
    }


@pytest.mark.parametrize("extractor", ["combined", "fusion"])
def test_an_action_scores_what_its_direction_scores_at_every_heading(extractor: str) -> None:
    kwargs = {"heading_key": "heading", "net_arch": [32]}
    if extractor == "fusion":
        kwargs |= {"features_extractor_class": EmbeddingFusionExtractor, "features_extractor_kwargs": {"embed_dim": 16}}
    model = DCQN("MultiInputPolicy", HeadingEnv(), policy_kwargs=kwargs, seed=0)
    headings = np.arange(4)
    with th.no_grad():
        q = model.q_net.critic_values(observations(headings))  # (critics, 4 headings, 4 actions)
    for h in range(4):
        for a in range(4):
            # Action a at heading h goes the same way as action (a + h) at heading 0. The rows are identical inputs in
            # different batch rows, which a CPU's matrix kernels may round differently: compare within float32 noise
            th.testing.assert_close(q[:, h, a], q[:, 0, (h + a) % 4], rtol=1e-5, atol=1e-6)
    # The greedy direction is the same whichever way the agent faces
    actions = model.predict({k: v.numpy() for k, v in observations(headings).items()}, deterministic=True)[0]
    assert len({(h + int(a)) % 4 for h, a in zip(headings, actions, strict=True)}) == 1


def test_without_heading_key_the_heading_is_an_input() -> None:
    model = DCQN("MultiInputPolicy", HeadingEnv(), policy_kwargs={"net_arch": [32]}, seed=0)
    with th.no_grad():
        q = model.q_net.critic_values(observations(np.arange(4)))
    rotated = th.stack([q[:, h, (np.arange(4) - h) % 4] for h in range(4)], dim=1)
    assert not th.allclose(rotated[:, 0], rotated[:, 1])  # no built-in rotation


def test_heading_key_is_saved_and_loaded(tmp_path: Path) -> None:
    model = DCQN("MultiInputPolicy", HeadingEnv(), policy_kwargs={"heading_key": "heading", "net_arch": [8]}, seed=0)
    model.learn(64)
    model.save(tmp_path / "model")
    loaded = DCQN.load(tmp_path / "model")
    assert loaded.policy.heading_key == "heading" and loaded.q_net.heading_key == "heading"
    obs = observations(np.array([0, 3]))
    with th.no_grad():
        th.testing.assert_close(
            loaded.q_net.critic_values(obs), model.q_net.critic_values(obs), rtol=0, atol=0
        )  # the same stored numbers


def test_a_bad_heading_key_is_refused() -> None:
    with pytest.raises(ValueError, match="'compass' is not a key"):
        DCQN("MultiInputPolicy", HeadingEnv(), policy_kwargs={"heading_key": "compass"})
    with pytest.raises(ValueError, match="'views': the heading must be one-hot over the 4 relative actions"):
        DCQN("MultiInputPolicy", HeadingEnv(), policy_kwargs={"heading_key": "views"})
    with pytest.raises(ValueError, match="not a key of the Dict"):
        DCQN("MlpPolicy", "CartPole-v1", policy_kwargs={"heading_key": "heading"})
