"""Experience revision without the goal keys (``goal_keys``): a closure seen on one goal's way revises every goal's.

CampusNav-v0's observations carry the goal (``goal_views``) in every step. Matched on every key, a collision on the way
to goal A revises goal A's stale copies only; with ``goal_keys=("goal_views",)`` it revises every goal's, and a
reopened road (a move, whose reward and termination are the goal's own) revises the same goal's copies only.
"""

from __future__ import annotations

import pickle
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from stable_baselines3.common.envs import BitFlippingEnv
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_dcqn import DCQN, replay
from sb3_dcqn.replay import replay_buffer_class

RevisionDict = replay_buffer_class("revision", base="Dict")
LeanRevisionDict = replay_buffer_class("lean", "revision", base="Dict")
GOAL_KEYS = ("goal_views",)

VIEW = spaces.Box(-20.0, 20.0, shape=(8,), dtype=np.float32)
SPACE = spaces.Dict({"views": VIEW, "goal_views": VIEW, "heading": spaces.Box(0.0, 1.0, shape=(4,), dtype=np.float32)})
ACTIONS = spaces.Discrete(4)
STEP, COLLISION, ARRIVAL = -0.005, -0.01, 1.0  # CampusNav-like rewards
A, B, C = 5, 6, 2  # goals (node numbers); C is node 2, reached along the road 1 -> 2


def views(node: int) -> np.ndarray:
    return np.arange(8, dtype=np.float32) + node


def obs_of(nodes: list[int], goals: list[int], headings: list[int] | None = None) -> dict[str, np.ndarray]:
    """The observations of several envs: the views of each env's node, of its goal, its heading."""
    headings = headings if headings is not None else [0] * len(nodes)
    return {
        "views": np.stack([views(node) for node in nodes]),
        "goal_views": np.stack([views(goal) for goal in goals]),
        "heading": np.eye(4, dtype=np.float32)[headings],
    }


def step(buffer: Any, node: int, goal: int, action: int, next_node: int, reward: float, done: bool = False) -> None:
    """One env's transition ``node --action--> next_node`` on the way to ``goal``."""
    buffer.add(obs_of([node], [goal]), obs_of([next_node], [goal]), np.array([[action]]), np.array([reward]),
               np.array([done]), [{}])  # fmt: skip


def drive(buffer: Any) -> None:
    """Rows 0-3: the road 1 -> 2 (action 0) driven for goals B, B, C (arriving) and A; rows 4-5: other moves."""
    step(buffer, 1, B, 0, 2, STEP)
    step(buffer, 1, B, 0, 2, STEP)
    step(buffer, 1, C, 0, 2, ARRIVAL, done=True)  # goal C reached along the road
    step(buffer, 1, A, 0, 2, STEP)
    step(buffer, 1, B, 1, 3, STEP)  # another road from node 1
    step(buffer, 2, B, 0, 4, STEP)


ROAD, OTHERS = [0, 1, 2, 3], [4, 5]


def test_goal_a_collision_rewrites_every_goals_stored_moves_through_the_road() -> None:
    buffer = RevisionDict(100, SPACE, ACTIONS, device="cpu", goal_keys=GOAL_KEYS)
    drive(buffer)
    # An arrival and a pass-through to the same node are the same road, not a contradiction
    assert buffer.revised == 0
    before = {key: array.copy() for key, array in buffer.next_observations.items()}
    step(buffer, 1, A, 0, 1, COLLISION)  # row 6: on goal A's way the road 1 -> 2 is now closed
    assert buffer.revised == 4
    for row in ROAD:
        # Copies, exact: each stale copy now stays at its own node, with its own goal and heading
        np.testing.assert_array_equal(buffer.next_observations["views"][row, 0], buffer.observations["views"][row, 0])
        np.testing.assert_array_equal(
            buffer.next_observations["heading"][row, 0], buffer.observations["heading"][row, 0]
        )
        np.testing.assert_array_equal(buffer.next_observations["goal_views"][row, 0], before["goal_views"][row, 0])
        assert buffer.rewards[row, 0] == pytest.approx(COLLISION, abs=1e-7)
        assert buffer.dones[row, 0] == 0.0
    np.testing.assert_array_equal(buffer.next_observations["goal_views"][1, 0], views(B))  # goal B's kept
    np.testing.assert_array_equal(buffer.next_observations["goal_views"][2, 0], views(C))
    # The other roads are untouched
    for row in OTHERS:
        for key, array in buffer.next_observations.items():
            np.testing.assert_array_equal(array[row, 0], before[key][row, 0])
    assert buffer.rewards[4, 0] == pytest.approx(STEP, abs=1e-7)
    # Goal C's sample is no longer terminal: the road it arrived along is closed
    samples = buffer._get_samples(np.array([2]))
    assert samples.dones.item() == 0.0 and samples.rewards.item() == pytest.approx(COLLISION, abs=1e-7)


