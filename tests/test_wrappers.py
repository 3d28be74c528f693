"""GaussianObservationNoise: fresh noise of the stated sigma on the stated keys of any Box / Dict-of-Box env, seeded
through reset, through gym.make and SB3's vector envs; route evaluation sees what the wrappers show."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces
from gymnasium.utils.env_checker import check_env as gym_check_env
from stable_baselines3.common.env_util import make_vec_env

from campusnav_env import CampusNavEnv, GaussianObservationNoise, ViewBuild, evaluate_routes
from campusnav_env.maps.campus import generate_campus
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.wrappers import any_wrapper_varies, observation_wrappers, wrapped_observations

GRAPH = generate_campus(16, seed=1)
SIGMA = 0.3


class ConstantEnv(gym.Env[np.ndarray, np.int64]):
    """A Box env whose every observation is the same vector (so that what changes is the wrapper's)."""

    def __init__(self, dtype: type = np.float32) -> None:
        high = 255 if np.issubdtype(dtype, np.integer) else 10.0
        self.observation_space = spaces.Box(0, high, shape=(3, 5), dtype=dtype)
        self.action_space = spaces.Discrete(2)
        self.value = np.full((3, 5), 4, dtype=dtype)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        return self.value.copy(), {}

    def step(self, action: int) -> tuple[np.ndarray, float, bool, bool, dict]:
        return self.value.copy(), 0.0, False, False, {}


@pytest.fixture(scope="module")
def campus_kwargs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    build = ViewBuild(
        render_settings=RenderSettings(64, 48), cache_dir=tmp_path_factory.mktemp("cache"), progress=False
    )
    return dict(world=GRAPH, goals=[0], encoder="pixels", view_build=build)


def test_box_noise_has_the_stated_sigma_and_zero_mean() -> None:
    env = GaussianObservationNoise(ConstantEnv(), sigma=SIGMA)
    observation, _ = env.reset(seed=0)
    noise = np.stack([observation] + [env.step(0)[0] for _ in range(1_999)]) - 4.0  # 30,000 draws
    assert noise.dtype == np.float32
    assert abs(noise.mean()) < 0.01 and abs(noise.std() - SIGMA) < 0.01
    assert np.abs(noise[0] - noise[1]).min() > 0  # fresh noise every observation
    assert env.observation_space.low.min() == np.finfo(np.float32).min  # noise may leave the env's bounds


def test_an_image_box_stays_a_valid_image() -> None:
    env = GaussianObservationNoise(ConstantEnv(np.uint8), sigma=2.0)
    env.reset(seed=0)
    noised = np.stack([env.step(0)[0] for _ in range(500)])
    assert noised.dtype == np.uint8 and env.observation_space == env.env.observation_space
    assert abs(noised.astype(float).std() - 2.0) < 0.1  # rounded to whole levels, same spread


def test_only_the_given_keys_get_noise_of_the_stated_sigma(campus_kwargs: dict[str, Any]) -> None:
    clean_env = CampusNavEnv(**campus_kwargs)
    env = GaussianObservationNoise(CampusNavEnv(**campus_kwargs), sigma=SIGMA, keys=["views"])
    options = {"start": 5, "heading": clean_env.headings_at(5)[0]}
    clean, _ = clean_env.reset(seed=0, options=options)
    noisy = [env.reset(seed=seed, options=options)[0] for seed in range(60)]
    noise = np.stack([observation["views"] for observation in noisy]) - clean["views"]
    assert abs(noise.mean()) < 0.02 and abs(noise.std() - SIGMA) < 0.02
    for observation in noisy:  # the other keys pass unchanged
        np.testing.assert_array_equal(observation["goal_views"], clean["goal_views"])
        np.testing.assert_array_equal(observation["heading"], clean["heading"])
    assert env.observation_space["goal_views"] == clean_env.observation_space["goal_views"]


def test_every_key_gets_noise_by_default(campus_kwargs: dict[str, Any]) -> None:
    env = GaussianObservationNoise(CampusNavEnv(**campus_kwargs), sigma=SIGMA)
    assert env.keys == ("goal_views", "heading", "views")
    observation, _ = env.reset(seed=0)
    assert not set(np.unique(observation["heading"])) <= {0.0, 1.0}


def test_the_noise_is_seeded_through_reset_and_is_not_the_envs_own_stream() -> None:
    env = GaussianObservationNoise(ConstantEnv(), sigma=1.0)
    first = [env.reset(seed=3)[0], env.step(0)[0]]
    again = [env.reset(seed=3)[0], env.step(0)[0]]
    other = env.reset(seed=4)[0]
    np.testing.assert_array_equal(np.stack(first), np.stack(again))
    assert not np.array_equal(first[0], other)
    env.reset(seed=3)
    envs_own = env.unwrapped.np_random.normal(size=(3, 5))  # what the env itself draws with the same seed
    assert not np.allclose(first[0] - 4.0, envs_own.astype(np.float32))


def test_it_works_through_gym_make_and_sb3_vector_envs(campus_kwargs: dict[str, Any]) -> None:
    wrapper = {"sigma": SIGMA, "keys": ["views"]}
    env = GaussianObservationNoise(gym.make("CampusNav-v0", **campus_kwargs), **wrapper)
    gym_check_env(env.unwrapped)
    assert observation_wrappers(env) == [env]

    def vec_env():
        return make_vec_env("CampusNav-v0", n_envs=2, seed=0, env_kwargs=campus_kwargs,
                            wrapper_class=GaussianObservationNoise, wrapper_kwargs=wrapper)  # fmt: skip

    venv = vec_env()
    first, again = venv.reset(), vec_env().reset()
    np.testing.assert_array_equal(first["views"], again["views"])  # the VecEnv's seeds reach the wrapper
    nodes, headings = venv.env_method("get_wrapper_attr", "node"), venv.env_method("get_wrapper_attr", "heading")
    unnoised = CampusNavEnv(**campus_kwargs).observations_at(np.array(nodes), np.array(headings), 0)["views"]
    assert abs(np.std(first["views"] - unnoised) - SIGMA) < 0.05


def test_route_evaluation_sees_the_noise_of_the_envs_wrappers(campus_kwargs: dict[str, Any]) -> None:
    nav = CampusNavEnv(**campus_kwargs)
    wrapped = GaussianObservationNoise(gym.wrappers.TimeLimit(nav, 50), sigma=SIGMA, keys=["views"])
    wrapped.reset(seed=0)
    seen: list[dict[str, np.ndarray]] = []

    def forward(observations: dict[str, np.ndarray]) -> np.ndarray:
        seen.append(observations)
        return np.zeros(len(observations["heading"]), dtype=np.int64)

    evaluate_routes(wrapped, forward, max_steps=6)
    assert len(seen) == 6  # noise: a revisit proves no loop, routes run to the step limit
    states = np.flatnonzero((nav.node_distances(0) > 0)[nav.graph.map.state_nodes])
    nodes, headings = nav.graph.map.state_nodes[states], nav.graph.map.state_headings[states]
    clean = nav.observations_at(nodes, headings, 0)
    noise = seen[0]["views"] - clean["views"]  # step 0: every start, in the evaluator's order
    assert abs(noise.std() - SIGMA) < 0.03
    np.testing.assert_array_equal(seen[0]["goal_views"], clean["goal_views"])
    seen.clear()
    evaluate_routes(nav, forward, max_steps=6)  # the bare env: no noise
    np.testing.assert_array_equal(seen[0]["views"], clean["views"])


def test_a_wrapper_without_a_batched_method_is_applied_to_each_entry(campus_kwargs: dict[str, Any]) -> None:
    nav = CampusNavEnv(**campus_kwargs)
    doubled_space = nav.observation_space
    doubled = gym.wrappers.TransformObservation(nav, lambda obs: {**obs, "views": 2 * obs["views"]}, doubled_space)
    batch = nav.observations_at(np.arange(4), np.zeros(4, dtype=int), 0)
    np.testing.assert_allclose(wrapped_observations(doubled, batch)["views"], 2 * batch["views"])
    assert not any_wrapper_varies(doubled) and any_wrapper_varies(GaussianObservationNoise(doubled, 0.1))
    assert not any_wrapper_varies(GaussianObservationNoise(doubled, 0.0))


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"sigma": -0.1}, ValueError, r"sigma must be >= 0, got -0\.1"),
        ({"sigma": float("nan")}, ValueError, r"sigma must be a finite number >= 0"),
        ({"sigma": 0.1, "keys": ["pictures"]}, ValueError, r"keys \['pictures'\] are not observation keys"),
        ({"sigma": 0.1, "keys": "views"}, TypeError, r"keys must be a sequence of keys, got the string 'views'"),
    ],
)
def test_bad_arguments_say_what_is_wrong(
    campus_kwargs: dict[str, Any], kwargs: dict[str, Any], error: type, match: str
) -> None:
    with pytest.raises(error, match=match):
        GaussianObservationNoise(CampusNavEnv(**campus_kwargs), **kwargs)


def test_spaces_it_cannot_noise_are_refused() -> None:
    with pytest.raises(ValueError, match=r"keys \['a'\] given, but the observation is a Box"):
        GaussianObservationNoise(ConstantEnv(), sigma=0.1, keys=["a"])
    with pytest.raises(TypeError, match="needs a Box or a Dict of Boxes observation space, got Discrete"):
        GaussianObservationNoise(gym.make("FrozenLake-v1"), sigma=0.1)
