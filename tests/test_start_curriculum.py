"""Start-distance curriculum: starts within a hop limit of the goal, and the callback that widens the limit on success.

The callback is driven by hand (episode ends fed as SB3's ``locals``) where a test needs a given success rate; the last
test trains a DCQN with it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import seeding
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import DummyVecEnv
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from campusnav_env import CampusNavEnv, generate_campus
from campusnav_env.callbacks import StartCurriculumCallback
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.rendering.street_view import RenderSettings
from sb3_dcqn import DCQN

WORLD = generate_campus(40, seed=1)  # 8 hops from the farthest start to Dreese Lab
LONGEST = 8


@pytest.fixture(scope="module")
def env_kwargs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    return dict(
        world=WORLD,
        goals="Dreese Lab",
        encoder="pixels",
        view_build=ViewBuild(
            render_settings=RenderSettings(width=64, height=48),
            cache_dir=tmp_path_factory.mktemp("cache"),
            progress=False,
        ),
        max_steps=30,
    )


def wrapped_vec_env(env_kwargs: dict[str, Any], n_envs: int = 2) -> DummyVecEnv:
    """Training envs as SB3 builds them: each CampusNavEnv behind Gymnasium wrappers."""
    return DummyVecEnv([lambda: gym.wrappers.RecordEpisodeStatistics(CampusNavEnv(**env_kwargs))] * n_envs)


def explorer(env: Any) -> DCQN:
    """A DCQN that never trains, with a logger that writes nothing: the model and logger a callback needs."""
    model = DCQN("MultiInputPolicy", env, learning_starts=100_000, policy_kwargs=dict(net_arch=[16]), seed=0)
    model.set_logger(configure(folder=None, format_strings=[]))
    return model


def started(callback: StartCurriculumCallback, model: DCQN) -> StartCurriculumCallback:
    callback.init_callback(model)
    callback.on_training_start(locals_={}, globals_={})
    return callback


def episodes_end(callback: StartCurriculumCallback, successes: list[bool | None]) -> None:
    """One step of the vector env at which env ``i`` ends an episode (``None``: an end without ``is_success``)."""
    infos = [{} if success is None else {"is_success": success} for success in successes]
    callback.update_locals({"dones": np.ones(len(successes), dtype=bool), "infos": infos})
    callback.on_step()


def model_value(callback: StartCurriculumCallback, key: str) -> float:
    """The value the callback last recorded under ``key`` in the model's SB3 logger."""
    return callback.model.logger.name_to_value[key]


def test_starts_lie_within_the_limit_and_cover_every_node_within_it(env_kwargs: dict[str, Any]) -> None:
    env = CampusNavEnv(**env_kwargs)
    distances = env.node_distances(env.goal_nodes[0])
    env.set_start_distance_limit(3)
    assert env.start_distance_limit == 3
    env.reset(seed=0)
    starts = [env.reset()[1]["node"] for _ in range(400)]
    assert all(1 <= distances[start] <= 3 for start in starts)
    assert set(starts) == set(np.flatnonzero((distances >= 1) & (distances <= 3)).tolist())  # uniform among them
    # A start given in the options ignores the limit
    far = int(np.argmax(distances))
    assert env.reset(options={"start": far})[1]["node"] == far


def test_without_a_limit_the_draws_are_those_of_an_env_without_a_curriculum(env_kwargs: dict[str, Any]) -> None:
    env = CampusNavEnv(**env_kwargs)
    env.set_start_distance_limit(2)
    env.set_start_distance_limit(None)
    distances = env.node_distances(env.goal_nodes[0])
    candidates = np.flatnonzero(distances > 0)
    rng, _ = seeding.np_random(7)  # the env's generator after reset(seed=7)
    _, info = env.reset(seed=7)
    for _ in range(20):
        assert int(rng.integers(1)) == 0  # the goal, drawn first (one goal here)
        start = int(rng.choice(candidates))
        heading = int(rng.choice(env.headings_at(start)))
        assert (info["node"], info["heading"]) == (start, heading)
        _, info = env.reset()


def test_bad_limits_are_refused_with_a_clear_error(env_kwargs: dict[str, Any]) -> None:
    env = CampusNavEnv(**env_kwargs)
    for bad in (0, -1, 1.5, True, "3"):
        with pytest.raises(ValueError, match="start_distance_limit must be None or an int of at least 1 hop"):
            env.start_distance_limit = bad
    assert env.start_distance_limit is None


