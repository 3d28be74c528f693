"""DCQN's Dict replay variants beyond SB3's: lean storage (observation tables), n-step returns and the count bonus."""

from __future__ import annotations

import pickle
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from gymnasium import spaces
from stable_baselines3 import HerReplayBuffer
from stable_baselines3.common.buffers import DictReplayBuffer, NStepReplayBuffer
from stable_baselines3.common.envs import IdentityEnv
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv

from campusnav_env import CampusNavEnv, generate_campus
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.rendering.street_view import RenderSettings
from sb3_dcqn import DCQN, replay
from sb3_dcqn.observation_table import ObservationTable
from sb3_dcqn.replay import DCQNHerReplayBuffer, LeanReplay, replay_buffer_class

Lean = replay.LeanDictReplayBuffer

VIEW = spaces.Box(-10.0, 10.0, shape=(6,), dtype=np.float32)
HEADING = spaces.Box(0.0, 1.0, shape=(4,), dtype=np.float32)
SPACE = spaces.Dict({"views": VIEW, "goal_views": VIEW, "heading": HEADING})
ACTIONS = spaces.Discrete(4)
N_NODES = 7
N_INTERSECTIONS = 24  # a small campus (its views render in seconds), 96 views for 64 features


def node_obs(nodes: list[int], headings: list[int] | None = None, goal: int = 5) -> dict[str, np.ndarray]:
    """The observations of several envs (one node each): views of the node, the goal's views, the heading."""
    views = np.array([np.arange(6, dtype=np.float32) + node for node in nodes], dtype=np.float32)
    headings = headings if headings is not None else [0] * len(nodes)
    return {
        "views": views,
        "goal_views": np.repeat(np.arange(6, dtype=np.float32)[None] + goal, len(nodes), axis=0),
        "heading": np.eye(4, dtype=np.float32)[headings],
    }


def random_walk(buffers: list[Any], steps: int, n_envs: int = 1, seed: int = 0) -> None:
    """The same random walk on N_NODES nodes added to every buffer; episodes end at node 0 or after 6 steps."""
    rng = np.random.default_rng(seed)
    nodes, ages = rng.integers(0, N_NODES, n_envs), np.zeros(n_envs, dtype=int)
    for _ in range(steps):
        actions = rng.integers(0, 4, n_envs)
        next_nodes = (nodes + actions - 1) % N_NODES
        ages += 1
        dones = (next_nodes == 0) | (ages >= 6)
        infos = [
            {"TimeLimit.truncated": bool(age >= 6 and node != 0)} for age, node in zip(ages, next_nodes, strict=True)
        ]
        rewards = np.where(next_nodes == 0, 1.0, -0.01).astype(np.float32)
        obs, next_obs = node_obs(list(nodes), list(actions)), node_obs(list(next_nodes), list(actions))
        for buffer in buffers:
            buffer.add(
                {k: v.copy() for k, v in obs.items()}, {k: v.copy() for k, v in next_obs.items()},
                actions.reshape(n_envs, 1), rewards, dones, infos,
            )  # fmt: skip
        nodes = np.where(dones, rng.integers(0, N_NODES, n_envs), next_nodes)
        ages[dones] = 0


def assert_same_samples(a: Any, b: Any) -> None:
    for key in a.observations:
        np.testing.assert_allclose(a.observations[key].numpy(), b.observations[key].numpy(), rtol=0, atol=1e-7)
        np.testing.assert_allclose(
            a.next_observations[key].numpy(), b.next_observations[key].numpy(), rtol=0, atol=1e-7
        )
    np.testing.assert_array_equal(a.actions.long().numpy(), b.actions.long().numpy())
    np.testing.assert_allclose(a.rewards.numpy(), b.rewards.numpy(), rtol=1e-6)
    np.testing.assert_array_equal(a.dones.numpy(), b.dones.numpy())


def sample_seeded(buffer: Any, batch_size: int, seed: int = 0) -> Any:
    np.random.seed(seed)  # the buffers draw their indices from numpy's global RNG
    return buffer.sample(batch_size)


