"""DCQN's replay variants as buffer classes: experience revision, prioritized replay, how they compose and combine."""

from __future__ import annotations

import pickle

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.buffers import DictReplayBuffer, NStepReplayBuffer, ReplayBuffer
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

from sb3_dcqn import DCQN, replay
from sb3_dcqn.replay import (
    DCQNDictReplayBuffer,
    DCQNHerReplayBuffer,
    DCQNReplayBuffer,
    PrioritizedReplay,
    RevisionReplay,
    replay_buffer_class,
    variants_of,
    with_variants,
)

RevisionBox = replay_buffer_class("revision", base="Box")
RevisionDict = replay_buffer_class("revision")
PrioritizedBox = replay_buffer_class("prioritized", base="Box")

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
    ("buffer_class", "space", "make_obs"), [(RevisionBox, BOX, box_obs), (RevisionDict, DICT, dict_obs)]
)
def test_a_collision_relabels_every_stored_copy_it_contradicts(buffer_class, space, make_obs) -> None:
    buffer = buffer_class(100, space, ACTIONS, device="cpu")
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
    buffer = RevisionDict(100, DICT, ACTIONS, device="cpu")
    add(buffer, dict_obs(1, heading=0), dict_obs(2), 0, -0.005)
    add(buffer, dict_obs(1, heading=1), dict_obs(1, heading=1), 0, -0.01)  # same views, other heading: other state
    assert buffer.revised == 0


def test_overwritten_transitions_leave_the_index() -> None:
    buffer = RevisionBox(4, BOX, ACTIONS, device="cpu")
    add(buffer, box_obs(1), box_obs(2), 0, -0.005)
    for node in range(5, 9):  # the ring buffer of 4 overwrites the first transition
        add(buffer, box_obs(node), box_obs(node + 1), 0, -0.005)
    add(buffer, box_obs(1), box_obs(1), 0, -0.01)
    assert buffer.revised == 0  # the contradicted copy is gone, nothing left to revise


def test_prioritized_sampling_follows_the_priorities_with_importance_weights() -> None:
    buffer = PrioritizedBox(100, BOX, ACTIONS, device="cpu", alpha=1.0, beta=1.0)
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
    # Rarely drawn transitions weigh most; weights are normalized to a maximum of 1
    weights = samples.weights.numpy().reshape(-1)
    assert weights.max() == pytest.approx(1.0) and weights[samples.indices == 7].max() < 0.05
    # Each sample is the transition its index names (node i was stored at row i)
    np.testing.assert_array_equal(samples.observations.numpy()[:, 0], samples.indices.astype(np.float32))
    buffer.update_priorities(np.array([3]), np.array([100.0]))
    add(buffer, box_obs(20), box_obs(21), 0, -0.005)
    assert buffer.priorities[10, 0] == pytest.approx(100.0 + buffer.priority_eps)  # max priority so far


def test_each_variant_checks_its_own_arguments() -> None:
    with pytest.raises(ValueError, match="optimize_memory_usage"):
        DCQNReplayBuffer(100, BOX, ACTIONS, optimize_memory_usage=True, handle_timeout_termination=False)
    with pytest.raises(ValueError, match="alpha must be in"):
        PrioritizedBox(100, BOX, ACTIONS, alpha=2.0)
    with pytest.raises(ValueError, match="n_steps must be an integer >= 1"):
        replay.NStepDictReplayBuffer(100, DICT, ACTIONS, n_steps=0)
    with pytest.raises(ValueError, match=r"count_bonus=\.\.\.\) > 0"):
        replay.CountBonusDictReplayBuffer(100, DICT, ACTIONS)
    with pytest.raises(TypeError, match="alpha"):  # an argument of a variant the class does not have
        RevisionDict(100, DICT, ACTIONS, alpha=0.5)