def test_without_goal_keys_the_collision_revises_its_own_goals_copies_only() -> None:
    buffer = RevisionDict(100, SPACE, ACTIONS, device="cpu")
    drive(buffer)
    step(buffer, 1, A, 0, 1, COLLISION)
    assert buffer.revised == 1  # row 3, goal A's; goal B's and C's copies still drive through
    np.testing.assert_array_equal(buffer.next_observations["views"][0, 0], views(2))
    np.testing.assert_array_equal(buffer.next_observations["views"][3, 0], views(1))


def test_a_reopened_road_rewrites_the_same_goals_copies_only() -> None:
    buffer = RevisionDict(100, SPACE, ACTIONS, device="cpu", goal_keys=GOAL_KEYS)
    drive(buffer)
    step(buffer, 1, A, 0, 1, COLLISION)  # row 6: closed for every goal
    assert buffer.revised == 4
    step(buffer, 1, B, 0, 2, STEP)  # row 7: goal B drives through again: the road reopened
    assert buffer.revised == 4 + 2  # goal B's two copies (rows 0, 1) move again
    for row in (0, 1):
        np.testing.assert_array_equal(buffer.next_observations["views"][row, 0], views(2))
        np.testing.assert_array_equal(buffer.next_observations["goal_views"][row, 0], views(B))
        assert buffer.rewards[row, 0] == pytest.approx(STEP, abs=1e-7) and buffer.dones[row, 0] == 0.0
    # Goals C and A keep the collision: a move's reward and termination are its goal's own (C would arrive)
    for row in (2, 3, 6):
        np.testing.assert_array_equal(buffer.next_observations["views"][row, 0], views(1))
        assert buffer.rewards[row, 0] == pytest.approx(COLLISION, abs=1e-7)
    step(buffer, 1, C, 0, 2, ARRIVAL, done=True)  # row 8: goal C arrives along it again
    assert buffer.revised == 4 + 2 + 1
    np.testing.assert_array_equal(buffer.next_observations["views"][2, 0], views(2))
    assert buffer.rewards[2, 0] == pytest.approx(ARRIVAL, abs=1e-7) and buffer.dones[2, 0] == 1.0
    # A collision on the same road again (goal A): every goal's moves, goal B's new one included
    step(buffer, 1, A, 0, 1, COLLISION)  # row 9
    assert buffer.revised == 4 + 2 + 1 + 5  # rows 0, 1, 2, 7, 8 (rows 3 and 6 already collide)


def test_a_terminal_stay_is_the_goals_own() -> None:
    # Staying where it is and ending the episode (e.g. stopping at the goal) is not a collision: same goal only
    buffer = RevisionDict(100, SPACE, ACTIONS, device="cpu", goal_keys=GOAL_KEYS)
    step(buffer, 2, B, 3, 4, STEP)
    step(buffer, 2, A, 3, 4, STEP)
    step(buffer, 2, A, 3, 2, ARRIVAL, done=True)
    assert buffer.revised == 1  # goal A's row 1; goal B's move is left
    np.testing.assert_array_equal(buffer.next_observations["views"][0, 0], views(4))
    np.testing.assert_array_equal(buffer.next_observations["views"][1, 0], views(2))


