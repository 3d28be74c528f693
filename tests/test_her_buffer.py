"""DCQN's HER buffer: relabelled transitions that reach their goal are terminal, collisions keep their penalty, and
held-out goals are never relabelling targets."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.envs import BitFlippingEnv
from stable_baselines3.common.vec_env import DummyVecEnv

from campusnav_env.features.view_build import ViewBuild
from campusnav_env.goal_env import CampusNavGoalEnv, held_out_split
from campusnav_env.rendering.street_view import RenderSettings
from sb3_dcqn import DCQN
from sb3_dcqn.replay import DCQNHerReplayBuffer, LeanHerReplayBuffer, RevisionHerReplayBuffer

N_CELLS = 5
GOAL_REWARD, STEP_REWARD = 1.0, -0.1


class Chain(gym.Env):
    """Cells 0..4 in a row; action 1 moves right, 0 left; the goal is a cell; +1 on reaching it, -0.1 otherwise."""

    def __init__(self, goal: int = 3) -> None:
        cell = spaces.Box(0.0, 1.0, (N_CELLS,), np.float32)
        self.observation_space = spaces.Dict({"observation": cell, "achieved_goal": cell, "desired_goal": cell})
        self.action_space = spaces.Discrete(2)
        self.goal, self.cell = goal, 0

    def _obs(self) -> dict[str, np.ndarray]:
        one_hot = np.eye(N_CELLS, dtype=np.float32)
        return {
            "observation": one_hot[self.cell],
            "achieved_goal": one_hot[self.cell],
            "desired_goal": one_hot[self.goal],
        }

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        self.cell = 0
        return self._obs(), {}

    def step(self, action: int) -> tuple[dict, float, bool, bool, dict]:
        self.cell = int(np.clip(self.cell + (1 if action == 1 else -1), 0, N_CELLS - 1))
        reached = self.cell == self.goal
        return self._obs(), GOAL_REWARD if reached else STEP_REWARD, reached, False, {}

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        return np.where(np.all(np.isclose(achieved_goal, desired_goal), axis=-1), GOAL_REWARD, STEP_REWARD)


class ChainGoalEnv(Chain):
    """The chain with the Gymnasium-Robotics ``compute_terminated``."""

    def compute_terminated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        return np.all(np.isclose(achieved_goal, desired_goal), axis=-1)


class ChainWithoutTerminated(Chain):
    """The chain of an env that predates ``compute_terminated`` (as SB3's BitFlippingEnv)."""


def walk_right(
    env_class: type[gym.Env], strategy: str, buffer_class: type = DCQNHerReplayBuffer, **kwargs: Any
) -> DCQNHerReplayBuffer:
    """A buffer holding one episode 0 -> 1 -> 2 -> 3 (goal 3: the last transition is terminal)."""
    vec_env = DummyVecEnv([env_class])
    buffer = buffer_class(
        100, vec_env.observation_space, vec_env.action_space, vec_env, goal_selection_strategy=strategy, **kwargs
    )
    obs = vec_env.reset()
    for _ in range(3):
        next_obs, reward, done, infos = vec_env.step(np.array([1]))
        stored_next = {key: value.copy() for key, value in next_obs.items()}
        if done[0]:
            stored_next = {key: infos[0]["terminal_observation"][key][None] for key in next_obs}
        buffer.add(obs, stored_next, np.array([[1]]), reward, done, infos)
        obs = next_obs
    return buffer


def relabelled(buffer: DCQNHerReplayBuffer, draws: int = 400) -> set[tuple[int, int, float, float]]:
    """Every (transition's next cell, new goal cell, reward, done) the buffer relabels, over many draws."""
    rows = np.arange(3).repeat(draws)
    samples = buffer._get_virtual_samples(rows, np.zeros_like(rows))
    next_cells = samples.next_observations["achieved_goal"].argmax(dim=1).numpy()
    goals = samples.observations["desired_goal"].argmax(dim=1).numpy()
    rewards = [round(float(r), 3) for r in samples.rewards.flatten()]  # float32 -0.1 back to -0.1
    return set(zip(next_cells.tolist(), goals.tolist(), rewards, samples.dones.flatten().tolist(), strict=True))


@pytest.mark.parametrize("buffer_class", [DCQNHerReplayBuffer, LeanHerReplayBuffer])
def test_a_relabelled_transition_that_reaches_its_new_goal_is_terminal(buffer_class: type) -> None:
    seen = relabelled(walk_right(ChainGoalEnv, "future", buffer_class))
    # Known values: next cell == new goal -> +1 and terminal. Future goals of 0->1: 1, 2, 3; of 1->2: 2, 3; of 2->3: 3
    expected = {(1, 1, 1.0, 1.0), (1, 2, STEP_REWARD, 0.0), (1, 3, STEP_REWARD, 0.0)}
    expected |= {(2, 2, 1.0, 1.0), (2, 3, STEP_REWARD, 0.0), (3, 3, 1.0, 1.0)}
    assert seen == expected


def test_sb3_dones_bootstrap_past_a_relabelled_goal_and_end_episodes_that_go_on() -> None:
    ours = relabelled(walk_right(ChainGoalEnv, "episode"))
    sb3 = relabelled(walk_right(ChainGoalEnv, "episode", terminal_relabels=False))
    # 0->1 relabelled with goal 1: reached, yet SB3 keeps the episode's done (0) and bootstraps past the goal
    assert (1, 1, 1.0, 0.0) in sb3
    assert (1, 1, 1.0, 1.0) in ours
    # 2->3 relabelled with goal 1: not reached, yet SB3 ends it (the original episode ended there)
    assert (3, 1, STEP_REWARD, 1.0) in sb3
    assert all(d == float(n == g) for n, g, _, d in ours)


def test_dcqn_td_target_of_a_reached_relabelled_goal_is_the_goal_reward() -> None:
    model = DCQN("MultiInputPolicy", ChainGoalEnv(), replay_buffer_class=HerReplayBuffer, learning_starts=0, seed=0)
    assert isinstance(model.replay_buffer, DCQNHerReplayBuffer)
    buffer = walk_right(ChainGoalEnv, "future")
    rows = np.arange(3).repeat(50)
    samples = buffer._get_virtual_samples(rows, np.zeros_like(rows))
    with th.no_grad():
        target = model.td_target(samples).flatten()
    reached = samples.dones.flatten() == 1
    assert reached.any() and (~reached).any()
    th.testing.assert_close(target[reached], th.full_like(target[reached], GOAL_REWARD))
    # The others bootstrap: reward + gamma * max_a min_i Q'_i(s', a)
    assert not th.allclose(target[~reached], th.full_like(target[~reached], STEP_REWARD))


def test_envs_without_compute_terminated_keep_sb3_dones_with_a_warning() -> None:
    buffer = walk_right(ChainWithoutTerminated, "future")
    with pytest.warns(UserWarning, match="compute_terminated"):
        buffer._get_virtual_samples(np.arange(3), np.zeros(3, dtype=np.int64))


def _bit_flipping_success(model: DCQN, episodes: int = 100) -> float:
    """Share of ``episodes`` (fixed seeds) in which ``model``'s greedy policy flips the bits to the goal in time."""
    env = BitFlippingEnv(n_bits=4, continuous=False)
    wins = 0
    for episode in range(episodes):
        obs, _ = env.reset(seed=1_000 + episode)
        done, info = False, {}
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
        wins += bool(info["is_success"])
    return wins / episodes


@pytest.mark.parametrize("strategy", ["future", "final", "episode"])
def test_dcqn_learns_sb3s_bit_flipping_with_her(strategy: str) -> None:
    """SB3's own HER check (tests/test_her.py), with DCQN in place of DQN, and the greedy policy then solves it."""
    model = DCQN(
        "MultiInputPolicy",
        BitFlippingEnv(n_bits=4, continuous=False),
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs=dict(n_sampled_goal=4, goal_selection_strategy=strategy),
        learning_starts=100,
        train_freq=1,
        batch_size=64,
        exploration_fraction=0.5,
        learning_rate=1e-3,
        gamma=0.9,
        target_update_interval=100,
        policy_kwargs=dict(net_arch=[64]),
        seed=0,
    )
    untrained = _bit_flipping_success(model)
    with pytest.warns(UserWarning, match="compute_terminated"):  # BitFlippingEnv predates it
        model.learn(700)
    assert isinstance(model.replay_buffer, DCQNHerReplayBuffer) and model.replay_buffer.size() == 700
    # 4 bits, 4 steps: the untrained greedy policy solves 4% of these episodes; 700 steps of HER solve all (measured)
    assert untrained < 0.5
    assert _bit_flipping_success(model) >= 0.9


def test_terminal_relabels_can_be_turned_off_through_replay_buffer_kwargs() -> None:
    model = DCQN(
        "MultiInputPolicy",
        ChainGoalEnv(),
        replay_buffer_class=HerReplayBuffer,
        replay_buffer_kwargs=dict(terminal_relabels=False),
    )
    assert model.replay_buffer.terminal_relabels is False


@pytest.fixture(scope="module")
def strict_model(shared_cache_dir: Path) -> tuple[DCQN, CampusNavGoalEnv, list[int]]:
    """Random driving on the campus, 20% of the goals held out, 3,000 steps stored (no training)."""
    training, held_out = held_out_split(101, 0.2, seed=3)
    env = CampusNavGoalEnv(
        goals=training,
        held_out_goals=held_out,
        encoder="pixels",
        view_dim=16,
        view_build=ViewBuild(
            render_settings=RenderSettings(width=64, height=48),
            cache_dir=shared_cache_dir,  # the session's (conftest.py): the campus's views are built once
            progress=False,
        ),
    )
    model = DCQN("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, learning_starts=10**6, seed=0)
    model.learn(3_000)
    return model, env, held_out


def test_relabelling_never_produces_a_held_out_goal(strict_model: tuple[DCQN, CampusNavGoalEnv, list[int]]) -> None:
    model, env, held_out = strict_model
    buffer = model.replay_buffer
    stored = env.goal_nodes_of(buffer.next_observations["achieved_goal"][: buffer.pos, 0])
    assert np.isin(stored, held_out).sum() > 100  # the agent drove through held-out intersections often
    np.random.seed(0)
    goals = np.concatenate(
        [env.goal_nodes_of(buffer.sample(256).observations["desired_goal"].numpy()) for _ in range(40)]
    )
    assert not np.isin(goals, held_out).any()
    assert len(set(goals.tolist())) > 60  # relabelling still reaches most training goals


def test_relabelled_rewards_keep_the_collision_penalty(strict_model: tuple[DCQN, CampusNavGoalEnv, list[int]]) -> None:
    model, env, _ = strict_model
    buffer = model.replay_buffer
    rows = np.flatnonzero(buffer.ep_length[: buffer.pos, 0] > 0)  # transitions of finished episodes
    samples = buffer._get_virtual_samples(rows, np.zeros_like(rows))
    rewards = samples.rewards.flatten().numpy()
    collided = buffer.reward_infos["collision"][rows, 0] == 1
    reached = samples.dones.flatten().numpy() == 1
    assert collided.any() and reached.any()
    np.testing.assert_allclose(rewards[collided & ~reached], env.collision_penalty, rtol=1e-6)
    np.testing.assert_allclose(rewards[~collided & ~reached], env.step_penalty, rtol=1e-6)
    np.testing.assert_allclose(rewards[reached], env.goal_reward, rtol=1e-6)


def test_the_buffer_survives_a_save_and_load(
    strict_model: tuple[DCQN, CampusNavGoalEnv, list[int]], tmp_path: Path
) -> None:
    model, env, held_out = strict_model
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    fresh = DCQN("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, learning_starts=10**6, seed=1)
    with pytest.warns(UserWarning, match="last trajectory"):  # SB3's HER: the episode under way is cut
        fresh.load_replay_buffer(tmp_path / "buffer.pkl")
    assert isinstance(fresh.replay_buffer, DCQNHerReplayBuffer) and fresh.replay_buffer.pos == model.replay_buffer.pos
    np.testing.assert_array_equal(
        fresh.replay_buffer.reward_infos["collision"], model.replay_buffer.reward_infos["collision"]
    )
    goals = env.goal_nodes_of(fresh.replay_buffer.sample(256).observations["desired_goal"].numpy())
    assert not np.isin(goals, held_out).any()


def test_revision_rewrites_a_closed_road_for_every_goal_its_transitions_carry(shared_cache_dir: Path) -> None:
    env = CampusNavGoalEnv(
        encoder="pixels", view_dim=16,
        view_build=ViewBuild(
            render_settings=RenderSettings(width=64, height=48), cache_dir=shared_cache_dir, progress=False
        ),
    )  # fmt: skip
    model = DCQN(
        "MultiInputPolicy", env, replay_buffer_class=RevisionHerReplayBuffer, learning_starts=10**6, seed=0,
    )  # fmt: skip
    model.learn(3_000)
    buffer = model.replay_buffer
    assert isinstance(buffer, RevisionHerReplayBuffer) and buffer.revised == 0
    n = buffer.pos
    here = env.goal_nodes_of(buffer.observations["achieved_goal"][:n, 0])
    there = env.goal_nodes_of(buffer.next_observations["achieved_goal"][:n, 0])
    moves = np.flatnonzero(here != there)
    # The most driven move: the same (observation, action) stored under several goals
    physical = [(int(here[i]), int(there[i]), int(buffer.actions[i, 0, 0])) for i in moves]
    (u, v, _), count = max(((m, physical.count(m)) for m in set(physical)), key=lambda item: item[1])
    assert count >= 3
    first = moves[physical.index((u, v, _))]
    same = np.flatnonzero(
        np.all(buffer.observations["observation"][:n, 0] == buffer.observations["observation"][first, 0], axis=1)
        & np.all(buffer.observations["heading"][:n, 0] == buffer.observations["heading"][first, 0], axis=1)
        & (buffer.actions[:n, 0, 0] == buffer.actions[first, 0, 0])
    )
    goals = env.goal_nodes_of(buffer.observations["desired_goal"][same, 0])
    # The road closes: the same observation and action now leave the agent where it was (a collision)
    obs = {key: value[first] for key, value in buffer.observations.items()}
    stayed = {key: value.copy() for key, value in obs.items()}
    stayed["desired_goal"] = obs["desired_goal"]
    buffer.add(obs, stayed, buffer.actions[first], np.array([env.collision_penalty]), np.array([False]),
               [{"collision": True}])  # fmt: skip
    assert buffer.revised == same.size
    np.testing.assert_array_equal(
        env.goal_nodes_of(buffer.next_observations["achieved_goal"][same, 0]), np.full(same.size, u)
    )
    # Each stored transition keeps its own goal and gets the collision's reward for it
    np.testing.assert_array_equal(env.goal_nodes_of(buffer.observations["desired_goal"][same, 0]), goals)
    np.testing.assert_allclose(buffer.rewards[same, 0], env.collision_penalty, rtol=1e-6)
    assert (buffer.reward_infos["collision"][same, 0] == 1).all() and not buffer.dones[same, 0].any()
