"""Re-adaptation options of DCQN's replay buffers: experience revision and prioritised replay; DCQN's flags."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_dcqn import DCQN
from sb3_dcqn.buffers import DCQNDictReplayBuffer, DCQNReplayBuffer

BOX = spaces.Box(-10.0, 10.0, shape=(3,), dtype=np.float32)
DICT = spaces.Dict({"views": BOX, "heading": spaces.Box(0.0, 1.0, shape=(4,), dtype=np.float32)})
ACTIONS = spaces.Discrete(4)


def box_obs(node: int) -> np.ndarray:
    return np.array([[node, 2.0 * node, -node]], dtype=np.float32)  # (n_envs=1, 3)


def dict_obs(node: int, heading: int = 0) -> dict[str, np.ndarray]:
    return {"views": box_obs(node), "heading": np.eye(4, dtype=np.float32)[[heading]]}


def add(buffer, obs, next_obs, action: int, reward: float, done: bool = False) -> None:
    buffer.add(obs, next_obs, np.array([[action]]), np.array([reward]), np.array([done]), [{}])


def drive(buffer, make_obs) -> None:
    """A hand-made history: node 1 --(action 0)--> node 2 three times, other moves in between."""
    for _ in range(3):
        add(buffer, make_obs(1), make_obs(2), 0, -0.005)  # the road 1 -> 2 was open
        add(buffer, make_obs(1), make_obs(3), 1, -0.005)  # another road from 1
        add(buffer, make_obs(2), make_obs(4), 0, 1.0, done=True)


@pytest.mark.parametrize(
    ("buffer_class", "space", "make_obs"), [(DCQNReplayBuffer, BOX, box_obs), (DCQNDictReplayBuffer, DICT, dict_obs)]
)
def test_a_collision_relabels_every_stored_copy_it_contradicts(buffer_class, space, make_obs) -> None:
    buffer = buffer_class(100, space, ACTIONS, device="cpu", revise_experience=True)
    drive(buffer, make_obs)
    assert buffer.revised == 0  # consistent history: nothing contradicted
    # The road closes: from node 1, action 0 now collides (the agent stays, collision penalty)
    add(buffer, make_obs(1), make_obs(1), 0, -0.01)
    assert buffer.revised == 3
    stored = buffer.next_observations if isinstance(space, spaces.Box) else buffer.next_observations["views"]
    revised_rows = [0, 3, 6]  # the three old copies of (node 1, action 0)
    for row in revised_rows:
        np.testing.assert_array_equal(stored[row], stored[9])  # now "stays at node 1": copied, exact
        assert buffer.rewards[row, 0] == np.float32(-0.01) and buffer.dones[row, 0] == 0.0
    # Transitions of other observations or actions are untouched
    np.testing.assert_array_equal(stored[1], make_obs(3) if isinstance(space, spaces.Box) else make_obs(3)["views"])
    assert buffer.rewards[2, 0] == np.float32(1.0) and buffer.dones[2, 0] == 1.0
    # The road reopens: the next transition along it revises the collisions back
    add(buffer, make_obs(1), make_obs(2), 0, -0.005)
    assert buffer.revised == 3 + 4
    assert all(buffer.rewards[row, 0] == np.float32(-0.005) for row in [*revised_rows, 9])


def test_revision_tells_observations_apart_by_every_key() -> None:
    buffer = DCQNDictReplayBuffer(100, DICT, ACTIONS, device="cpu", revise_experience=True)
    add(buffer, dict_obs(1, heading=0), dict_obs(2), 0, -0.005)
    add(buffer, dict_obs(1, heading=1), dict_obs(1, heading=1), 0, -0.01)  # same views, other heading: other state
    assert buffer.revised == 0


def test_overwritten_transitions_leave_the_index() -> None:
    buffer = DCQNReplayBuffer(4, BOX, ACTIONS, device="cpu", revise_experience=True)
    add(buffer, box_obs(1), box_obs(2), 0, -0.005)
    for node in range(5, 9):  # the ring buffer of 4 overwrites the first transition
        add(buffer, box_obs(node), box_obs(node + 1), 0, -0.005)
    add(buffer, box_obs(1), box_obs(1), 0, -0.01)
    assert buffer.revised == 0  # the contradicted copy is gone, nothing left to revise


def test_prioritised_sampling_follows_the_priorities_with_importance_weights() -> None:
    buffer = DCQNReplayBuffer(100, BOX, ACTIONS, device="cpu", prioritized=True, alpha=1.0, beta=1.0)
    for node in range(10):
        add(buffer, box_obs(node), box_obs(node + 1), 0, -0.005)
    assert np.all(buffer.priorities[:10] == 1.0)  # new transitions come in at the highest priority
    errors = np.full(10, 0.01)
    errors[7] = 9.0
    buffer.update_priorities(np.arange(10), errors)
    np.random.seed(0)
    samples = buffer.sample(2000)
    share_of_7 = np.mean(samples.indices == 7)
    expected = (9.0 + buffer.priority_eps) / (9.0 + 9 * 0.01 + 10 * buffer.priority_eps)
    assert share_of_7 == pytest.approx(expected, abs=0.02)
    # Rarely drawn transitions weigh most; weights are normalised to a maximum of 1
    weights = samples.weights.numpy().reshape(-1)
    assert weights.max() == pytest.approx(1.0) and weights[samples.indices == 7].max() < 0.05
    # Each sample is the transition its index names (node i was stored at row i)
    np.testing.assert_array_equal(samples.observations.numpy()[:, 0], samples.indices.astype(np.float32))
    buffer.update_priorities(np.array([3]), np.array([100.0]))
    add(buffer, box_obs(20), box_obs(21), 0, -0.005)
    assert buffer.priorities[10, 0] == pytest.approx(100.0 + buffer.priority_eps)  # max priority so far


def test_bad_buffer_settings_are_refused() -> None:
    with pytest.raises(ValueError, match="optimize_memory_usage"):
        DCQNReplayBuffer(100, BOX, ACTIONS, optimize_memory_usage=True, handle_timeout_termination=False)
    with pytest.raises(ValueError, match="alpha"):
        DCQNReplayBuffer(100, BOX, ACTIONS, alpha=2.0)


def test_dcqn_selects_the_buffer_and_trains_with_priorities_and_revision() -> None:
    model = DCQN(
        "MlpPolicy",
        "CartPole-v1",
        experience_revision=True,
        prioritized_replay=True,
        learning_starts=50,
        train_freq=1,
        seed=0,
        policy_kwargs=dict(net_arch=[16]),
    )
    assert isinstance(model.replay_buffer, DCQNReplayBuffer)
    assert model.replay_buffer.revise_experience and model.replay_buffer.prioritized
    model.learn(300)
    assert model.replay_buffer.priorities[:300].std() > 0  # TD errors came back from train()
    assert model.replay_buffer.beta > 0.4  # annealed towards 1
    dict_model = DCQN("MultiInputPolicy", DictCartPole(), experience_revision=True)
    assert isinstance(dict_model.replay_buffer, DCQNDictReplayBuffer)


def test_dcqn_flags_are_checked() -> None:
    with pytest.raises(ValueError, match="n-step"):
        DCQN("MlpPolicy", "CartPole-v1", experience_revision=True, n_steps=3)
    with pytest.raises(ValueError, match="need DCQNReplayBuffer or DCQNDictReplayBuffer"):
        DCQN("MlpPolicy", "CartPole-v1", prioritized_replay=True, replay_buffer_class=ReplayBuffer)


class DictCartPole(gym.ObservationWrapper):
    """CartPole with a Dict observation, to check the buffer choice."""

    def __init__(self) -> None:
        super().__init__(gym.make("CartPole-v1"))
        self.observation_space = spaces.Dict({"state": self.env.observation_space})

    def observation(self, observation: np.ndarray) -> dict[str, np.ndarray]:
        return {"state": observation}
