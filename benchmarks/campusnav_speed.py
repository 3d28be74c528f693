"""CampusNav speed: env steps per second against FrozenLake-v1 in the same run, and the cost of building the campus.

Measures
- env steps/s of CampusNav-v0 (features mode), a single env and an SB3 DummyVecEnv of 8, with random actions
  (resets included), against FrozenLake-v1 measured the same way in the same process (the ratio is what to compare
  across machines);
- the time to generate the default campus graph, build its 3D world, render all 404 street views (640x480) and encode
  them with the chosen encoder (into a fresh temporary cache, so nothing is reused);
- the views/s of the pixel-projection encoder (the cheap default of tests and quick runs) on those 404 views in one
  batch (a wall-clock rate, so a benchmark and not a unit test).

Usage::

    python benchmarks/campusnav_speed.py                      # EfficientNet-Lite0, writes results/campusnav_speed.md
    python benchmarks/campusnav_speed.py --encoder pixels --steps 20000
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.vec_env import DummyVecEnv

import campusnav_env  # noqa: F401  (registers the ids)
from benchmarks.report import RESULTS_DIR, command_line, machine_line, write_results
from campusnav_env.features.encoders import PixelProjectionEncoder, make_encoder
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.maps.campus import generate_campus
from campusnav_env.rendering.street_view import RenderSettings, StreetViewRenderer
from campusnav_env.rendering.world import build_world


def single_env_steps_per_second(env: gym.Env, n_steps: int, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    actions = rng.integers(env.action_space.n, size=n_steps)
    env.reset(seed=seed)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(int(action))
        if terminated or truncated:
            env.reset()
    return n_steps / (time.perf_counter() - start)


def vec_env_steps_per_second(vec_env: DummyVecEnv, n_steps: int, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    vec_env.seed(seed)
    vec_env.reset()
    n_calls = max(n_steps // vec_env.num_envs, 1)
    actions = rng.integers(vec_env.action_space.n, size=(n_calls, vec_env.num_envs))
    start = time.perf_counter()
    for batch in actions:
        vec_env.step(batch)  # auto-resets finished envs
    return n_calls * vec_env.num_envs / (time.perf_counter() - start)


def build_timings(encoder_name: str) -> tuple[dict[str, float], np.ndarray]:
    """Seconds of each step of building the default campus, and its ``(101, 4, 480, 640, 3)`` rendered views."""
    timings = {}
    start = time.perf_counter()
    graph = generate_campus()
    timings["generate campus graph (101 nodes)"] = time.perf_counter() - start
    start = time.perf_counter()
    world = build_world(graph)
    timings["build 3D world"] = time.perf_counter() - start
    renderer = StreetViewRenderer(world, RenderSettings())
    start = time.perf_counter()
    views = np.stack([renderer.render_node(node) for node in range(graph.n_nodes)])
    timings["render 404 views at 640x480"] = time.perf_counter() - start
    encoder = make_encoder(encoder_name)
    start = time.perf_counter()
    for node_views in views:
        encoder.encode(node_views)
    timings[f"encode 404 views ({encoder.name})"] = time.perf_counter() - start
    return timings, views


def pixel_projection_views_per_second(views: np.ndarray) -> tuple[str, float]:
    """
    Views/s of :class:`PixelProjectionEncoder` (default size) encoding ``views`` in one batch, after a warm-up batch.

    :param views: ``(n, H, W, 3)`` uint8 street views
    :return: ``(encoder name, views per second)``
    """
    encoder = PixelProjectionEncoder()
    encoder.encode(views[:4])  # first call: allocations and the projection matrix's pages
    start = time.perf_counter()
    encoder.encode(views)
    return encoder.name, len(views) / (time.perf_counter() - start)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=50_000, help="env steps per measurement")
    parser.add_argument("--encoder", default="efficientnet-lite0")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "campusnav_speed.md")
    args = parser.parse_args(argv)
    th.set_num_threads(args.threads)

    timings, views = build_timings(args.encoder)
    all_views = views.reshape(-1, *views.shape[2:])
    projection_name, projection_rate = pixel_projection_views_per_second(all_views)
    # The env as users get it: default encoder, features from the on-disk cache (built on first use)
    make_campus = dict(encoder=args.encoder, view_build=ViewBuild(progress=False))
    rates = {
        "FrozenLake-v1, single env": single_env_steps_per_second(gym.make("FrozenLake-v1"), args.steps),
        "CampusNav-v0, single env": single_env_steps_per_second(gym.make("CampusNav-v0", **make_campus), args.steps),
        "FrozenLake-v1, DummyVecEnv x 8": vec_env_steps_per_second(
            DummyVecEnv([lambda: gym.make("FrozenLake-v1")] * 8), args.steps
        ),
        "CampusNav-v0, DummyVecEnv x 8": vec_env_steps_per_second(
            DummyVecEnv([lambda: gym.make("CampusNav-v0", **make_campus)] * 8), args.steps
        ),
    }
    single_ratio = rates["CampusNav-v0, single env"] / rates["FrozenLake-v1, single env"]
    vec_ratio = rates["CampusNav-v0, DummyVecEnv x 8"] / rates["FrozenLake-v1, DummyVecEnv x 8"]
    lines = [
        "# CampusNav speed",
        "",
        machine_line(torch_threads=th.get_num_threads()),
        "",
        "| env | steps/s |",
        "|---|---|",
        *[f"| {name} | {rate:,.0f} |" for name, rate in rates.items()],
        "",
        f"CampusNav / FrozenLake: {single_ratio:.2f} (single env), {vec_ratio:.2f} (DummyVecEnv x 8); "
        "CampusNav in features mode with the encoder below, random actions, resets included.",
        "",
        "| building the default campus | seconds |",
        "|---|---|",
        *[f"| {name} | {seconds:.2f} |" for name, seconds in timings.items()],
        "",
        "| encoder throughput | views/s |",
        "|---|---|",
        f"| {projection_name}, one batch of {len(all_views)} views at 640x480 | {projection_rate:,.0f} |",
        "",
        command_line("campusnav_speed.py", argv),
    ]
    text = "\n".join(lines)
    print(text)
    write_results(args.out, text)


if __name__ == "__main__":
    main()