def test_callback_widens_on_success_and_sets_every_env(env_kwargs: dict[str, Any]) -> None:
    vec_env = wrapped_vec_env(env_kwargs)
    model = explorer(vec_env)
    callback = started(StartCurriculumCallback(initial=2, growth=1.5, success_threshold=0.75, window=4), model)
    assert vec_env.get_attr("start_distance_limit") == [2, 2]
    episodes_end(callback, [True, True])
    assert callback.start_distance_limit == 2  # the window is not full yet
    episodes_end(callback, [True, False])  # 3 of 4: at the threshold
    assert callback.start_distance_limit == 3  # max(2 + 1, ceil(2 * 1.5))
    assert vec_env.get_attr("start_distance_limit") == [3, 3]
    assert model_value(callback, "curriculum/start_distance_limit") == 3
    # Resets of both envs obey the new limit
    distances = vec_env.envs[0].unwrapped.node_distances(vec_env.envs[0].unwrapped.goal_nodes[0])
    for _ in range(20):
        vec_env.reset()
        assert all(distances[node] <= 3 for node in vec_env.get_attr("node"))


def test_callback_does_not_widen_below_the_threshold(env_kwargs: dict[str, Any]) -> None:
    vec_env = wrapped_vec_env(env_kwargs)
    callback = started(StartCurriculumCallback(initial=2, success_threshold=0.75, window=4), explorer(vec_env))
    for _ in range(10):
        episodes_end(callback, [True, False])  # 1 in 2 over every window
        episodes_end(callback, [None, True])  # an episode without is_success is a failure
    assert callback.start_distance_limit == 2 and callback.widenings == []
    assert vec_env.get_attr("start_distance_limit") == [2, 2]
    assert model_value(callback, "curriculum/success_rate") == pytest.approx(0.5)


def test_successes_since_the_last_widening_count_only(env_kwargs: dict[str, Any]) -> None:
    vec_env = wrapped_vec_env(env_kwargs)
    callback = started(StartCurriculumCallback(initial=2, success_threshold=1.0, window=2), explorer(vec_env))
    episodes_end(callback, [True, True])
    assert callback.start_distance_limit == 3
    episodes_end(callback, [True, False])  # a full window again, but only half of it succeeded
    assert callback.start_distance_limit == 3


def test_callback_reaches_the_whole_map_and_stops_there(env_kwargs: dict[str, Any]) -> None:
    vec_env = wrapped_vec_env(env_kwargs)
    callback = started(
        StartCurriculumCallback(initial=2, growth=1.5, success_threshold=1.0, window=2), explorer(vec_env)
    )
    for _ in range(6):
        episodes_end(callback, [True, True])
    # 2 -> 3 -> 5 -> 8, which covers the 8 hops of the farthest start: anywhere (None)
    assert [limit for _, limit in callback.widenings] == [3, 5, None]
    assert callback.finished and callback.start_distance_limit is None
    assert vec_env.get_attr("start_distance_limit") == [None, None]
    assert model_value(callback, "curriculum/start_distance_limit") == LONGEST  # the whole map, as a number


def test_an_initial_limit_that_covers_the_map_means_anywhere(env_kwargs: dict[str, Any]) -> None:
    vec_env = wrapped_vec_env(env_kwargs, n_envs=1)
    callback = started(StartCurriculumCallback(initial=LONGEST), explorer(vec_env))
    assert callback.finished and vec_env.get_attr("start_distance_limit") == [None]


def test_bad_callback_arguments_are_refused() -> None:
    for kwargs, message in (
        (dict(initial=0), "initial must be an int of at least 1 hop"),
        (dict(growth=1.0), "growth must be a finite factor above 1"),
        (dict(success_threshold=0.0), r"success_threshold must lie in \(0, 1\]"),
        (dict(window=0), "window must be at least 1 episode"),
    ):
        with pytest.raises(ValueError, match=message):
            StartCurriculumCallback(**kwargs)


def test_dcqn_trains_with_the_curriculum_on_two_envs(env_kwargs: dict[str, Any], tmp_path: Path) -> None:
    vec_env = wrapped_vec_env(env_kwargs)
    model = DCQN(
        "MultiInputPolicy",
        vec_env,
        learning_starts=50,
        buffer_size=1_000,
        batch_size=16,
        train_freq=4,
        policy_kwargs=dict(net_arch=[16]),
        seed=0,
        tensorboard_log=str(tmp_path),
    )
    # One hop from the goal, a random walk of 30 steps mostly gets there: the limit widens early on
    callback = StartCurriculumCallback(initial=1, growth=2.0, success_threshold=0.5, window=4)
    model.learn(300, callback=callback, log_interval=1)
    assert model.num_timesteps >= 300
    assert callback.widenings, "a random walk from next to the goal succeeds often enough to widen the starts"
    assert vec_env.get_attr("start_distance_limit") == [callback.start_distance_limit] * 2
    (run,) = [path for path in tmp_path.iterdir() if path.is_dir()]
    events = EventAccumulator(str(run))
    events.Reload()
    logged = [event.value for event in events.Scalars("curriculum/start_distance_limit")]
    assert logged and logged[0] == 1 and logged[-1] == (callback.start_distance_limit or LONGEST)