# --- the observation table ------------------------------------------------------------------------------------------


def test_the_table_reads_and_writes_like_the_array_it_stands_for() -> None:
    table, array = ObservationTable((6, 2, 3), np.float32), np.zeros((6, 2, 3), dtype=np.float32)
    rng = np.random.default_rng(0)
    for step in range(50):
        rows = rng.integers(0, 4, (2, 1)).astype(np.float32) * np.ones(3, dtype=np.float32)
        table[step % 6] = rows
        array[step % 6] = rows
    batch, envs = np.array([0, 5, 5, 2]), np.array([1, 0, 0, 1])
    np.testing.assert_array_equal(table[batch, envs], array[batch, envs])
    np.testing.assert_array_equal(table[batch, envs, :], array[batch, envs, :])
    np.testing.assert_array_equal(table[:4, 1], array[:4, 1])
    np.testing.assert_array_equal(table[3], array[3])
    # One row copied to several slots, and one slot written twice (the last write wins, as in numpy)
    table[np.array([1, 4]), np.array([0, 1])] = table[2, 1]
    array[np.array([1, 4]), np.array([0, 1])] = array[2, 1]
    table[np.array([0, 0]), np.array([0, 0])] = np.array([[9.0, 9.0, 9.0], [8.0, 8.0, 8.0]], dtype=np.float32)
    array[np.array([0, 0]), np.array([0, 0])] = np.array([[9.0, 9.0, 9.0], [8.0, 8.0, 8.0]], dtype=np.float32)
    np.testing.assert_array_equal(np.asarray(table), array)
    assert table.shape == array.shape and table.dtype == array.dtype and len(table) == 6
    # Each distinct row stored once, and counted by exactly the slots that hold it
    assert table.rows.n_rows == len({row.tobytes() for row in array.reshape(-1, 3)})
    assert table.rows.refs.sum() == table.ids.size
    # A read is a copy: writing to it leaves the table alone
    read = table[3, 0]
    read[:] = -1.0
    np.testing.assert_array_equal(table[3, 0], array[3, 0])


def test_rows_no_slot_holds_are_reused_so_the_table_stays_bounded() -> None:
    buffer = Lean(10, SPACE, ACTIONS, device="cpu")
    for node in range(1_000):  # never the same views twice
        obs, next_obs = node_obs([node]), node_obs([node + 1])
        buffer.add(obs, next_obs, np.array([[0]]), np.array([0.0]), np.array([False]), [{}])
    rows = buffer.observations["views"].rows
    # 10 slots x (observation, next observation), the next of one the observation of the next: 11 live views
    assert rows.n_rows == 11
    assert len(rows.rows) <= 32  # grown geometrically to the live rows, never to the 1,001 views seen
    assert buffer.observations["goal_views"].rows.n_rows == 1  # the goal's views, stored once
    np.testing.assert_array_equal(buffer.next_observations["views"][9, 0], node_obs([1_000])["views"][0])


# --- lean storage: the same samples, a fraction of the bytes --------------------------------------------------------


def drifting_walk(buffers: list[Any], steps: int, n_envs: int, start: int, seed: int = 0) -> None:
    """
    A walk whose views keep changing, added to every buffer: each step stays (shares the views) or moves 1-3 nodes on
    along an endless street (new views); episodes end after 6 steps and restart 100 nodes on. Old views leave the
    buffer for good, so a lean buffer must free their rows and reuse them. Env ``i`` starts at node
    ``start + 1_000_000 * i`` (walks from starts 10,000 apart never meet in fewer than 90 steps).
    """
    rng = np.random.default_rng(seed)
    nodes, ages = start + np.arange(n_envs) * 1_000_000, np.zeros(n_envs, dtype=int)
    for _ in range(steps):
        actions = rng.integers(0, 4, n_envs)
        next_nodes = nodes + actions
        ages += 1
        dones = ages >= 6
        infos = [{"TimeLimit.truncated": bool(done)} for done in dones]
        rewards = np.where(actions == 0, -0.01, 0.1).astype(np.float32)
        obs, next_obs = node_obs(list(nodes), list(actions)), node_obs(list(next_nodes), list(actions))
        for buffer in buffers:
            buffer.add(
                {k: v.copy() for k, v in obs.items()}, {k: v.copy() for k, v in next_obs.items()},
                actions.reshape(n_envs, 1), rewards, dones, infos,
            )  # fmt: skip
        nodes = np.where(dones, next_nodes + 100, next_nodes)
        ages[dones] = 0


