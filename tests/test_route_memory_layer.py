"""The route memory as a layer: DQN, QR-DQN and DCQN wear it alike; what it does, what it names, what it saves."""

from __future__ import annotations

import pickle
import subprocess
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from sb3_contrib import QRDQN
from stable_baselines3 import DQN, PPO, HerReplayBuffer
from stable_baselines3.common.envs import BitFlippingEnv
from stable_baselines3.common.evaluation import evaluate_policy

from campusnav_env import CampusNavEnv
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.goal_env import CampusNavGoalEnv
from campusnav_env.maps.navigation import RoadClosureError
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.route_evaluation import evaluate_routes
from sb3_dcqn import DCQN, RouteMemoryDCQN, RouteMemoryDQN, algorithm_name, with_route_memory
from sb3_dcqn.place_frame import place_frame_of
from sb3_dcqn.replay import DCQNHerReplayBuffer, RevisionDictReplayBuffer, RevisionHerReplayBuffer
from sb3_dcqn.replay.revision import RevisionReplay
from sb3_dcqn.route_memory import UntriedExplorer, batch_of_one
from sb3_dcqn.route_memory.layer import LOOP_REPEATS

pytestmark = pytest.mark.usefixtures("shared_feature_cache")

SMALL = {"encoder": "pixels", "view_build": ViewBuild(render_settings=RenderSettings(64, 48), progress=False)}
NET = {"policy_kwargs": {"net_arch": [32]}}
QUANTILES = {"policy_kwargs": {"net_arch": [32], "n_quantiles": 10}}  # QR-DQN's, small: its default is 200
ROOT = Path(__file__).resolve().parents[1]
RouteMemoryQRDQN = with_route_memory(QRDQN)
# The memory's behaviour tests run for every algorithm that wears it
WEARERS = pytest.mark.parametrize(
    "wearer", [RouteMemoryDCQN, RouteMemoryDQN], ids=lambda cls: algorithm_name(cls, for_files=True)
)


@pytest.fixture(scope="module")
def plain_env() -> CampusNavEnv:
    return CampusNavEnv(goals=["Dreese Lab", "Cinema"], **SMALL)


def small(wearer: type) -> dict[str, Any]:
    """Small networks for a test: QR-DQN's with few quantiles."""
    return QUANTILES if issubclass(wearer, QRDQN) else NET


def store(model: Any, env: gym.Env, action: int, reset: dict[str, Any] | None = None) -> dict[str, Any]:
    """One real step of ``env`` (reset with ``reset`` options first, where given), stored by the model as its rollouts
    store one; returns the step's info."""
    observation, _ = env.reset(options=reset)
    following, reward, terminated, truncated, info = env.step(action)
    model._last_obs = batch_of_one(observation)
    model._store_transition(
        model.replay_buffer,
        np.array([action]),
        batch_of_one(following),
        np.array([reward]),
        np.array([terminated or truncated]),
        [info],
    )
    return info


def closable(env: CampusNavEnv, u: int, v: int) -> bool:
    """Whether the road u-v can close without cutting a goal off (it is left open)."""
    try:
        env.close_road(u, v)
    except RoadClosureError:
        return False
    env.reopen_road(u, v)
    return True


# ----------------------------------------------------------------------------------------------- the classes
def test_the_classes_are_made_once_named_by_their_algorithm_and_pickle() -> None:
    assert with_route_memory(DQN) is RouteMemoryDQN and with_route_memory(DCQN) is RouteMemoryDCQN
    assert with_route_memory(QRDQN) is RouteMemoryQRDQN and with_route_memory(RouteMemoryDQN) is RouteMemoryDQN
    assert issubclass(RouteMemoryDQN, DQN) and issubclass(RouteMemoryQRDQN, QRDQN)
    assert RouteMemoryQRDQN.__name__ == "RouteMemoryQRDQN"
    for made in (RouteMemoryDQN, RouteMemoryDCQN, RouteMemoryQRDQN):
        assert pickle.loads(pickle.dumps(made)) is made
    with pytest.raises(ValueError, match=r"discrete off-policy SB3 algorithm class .* got <class '.*PPO'>"):
        with_route_memory(PPO)


