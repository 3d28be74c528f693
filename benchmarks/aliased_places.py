"""Aliased places: intersections that look alike, and what the route memory's recogniser makes of them.

Two counts per map, encoder and world:

- **on the map itself**, from the env's own view table: pairs of intersections whose feature vectors are equal, and
  within ``1e-4`` in every entry (the env's goal tolerance);
- **in the memory**, after the memory explored the map (its explorer, every transition remembered) in that world:
  states that hold pictures of two intersections or more (**merged wrongly**), intersections spread over two states
  or more (**split**), and pictures of explored intersections it answers unsure of (**unsure**), over every
  (intersection, heading) pair, pictured ``--draws`` times in a world whose pictures vary; the states the memory
  found aliased itself (a slot that led to two places); and its **wrong moves**: remembered moves (a state's slot that
  led to another state) whose end is not the intersection that road leads to, each state read as the intersection
  most of its pictures show (a picture taken for another place when a move was remembered: routes through it are
  wrong though no state holds two places).

Worlds (``--worlds``, :data:`benchmarks.campusnav_runs.WORLDS`): fixed views, fresh noise on the views, K renders per
view. Usage::

    python benchmarks/aliased_places.py                       # campus (both encoders), 1k cities, a town: every world
    python benchmarks/aliased_places.py --cities 1000 --map-seeds 31 --encoders pixels --worlds fixed "noise 0.05"
    # the city CampusNavCity-v0 builds (map seed 0) with the shipped features:
    python benchmarks/aliased_places.py --worlds --map-seeds 0 --city-encoders efficientnet-lite0 \
        --out benchmarks/results/aliased_places_efficientnet_city.md
"""

from __future__ import annotations

import argparse
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.campusnav_runs import WORLDS
from benchmarks.report import RESULTS_DIR, described, machine_line, markdown_table, publish
from campusnav_env.env import CampusNavEnv
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.maps.campus import generate_city
from campusnav_env.maps.examples import example_path
from campusnav_env.rendering.street_view import RenderSettings
from campusnav_env.wrappers import GaussianObservationNoise
from sb3_dcqn.route_memory import RouteMemory, UntriedExplorer, batch_of_one
from sb3_dcqn.route_memory.edges import ROUTES

TOLERANCE = 1e-4
PIXELS = "pixels"
EXPLORE_STEPS_PER_NODE = 40  # the memory explores at most this many steps per intersection


def aliased_pairs(views: np.ndarray, tolerance: float) -> tuple[int, int]:
    """Pairs of rows that are equal, and pairs within ``tolerance`` in every entry (sorting by the first feature
    keeps it linear-ish: only rows within the tolerance in it are compared)."""
    rows = np.asarray(views, dtype=np.float64).reshape(len(views), -1)
    order = np.argsort(rows[:, 0], kind="stable")
    rows = rows[order]
    equal = close = 0
    for i in range(len(rows)):
        j = i + 1
        while j < len(rows) and rows[j, 0] - rows[i, 0] <= tolerance:
            difference = np.abs(rows[j] - rows[i]).max()
            equal += int(difference == 0.0)
            close += int(difference <= tolerance)
            j += 1
    return equal, close


def make_env(world: str, map_seed: int, size: int, encoder: str, variation: dict[str, Any] | None) -> CampusNavEnv:
    build = ViewBuild(
        render_settings=RenderSettings(64, 48) if encoder == PIXELS else None,
        progress=False,
        fit_views_to_encoder=world != "campus",
    )
    graph: Any = {"campus": "campus", "town": example_path("small_town.graphml")}.get(world)
    graph = generate_city(size, seed=map_seed) if graph is None else graph
    goals = 0 if world == "town" else "Dreese Lab"  # the town names no landmark of the campus's
    return CampusNavEnv(
        world=graph, goals=goals, view_dim=64, encoder=encoder, view_build=build, view_variation=variation
    )


def explore(env: Any, memory: RouteMemory, seed: int, max_steps: int) -> int:
    """Drive the memory's explorer (a uniform action where it has none) until nothing is untried; the steps."""
    explorer = UntriedExplorer(memory)
    rng = np.random.default_rng(seed)
    observation, _ = env.reset(seed=seed)
    for step in range(1, max_steps + 1):
        action = int(explorer.actions(batch_of_one(observation))[0])
        action = action if action >= 0 else int(rng.integers(4))
        following, reward, terminated, truncated, info = env.step(action)
        memory.add(observation, action, following, reward, terminated, info.get("is_success"))
        observation = following
        if terminated or truncated:
            observation, _ = env.reset()
        if memory.recogniser.calibrated and memory.n_states and memory.frontier().size == 0:
            return step
    return max_steps