@pytest.mark.parametrize("n_envs", [1, 3])
def test_lean_samples_equal_the_plain_dict_buffers_on_the_same_data(n_envs: int) -> None:
    plain = DictReplayBuffer(40, SPACE, ACTIONS, device="cpu", n_envs=n_envs)
    lean = Lean(40, SPACE, ACTIONS, device="cpu", n_envs=n_envs)
    random_walk([plain, lean], 50, n_envs=n_envs)  # on 7 nodes, wrapping around: overwritten slots too
    assert isinstance(lean.observations["views"], ObservationTable)
    assert lean.actions.dtype == np.uint8
    views = lean.observations["views"].rows
    reserved = len(views.rows)
    seen: set[bytes] = set()
    for chunk in range(10):  # 10 x 40 steps: the buffer wraps 10 times over views it never saw before
        drifting_walk([plain, lean], 40, n_envs=n_envs, start=10_000 * (chunk + 1), seed=chunk)
        seen |= {row.tobytes() for row in plain.next_observations["views"].reshape(-1, 6)}
        for seed in range(3):
            assert_same_samples(sample_seeded(lean, 64, seed), sample_seeded(plain, 64, seed))
        for key in SPACE:
            np.testing.assert_array_equal(np.asarray(lean.observations[key]), plain.observations[key])
            np.testing.assert_array_equal(np.asarray(lean.next_observations[key]), plain.next_observations[key])
        # Exactly the views some slot holds are stored, each counted by the slots holding it
        live = np.concatenate([plain.observations["views"], plain.next_observations["views"]]).reshape(-1, 6)
        assert views.n_rows == len({row.tobytes() for row in live})
        assert views.refs.sum() == 2 * lean.buffer_size * n_envs
    # The rows of views that left the buffer were reused: the reserve stays bounded by the live views
    assert len(seen) > 4 * len(views.rows)
    assert len(views.rows) <= max(reserved, 2 * 2 * lean.buffer_size * n_envs)


def test_the_lean_buffer_survives_pickle_and_dcqns_save_and_load(tmp_path: Path) -> None:
    env = DictNodes()
    model = DCQN("MultiInputPolicy", env, replay_buffer_class=Lean, learning_starts=10**6, buffer_size=500, seed=0)
    model.learn(300)
    buffer = model.replay_buffer
    assert isinstance(buffer, Lean)
    copy = pickle.loads(pickle.dumps(buffer))
    # Observations and next observations still share one table of rows per key
    assert copy.observations["views"].rows is copy.next_observations["views"].rows
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    fresh = DCQN("MultiInputPolicy", env, replay_buffer_class=Lean, learning_starts=10**6, buffer_size=500, seed=1)
    fresh.load_replay_buffer(tmp_path / "buffer.pkl")
    for loaded in (copy, fresh.replay_buffer):
        assert loaded.pos == buffer.pos
        assert_same_samples(sample_seeded(loaded, 32), sample_seeded(buffer, 32))
    fresh.learn(100, reset_num_timesteps=False)  # and keeps filling
    assert fresh.replay_buffer.pos == 400