def test_names_say_what_ran_and_the_tensorboard_run_is_named_so(tmp_path: Path) -> None:
    assert [algorithm_name(cls) for cls in (DCQN, DQN, RouteMemoryDCQN, RouteMemoryDQN, RouteMemoryQRDQN)] == [
        "DCQN",
        "DQN",
        "DCQN + memory",
        "DQN + memory",
        "QRDQN + memory",
    ]
    model = RouteMemoryDQN("MlpPolicy", "FrozenLake-v1", learning_starts=20, tensorboard_log=str(tmp_path), **NET)
    assert algorithm_name(model) == "DQN + memory" and repr(model) == "<RouteMemoryDQN: DQN + memory>"
    model.learn(60)
    assert [path.name for path in tmp_path.iterdir()] == ["DQN-memory_1"]
    off = RouteMemoryDQN("MlpPolicy", "FrozenLake-v1", route_memory=False)
    assert off.memory is None and algorithm_name(off) == "DQN" and algorithm_name(off, for_files=True) == "DQN"


def test_unknown_settings_are_named_with_the_known_ones() -> None:
    with pytest.raises(
        ValueError, match=r"unknown settings \['max_state'\]; known: explore, success_reward, .*max_states"
    ):
        RouteMemoryDCQN("MlpPolicy", "CartPole-v1", route_memory={"max_state": 3})
    with pytest.raises(ValueError, match="route_memory must be True, False or a dict of settings, got 'yes'"):
        RouteMemoryDQN("MlpPolicy", "CartPole-v1", route_memory="yes")
    with pytest.raises(TypeError, match="route_memory"):  # DCQN itself is DQN's constructor: the memory is a layer
        DCQN("MlpPolicy", "CartPole-v1", route_memory=True)


def test_a_model_wearing_the_memory_loads_in_a_fresh_process(tmp_path: Path) -> None:
    models = {}
    for name, wearer in (("dqn", RouteMemoryDQN), ("qrdqn", RouteMemoryQRDQN)):
        model = wearer("MlpPolicy", "FrozenLake-v1", learning_starts=50, seed=0, **small(wearer))
        model.learn(300)
        model.save(tmp_path / name)
        models[name] = model
    (tmp_path / "class.pkl").write_bytes(pickle.dumps(RouteMemoryQRDQN))
    script = (
        "import pickle, sys, numpy as np\n"
        "from sb3_dcqn import RouteMemoryDQN\n"
        "qrdqn_class = pickle.loads(open(sys.argv[1] + '/class.pkl', 'rb').read())  # made anew, by its name\n"
        "for name, cls in (('dqn', RouteMemoryDQN), ('qrdqn', qrdqn_class)):\n"
        "    model = cls.load(sys.argv[1] + '/' + name)\n"
        "    actions = model.predict(np.arange(16), deterministic=True)[0]\n"
        "    print(name, type(model).__name__, model.memory.n_states, ' '.join(map(str, actions)))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", script, str(tmp_path)], cwd=ROOT, capture_output=True, text=True, check=True
    )
    lines = done.stdout.strip().splitlines()
    for line, (name, model) in zip(lines, models.items(), strict=True):
        actions = " ".join(map(str, model.predict(np.arange(16), deterministic=True)[0]))
        assert line == f"{name} {type(model).__name__} {model.memory.n_states} {actions}"


# ----------------------------------------------------------------------------------------------- acting with it
@pytest.mark.parametrize(
    "wearer", [RouteMemoryDCQN, RouteMemoryDQN, RouteMemoryQRDQN], ids=lambda cls: algorithm_name(cls, for_files=True)
)
def test_the_memory_reaches_frozen_lakes_goal_saves_with_the_model_and_is_off_for_the_bare_class(
    wearer: type, tmp_path: Path
) -> None:
    env = gym.make("FrozenLake-v1", is_slippery=False, map_name="8x8")
    # FrozenLake gives no is_success: its goal is the reward above success_reward
    model = wearer(
        "MlpPolicy",
        env,
        route_memory={"success_reward": 0.0},
        learning_starts=100,
        exploration_fraction=1.0,
        seed=0,
        **small(wearer),
    )
    model.learn(3_000)
    observation, _ = env.reset(seed=0)
    for _ in range(30):
        action, _ = model.predict(observation, deterministic=True)
        observation, reward, terminated, truncated, _ = env.step(int(action))
        if terminated or truncated:
            break
    assert reward == 1.0
    batch = np.arange(64)
    model.save(tmp_path / "lake.zip")
    loaded = wearer.load(tmp_path / "lake.zip")  # no replay buffer: the memory is in the model's file
    np.testing.assert_array_equal(
        loaded.predict(batch, deterministic=True)[0], model.predict(batch, deterministic=True)[0]
    )
    assert loaded.memory.n_states == model.memory.n_states > 0
    bare = wearer.bare_class("MlpPolicy", env, learning_starts=10, seed=0, **small(wearer))
    bare.learn(200)
    assert not hasattr(bare, "memory")
    np.testing.assert_array_equal(
        bare.predict(batch, deterministic=True)[0], bare.policy.predict(batch, deterministic=True)[0]
    )