def closing_world(buffers: list[Any], steps: int, n_envs: int = 1, seed: int = 0) -> None:
    """
    The same history added to every buffer: a ring of 7 nodes with roads that close and reopen, goals drawn per
    episode, arrival at the goal ends the episode, a time limit of 8 steps.
    """
    rng = np.random.default_rng(seed)
    open_roads = np.ones((7, 4), dtype=bool)
    nodes, goals, ages = rng.integers(0, 7, n_envs), rng.integers(0, 7, n_envs), np.zeros(n_envs, dtype=int)
    headings = np.zeros(n_envs, dtype=int)
    for t in range(steps):
        if t % 15 == 0:  # a road closes or reopens
            open_roads[rng.integers(0, 7), rng.integers(0, 4)] ^= True
        actions = rng.integers(0, 4, n_envs)
        moved = open_roads[nodes, actions]
        next_nodes = np.where(moved, (nodes + actions - 1) % 7, nodes)
        arrived = moved & (next_nodes == goals)
        rewards = np.where(arrived, ARRIVAL, np.where(moved, STEP, COLLISION)).astype(np.float32)
        ages += 1
        dones = arrived | (ages >= 8)
        infos = [{"TimeLimit.truncated": bool(age >= 8 and not a)} for age, a in zip(ages, arrived, strict=True)]
        obs = obs_of(list(nodes), list(goals), list(headings))
        next_obs = obs_of(list(next_nodes), list(goals), list(headings))
        for buffer in buffers:
            buffer.add({k: v.copy() for k, v in obs.items()}, {k: v.copy() for k, v in next_obs.items()},
                       actions.reshape(n_envs, 1), rewards, dones, infos)  # fmt: skip
        restart = rng.integers(0, 7, n_envs)
        nodes = np.where(dones, restart, next_nodes)
        goals = np.where(dones, rng.integers(0, 7, n_envs), goals)
        ages[dones] = 0


def assert_same_buffers(a: Any, b: Any) -> None:
    """Stored transitions and seeded samples equal (copies of the same inputs, exact)."""
    assert a.revised == b.revised
    for key in a.observations:
        np.testing.assert_array_equal(np.asarray(a.next_observations[key]), np.asarray(b.next_observations[key]))
    for name in ("rewards", "dones", "timeouts"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    for seed in range(3):
        np.random.seed(seed)
        first = a.sample(64)
        np.random.seed(seed)
        second = b.sample(64)
        for key in first.observations:
            np.testing.assert_array_equal(first.next_observations[key].numpy(), second.next_observations[key].numpy())
        np.testing.assert_array_equal(first.rewards.numpy(), second.rewards.numpy())
        np.testing.assert_array_equal(first.dones.numpy(), second.dones.numpy())


def test_the_default_revises_exactly_as_without_the_argument() -> None:
    plain = RevisionDict(120, SPACE, ACTIONS, device="cpu")  # wraps around: overwritten slots leave the index
    default = RevisionDict(120, SPACE, ACTIONS, device="cpu", goal_keys=())
    goal_free = RevisionDict(120, SPACE, ACTIONS, device="cpu", goal_keys=GOAL_KEYS)
    closing_world([plain, default, goal_free], steps=300)
    assert plain.revised > 0
    assert_same_buffers(plain, default)
    assert goal_free.revised > plain.revised  # collisions seen for one goal reach the other goals' copies


@pytest.mark.parametrize("n_envs", [1, 3])
def test_lean_storage_with_goal_free_revision_stores_the_same(n_envs: int) -> None:
    assert LeanRevisionDict is replay.LeanRevisionDictReplayBuffer
    plain = RevisionDict(100, SPACE, ACTIONS, device="cpu", n_envs=n_envs, goal_keys=GOAL_KEYS)
    lean = LeanRevisionDict(100, SPACE, ACTIONS, device="cpu", n_envs=n_envs, goal_keys=GOAL_KEYS)
    closing_world([plain, lean], steps=200, n_envs=n_envs, seed=1)
    assert lean.revised > 0 and lean.goal_keys == GOAL_KEYS
    assert_same_buffers(plain, lean)


def test_a_collision_in_one_env_revises_the_copies_of_every_env() -> None:
    buffer = RevisionDict(50, SPACE, ACTIONS, device="cpu", n_envs=2, goal_keys=GOAL_KEYS)
    moves = np.array([[0], [0]])
    # Both envs drive the road 1 -> 2, env 0 for goal A, env 1 for goal B
    for _ in range(2):
        buffer.add(obs_of([1, 1], [A, B]), obs_of([2, 2], [A, B]), moves, np.array([STEP, STEP]),
                   np.array([False, False]), [{}, {}])  # fmt: skip
    # Env 0 collides on goal A's way while env 1 drives elsewhere for goal B
    buffer.add(obs_of([1, 3], [A, B]), obs_of([1, 4], [A, B]), moves, np.array([COLLISION, STEP]),
               np.array([False, False]), [{}, {}])  # fmt: skip
    assert buffer.revised == 4
    for row in (0, 1):
        for env, goal in ((0, A), (1, B)):
            np.testing.assert_array_equal(buffer.next_observations["views"][row, env], views(1))
            np.testing.assert_array_equal(buffer.next_observations["goal_views"][row, env], views(goal))
            assert buffer.rewards[row, env] == pytest.approx(COLLISION, abs=1e-7)
    np.testing.assert_array_equal(buffer.next_observations["views"][2, 1], views(4))  # env 1's own move, left


def test_goal_free_revision_survives_pickling_and_buffers_saved_before_it_load() -> None:
    buffer = RevisionDict(100, SPACE, ACTIONS, device="cpu", goal_keys=GOAL_KEYS)
    drive(buffer)
    loaded = pickle.loads(pickle.dumps(buffer))
    step(loaded, 1, A, 0, 1, COLLISION)
    assert loaded.goal_keys == GOAL_KEYS and loaded.revised == 4
    # A buffer pickled before goal_keys existed: every key matched, as it was
    old = RevisionDict(100, SPACE, ACTIONS, device="cpu")
    drive(old)
    state = dict(old.__dict__)
    del state["goal_keys"], state["_goal_of"]
    revived = RevisionDict.__new__(RevisionDict)
    revived.__setstate__(state)
    step(revived, 1, A, 0, 1, COLLISION)
    assert revived.goal_keys == () and revived.revised == 1


class GoalViewsWalk(gym.Env):
    """A tiny env with CampusNav-v0's observation keys, to build DCQN with goal-free revision."""

    observation_space = SPACE
    action_space = ACTIONS

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict[str, np.ndarray], dict]:
        super().reset(seed=seed)
        self.node = 1
        return self._obs(), {}

    def step(self, action: int) -> tuple[dict[str, np.ndarray], float, bool, bool, dict]:
        self.node = self.node if action == 0 else (self.node + 1) % 7  # action 0: a closed road
        return self._obs(), STEP, self.node == A, False, {}

    def _obs(self) -> dict[str, np.ndarray]:
        return {key: value[0] for key, value in obs_of([self.node], [A]).items()}