def test_a_campusnav_transition_costs_at_most_64_bytes_at_view_dim_64(tmp_path: Path) -> None:
    env = CampusNavEnv(
        world=generate_campus(N_INTERSECTIONS, seed=1), encoder="pixels", view_dim=64,
        view_build=ViewBuild(render_settings=RenderSettings(64, 48), cache_dir=tmp_path, progress=False),
    )  # fmt: skip
    model = DCQN("MultiInputPolicy", env, replay_buffer_class=Lean, buffer_size=5_000, learning_starts=10**6, seed=0)
    model.learn(1_000)
    buffer = model.replay_buffer
    # Every per-transition array (actions, rewards, dones, timeouts, priorities) and the tables' row indices
    arrays = [value for value in vars(buffer).values() if isinstance(value, np.ndarray) and value.ndim >= 2]
    assert all(array.shape[:2] == (5_000, 1) for array in arrays)
    tables = [*buffer.observations.values(), *buffer.next_observations.values()]
    bytes_per_transition = (sum(a.nbytes for a in arrays) + sum(t.index_nbytes for t in tables)) / 5_000
    assert bytes_per_transition <= 64
    # The views table holds one row (4 x 64 float32 in compass order, 1 KB) per intersection seen, the goal's views one
    views = buffer.observations["views"].rows
    assert views.rows.shape[1] == 4 * 64 and views.n_rows <= N_INTERSECTIONS + 1  # + the empty slots' zero row
    assert buffer.observations["goal_views"].rows.n_rows == 2
    plain = DictReplayBuffer(5_000, env.observation_space, env.action_space, device="cpu")
    plain_bytes = sum(a.nbytes for d in (plain.observations, plain.next_observations) for a in d.values())
    assert plain_bytes / 5_000 > 4_000  # what SB3's buffer takes per transition: every vector twice


# --- lean storage with several envs, revision and hindsight relabelling ---------------------------------------------


def test_revision_with_lean_storage_rewrites_the_contradicted_next_observations() -> None:
    buffer = replay.LeanRevisionDictReplayBuffer(100, SPACE, ACTIONS, device="cpu")
    for _ in range(3):  # node 1 --(action 0)--> node 2, three times
        buffer.add(node_obs([1]), node_obs([2]), np.array([[0]]), np.array([-0.005]), np.array([False]), [{}])
    # The road closes: from node 1, action 0 now stays at node 1
    buffer.add(node_obs([1]), node_obs([1]), np.array([[0]]), np.array([-0.01]), np.array([False]), [{}])
    assert buffer.revised == 3
    for row in range(3):
        np.testing.assert_array_equal(buffer.next_observations["views"][row, 0], node_obs([1])["views"][0])
        assert buffer.rewards[row, 0] == np.float32(-0.01)
    # Node 1's views and the empty slots' zero row: node 2's views are held by no slot any more
    assert buffer.observations["views"].rows.n_rows == 2


def test_hindsight_relabelling_and_revision_with_lean_storage_give_the_same_samples() -> None:
    vec_env = DummyVecEnv([GoalChain, GoalChain])
    plain, lean = (
        buffer_class(60, vec_env.observation_space, vec_env.action_space, vec_env, n_envs=2)
        for buffer_class in (replay.RevisionHerReplayBuffer, replay.LeanRevisionHerReplayBuffer)
    )
    obs = vec_env.reset()
    rng = np.random.default_rng(0)
    for _ in range(40):
        actions = rng.integers(0, 2, 2)
        next_obs, rewards, dones, infos = vec_env.step(actions)
        stored = {key: value.copy() for key, value in next_obs.items()}
        for env, done in enumerate(dones):
            if done:
                for key in stored:
                    stored[key][env] = infos[env]["terminal_observation"][key]
        for buffer in (plain, lean):
            buffer.add({k: v.copy() for k, v in obs.items()}, stored, actions.reshape(2, 1), rewards, dones, infos)
        obs = next_obs
    # The road from cell 1 to cell 2 closes: moving right from cell 1 (in either env) now stays at cell 1
    eye = np.eye(5, dtype=np.float32)
    at_1 = {"observation": eye[[1, 1]], "achieved_goal": eye[[1, 1]], "desired_goal": eye[[3, 3]]}
    for buffer in (plain, lean):
        buffer.add({k: v.copy() for k, v in at_1.items()}, {k: v.copy() for k, v in at_1.items()},
                   np.array([[1], [1]]), np.array([-0.1, -0.1]), np.array([False, False]), [{}, {}])  # fmt: skip
    assert lean.revised == plain.revised > 0
    for key in lean.observations:
        np.testing.assert_array_equal(np.asarray(lean.next_observations[key]), plain.next_observations[key])
    np.testing.assert_array_equal(lean.rewards, plain.rewards)
    assert isinstance(lean.next_observations["achieved_goal"], ObservationTable)
    for seed in range(3):
        assert_same_samples(sample_seeded(lean, 64, seed), sample_seeded(plain, 64, seed))