def test_a_combination_is_a_class_named_by_its_parts_importable_and_picklable() -> None:
    cls = replay_buffer_class("revision", "lean", base="Her")  # any order
    assert cls is replay.LeanRevisionHerReplayBuffer and cls.__name__ == "LeanRevisionHerReplayBuffer"
    assert issubclass(cls, RevisionReplay) and issubclass(cls, DCQNHerReplayBuffer)
    assert pickle.loads(pickle.dumps(cls)) is cls
    assert variants_of(cls) == ("Her", frozenset({"lean", "revision"}))
    assert replay_buffer_class() is DCQNDictReplayBuffer  # no variant: the base
    assert replay_buffer_class("nstep", base="Box") is NStepReplayBuffer  # SB3's own, not a second class of its name
    with pytest.raises(AttributeError, match="NoSuchDictReplayBuffer"):
        _ = replay.NoSuchDictReplayBuffer


def test_one_place_decides_what_combines_and_the_error_names_both_sides() -> None:
    with pytest.raises(ValueError, match=r"n-step returns \(nstep\) does not combine with experience revision"):
        replay_buffer_class("revision", "nstep")
    with pytest.raises(
        ValueError, match=r"hindsight relabelling \(HerReplayBuffer\) does not combine with prioritized"
    ):
        with_variants(HerReplayBuffer, "prioritized")
    with pytest.raises(ValueError, match=r"Box observations \(ReplayBuffer\) does not combine with lean storage"):
        replay_buffer_class("lean", base="Box")
    with pytest.raises(ValueError, match=r"hindsight relabelling \(HerReplayBuffer\) does not combine with the count"):
        replay_buffer_class("count_bonus", base="Her")
    with pytest.raises(ValueError, match="unknown replay variant 'per'"):
        replay_buffer_class("per")
    assert with_variants(HerReplayBuffer, "revision") is replay.RevisionHerReplayBuffer
    assert with_variants(DictReplayBuffer, "lean", "nstep") is replay.LeanNStepDictReplayBuffer
    assert with_variants(replay.LeanDictReplayBuffer, "revision") is replay.LeanRevisionDictReplayBuffer


def test_dcqn_builds_the_buffer_class_it_is_given_and_trains_with_priorities_and_revision() -> None:
    model = DCQN(
        "MlpPolicy",
        "CartPole-v1",
        replay_buffer_class=replay.RevisionPrioritizedReplayBuffer,
        learning_starts=50,
        train_freq=1,
        seed=0,
        policy_kwargs=dict(net_arch=[16]),
    )
    buffer = model.replay_buffer
    assert isinstance(buffer, RevisionReplay) and isinstance(buffer, PrioritizedReplay)
    model.learn(300)
    assert buffer.priorities[:300].std() > 0  # TD errors came back from the training step
    # Annealed towards 1 with the share of training done at the last gradient step (all of it: 300 of 300 steps)
    assert buffer.beta == pytest.approx(0.4 + 0.6 * (1.0 - model._current_progress_remaining), abs=1e-6)
    assert buffer.beta == pytest.approx(1.0, abs=1e-6)
    # A move stored twice, then contradicted: both copies revised, and the next training step reports it
    state = np.zeros((1, 4), dtype=np.float32)
    for reward in (1.0, 1.0, 0.0):
        add(buffer, state, state + 1.0, 0, reward)
    assert buffer.revised == 2
    model.train(gradient_steps=1, batch_size=16)
    assert model.logger.name_to_value["train/revised_transitions"] == 2
    dict_model = DCQN("MultiInputPolicy", DictCartPole(), replay_buffer_class=RevisionDict)
    assert isinstance(dict_model.replay_buffer, RevisionDict)


def test_train_weights_the_loss_by_the_samples_importance_weights_through_the_feedback_channel() -> None:
    seen = []

    class Recording(DCQN):
        def critic_loss(self, current_q_values, target_q_values, weights=None):
            seen.append(weights)
            return super().critic_loss(current_q_values, target_q_values, weights)

    prioritized = Recording("MlpPolicy", "CartPole-v1", replay_buffer_class=PrioritizedBox, learning_starts=50, seed=0)
    prioritized.learn(60)
    assert seen and all(w is not None and w.shape == (prioritized.batch_size, 1) and w.max() <= 1.0 for w in seen)
    seen.clear()
    plain = Recording("MlpPolicy", "CartPole-v1", replay_buffer_class=ReplayBuffer, learning_starts=50, seed=0)
    plain.learn(60)  # SB3's own buffer takes no feedback: an unweighted loss, nothing reported
    assert seen and all(w is None for w in seen) and "train/revised_transitions" not in plain.logger.name_to_value