def test_dcqn_passes_goal_keys_to_a_revision_buffer() -> None:
    model = DCQN(
        "MultiInputPolicy", GoalViewsWalk(), replay_buffer_class=replay.RevisionDictReplayBuffer,
        replay_buffer_kwargs=dict(goal_keys=GOAL_KEYS), learning_starts=40, buffer_size=200, seed=0,
        policy_kwargs=dict(net_arch=[8]),
    )  # fmt: skip
    model.learn(60)
    buffer = model.replay_buffer
    assert buffer.goal_keys == GOAL_KEYS
    assert buffer.revised == 0  # the walk never changed: nothing it stored contradicts anything else
    # The road 1 -> 2 closes: one bump, seen on the way to goal B, revises every stored move along it (goal A's)
    stored = buffer.observations["views"][: buffer.pos, 0]
    along = int(((stored == views(1)).all(axis=1) & (buffer.actions[: buffer.pos, 0, 0] == 1)).sum())
    assert along > 0
    step(buffer, 1, B, 1, 1, COLLISION)
    assert buffer.revised == along


def test_goal_keys_that_do_not_fit_the_buffer_are_named() -> None:
    assert RevisionDict(10, SPACE, ACTIONS, goal_keys=["goal_views"]).goal_keys == GOAL_KEYS  # a YAML list too
    with pytest.raises(ValueError, match=r"goal key 'goal' is not in the observation space.*'goal_views'"):
        RevisionDict(10, SPACE, ACTIONS, device="cpu", goal_keys=("goal",))
    with pytest.raises(ValueError, match=r"goal_keys is a sequence of keys, got the string 'goal_views'"):
        RevisionDict(10, SPACE, ACTIONS, device="cpu", goal_keys="goal_views")
    with pytest.raises(ValueError, match=r"leave no key .* to tell observations apart"):
        RevisionDict(10, SPACE, ACTIONS, device="cpu", goal_keys=("views", "goal_views", "heading"))
    with pytest.raises(ValueError, match=r"RevisionReplayBuffer: goal_keys=\('goal_views',\) needs Dict observations"):
        replay_buffer_class("revision", base="Box")(10, VIEW, ACTIONS, device="cpu", goal_keys=GOAL_KEYS)
    # Hindsight relabelling leaves desired_goal out itself: that one key, or none
    vec_env = DummyVecEnv([lambda: BitFlippingEnv(n_bits=4)])
    her = replay.RevisionHerReplayBuffer
    args = (10, vec_env.observation_space, vec_env.action_space, vec_env)
    assert her(*args, goal_keys=("desired_goal",)).goal_keys == ("desired_goal",)
    with pytest.raises(ValueError, match=r"the goal left out of the match is 'desired_goal'.*\('achieved_goal',\)"):
        her(*args, goal_keys=("achieved_goal",))