def test_dcqn_learns_with_lean_hindsight_relabelling() -> None:
    model = DCQN(
        "MultiInputPolicy", GoalChain(), replay_buffer_class=replay.LeanHerReplayBuffer, buffer_size=1_000,
        learning_starts=50, batch_size=16, policy_kwargs=dict(net_arch=[16]), seed=0,
    )  # fmt: skip
    model.learn(120)
    assert isinstance(model.replay_buffer, DCQNHerReplayBuffer) and isinstance(model.replay_buffer, LeanReplay)
    assert model.replay_buffer.terminal_relabels  # DCQN's HER: relabelled transitions that reach their goal end


# --- n-step returns with Dict observations --------------------------------------------------------------------------


def test_n_step_returns_stop_at_a_termination_and_at_a_time_limit() -> None:
    gamma = 0.5
    buffer = replay.LeanNStepDictReplayBuffer(20, SPACE, ACTIONS, device="cpu", n_steps=3, gamma=gamma)
    # Episode 1: nodes 1 -> 2 -> 3 -> 4 -> 5, terminated at 5; episode 2: 6 -> 1 -> 2, cut by the time limit at 2
    steps = [(1, 2, 1.0, False, False), (2, 3, 2.0, False, False), (3, 4, 4.0, False, False),
             (4, 5, 8.0, True, False), (6, 1, 16.0, False, False), (1, 2, 32.0, True, True),
             (2, 3, 64.0, False, False)]  # fmt: skip
    for node, next_node, reward, done, timeout in steps:
        buffer.add(node_obs([node]), node_obs([next_node]), np.array([[0]]), np.array([reward]), np.array([done]),
                   [{"TimeLimit.truncated": timeout}])  # fmt: skip
    samples = buffer._get_samples(np.arange(7))
    # (return, discount, last node, done): the window ends at the first end, or after 3 steps, or at the newest step
    expected = [
        (1 + gamma * 2 + gamma**2 * 4, gamma**3, 4, 0.0),
        (2 + gamma * 4 + gamma**2 * 8, gamma**3, 5, 1.0),  # the termination inside the window: done, no bootstrap
        (4 + gamma * 8, gamma**2, 5, 1.0),
        (8.0, gamma, 5, 1.0),
        (16 + gamma * 32, gamma**2, 2, 0.0),  # the time limit inside the window: bootstraps from node 2
        (32.0, gamma, 2, 0.0),
        (64.0, gamma, 3, 0.0),  # the newest transition: the slot after it holds no step of this episode
    ]
    returns, discounts, last_nodes, dones = (np.array(column) for column in zip(*expected, strict=True))
    np.testing.assert_allclose(samples.rewards.numpy().ravel(), returns, rtol=1e-6)
    np.testing.assert_allclose(samples.discounts.numpy().ravel(), discounts, rtol=1e-6)
    np.testing.assert_array_equal(samples.next_observations["views"].numpy()[:, 0], last_nodes)
    np.testing.assert_array_equal(samples.dones.numpy().ravel(), dones)


