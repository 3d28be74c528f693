"""DCQN's behaviour as an SB3 algorithm: the TD target, twin critics, persistence, envs, logging and learning."""

from __future__ import annotations

import inspect
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from gymnasium.wrappers import FilterObservation, FlattenObservation
from stable_baselines3 import DQN
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.envs import FakeImageEnv, IdentityEnv
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecFrameStack

from sb3_dcqn import DCQN, MlpPolicy, dcqn_td_target
from sb3_dcqn.policies import EnsembleLinear, create_ensemble_mlp

SMALL = dict(learning_starts=50, buffer_size=1_000, batch_size=16, policy_kwargs=dict(net_arch=[16]))


class TwoKeyEnv(gym.Env):
    """Deterministic toy env with a Dict observation: reward for choosing the sign of `a[0] + b[1]`."""

    def __init__(self) -> None:
        self.observation_space = spaces.Dict(
            {"a": spaces.Box(-1, 1, (2,), np.float32), "b": spaces.Box(-1, 1, (3,), np.float32)}
        )
        self.action_space = spaces.Discrete(2)
        self._obs: dict[str, np.ndarray] = {}
        self._t = 0

    def _sample(self) -> dict[str, np.ndarray]:
        return {k: self.np_random.uniform(-1, 1, s.shape).astype(np.float32) for k, s in self.observation_space.items()}

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._t = 0
        self._obs = self._sample()
        return self._obs, {}

    def step(self, action):
        reward = float(int(action) == int(self._obs["a"][0] + self._obs["b"][1] > 0))
        self._t += 1
        self._obs = self._sample()
        return self._obs, reward, False, self._t >= 20, {}


# --- the TD target -------------------------------------------------------------------------------------------------


def test_td_target_takes_max_over_actions_of_min_over_target_critics() -> None:
    # (n_critics=2, batch=3, n_actions=2)
    next_q = th.tensor(
        [
            [[1.0, 5.0], [2.0, 0.0], [-1.0, -3.0]],
            [[3.0, 4.0], [1.0, 7.0], [-2.0, 0.0]],
        ]
    )
    rewards = th.tensor([[0.5], [-0.005], [1.0]])
    dones = th.tensor([[0.0], [0.0], [1.0]])
    target = dcqn_td_target(next_q, rewards, dones, 0.95)
    # min over critics -> [[1, 4], [1, 0], [-2, -3]]; max over actions -> [4, 1, -2]; last row is terminal
    expected = th.tensor([[0.5 + 0.95 * 4.0], [-0.005 + 0.95 * 1.0], [1.0]])
    assert th.allclose(target, expected)


def test_td_target_accepts_per_row_discounts_of_n_step_returns() -> None:
    next_q = th.ones(2, 2, 3)
    discounts = th.tensor([[0.9], [0.81]])
    target = dcqn_td_target(next_q, th.zeros(2, 1), th.zeros(2, 1), discounts)
    assert th.allclose(target, discounts)


def test_train_regresses_both_critics_to_the_shared_min_target() -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    model.learn(100)
    # Draw the batch that train() will draw next, by replaying the RNG state
    state = np.random.get_state()
    data = model.replay_buffer.sample(8)
    np.random.set_state(state)
    with th.no_grad():
        next_q = model.q_net_target.critic_values(data.next_observations)
        target = dcqn_td_target(next_q, data.rewards, data.dones, model.gamma)
        q = model.q_net.critic_values(data.observations)
    taken = q.gather(2, data.actions.long().unsqueeze(0).expand(2, -1, -1))
    per_critic = [th.nn.functional.smooth_l1_loss(taken[i], target).item() for i in range(2)]
    assert np.all(np.isfinite(per_critic))
    model.train(gradient_steps=1, batch_size=8)
    # Batched critics against the per-critic losses recomputed here: float32 rounding only
    assert model.logger.name_to_value["train/loss"] == pytest.approx(sum(per_critic), rel=1e-5)
    assert model.logger.name_to_value["train/critic_1_loss"] == pytest.approx(per_critic[0], rel=1e-5)
    assert model.logger.name_to_value["train/critic_2_loss"] == pytest.approx(per_critic[1], rel=1e-5)


# --- twin critics ----------------------------------------------------------------------------------------------------