@WEARERS
def test_the_settings_reach_the_memory_and_nothing_is_read_from_the_envs_frame_silently(
    wearer: type, plain_env: CampusNavEnv
) -> None:
    model = wearer(
        "MultiInputPolicy",
        plain_env,
        route_memory={"explore": False, "success_reward": -0.5, "max_states": 77, "retry_after": 9},
        learning_starts=10,
        **NET,
    )
    memory = model.memory
    assert (memory.max_states, memory.retry_after, model._success_reward) == (77, 9, -0.5)
    assert memory.place_frame == place_frame_of(plain_env) and not model.explores_untried
    if wearer is RouteMemoryDCQN:  # the critics score compass slots only where policy_kwargs say so
        assert model.policy.q_net.heading_key is None
        slots = wearer("MultiInputPolicy", plain_env, policy_kwargs={"heading_key": "heading", "net_arch": [8]})
        assert slots.policy.q_net.heading_key == "heading"


@WEARERS
def test_a_hindsight_buffer_gains_revision_and_the_goal_pictures_are_remembered(wearer: type) -> None:
    env = CampusNavGoalEnv(**SMALL)
    model = wearer("MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, learning_starts=250, **NET)
    # A closure the memory learns stops the stale transitions through it voting in the algorithm's replay too
    assert type(model.replay_buffer) is RevisionHerReplayBuffer
    assert isinstance(model.replay_buffer, DCQNHerReplayBuffer)
    model.learn(300)
    memory = model.memory
    node = next(
        n for n in range(env.graph.n_nodes) if memory.state_of(env.observation_at(n, env.headings_at(n)[0], n)) >= 0
    )
    here = env.observation_at(node, env.headings_at(node)[0], node)
    assert memory.state_of(here) in memory.goal_states(here)  # a visited place pictures its own goal


@WEARERS
def test_the_memory_on_bit_flipping_reaches_visited_goals_in_hamming_steps(wearer: type) -> None:
    env = BitFlippingEnv(n_bits=4, continuous=False, max_steps=4)
    model = wearer("MultiInputPolicy", env, learning_starts=200, seed=0, **NET)
    model.learn(1_500)
    reached = asked = 0
    for episode in range(12):
        observation, _ = env.reset(seed=episode)
        distance = int(np.abs(observation["observation"] - observation["desired_goal"]).sum())
        asked += distance > 0  # a goal drawn equal to the start ends the episode at any step
        for step in range(1, 5):
            action, _ = model.predict(observation, deterministic=True)
            observation, _, terminated, _, _ = env.step(action)
            if terminated:
                reached += distance > 0 and step == distance
                break
    assert asked >= 8 and reached == asked


@WEARERS
def test_the_memory_routes_every_start_and_heading_of_the_places_it_saw(wearer: type, plain_env: CampusNavEnv) -> None:
    model = wearer("MultiInputPolicy", plain_env, learning_starts=100, seed=0, **NET)
    model.learn(600)
    with_memory = evaluate_routes(plain_env, lambda obs: model.predict(obs, deterministic=True)[0], max_steps=40)
    alone = evaluate_routes(plain_env, lambda obs: model.policy.predict(obs, deterministic=True)[0], max_steps=40)
    assert with_memory.success_rate > alone.success_rate

    def remembered(route: Any) -> bool:
        goal = plain_env.resolve_goal(route.goal)[1]
        return model.memory.route_from(plain_env.observation_at(route.start, route.heading, goal)) != []

    # Every heading of a place the memory has a route from at one heading reaches the goal: no unseen start states
    routed = {(route.goal, route.start) for route in with_memory.routes if remembered(route)}
    failed_at_a_routed_place = [
        route for route in with_memory.routes if (route.goal, route.start) in routed and not route.success
    ]
    assert len(routed) > 50 and failed_at_a_routed_place == []


def test_a_rollout_step_with_no_route_to_the_goal_explores_towards_the_untried_and_evaluation_asks_the_critics() -> (
    None
):
    env = CampusNavEnv(goals=["Dreese Lab", "Cinema", "Intramural fields", "Town house"], **SMALL)
    model = RouteMemoryDCQN("MultiInputPolicy", env, learning_starts=10_000, seed=0, **NET)
    model.learn(120)  # the warm-up explores: a part of the campus is known, not every goal's place
    model.exploration_rate = 0.0  # a rollout's greedy step from here on
    memory, graph = model.memory, env.graph.map
    poses = [(int(graph.state_nodes[s]), int(graph.state_headings[s])) for s in range(graph.n_states)]
    known = [pose for pose in poses if memory.state_of(env.observation_at(*pose, env.goal_nodes[0])) >= 0]
    unseen_goal = next(
        goal
        for goal in env.goal_nodes
        if not any(memory.state_of(env.observation_at(goal, heading, goal)) >= 0 for heading in env.headings_at(goal))
    )
    differs = 0
    for pose in known[:40]:
        observation = env.observation_at(*pose, unseen_goal)
        assert memory.route_actions(batch_of_one(observation)).tolist() == [-1]  # no route to a place never seen
        path = memory.path_to_untried(memory.state_of(observation))
        assert path is not None
        towards_untried = int(memory.slot_actions(batch_of_one(observation), np.array(path[:1]))[0])
        model._explorer = UntriedExplorer(memory, 1)  # a fresh path for each start
        assert int(model.predict(observation)[0]) == towards_untried
        critics = int(model.policy.predict(observation, deterministic=True)[0])
        assert int(model.predict(observation, deterministic=True)[0]) == critics  # evaluation never explores
        differs += critics != towards_untried
    assert len(known) > 40 and differs > 0  # the critics would have gone elsewhere


def test_explore_first_drives_to_the_untried_while_one_is_in_reach_even_where_a_route_is_known() -> None:
    env = CampusNavEnv(goals=["Dreese Lab"], **SMALL)
    model = RouteMemoryDCQN(
        "MultiInputPolicy", env, learning_starts=10_000, seed=0, route_memory={"explore": "first"}, **NET
    )
    model.learn(300)  # the warm-up explores: the goal is found and a part of the campus known
    model.exploration_rate = 0.0  # a rollout's greedy step from here on
    memory, graph, goal = model.memory, env.graph.map, env.goal_nodes[0]
    routed_yet_untried = 0
    for state in range(graph.n_states):
        observation = env.observation_at(int(graph.state_nodes[state]), int(graph.state_headings[state]), goal)
        place = memory.state_of(observation)
        if place < 0 or memory.route_actions(batch_of_one(observation))[0] < 0:
            continue
        path = memory.path_to_untried(place, retry=False)
        model._explorer = UntriedExplorer(memory, 1)  # a fresh path for each start
        action = int(model.predict(observation)[0])
        if path is None:  # nothing untried in reach: the route
            assert action == int(memory.route_actions(batch_of_one(observation))[0])
        else:
            assert action == int(memory.slot_actions(batch_of_one(observation), np.array(path[:1]))[0])
            routed_yet_untried += 1
    assert routed_yet_untried > 10
    with pytest.raises(ValueError, match=r"explore must be True, False or 'first', got 'always'"):
        RouteMemoryDCQN("MultiInputPolicy", env, route_memory={"explore": "always"}, **NET)


# ----------------------------------------------------------------------------------------------- what it learns
@WEARERS
def test_success_is_the_envs_word_else_a_reward_above_the_success_reward_setting_else_none(wearer: type) -> None:
    env = gym.make("FrozenLake-v1", is_slippery=False, map_name="8x8")

    def reach_goal(model: Any, info: dict[str, Any]) -> list[int]:
        """Store the last step onto the goal (62 -> 63, right), with ``info``; the memory's route from 62."""
        model._last_obs = np.array([62])
        model._store_transition(
            model.replay_buffer, np.array([2]), np.array([63]), np.array([1.0]), np.array([True]), [info]
        )
        return model.memory.route_from(np.int64(62))

    plain = wearer("MlpPolicy", env, learning_starts=10, **NET)
    assert reach_goal(plain, {}) == []  # no is_success, no bar: an end, not a goal (CartPole's falls are no goals)
    assert reach_goal(wearer("MlpPolicy", env, route_memory={"success_reward": 0.0}, **NET), {}) == [2]
    assert reach_goal(wearer("MlpPolicy", env, **NET), {"is_success": True}) == [2]
    assert reach_goal(wearer("MlpPolicy", env, route_memory={"success_reward": 0.0}, **NET), {"is_success": 0}) == []


@WEARERS
def test_one_bump_at_one_heading_revises_the_roads_copies_driven_at_another_heading_for_another_goal(
    wearer: type,
) -> None:
    env = CampusNavEnv(goals=["Dreese Lab", "Cinema"], **SMALL)
    # The campus's views repeat bit for bit: six transitions are enough to know its places (no calibration needed)
    model = wearer(
        "MultiInputPolicy", env, learning_starts=10_000, buffer_size=64, route_memory={"recognition": "exact"}, **NET
    )
    assert type(model.replay_buffer) is RevisionDictReplayBuffer and model.replay_buffer.goal_keys == ("goal_views",)
    graph = env.graph
    u, v = next(road for road in graph.map.roads if len(env.headings_at(road[0])) >= 2 and closable(env, *road))
    slot = int(np.flatnonzero(graph.map.slots[u] == v)[0])
    driving, bumping = env.headings_at(u)[:2]
    for _ in range(5):  # the road u -> v, driven five times at one heading towards Dreese Lab
        info = store(model, env, (slot - driving) % 4, {"start": u, "heading": driving, "goal": "Dreese Lab"})
        assert info["node"] == v
    env.close_road(u, v)
    try:
        info = store(model, env, (slot - bumping) % 4, {"start": u, "heading": bumping, "goal": "Cinema"})
    finally:
        env.reopen_road(u, v)
    assert info["collision"]
    buffer = model.replay_buffer
    assert buffer.revised == 5  # every copy, whatever its heading and goal
    copies = slice(0, 5)
    # Each copy now ends where it started (its own views and heading), with the bump's reward, not done
    for key in ("views", "heading"):
        np.testing.assert_array_equal(buffer.next_observations[key][copies], buffer.observations[key][copies])
    np.testing.assert_allclose(buffer.rewards[copies, 0], env.collision_penalty, rtol=0, atol=1e-9)
    assert not buffer.dones[copies].any()
    dreese = env.observation_at(u, driving, env.resolve_goal("Dreese Lab")[1])["goal_views"]
    np.testing.assert_array_equal(buffer.next_observations["goal_views"][copies, 0], np.stack([dreese] * 5))


@pytest.mark.parametrize("wearer", [RouteMemoryDQN], ids=["DQN-memory"])
def test_a_model_whose_memory_stepped_aside_acts_as_its_algorithm_and_leaves_its_data_alone(wearer: type) -> None:
    env = gym.make("FrozenLake-v1", is_slippery=False)
    model = wearer("MlpPolicy", env, learning_starts=10, seed=0, **NET)
    model.learn(100)
    model.memory.stepped_aside = True  # recognition failed: the memory answers -1 everywhere, and says so itself
    batch = np.arange(16)
    np.testing.assert_array_equal(
        model.predict(batch, deterministic=True)[0], model.policy.predict(batch, deterministic=True)[0]
    )
    keys = model._place_keys(np.array([0]), np.array([1]), np.array([4]))
    assert keys.moves.tolist() == [-1]  # no revision (not even by the bytes): the critics' data as they came


def test_on_observations_that_never_repeat_the_memory_steps_aside_early_says_so_and_biases_nothing(
    recwarn: pytest.WarningsRecorder,
) -> None:
    model = RouteMemoryDQN("MlpPolicy", "CartPole-v1", learning_starts=400, seed=0, **NET)
    taken: list[int] = []
    sample = model._sample_action

    def recorded(*args: Any, **kwargs: Any) -> tuple[np.ndarray, np.ndarray]:
        actions = sample(*args, **kwargs)
        taken.extend(np.asarray(actions[0]).reshape(-1).tolist())
        return actions

    model._sample_action = recorded
    model.learn(400)  # the warm-up: the memory's exploration, until it steps aside
    said = [str(warning.message) for warning in recwarn if "route memory" in str(warning.message)]
    assert len(said) == 1 and "states never repeat" in said[0]  # once, early: after 100 transitions, not 1,000
    assert model.memory.stepped_aside and model.memory.n_states <= 110
    # Where it knows nothing, its choice is the uniform one: no push to slot 0 at every new observation
    assert 0.35 < np.mean(np.array(taken) == 0) < 0.65


def test_the_memorys_statistics_are_logged_under_memory_at_each_rollout_end() -> None:
    model = RouteMemoryDQN("MlpPolicy", "FrozenLake-v1", learning_starts=10, seed=0, **NET)
    model.memory.statistics = lambda: {"places": float(model.memory.n_states)}  # what the memory says of itself
    model.learn(40)
    assert model.logger.name_to_value["memory/places"] == model.memory.n_states > 0


def test_the_buffer_that_gains_revision_is_said_once_and_a_users_own_class_is_kept(capsys) -> None:
    RouteMemoryDQN("MlpPolicy", "FrozenLake-v1", verbose=1)
    said = [line for line in capsys.readouterr().out.splitlines() if line.startswith("route_memory:")]
    assert said == ["route_memory: the default buffer revises what the memory's bumps contradict: RevisionReplayBuffer"]

    from stable_baselines3.common.buffers import ReplayBuffer

    class Own(ReplayBuffer):
        """A user's own buffer: its own business."""

    model = RouteMemoryDQN("MlpPolicy", "FrozenLake-v1", replay_buffer_class=Own, verbose=1)
    assert type(model.replay_buffer) is Own and "route_memory:" not in capsys.readouterr().out
    lean_n_step = RouteMemoryDCQN("MlpPolicy", "FrozenLake-v1", n_steps=3)
    assert not isinstance(lean_n_step.replay_buffer, RevisionReplay)  # a revised transition is one step


# ----------------------------------------------------------------------------------------------- evaluation
@WEARERS
def test_evaluation_never_repeats_a_move_that_just_bumped_into_a_barrier(wearer: type) -> None:
    env = CampusNavEnv(visible_closures=True, **SMALL)
    model = wearer("MultiInputPolicy", env, learning_starts=100, exploration_fraction=1.0, seed=0, **NET)
    model.learn(800)  # exploring towards the untried all along: the memory knows the campus
    goal = env.goal_nodes[0]

    def first_road(node: int, heading: int) -> tuple[int, int] | None:
        """The first action of the memory's route from (node, heading) and the intersection it leads to."""
        route = model.memory.route_from(env.observation_at(node, heading, goal))
        if len(route) < 3:
            return None
        state = int(env.graph.map.state_of[node, heading])
        return route[0], int(env.graph.map.state_nodes[env.graph.move(state, route[0])[0]])

    # A start whose route's first road can close without cutting the goal off: the memory does not know it closed
    node, heading, (first, barrier) = next(
        (node, heading, road)
        for node in range(env.graph.n_nodes)
        for heading in env.headings_at(node)
        if (road := first_road(node, heading)) is not None and closable(env, node, road[1])
    )
    env.close_road(node, barrier)

    def bumps(episode_starts: bool) -> list[tuple[int, int]]:
        """The (node, compass slot) of every collision in a 30-step episode from the chosen start."""
        observation, info = env.reset(options={"start": node, "heading": heading})
        collided = []
        for step in range(30):
            start = np.array([step == 0]) if episode_starts else None
            action = int(model.predict(batch_of_one(observation), episode_start=start, deterministic=True)[0][0])
            here = (info["node"], (int(observation["heading"].argmax()) + action) % 4)
            observation, _, terminated, truncated, info = env.step(action)
            if info["collision"]:
                collided.append(here)
            if terminated or truncated:
                break
        return collided

    try:
        alone = bumps(episode_starts=False)  # each call stands alone: the memory sends it into the barrier again
        # The start's picture shows the barrier: the memory is unsure of it until the graph's prior settles it (the
        # query cache then answers it so in later episodes too); from the second episode on the memory routes from it
        bumps(episode_starts=True)
        guarded = bumps(episode_starts=True)
        again = bumps(episode_starts=True)  # a new episode: the guard starts afresh, the same single bump
    finally:
        env.reopen_road(node, barrier)
    assert len(alone) >= 25
    # One bump into the barrier, never repeated; the best other actions may bump elsewhere (at a dead end the memory
    # never saw, say), each move once at most
    assert guarded[0] == (node, (heading + first) % 4) and len(set(guarded)) == len(guarded)
    assert again == guarded  # a new episode: the guard starts afresh


@WEARERS
def test_evaluation_leaves_a_loop_the_memorys_routes_would_drive_round_for_the_whole_episode(wearer: type) -> None:
    env = CampusNavEnv(**SMALL)
    model = wearer("MultiInputPolicy", env, learning_starts=100, exploration_fraction=1.0, seed=0, **NET)
    model.learn(800)  # the memory knows the campus
    goal = env.goal_nodes[0]
    near_goal = {goal, *env.graph.map.slots[goal].tolist()}
    crossings = [node for node in range(env.graph.n_nodes) if (env.graph.map.slots[node] >= 0).sum() >= 3]
    u, v = next(
        (u, int(v))
        for u in crossings
        for v in env.graph.map.slots[u]
        if v in crossings and {u, v}.isdisjoint(near_goal)
    )  # two crossings: each has ways on besides the other
    # Each of two neighbours remembered as a road to the goal by the road to the other (as look-alike places taken
    # for one place would be): the memory's routes go from one to the other and back
    at_goal = env.observation_at(goal, env.headings_at(goal)[0], goal)
    for here, there in ((u, v), (v, u)):
        heading = env.headings_at(here)[0]
        slot = int(np.flatnonzero(env.graph.map.slots[here] == there)[0])
        model.memory.add(env.observation_at(here, heading, goal), (slot - heading) % 4, at_goal, -0.005, False)

    def moves(episode_starts: bool) -> list[tuple[int, int]]:
        """The (node, compass slot) of every move in a 30-step episode from u."""
        observation, info = env.reset(options={"start": u, "goal": int(goal)})
        made = []
        for step in range(30):
            start = np.array([step == 0]) if episode_starts else None
            action = int(model.predict(batch_of_one(observation), episode_start=start, deterministic=True)[0][0])
            made.append((info["node"], (int(observation["heading"].argmax()) + action) % 4))
            observation, _, terminated, truncated, info = env.step(action)
            if terminated or truncated:
                break
        return made

    road, back = ((a, int(np.flatnonzero(env.graph.map.slots[a] == b)[0])) for a, b in ((u, v), (v, u)))
    alone = moves(episode_starts=False)  # each call stands alone: round and round
    assert alone[:4] == [road, back, road, back] and alone.count(road) >= 14
    guarded = moves(episode_starts=True)
    assert guarded[:4] == [road, back] * LOOP_REPEATS  # round as often as a loop takes to show
    assert guarded[4][0] == u and guarded[4] != road  # then the algorithm's best other move there
    assert guarded.count(road) < alone.count(road) / 2


def test_evaluation_hands_the_recogniser_the_place_each_envs_last_move_leads_to() -> None:
    env = CampusNavEnv(**SMALL)  # fixed views: where the agent is, the memory knows exactly
    model = RouteMemoryDQN("MultiInputPolicy", env, learning_starts=100, exploration_fraction=1.0, seed=0, **NET)
    model.learn(800)
    memory, asked = model.memory, []
    states_of = memory.states_of

    def spy(observations: Any, *, add: bool = False, expected: np.ndarray | None = None) -> np.ndarray:
        asked.append((None if expected is None else expected.tolist(), states_of(observations).tolist()))
        return states_of(observations, add=add, expected=expected)

    memory.states_of = spy
    for episode in range(2):
        observation, _ = env.reset(seed=episode)
        for step in range(6):
            action = model.predict(batch_of_one(observation), episode_start=np.array([step == 0]), deterministic=True)
            observation, _, terminated, truncated, _ = env.step(int(action[0][0]))
            if terminated or truncated:
                break
    priors = [prior for prior, _ in asked if prior is not None]
    assert len(priors) >= 8 and priors[0] == [-1]  # one recognition per step; a new episode expects nothing
    expected_right = [prior == where for prior, where in asked[1:] if prior is not None and prior != [-1]]
    assert len(expected_right) >= 5 and all(expected_right)  # every prior named where the agent then was


def test_route_evaluation_of_the_model_hands_each_route_the_place_its_last_move_leads_to() -> None:
    env = CampusNavEnv(**SMALL)
    model = RouteMemoryDQN("MultiInputPolicy", env, learning_starts=100, exploration_fraction=1.0, seed=0, **NET)
    model.learn(800)
    memory, checked = model.memory, []
    states_of = memory.states_of

    def spy(observations: Any, *, add: bool = False, expected: np.ndarray | None = None) -> np.ndarray:
        states = states_of(observations, add=add, expected=expected)
        if expected is not None and (expected >= 0).any():
            checked.append(bool((expected[expected >= 0] == states_of(observations)[expected >= 0]).all()))
        return states

    memory.states_of = spy
    report = evaluate_routes(env, model, chunk_size=32)  # routes of every length: rows drop at every step
    assert report.routes and len(checked) >= 10 and all(checked)  # each route's prior: where that route then was


def test_an_evaluation_episode_that_goes_on_where_the_memory_placed_its_goal_goes_to_its_other_places() -> None:
    env = CampusNavEnv(**SMALL)
    model = RouteMemoryDQN("MultiInputPolicy", env, learning_starts=100, exploration_fraction=1.0, seed=0, **NET)
    model.learn(800)
    memory = model.memory
    nodes, headings = env.graph.map.state_nodes, env.graph.map.state_headings
    batch = env.observations_at(nodes, headings, env.goal_nodes[0])
    states = memory.states_of(batch)
    first, second = np.unique(states[memory.route_actions(batch) >= 0])[:2]
    # A goal picture the memory cannot name one place for: a matcher's two candidates, neither of them the goal
    memory.goals.states = lambda *args, **kwargs: np.array([first, second])
    at_first, at_second = states == first, states == second
    starts = np.ones(nodes.size, dtype=bool)
    actions, state = model.predict(batch, episode_start=starts, deterministic=True)
    memory.goals.states = lambda *args, **kwargs: np.array([second])
    to_second = memory.route_actions(batch)
    np.testing.assert_array_equal(actions[at_first], to_second[at_first])  # went on at one: on to the other
    memory.goals.states = lambda *args, **kwargs: np.array([first, second])
    # The same episodes a step later, those at the first candidate now at the second: the goal is at neither
    moved = np.where(at_first, np.flatnonzero(at_second)[0], np.arange(nodes.size))
    later_batch = env.observations_at(nodes[moved], headings[moved], env.goal_nodes[0])
    later, _ = model.predict(later_batch, state=state, episode_start=~starts, deterministic=True)
    critics = model.policy.predict(later_batch, deterministic=True)[0]
    np.testing.assert_array_equal(later[at_first], critics[at_first])  # the algorithm's for the rest of the episode
    # A new episode there: the goal may be at either again, and going on at the second says it is at the first
    again, _ = model.predict(later_batch, episode_start=starts, deterministic=True)
    memory.goals.states = lambda *args, **kwargs: np.array([first])
    np.testing.assert_array_equal(again[at_first], memory.route_actions(later_batch)[at_first])
    assert (again[at_first] >= 0).all()


def test_sb3s_evaluate_policy_passes_episode_starts_and_the_guard_keeps_each_env_apart() -> None:
    env = CampusNavEnv(visible_closures=True, **SMALL)
    model = RouteMemoryDQN("MultiInputPolicy", env, learning_starts=100, seed=0, **NET)
    model.learn(400)
    guard_sizes = []
    original = model._without_repeated_moves

    def spy(batch: Any, actions: np.ndarray, episode_start: np.ndarray) -> np.ndarray:
        guard_sizes.append(episode_start.size)
        return original(batch, actions, episode_start)

    model._without_repeated_moves = spy
    evaluate_policy(model, model.get_env(), n_eval_episodes=2)
    assert guard_sizes and set(guard_sizes) == {1} and model._episode_guard.n_envs == 1


# ----------------------------------------------------------------------------------------------- the benchmark rows
def test_the_benchmarks_memory_rows_are_each_algorithm_wearing_the_same_memory() -> None:
    from benchmarks.campusnav_runs import TASKS, VARIANTS

    task = TASKS["quick"]
    rows = {"DQN + memory": "DQN + memory", "QRDQN + memory": "QRDQN + memory", "DCQN + memory": "DCQN + memory"}
    rows["DCQN, critics alone"] = "DCQN"  # the shipped entry's memory turned off
    for row, ran in rows.items():
        variant = VARIANTS[row]
        entry = variant.entry(task)
        model = variant.make_model(task.make_env(entry), entry, seed=0)
        assert algorithm_name(model) == ran and (model.memory is not None) == ran.endswith("memory")
    assert VARIANTS["DCQN, route memory"] is VARIANTS["DCQN + memory"]  # earlier results' name of the row


class PictureCorridor(gym.Env):
    """Seven cells in a row seen as a channel-last image (SB3 trains on it channel first: ``VecTransposeImage``); the
    goal in the middle (+1, the episode ends), left and right the two actions, every start but the goal's."""

    observation_space = gym.spaces.Box(0, 255, (7, 7, 3), np.uint8)
    action_space = gym.spaces.Discrete(2)

    def _picture(self) -> np.ndarray:
        picture = np.zeros((7, 7, 3), dtype=np.uint8)
        picture[:, self.cell] = 255
        return picture

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        self.cell, self.steps = int(self.np_random.choice([0, 1, 2, 4, 5, 6])), 0
        return self._picture(), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        self.cell, self.steps = int(np.clip(self.cell + (1 if action else -1), 0, 6)), self.steps + 1
        return self._picture(), float(self.cell == 3), self.cell == 3, self.steps >= 30, {"is_success": self.cell == 3}


def test_a_raw_envs_channel_last_picture_is_recognised_as_training_saw_it_channel_first() -> None:
    model = RouteMemoryDQN("MlpPolicy", PictureCorridor(), learning_starts=10_000, seed=0, **NET)
    model.learn(600)  # no gradient step: the critics are as initialised, the routes the memory's alone
    env = PictureCorridor()
    actions = []
    for cell in (0, 1, 2, 4, 5, 6):
        env.reset()
        env.cell = cell
        action, _ = model.predict(env._picture(), episode_start=np.array([True]), deterministic=True)
        actions.append(int(action))
    assert actions == [1, 1, 1, 0, 0, 0]  # towards the goal from either side: the memory knew every picture