def test_priorities_come_from_the_training_step_even_with_a_critic_loss_of_ones_own() -> None:
    class OwnLoss(DCQN):
        def critic_loss(self, current_q_values, target_q_values, weights=None):  # ignores the weights
            return ((current_q_values - target_q_values.expand_as(current_q_values)) ** 2).mean()

    model = OwnLoss(
        "MlpPolicy", "CartPole-v1", replay_buffer_class=PrioritizedBox, learning_starts=50, train_freq=1, seed=0
    )
    model.learn(200)
    assert model.replay_buffer.priorities[:200].std() > 0


def test_dcqn_checks_its_options_with_the_buffer_class() -> None:
    with pytest.raises(ValueError, match=r"n-step returns \(nstep\) does not combine with experience revision"):
        DCQN("MlpPolicy", "CartPole-v1", replay_buffer_class=RevisionBox, n_steps=3)
    with pytest.raises(ValueError, match=r"n-step returns \(nstep\) does not combine with blocked_action_target"):
        DCQN("MultiInputPolicy", DictCartPole(), blocked_action_target=True, n_steps=3)
    # n_steps with Dict observations (SB3 has no buffer for it) and with one of DCQN's classes adds the variant
    model = DCQN("MultiInputPolicy", DictCartPole(), n_steps=3, gamma=0.9)
    assert type(model.replay_buffer) is replay.NStepDictReplayBuffer
    assert (model.replay_buffer.n_steps, model.replay_buffer.gamma) == (3, 0.9)
    lean = DCQN("MultiInputPolicy", DictCartPole(), replay_buffer_class=replay.LeanDictReplayBuffer, n_steps=4)
    assert type(lean.replay_buffer) is replay.LeanNStepDictReplayBuffer and lean.replay_buffer.n_steps == 4
    # SB3's own buffers and a user's own class are built as given
    assert type(DCQN("MlpPolicy", "CartPole-v1", replay_buffer_class=ReplayBuffer).replay_buffer) is ReplayBuffer


class DictCartPole(gym.ObservationWrapper):
    """CartPole with a Dict observation, to check the buffer choice."""

    def __init__(self) -> None:
        super().__init__(gym.make("CartPole-v1"))
        self.observation_space = spaces.Dict({"state": self.env.observation_space})

    def observation(self, observation: np.ndarray) -> dict[str, np.ndarray]:
        return {"state": observation}


@pytest.mark.parametrize(("ours", "theirs", "space", "make_obs"), [
    (DCQNReplayBuffer, ReplayBuffer, BOX, box_obs), (DCQNDictReplayBuffer, DictReplayBuffer, DICT, dict_obs),
])  # fmt: skip
def test_dcqns_bases_sample_exactly_as_sb3s_buffers(ours, theirs, space, make_obs) -> None:
    a, b = ours(8, space, ACTIONS, device="cpu"), theirs(8, space, ACTIONS, device="cpu")
    for node in range(11):  # wraps around
        for buffer in (a, b):
            add(buffer, make_obs(node), make_obs(node + 1), node % 4, -0.005 * node, done=node % 5 == 4)
    for seed in range(3):
        np.random.seed(seed)
        mine = a.sample(16)
        np.random.seed(seed)
        sb3 = b.sample(16)
        for x, y in zip(mine[:5], sb3[:5], strict=True):
            if isinstance(x, dict):
                for key in x:
                    np.testing.assert_allclose(x[key].numpy(), y[key].numpy(), rtol=0, atol=0)
            else:
                np.testing.assert_allclose(x.numpy(), y.numpy(), rtol=0, atol=0)