def test_ensemble_linear_equals_independent_linear_layers() -> None:
    layer = EnsembleLinear(2, 5, 3)
    x = th.randn(4, 5)
    out = layer(x)
    assert out.shape == (2, 4, 3)
    # One baddbmm against a plain matmul per member: float32 rounding only, on O(1) outputs
    for i in range(2):
        assert th.allclose(out[i], x @ layer.weight[i] + layer.bias[i], atol=1e-6)
    per_member = th.randn(2, 4, 5)
    assert th.allclose(layer(per_member)[1], per_member[1] @ layer.weight[1] + layer.bias[1], atol=1e-6)


def test_ensemble_members_are_initialised_independently() -> None:
    mlp = create_ensemble_mlp(2, 8, 4, [16])
    first = mlp[0]
    assert not th.allclose(first.weight[0], first.weight[1])


def test_critic_values_return_one_row_of_q_values_per_critic() -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    obs = th.as_tensor(np.stack([model.observation_space.sample() for _ in range(7)]))
    assert model.q_net.critic_values(obs).shape == (2, 7, 2)
    assert model.q_net_target.critic_values(obs).shape == (2, 7, 2)


@pytest.mark.parametrize("network", ["q_net", "q_net_target"])
def test_q_net_returns_what_dqns_q_net_returns_the_greedy_values(network: str) -> None:
    # Code written for SB3's DQN: q_net(obs) is (batch, n_actions) and its argmax over dim 1 is the greedy action
    dqn = DQN("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    model = DCQN("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    obs = np.stack([model.observation_space.sample() for _ in range(9)])
    with th.no_grad():
        dqn_q = getattr(dqn, network)(th.as_tensor(obs))
        q_values = getattr(model, network)(th.as_tensor(obs))
        per_critic = getattr(model, network).critic_values(th.as_tensor(obs))
    assert q_values.shape == dqn_q.shape == (9, 2)
    th.testing.assert_close(q_values, per_critic.mean(dim=0), rtol=1e-5, atol=1e-6)
    if network == "q_net":
        actions, _ = model.predict(obs, deterministic=True)
        # Ties between the two actions within float noise could break either way
        chosen = q_values.gather(1, th.as_tensor(actions).long().reshape(-1, 1)).reshape(-1)
        th.testing.assert_close(chosen, q_values.max(dim=1).values, rtol=0, atol=1e-6)
        assert (q_values.argmax(dim=1).numpy() == actions).mean() >= 8 / 9


def test_greedy_action_maximises_the_mean_of_the_critics() -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", seed=3, **SMALL)
    obs = np.stack([model.observation_space.sample() for _ in range(64)])
    with th.no_grad():
        q = model.q_net.critic_values(th.as_tensor(obs))
    mean_q = q.mean(dim=0)
    # The batch tells the rules apart: acting on either critic alone would choose other actions for some observations
    for critic_q in q:
        assert (critic_q.argmax(dim=1) != mean_q.argmax(dim=1)).any()
    actions, _ = model.predict(obs, deterministic=True)
    chosen_q = mean_q.gather(1, th.as_tensor(actions).long().reshape(-1, 1)).squeeze(1)
    # predict evaluates the critics in its own forward pass: float32 rounding (~1e-7 here) could only flip a near-tie,
    # and 1e-6 is far below the gaps between actions (the smallest in this batch is ~2e-3)
    assert th.allclose(chosen_q, mean_q.max(dim=1).values, rtol=0, atol=1e-6)


def test_target_critics_share_no_parameters_with_online_critics() -> None:
    model = DCQN("CnnPolicy", FakeImageEnv(screen_height=40, screen_width=40, n_channels=1), seed=0, **SMALL)
    online = {p.data_ptr() for p in model.q_net.parameters()}
    target = {p.data_ptr() for p in model.q_net_target.parameters()}
    assert online.isdisjoint(target)
    # The optimizer trains the online critics only
    optimised = {p.data_ptr() for group in model.policy.optimizer.param_groups for p in group["params"]}
    assert optimised == online


def test_parametric_extractors_are_one_per_critic_unless_shared() -> None:
    env = FakeImageEnv(screen_height=40, screen_width=40, n_channels=1)
    separate = DCQN("CnnPolicy", env, seed=0, **SMALL)
    assert len(separate.q_net.extra_features_extractors) == 1
    shared = DCQN("CnnPolicy", env, seed=0, policy_kwargs=dict(share_features_extractor=True))
    assert shared.q_net.shares_features_extractor


def test_target_update_copies_each_critic_into_its_own_target() -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", target_update_interval=10_000, seed=0, **SMALL)
    model.learn(200)
    assert not th.allclose(model.q_net.q_net[0].weight, model.q_net_target.q_net[0].weight)
    model._n_calls = model.target_update_interval - 1
    model._on_step()
    # A hard update (tau = 1) copies the parameters: exact
    for online, target in zip(model.q_net.parameters(), model.q_net_target.parameters(), strict=True):
        assert th.equal(online, target)


def test_rejects_continuous_action_spaces() -> None:
    with pytest.raises(AssertionError, match="only supports"):
        DCQN("MlpPolicy", "Pendulum-v1")


def test_dcqn_takes_dqns_parameters_plus_the_targets_two_options_and_predicts_as_dqn() -> None:
    dqn = set(inspect.signature(DQN.__init__).parameters)
    dcqn = set(inspect.signature(DCQN.__init__).parameters)
    assert dqn <= dcqn and dcqn - dqn == {"blocked_action_target", "pessimistic_target"}
    assert DCQN.predict is DQN.predict  # epsilon-greedy over the greedy action: the mean of the critics


@pytest.mark.usefixtures("shared_feature_cache")
@pytest.mark.parametrize("wrapping", ["flatten", "filter", "frame_stack"])
def test_dcqn_builds_and_learns_on_campusnav_behind_wrappers_that_change_its_spaces(wrapping: str) -> None:
    # DCQN reads nothing from the env's metadata: a frame declaration that no longer fits the wrapped spaces is none
    # of its business (the critics score compass slots where policy_kwargs give heading_key)
    from campusnav_env import CampusNavEnv, ViewBuild
    from campusnav_env.rendering.street_view import RenderSettings

    env = CampusNavEnv(encoder="pixels", view_build=ViewBuild(render_settings=RenderSettings(64, 48), progress=False))
    wrapped: Any = {
        "flatten": lambda: FlattenObservation(env),
        "filter": lambda: FilterObservation(env, ["views", "heading"]),
        "frame_stack": lambda: VecFrameStack(DummyVecEnv([lambda: env]), 2),
    }[wrapping]()
    policy = "MlpPolicy" if wrapping == "flatten" else "MultiInputPolicy"
    model = DCQN(policy, wrapped, seed=0, **SMALL)
    model.learn(80)
    assert model.num_timesteps == 80 and model.policy.q_net.heading_key is None


# --- persistence -----------------------------------------------------------------------------------------------------


def test_save_and_load_give_identical_parameters_and_deterministic_predictions(tmp_path: Path) -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    model.learn(300)
    obs = np.stack([model.observation_space.sample() for _ in range(32)])
    before, _ = model.predict(obs, deterministic=True)
    model.save(tmp_path / "dcqn")
    loaded = DCQN.load(tmp_path / "dcqn")
    after, _ = loaded.predict(obs, deterministic=True)
    np.testing.assert_array_equal(before, after)
    for name, tensor in model.policy.state_dict().items():
        assert th.equal(tensor, loaded.policy.state_dict()[name]), name
    assert loaded.policy.n_critics == 2
    assert loaded.exploration_rate == model.exploration_rate


def test_get_and_set_parameters_round_trip_and_reject_bad_input() -> None:
    source = DCQN("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    target = DCQN("MlpPolicy", "CartPole-v1", seed=1, **SMALL)
    target.set_parameters(source.get_parameters())
    for name, tensor in source.policy.state_dict().items():
        assert th.equal(tensor, target.policy.state_dict()[name])

    params = source.get_parameters()
    with pytest.raises(ValueError, match="not_an_object"):
        target.set_parameters({**params, "not_an_object": {}})
    del params["policy"]["q_net.q_net.0.weight"]
    with pytest.raises(RuntimeError, match=r"q_net\.q_net\.0\.weight"):
        target.set_parameters(params)
    with pytest.raises(ValueError, match="policy"):
        target.set_parameters({"policy.optimizer": source.get_parameters()["policy.optimizer"]}, exact_match=True)


def test_replay_buffer_save_and_load(tmp_path: Path) -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    model.learn(120)
    model.save_replay_buffer(tmp_path / "buffer")
    fresh = DCQN("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    fresh.load_replay_buffer(tmp_path / "buffer")
    assert fresh.replay_buffer.size() == model.replay_buffer.size() == 120
    np.testing.assert_array_equal(fresh.replay_buffer.observations, model.replay_buffer.observations)


def test_set_env_and_continued_learning_keep_the_timestep_count() -> None:
    model = DCQN("MlpPolicy", "CartPole-v1", seed=0, **SMALL)
    model.learn(100)
    model.set_env(make_vec_env("CartPole-v1", n_envs=1, seed=1))
    model.learn(100, reset_num_timesteps=False)
    assert model.num_timesteps == 200
    with pytest.raises(ValueError, match="Observation spaces do not match"):
        model.set_env(make_vec_env("Acrobot-v1", n_envs=1))


# --- observations, envs and reproducibility -------------------------------------------------------------------------


def _train_and_probe(probe: np.ndarray) -> tuple[np.ndarray, list[th.Tensor]]:
    model = DCQN(
        "MlpPolicy",
        gym.make("CartPole-v1"),
        seed=7,
        learning_starts=30,
        train_freq=2,
        target_update_interval=50,
        **{k: v for k, v in SMALL.items() if k != "learning_starts"},
    )
    model.learn(300)
    actions, _ = model.predict(probe, deterministic=True)
    return actions, [p.detach().clone() for p in model.q_net.parameters()]


def _collect_random_transitions(policy: str, env: gym.Env) -> DCQN:
    # learning_starts beyond the 64 steps: only seeded random actions, so twin envs yield the same transitions
    model = DCQN(policy, env, seed=7, learning_starts=1_000, buffer_size=1_000, policy_kwargs=dict(net_arch=[16]))
    model.learn(64)
    return model


def test_dict_observations_train_like_their_flattened_twin() -> None:
    # Two code paths (SB3's CombinedExtractor on Dict observations, FlattenExtractor on FlattenObservation) can round
    # differently, and over a long run a flipped greedy action makes the runs diverge legitimately. So the check is
    # one short stretch of training on identical parameters and identical minibatches, compared with a tolerance.
    dict_model = _collect_random_transitions("MultiInputPolicy", TwoKeyEnv())
    flat_model = _collect_random_transitions("MlpPolicy", FlattenObservation(TwoKeyEnv()))
    dict_buffer, flat_buffer = dict_model.replay_buffer, flat_model.replay_buffer
    # The same stored transitions (copies of the env's numbers, no arithmetic: exact)
    flattened = np.concatenate([dict_buffer.observations["a"], dict_buffer.observations["b"]], axis=-1)
    np.testing.assert_array_equal(flattened, flat_buffer.observations)
    np.testing.assert_array_equal(dict_buffer.actions, flat_buffer.actions)
    flat_model.policy.load_state_dict(dict_model.policy.state_dict())

    probe_env = TwoKeyEnv()
    probe_env.reset(seed=0)
    samples = [probe_env._sample() for _ in range(40)]
    probe = {k: np.stack([sample[k] for sample in samples]) for k in probe_env.observation_space}
    flat_probe = np.concatenate([probe["a"], probe["b"]], axis=1)
    with th.no_grad():
        dict_q = dict_model.q_net.critic_values(dict_model.policy.obs_to_tensor(probe)[0])
        flat_q = flat_model.q_net.critic_values(th.as_tensor(flat_probe))
    # Same weights, inputs concatenated in the same order: float32 rounding at most (Q-values are O(1))
    assert th.allclose(dict_q, flat_q, rtol=1e-5, atol=1e-6)

    for model in (dict_model, flat_model):
        np.random.seed(0)  # the replay buffers draw minibatch indices from numpy's global RNG
        model.train(gradient_steps=5, batch_size=16)
    assert dict_model.logger.name_to_value["train/loss"] == pytest.approx(
        flat_model.logger.name_to_value["train/loss"], rel=1e-5
    )
    # Adam moves a weight by up to about lr = 1e-4 per step; rounding changes a step by a relative ~1e-6, while other
    # minibatches give differences of ~1e-4: atol 1e-6 tells the same updates apart with a wide margin on any CPU
    for a, b in zip(dict_model.q_net.parameters(), flat_model.q_net.parameters(), strict=True):
        assert th.allclose(a, b, rtol=0, atol=1e-6)


def test_same_seed_gives_the_same_results() -> None:
    probe = np.stack([np.full(4, v, dtype=np.float32) for v in np.linspace(-0.2, 0.2, 16)])
    first = _train_and_probe(probe)
    second = _train_and_probe(probe)
    # The same computation run twice in one process: bit for bit the same
    np.testing.assert_array_equal(first[0], second[0])
    for a, b in zip(first[1], second[1], strict=True):
        assert th.equal(a, b)


@pytest.mark.parametrize(
    ("train_freq", "n_envs"),
    # SB3 allows episodic train_freq with a single env only
    [(4, 1), (4, 3), ((5, "step"), 1), ((5, "step"), 3), ((2, "episode"), 1)],
)
def test_several_envs_and_train_freq_forms(train_freq: int | tuple[int, str], n_envs: int) -> None:
    env = make_vec_env("CartPole-v1", n_envs=n_envs, seed=0)
    model = DCQN("MlpPolicy", env, train_freq=train_freq, seed=0, **SMALL)
    model.learn(150)
    assert model.num_timesteps >= 150
    assert model._n_updates > 0


def test_gradient_steps_minus_one_does_one_update_per_env_step() -> None:
    env = make_vec_env("CartPole-v1", n_envs=2, seed=0)
    model = DCQN("MlpPolicy", env, train_freq=4, gradient_steps=-1, seed=0, **SMALL)
    model.learn(200)
    # each rollout collects 4 steps x 2 envs = 8 transitions and then does 8 gradient steps
    # once more than learning_starts (50) transitions are stored
    training_rollouts = sum(1 for k in range(1, 200 // 8 + 1) if 8 * k > 50)
    assert model._n_updates == 8 * training_rollouts


def test_cnn_policy_trains_its_image_critics_and_acts_on_their_mean() -> None:
    from stable_baselines3.common.torch_layers import NatureCNN

    env = FakeImageEnv(screen_height=40, screen_width=40, n_channels=1, discrete=True)
    model = DCQN("CnnPolicy", env, seed=0, learning_starts=20, buffer_size=200, batch_size=8, train_freq=4)
    assert isinstance(model.q_net.features_extractor, NatureCNN)  # the images go through SB3's CNN
    before = [p.detach().clone() for p in model.q_net.parameters()]
    model.learn(60)
    assert model._n_updates == sum(1 for step in range(4, 61, 4) if step > 20)  # a gradient step per rollout
    moved = [not th.equal(old, new) for old, new in zip(before, model.q_net.parameters(), strict=True)]
    assert all(moved)  # every critic parameter, the CNN's included, was trained
    images = np.stack([env.observation_space.sample() for _ in range(5)])
    actions, _ = model.predict(images, deterministic=True)
    with th.no_grad():
        mean_q = model.q_net(model.policy.obs_to_tensor(images)[0])
    np.testing.assert_array_equal(actions, mean_q.argmax(dim=1).cpu().numpy())


# --- logging -------------------------------------------------------------------------------------------------------


def test_tensorboard_run_directory_and_scalars(tmp_path: Path) -> None:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    model = DCQN("MlpPolicy", "CartPole-v1", tensorboard_log=str(tmp_path), seed=0, **SMALL)
    model.learn(400, log_interval=1)
    run_dir = tmp_path / "DCQN_1"
    assert run_dir.is_dir()
    events = EventAccumulator(str(run_dir))
    events.Reload()
    tags = set(events.Tags()["scalars"])
    expected = {
        "train/loss",
        "train/critic_1_loss",
        "train/critic_2_loss",
        "train/q_mean",
        "train/q_abs_diff",
        "train/target_q_mean",
        "rollout/exploration_rate",
        "rollout/ep_rew_mean",
        "rollout/ep_len_mean",
    }
    assert expected <= tags, expected - tags


# --- learning ------------------------------------------------------------------------------------------------------


def test_solves_identity_env_to_full_reward() -> None:
    env = IdentityEnv(dim=4, ep_length=10)
    model = DCQN(
        MlpPolicy,
        env,
        learning_rate=3e-3,
        learning_starts=100,
        buffer_size=5_000,
        batch_size=32,
        gamma=0.0,
        target_update_interval=100,
        exploration_fraction=0.5,
        policy_kwargs=dict(net_arch=[32]),
        seed=0,
    )
    model.learn(3_000)
    mean_reward, _ = evaluate_policy(model, DummyVecEnv([lambda: Monitor(IdentityEnv(dim=4, ep_length=10))]), 10)
    assert mean_reward == pytest.approx(10.0)
