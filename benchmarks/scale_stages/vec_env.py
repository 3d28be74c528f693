"""Scale, vector envs: env steps/s on the 101-node campus with ``DummyVecEnv`` and ``SubprocVecEnv`` of 1, 2 and 4
envs (random actions), and the cost of one env step by part.

Run by ``scale.py`` (stage ``vecenv``, on the plan's smallest map with the features its training uses); alone::

    python benchmarks/scale_vec_env.py --runs-file /tmp/vec.jsonl --out /tmp/vec.md
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from benchmarks.report import markdown_table
from benchmarks.scale_common import GOAL, VIEW_DIM, Plan, env_kwargs_for, make_graph, seconds_per_call

STAGE = "vecenv"
WARM_UP_STEPS = 50


def campus_env_factory(graph: Any, encoder: str, cache_dir: str) -> Callable[[], Any]:
    """A picklable env factory for the vector envs: the map with one of the two feature builds, one torch thread."""

    def make() -> Any:
        import torch

        from campusnav_env.env import CampusNavEnv
        from campusnav_env.features.view_build import with_view_build

        torch.set_num_threads(1)
        env_kwargs = with_view_build(env_kwargs_for(encoder), cache_dir=cache_dir, progress=False)
        return CampusNavEnv(world=graph, goals=GOAL, view_dim=VIEW_DIM, **env_kwargs)

    return make


def measure_vecenv(plan: Plan) -> dict[str, Any]:
    """
    Env steps/s with DummyVecEnv and SubprocVecEnv (random actions), and one env step's parts.

    :param plan: The run (its smallest map, ``vec_counts`` and ``vec_seconds``)
    :return: the stage's record
    """
    from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv

    n_nodes = plan.sizes[0]
    encoder = plan.train_encoder(n_nodes)
    make = campus_env_factory(make_graph(n_nodes, plan.extent), encoder, plan.cache_dir)
    rng = np.random.default_rng(0)
    rows = []
    for kind, cls in (("DummyVecEnv", DummyVecEnv), ("SubprocVecEnv", SubprocVecEnv)):
        for count in plan.vec_counts:
            vec_env = cls([make] * count)
            vec_env.reset()
            for _ in range(WARM_UP_STEPS):
                vec_env.step(rng.integers(0, 4, count))
            steps = 0
            begin = time.perf_counter()
            while time.perf_counter() - begin < plan.vec_seconds:
                vec_env.step(rng.integers(0, 4, count))
                steps += 1
            seconds = time.perf_counter() - begin
            vec_env.close()
            rows.append({"vec_env": kind, "envs": count, "steps_per_second": steps * count / seconds})
    # One env step by part (random actions; the episode restarts when it ends)
    env = make()
    env.reset(seed=0)
    state = {"done": False}

    def step() -> None:
        if state["done"]:
            env.reset()
        _, _, terminated, truncated, _ = env.step(int(rng.integers(4)))
        state["done"] = terminated or truncated

    repeats = 3_000 if not plan.quick else 500
    parts = {
        "env.step (whole)": seconds_per_call(step, repeats),
        "graph.move": seconds_per_call(
            lambda: env.graph.move(int(env.graph.map.state_of[env.node, env.heading]), 0), repeats
        ),
        "observation (views, goal views, heading)": seconds_per_call(
            lambda: env.observation_at(env.node, env.heading, env.goal), repeats
        ),
        # The step's info dict has no public builder: timed through the env's own (private) one, as step() calls it
        "info (incl. shortest_distance, action_mask)": seconds_per_call(lambda: env._info(collision=False), repeats),
        "reset": seconds_per_call(env.reset, repeats // 10),
    }
    dummy = DummyVecEnv([lambda: env])
    dummy.reset()
    parts["DummyVecEnv(1).step"] = seconds_per_call(lambda: dummy.step(rng.integers(0, 4, 1)), repeats)
    subproc = SubprocVecEnv([make])
    subproc.reset()
    parts["SubprocVecEnv(1).step"] = seconds_per_call(lambda: subproc.step(rng.integers(0, 4, 1)), repeats)
    subproc.close()
    return {
        "stage": STAGE,
        "size": n_nodes,
        "encoder": encoder,
        "rows": rows,
        "parts_us": {k: 1e6 * v for k, v in parts.items()},
    }


def vecenv_tables(vec: dict[str, Any]) -> list[str]:
    """Steps/s per vector env, and one env step's parts."""
    base = next(r["steps_per_second"] for r in vec["rows"] if r["vec_env"] == "DummyVecEnv" and r["envs"] == 1)
    speeds = markdown_table(
        ["vector env", "envs", "env steps/s (all envs)", "vs DummyVecEnv, 1 env"],
        [
            [row["vec_env"], row["envs"], f"{row['steps_per_second']:,.0f}", f"{row['steps_per_second'] / base:.2f}x"]
            for row in vec["rows"]
        ],
    )
    parts = markdown_table(
        ["part of one env step", "us per call"], [[n, f"{us:,.1f}"] for n, us in vec["parts_us"].items()]
    )
    return [*speeds, "", *parts]


def vec_env_section(vec: dict[str, Any]) -> list[str]:
    """The results section."""
    return [
        f"## Env steps/s: DummyVecEnv vs SubprocVecEnv ({vec['size']} intersections, {vec['encoder']} features, "
        "random actions)",
        "",
        *vecenv_tables(vec),
    ]