def memory_counts(env: Any, nav: CampusNavEnv, seed: int, draws: int) -> dict[str, Any]:
    """Explore, then recognise every (intersection, heading) pair ``draws`` times: merged, split, unsure."""
    memory = RouteMemory.for_env(env)
    steps = explore(env, memory, seed, EXPLORE_STEPS_PER_NODE * nav.graph.n_nodes)
    states_of_node: dict[int, set[int]] = {}
    nodes_of_state: dict[int, Counter[int]] = {}
    unsure = asked = 0
    nodes, headings = nav.graph.map.state_nodes, nav.graph.map.state_headings
    goal = nav.goal_nodes[0]
    for _ in range(draws):
        observations = nav.observations_at(nodes, headings, goal)
        if isinstance(env, GaussianObservationNoise):
            observations = env.observations(observations)
        states = memory.states_of(observations)
        for node, state in zip(nodes.tolist(), states.tolist(), strict=True):
            if state < 0:
                unsure += 1
            else:
                states_of_node.setdefault(node, set()).add(state)
                nodes_of_state.setdefault(state, Counter())[node] += 1
            asked += 1
    return {
        "explore_steps": steps,
        "states": memory.n_states,
        "merged": sum(len(members) > 1 for members in nodes_of_state.values()),
        "split": sum(len(members) > 1 for members in states_of_node.values()),
        "unsure": unsure / asked,
        "aliased": len(memory.aliased),
        "wrong_moves": wrong_moves(
            memory, nav, {state: nodes.most_common(1)[0][0] for state, nodes in nodes_of_state.items()}
        ),
        "stepped_aside": memory.stepped_aside,
    }


def wrong_moves(memory: RouteMemory, nav: CampusNavEnv, node_of: dict[int, int]) -> int:
    """Remembered moves between states read as intersections (``node_of``) whose end is not where the road leads
    (slots are compass directions: the env declares its heading as the memory's frame)."""
    table, state_of, state_nodes = nav.graph.transition_table, nav.graph.map.state_of, nav.graph.map.state_nodes
    outcome, target = memory.edges.outcome, memory.edges.target
    wrong = 0
    for state, node in node_of.items():
        heading = int(np.flatnonzero(state_of[node] >= 0)[0])  # any heading: the slot fixes the action
        for slot in range(memory.n_actions):
            following = int(target[state, slot])
            if outcome[state, slot] not in ROUTES or following in (-1, state) or following not in node_of:
                continue
            leads = int(table[state_of[node, heading], (slot - heading) % memory.n_actions])
            wrong += int(leads < 0 or int(state_nodes[leads]) != node_of[following])
    return wrong


def count(world: str, map_seed: int, size: int, encoder: str, world_name: str, draws: int) -> dict[str, Any]:
    settings = WORLDS[world_name]
    nav = make_env(world, map_seed, size, encoder, settings.variation)
    env = GaussianObservationNoise(nav, settings.noise, keys=["views"]) if settings.noise else nav
    equal, close = aliased_pairs(nav._open_views, TOLERANCE)
    return {
        "map": world, "map_seed": map_seed, "size": nav.graph.n_nodes, "encoder": encoder, "world": world_name,
        "equal": equal, "close": close, **memory_counts(env, nav, seed=map_seed, draws=draws if nav.observations_vary
        or settings.noise else 1),
    }  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--encoders", nargs="+", default=["efficientnet-lite0", PIXELS])
    parser.add_argument("--cities", nargs="*", type=int, default=[1000], help="sizes of generated cities")
    parser.add_argument("--city-encoders", nargs="+", default=[PIXELS], help="the cities' features (raw pixels: fast)")
    parser.add_argument("--map-seeds", nargs="+", type=int, default=[31, 47, 59])
    every_world = ["fixed", "noise 0.05", "variation 8"]
    parser.add_argument("--worlds", nargs="*", default=every_world, choices=list(WORLDS))
    parser.add_argument("--city-worlds", nargs="+", default=every_world, choices=list(WORLDS))
    parser.add_argument("--draws", type=int, default=3, help="pictures of each (intersection, heading) asked")
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "aliased_places.md")
    args = parser.parse_args(argv)
    records = [
        count("campus", 0, 101, encoder, world, args.draws) for encoder in args.encoders for world in args.worlds
    ]
    records += [count("town", 0, 15, PIXELS, world, args.draws) for world in args.worlds]
    records += [
        count("city", seed, size, encoder, world, args.draws)
        for size in args.cities
        for seed in args.map_seeds
        for encoder in args.city_encoders
        for world in args.city_worlds
    ]
    rows = [
        [
            r["map"], str(r["map_seed"]), f"{r['size']:,}", r["encoder"], r["world"], str(r["equal"]), str(r["close"]),
            f"{r['states']:,}", str(r["merged"]), str(r["split"]), f"{r['unsure']:.3f}", str(r["aliased"]),
            str(r["wrong_moves"]),
            f"{r['explore_steps']:,}" + (" (stepped aside)" if r["stepped_aside"] else ""),
        ]
        for r in records
    ]  # fmt: skip
    header = [
        "map", "map seed", "intersections", "features", "world", "pairs equal", f"pairs within {TOLERANCE:g}",
        "memory states", "merged wrongly", "split", "unsure share", "aliased (found)", "wrong moves",
        "exploration steps",
    ]  # fmt: skip
    lines = [
        "# Aliased places",
        "",
        described(__doc__),
        "",
        "The town is the shipped `small_town.graphml` (15 intersections, metres). No real OSM map is on this machine.",
        "",
        machine_line("one process"),
        "",
        *markdown_table(header, rows),
    ]
    publish(args.out, lines, "aliased_places.py", argv)


if __name__ == "__main__":
    main()
