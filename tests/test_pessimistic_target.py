"""The ``pessimistic_target`` ablation: with it off, the TD target takes the first target critic instead of the min."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch as th

from sb3_dcqn import DCQN, dcqn_td_target

SMALL = dict(learning_starts=50, buffer_size=1_000, batch_size=16, policy_kwargs=dict(net_arch=[16]))


def _next_q() -> th.Tensor:
    """Two target critics, two rows, three actions: critic 1 is the optimist in row 0, critic 2 in row 1."""
    critic_1 = [[5.0, 1.0, 2.0], [0.0, 3.0, 1.0]]
    critic_2 = [[4.0, 3.0, 0.0], [6.0, 2.0, 7.0]]
    return th.tensor([critic_1, critic_2])


def test_without_the_min_the_target_is_r_plus_gamma_max_of_the_first_critic() -> None:
    rewards, dones = th.tensor([[-0.005], [1.0]]), th.tensor([[0.0], [1.0]])
    target = dcqn_td_target(_next_q(), rewards, dones, 0.95, pessimistic=False)
    # Row 0: max of critic 1 is 5; row 1 is terminal: the reward alone
    assert target[:, 0].tolist() == pytest.approx([-0.005 + 0.95 * 5.0, 1.0])
    target = dcqn_td_target(_next_q(), rewards, th.zeros(2, 1), 0.95, pessimistic=False)
    assert target[1].item() == pytest.approx(1.0 + 0.95 * 3.0)  # critic 2's larger values are ignored


def test_with_the_min_the_target_takes_max_over_actions_of_the_element_wise_min() -> None:
    rewards, dones = th.tensor([[-0.005], [1.0]]), th.zeros(2, 1)
    target = dcqn_td_target(_next_q(), rewards, dones, 0.95)
    # min over critics: row 0 [4, 1, 0] -> 4; row 1 [0, 2, 1] -> 2 (neither critic's own max)
    assert target[:, 0].tolist() == pytest.approx([-0.005 + 0.95 * 4.0, 1.0 + 0.95 * 2.0])
    assert th.equal(target, dcqn_td_target(_next_q(), rewards, dones, 0.95, pessimistic=True))


def test_excluded_actions_apply_to_the_single_critic_target_too() -> None:
    excluded = th.tensor([[True, False, False], [False, False, False]])
    target = dcqn_td_target(_next_q(), th.zeros(2, 1), th.zeros(2, 1), 0.5, excluded, pessimistic=False)
    assert target[:, 0].tolist() == pytest.approx([0.5 * 2.0, 0.5 * 3.0])


def test_train_regresses_both_critics_to_the_first_target_critic() -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", pessimistic_target=False, seed=0, **{**SMALL, "learning_starts": 0})
    model._setup_learn(total_timesteps=1)
    rng = np.random.default_rng(0)
    for _ in range(16):
        obs = rng.normal(size=(1, 4)).astype(np.float32)
        model.replay_buffer.add(obs, obs + 0.1, np.array([0]), np.array([1.0]), np.array([False]), [{}])
    state = np.random.get_state()
    data = model.replay_buffer.sample(16)
    np.random.set_state(state)
    with th.no_grad():
        next_q = model.q_net_target.critic_values(data.next_observations)
        target = data.rewards + model.gamma * next_q[0].max(dim=1).values.reshape(-1, 1)
        taken = model.q_net.critic_values(data.observations).gather(
            2, data.actions.long().unsqueeze(0).expand(2, -1, -1)
        )
    expected = sum(th.nn.functional.smooth_l1_loss(taken[i], target).item() for i in range(2))
    model.train(gradient_steps=1, batch_size=16)
    assert model.logger.name_to_value["train/loss"] == pytest.approx(expected, rel=1e-5)


def test_a_short_learn_runs_without_the_min() -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", pessimistic_target=False, seed=0, **SMALL)
    model.learn(200)
    assert model.num_timesteps == 200
    assert model._n_updates > 0


def test_save_and_load_keep_the_flag(tmp_path: Path) -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", pessimistic_target=False, **SMALL)
    model.save(tmp_path / "single")
    assert DCQN.load(tmp_path / "single").pessimistic_target is False
    DCQN("MlpPolicy", "CartPole-v1", **SMALL).save(tmp_path / "default")
    assert DCQN.load(tmp_path / "default").pessimistic_target is True
