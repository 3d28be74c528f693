"""The adaptation boost: more exploration and more gradient steps for a while after the world seems to change."""

from __future__ import annotations

from pathlib import Path

import pytest
from stable_baselines3 import DQN
from stable_baselines3.common.utils import LinearSchedule

from sb3_dcqn import DCQN
from sb3_dcqn.adaptation_boost import AdaptationBoost
from sb3_dcqn.replay import RevisionReplayBuffer

SMALL = dict(learning_starts=0, exploration_fraction=0.01, seed=0, policy_kwargs=dict(net_arch=[16]))


class RevisionNow(AdaptationBoost):
    """A boost whose buffer reports one revision at a given step (as if a closure had just been seen)."""

    def __init__(self, at_step: int, **kwargs) -> None:
        super().__init__(trigger="revision", **kwargs)
        self.at_step = at_step

    def _on_step(self) -> bool:
        if self.num_timesteps == self.at_step:
            self.model.replay_buffer.revised += 1
        return super()._on_step()


def test_a_revision_boosts_exploration_and_the_replay_ratio_for_a_while() -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", replay_buffer_class=RevisionReplayBuffer, **SMALL)
    model.learn(200)
    assert model.exploration_rate == pytest.approx(0.05)
    boost = RevisionNow(at_step=210, exploration=0.5, replay_ratio=3, steps=100)
    updates = model._n_updates
    model.learn(40, reset_num_timesteps=False, callback=boost)
    # Boosted from step 210 on: epsilon at the floor, three gradient steps per training call (train_freq 4)
    assert boost.boosts == 1 and boost.boosted and model.exploration_rate == 0.5
    assert model._n_updates - updates == 10 // 4 + 3 * (30 // 4 + 1)
    # After learn() the model is as it was: its own schedule and replay ratio
    assert isinstance(model.exploration_schedule, LinearSchedule) and model.gradient_steps == 1


def test_the_boost_ends_after_its_steps() -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", replay_buffer_class=RevisionReplayBuffer, **SMALL)
    model.learn(200)
    boost = RevisionNow(at_step=210, exploration=0.5, steps=20)
    model.learn(60, reset_num_timesteps=False, callback=boost)
    assert not boost.boosted and model.exploration_rate == pytest.approx(0.05)


def test_the_boost_works_with_sb3_dqn_and_a_model_saved_mid_boost_loads(tmp_path: Path) -> None:
    model = DQN("MlpPolicy", "CartPole-v1", **SMALL)
    saved = tmp_path / "mid_boost"

    class SaveWhileBoosted(AdaptationBoost):
        def _on_step(self) -> bool:
            running = super()._on_step()
            if self.boosted and not saved.with_suffix(".zip").exists():
                self.model.save(saved)  # as a CheckpointCallback would, with the boosted schedule in place
            return running

    boost = SaveWhileBoosted(trigger="td_error", factor=1e-9, exploration=0.4)  # any loss above ~0 fires
    model.learn(300, callback=boost)
    assert boost.boosts > 0 and saved.with_suffix(".zip").exists()
    loaded = DQN.load(saved)
    # A loaded model builds its own schedule again (SB3's _setup_model): no boost carried over
    assert isinstance(loaded.exploration_schedule, LinearSchedule)


def test_bad_settings_are_refused_naming_the_value() -> None:
    with pytest.raises(ValueError, match="trigger must be one of"):
        AdaptationBoost(trigger="moon")
    with pytest.raises(ValueError, match="replay_ratio >= 1"):
        AdaptationBoost(trigger="td_error", replay_ratio=0)
    model = DCQN("MlpPolicy", "CartPole-v1", **SMALL)
    with pytest.raises(ValueError, match="needs a replay buffer with experience revision"):
        model.learn(10, callback=AdaptationBoost(trigger="revision"))
