"""Aliased places: intersections whose four views picture the same as another intersection's.

A route memory keys its states by the pictures of a place (``sb3_dcqn.route_memory``); two intersections that look
the same would be one state. The memory detects them as it drives (a slot that leads to two different places,
``RouteMemory.aliased``) and never routes through them; this benchmark counts them on the maps themselves, from the
env's own view table: pairs of intersections whose feature vectors are equal, and within ``1e-4`` in every entry (the
env's goal tolerance), per map and encoder. Usage::

    python benchmarks/aliased_places.py                       # the campus (EfficientNet-Lite0 and pixels), 1k cities
    python benchmarks/aliased_places.py --cities 1000 --map-seeds 31 47 59 --encoders pixels
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks.report import RESULTS_DIR, machine_line, markdown_table, publish
from campusnav_env.env import CampusNavEnv
from campusnav_env.features.view_build import ViewBuild
from campusnav_env.maps.campus import generate_city
from campusnav_env.rendering.street_view import RenderSettings

TOLERANCE = 1e-4
PIXELS = "pixels"


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


def count(world: str, map_seed: int, size: int, encoder: str) -> dict[str, Any]:
    build = ViewBuild(
        render_settings=RenderSettings(64, 48) if encoder == PIXELS else None,
        progress=False,
        fit_views_to_encoder=world != "campus",
    )
    graph = "campus" if world == "campus" else generate_city(size, seed=map_seed)
    env = CampusNavEnv(world=graph, view_dim=64, encoder=encoder, view_build=build)
    equal, close = aliased_pairs(env._open_views, TOLERANCE)
    return {"map": world, "map_seed": map_seed, "size": env.graph.n_nodes, "encoder": encoder, "equal": equal,
            "close": close}  # fmt: skip


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n")[0])
    parser.add_argument("--encoders", nargs="+", default=["efficientnet-lite0", PIXELS])
    parser.add_argument("--cities", nargs="*", type=int, default=[1000], help="sizes of generated cities (pixels)")
    parser.add_argument("--map-seeds", nargs="+", type=int, default=[31, 47, 59])
    parser.add_argument("--out", type=Path, default=RESULTS_DIR / "aliased_places.md")
    args = parser.parse_args(argv)
    records = [count("campus", 0, 101, encoder) for encoder in args.encoders]
    records += [count("city", seed, size, PIXELS) for size in args.cities for seed in args.map_seeds]
    rows = [
        [r["map"], str(r["map_seed"]), f"{r['size']:,}", r["encoder"], str(r["equal"]), str(r["close"])]
        for r in records
    ]
    header = ["map", "map seed", "intersections", "features", "pairs equal", f"pairs within {TOLERANCE:g}"]
    lines = [
        "# Aliased places",
        "",
        (__doc__ or "").split("Usage::")[0].split("\n\n")[1].replace("\n", " ").strip(),
        "",
        machine_line("one process"),
        "",
        *markdown_table(header, rows),
    ]
    publish(args.out, lines, "aliased_places.py", argv)


if __name__ == "__main__":
    main()
