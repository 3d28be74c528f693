"""The blocked-action target: an action that left the observation unchanged is left out of its own target's max."""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from sb3_dcqn import DCQN, dcqn_td_target
from sb3_dcqn.targets import blocked_actions


def test_the_mask_marks_the_taken_action_of_rows_whose_observation_did_not_change() -> None:
    observations = th.tensor([[1.0, 2.0], [1.0, 2.0], [3.0, 4.0]])
    next_observations = th.tensor([[1.0, 2.0], [1.0, 2.5], [3.0, 4.0]])
    actions = th.tensor([[2], [2], [0]])
    mask = blocked_actions(observations, next_observations, actions, n_actions=4)
    expected = th.tensor([[0, 0, 1, 0], [0, 0, 0, 0], [1, 0, 0, 0]], dtype=th.bool)
    assert th.equal(mask, expected)


def test_with_dict_observations_every_key_must_be_unchanged() -> None:
    views = th.tensor([[1.0], [1.0]])
    heading = th.tensor([[1.0, 0.0], [1.0, 0.0]])
    turned = th.tensor([[1.0, 0.0], [0.0, 1.0]])  # row 1: same views, other heading (it moved)
    mask = blocked_actions(
        {"views": views, "heading": heading}, {"views": views, "heading": turned}, th.tensor([[1], [1]]), n_actions=2
    )
    assert mask.tolist() == [[False, True], [False, False]]


def test_the_target_takes_the_best_other_action_for_blocked_rows() -> None:
    next_q = th.tensor([[[5.0, 1.0, 2.0]], [[4.0, 3.0, 0.0]]])  # (critics, batch 1, actions): min -> [4, 1, 0]
    excluded = th.tensor([[True, False, False]])
    target = dcqn_td_target(next_q, th.tensor([[-0.01]]), th.zeros(1, 1), 0.9, excluded)
    # Without the mask the blocked action's own stale value (4) would be bootstrapped; with it, the best other (1)
    assert target.item() == pytest.approx(-0.01 + 0.9 * 1.0)
    assert dcqn_td_target(next_q, th.tensor([[-0.01]]), th.zeros(1, 1), 0.9).item() == pytest.approx(-0.01 + 0.9 * 4)


def test_train_regresses_a_blocked_action_to_the_masked_target() -> None:
    model = DCQN(
        "MlpPolicy",
        "CartPole-v1",
        blocked_action_target=True,
        learning_starts=0,
        buffer_size=100,
        batch_size=8,
        policy_kwargs=dict(net_arch=[16]),
        seed=0,
    )
    model._setup_learn(total_timesteps=1)
    rng = np.random.default_rng(0)
    for i in range(8):  # half the transitions stay where they were (collisions), half move
        obs = rng.normal(size=(1, 4)).astype(np.float32)
        next_obs = obs.copy() if i % 2 == 0 else obs + 1.0
        model.replay_buffer.add(obs, next_obs, np.array([i % 2]), np.array([-0.01]), np.array([False]), [{}])
    state = np.random.get_state()
    data = model.replay_buffer.sample(8)
    np.random.set_state(state)
    with th.no_grad():
        excluded = blocked_actions(data.observations, data.next_observations, data.actions, 2)
        target = dcqn_td_target(
            model.q_net_target.critic_values(data.next_observations), data.rewards, data.dones, model.gamma, excluded
        )
        taken = model.q_net.critic_values(data.observations).gather(
            2, data.actions.long().unsqueeze(0).expand(2, -1, -1)
        )
    assert excluded.any()
    expected = sum(th.nn.functional.smooth_l1_loss(taken[i], target).item() for i in range(2))
    model.train(gradient_steps=1, batch_size=8)
    assert model.logger.name_to_value["train/loss"] == pytest.approx(expected, rel=1e-5)


def test_n_step_returns_are_refused() -> None:
    with pytest.raises(ValueError, match=r"n-step returns \(nstep\) does not combine with blocked_action_target"):
        DCQN("MlpPolicy", "CartPole-v1", blocked_action_target=True, n_steps=3)