def test_n_step_samples_equal_sb3s_n_step_buffer_on_the_same_data() -> None:
    box = spaces.Box(-10.0, 10.0, shape=(6,), dtype=np.float32)
    theirs = NStepReplayBuffer(30, box, ACTIONS, device="cpu", n_envs=2, n_steps=3, gamma=0.9)
    ours = replay.NStepDictReplayBuffer(
        30, spaces.Dict({"views": box}), ACTIONS, device="cpu", n_envs=2, n_steps=3, gamma=0.9
    )

    class Views:  # SB3's buffer takes the views array, ours the Dict
        def add(self, obs, next_obs, *rest) -> None:
            theirs.add(obs["views"], next_obs["views"], *rest)

    class OnlyViews:
        def add(self, obs, next_obs, *rest) -> None:
            ours.add({"views": obs["views"]}, {"views": next_obs["views"]}, *rest)

    random_walk([Views(), OnlyViews()], 45, n_envs=2)  # wrapped around
    for seed in range(3):
        a, b = sample_seeded(ours, 64, seed), sample_seeded(theirs, 64, seed)
        np.testing.assert_allclose(a.observations["views"].numpy(), b.observations.numpy(), rtol=0, atol=1e-7)
        np.testing.assert_allclose(a.next_observations["views"].numpy(), b.next_observations.numpy(), atol=1e-7)
        np.testing.assert_allclose(a.rewards.numpy(), b.rewards.numpy(), rtol=1e-6)
        np.testing.assert_allclose(a.discounts.numpy(), b.discounts.numpy(), rtol=1e-6)
        np.testing.assert_array_equal(a.dones.numpy(), b.dones.numpy())


def test_dcqn_with_n_steps_and_a_dict_space_uses_its_own_buffer(recwarn: pytest.WarningsRecorder) -> None:
    model = DCQN(
        "MultiInputPolicy",
        DictNodes(),
        n_steps=3,
        gamma=0.9,
        buffer_size=1_000,
        learning_starts=50,
        batch_size=16,
        seed=0,
    )
    assert type(model.replay_buffer) is replay.NStepDictReplayBuffer
    assert (model.replay_buffer.n_steps, model.replay_buffer.gamma) == (3, 0.9)
    assert not [w for w in recwarn if "n_steps" in str(w.message)]  # SB3's "n_steps is ignored" does not apply
    model.learn(120)
    assert model.replay_buffer.sample(8).discounts is not None


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(n_steps=3, replay_buffer_class=HerReplayBuffer), r"hindsight relabelling .* n-step returns"),
        (
            dict(n_steps=3, replay_buffer_class=replay.RevisionDictReplayBuffer),
            r"n-step returns .* experience revision",
        ),
        (dict(replay_buffer_class=HerReplayBuffer, blocked_action_target=True, n_steps=2), r"hindsight .* n-step"),
    ],
)
def test_dcqn_refuses_what_its_dict_buffer_cannot_do(kwargs: dict[str, Any], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        DCQN("MultiInputPolicy", GoalChain(), **kwargs)


def test_lean_storage_needs_a_dict_space_and_n_steps_no_priorities() -> None:
    with pytest.raises(ValueError, match="Dict observations only"):
        replay_buffer_class("lean", base="Box")
    with pytest.raises(ValueError, match="Dict observations only"):  # the mix-in's own check, on any base
        type("LeanBox", (LeanReplay, replay.DCQNReplayBuffer), {})(10, spaces.Box(0, 1, (3,)), ACTIONS)
    with pytest.raises(ValueError, match=r"n-step returns \(nstep\) does not combine with prioritized replay"):
        replay_buffer_class("nstep", "prioritized")


# --- the count bonus ------------------------------------------------------------------------------------------------


def test_the_count_bonus_is_scaled_by_one_over_the_root_of_the_visits() -> None:
    buffer = replay.LeanCountBonusDictReplayBuffer(4, SPACE, ACTIONS, device="cpu", count_bonus=0.3)
    arrivals = [2, 3, 2, 2, 3, 4]  # node 2 reached 3 times, node 3 twice, node 4 once; the buffer of 4 wraps
    for node in arrivals:
        buffer.add(node_obs([1]), node_obs([node]), np.array([[0]]), np.array([-0.01]), np.array([False]), [{}])
    samples = buffer._get_samples(np.arange(4))  # slots hold the arrivals at 3, 4, 2, 2 (the first two overwritten)
    visits = np.array([2, 1, 3, 3])
    np.testing.assert_array_equal(buffer.visits(np.arange(4), np.zeros(4, dtype=int)), visits)
    np.testing.assert_allclose(samples.rewards.numpy().ravel(), -0.01 + 0.3 / np.sqrt(visits), rtol=1e-6)
    # Another heading at the same node is another observation, counted apart
    buffer.add(node_obs([1]), node_obs([2], headings=[1]), np.array([[0]]), np.array([0.0]), np.array([False]), [{}])
    assert buffer.visits(np.array([2]), np.array([0]))[0] == 1


def test_dcqn_passes_the_count_bonus_to_its_dict_buffer() -> None:
    model = DCQN(
        "MultiInputPolicy", DictNodes(), replay_buffer_class=replay.CountBonusDictReplayBuffer,
        replay_buffer_kwargs=dict(count_bonus=0.05), buffer_size=1_000, learning_starts=10**6, seed=0,
    )  # fmt: skip
    model.learn(50)
    assert model.replay_buffer.count_bonus == 0.05 and not isinstance(model.replay_buffer, LeanReplay)


# --- learning -------------------------------------------------------------------------------------------------------


class DictNodes(gym.ObservationWrapper):
    """SB3's IdentityEnv (say the state you see) with a Dict observation that repeats: the state's views, a goal."""

    def __init__(self) -> None:
        super().__init__(IdentityEnv(dim=4, ep_length=10))
        self.env.action_space.seed(0)  # IdentityEnv draws its states from it: the same episodes in every run
        view = spaces.Box(0.0, 1.0, (8,), np.float32)
        self.observation_space = spaces.Dict({"views": view, "goal_views": view})

    def observation(self, observation: Any) -> dict[str, np.ndarray]:
        views = np.zeros(8, dtype=np.float32)
        views[int(observation)] = 1.0
        return {"views": views, "goal_views": np.full(8, 0.5, dtype=np.float32)}


def learner(**kwargs: Any) -> DCQN:
    return DCQN(
        "MultiInputPolicy", DictNodes(), learning_rate=3e-3, learning_starts=100, buffer_size=5_000, batch_size=32,
        gamma=0.0, target_update_interval=100, exploration_fraction=0.5, policy_kwargs=dict(net_arch=[32]), seed=0,
        **kwargs,
    )  # fmt: skip


def test_dcqn_learns_with_lean_replay_exactly_as_with_the_plain_buffer() -> None:
    # One after the other: each seeds numpy's global RNG when it is built and draws from it while it learns
    lean = learner(replay_buffer_class=Lean).learn(800)
    plain = learner().learn(800)
    for a, b in zip(lean.q_net.parameters(), plain.q_net.parameters(), strict=True):
        assert th.allclose(a, b, rtol=0, atol=1e-6)  # the same samples, so the same updates
    mean_reward, _ = evaluate_policy(lean, DummyVecEnv([lambda: Monitor(DictNodes())]), 10)
    assert mean_reward == pytest.approx(10.0)


class GoalChain(gym.Env):
    """Cells 0..4 in a row, action 1 right, 0 left; a goal env (achieved and desired goal) with compute_terminated."""

    def __init__(self) -> None:
        cell = spaces.Box(0.0, 1.0, (5,), np.float32)
        self.observation_space = spaces.Dict({"observation": cell, "achieved_goal": cell, "desired_goal": cell})
        self.action_space = spaces.Discrete(2)
        self.cell, self.goal, self.t = 0, 3, 0

    def _obs(self) -> dict[str, np.ndarray]:
        eye = np.eye(5, dtype=np.float32)
        return {"observation": eye[self.cell], "achieved_goal": eye[self.cell], "desired_goal": eye[self.goal]}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        self.cell, self.t = 0, 0
        return self._obs(), {}

    def step(self, action: int) -> tuple[dict, float, bool, bool, dict]:
        self.cell = int(np.clip(self.cell + (1 if action == 1 else -1), 0, 4))
        self.t += 1
        reached = self.cell == self.goal
        return self._obs(), 1.0 if reached else -0.1, reached, self.t >= 8 and not reached, {}

    def compute_reward(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        return np.where(np.all(achieved_goal == desired_goal, axis=-1), 1.0, -0.1)

    def compute_terminated(self, achieved_goal: np.ndarray, desired_goal: np.ndarray, info: Any) -> np.ndarray:
        return np.all(achieved_goal == desired_goal, axis=-1)
