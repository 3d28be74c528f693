"""
Contact sheet of street views: the N/E/S/W views of a few intersections above the map, as one PNG.

Each view is labelled with its compass slot and the bearing it looks along (the road in that slot, see
:func:`~campusnav_env.maps.compass.view_bearings`), e.g. ``E 034``.

Command line (console script ``campusnav-views``)::

    campusnav-views --out views.png                     # the first three goals of the built-in campus
    campusnav-views --nodes 5 17 40 --time-of-day 18.5 --cars
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from campusnav_env.atomic_files import write_png
from campusnav_env.rendering.map_view import draw_map
from campusnav_env.rendering.street_view import RenderSettings, StreetViewRenderer
from campusnav_env.rendering.world import build_world

if TYPE_CHECKING:
    from campusnav_env.maps.road_graph import RoadGraph

__all__ = ["default_nodes", "main", "write_contact_sheet"]

_COMPASS = ("N", "E", "S", "W")
_BACKGROUND = (250, 250, 248)
_INK = (30, 30, 34)


def default_nodes(graph: RoadGraph, n_nodes: int = 3) -> list[int]:
    """The first ``n_nodes`` distinct landmark nodes: campus goals first, then other landmarks, then 0, 1, ..."""
    from campusnav_env.maps.campus import GOALS

    names = [n for n in GOALS if n in graph.landmarks] + [n for n in graph.landmarks if n not in GOALS]
    nodes: list[int] = []
    for name in names:
        if graph.landmarks[name] not in nodes:
            nodes.append(int(graph.landmarks[name]))
    nodes += [n for n in range(graph.n_nodes) if n not in nodes]
    return nodes[: max(0, n_nodes)]


def _label(image: np.ndarray, text: str, origin: tuple[int, int], scale: float = 0.6) -> None:
    """White text with a dark outline, legible on any view."""
    for colour, thickness in (((0, 0, 0), 4), ((255, 255, 255), 1)):
        cv2.putText(image, text, origin, cv2.FONT_HERSHEY_SIMPLEX, scale, colour, thickness, cv2.LINE_AA)


def write_contact_sheet(
    path: str | os.PathLike[str],
    *,
    graph: RoadGraph | None = None,
    nodes: Sequence[int] | None = None,
    settings: RenderSettings | None = None,
    n_nodes: int = 3,
    world_seed: int = 0,
    rng: np.random.Generator | None = None,
) -> Path:
    """
    Render the four views of a few nodes and write them, labelled, above the map as one PNG.

    :param path: Output PNG file (its folder must exist)
    :param graph: Road network; ``None`` = the built-in campus
    :param nodes: Nodes to show; ``None`` = the first ``n_nodes`` landmark nodes (goals first)
    :param settings: Render settings; ``None`` = defaults. Views wider than 320 pixels are shown at half size
    :param n_nodes: How many nodes when ``nodes`` is ``None``
    :param world_seed: Seed of the buildings, trees and fields
    :param rng: Source of the random appearance changes the settings ask for (time of day, cars)
    :return: The path written
    :raises FileNotFoundError: if the folder of ``path`` does not exist
    :raises ValueError: if there are no nodes to show or a node is out of range
    """
    path = Path(path)
    if not path.parent.is_dir():
        raise FileNotFoundError(f"folder of the contact sheet {path} does not exist")
    if graph is None:
        from campusnav_env.maps.campus import default_campus

        graph = default_campus()
    nodes = default_nodes(graph, n_nodes) if nodes is None else [int(n) for n in nodes]
    if not nodes:
        raise ValueError("no nodes to show: pass nodes or n_nodes >= 1")
    for n in nodes:
        if not 0 <= n < graph.n_nodes:
            raise ValueError(f"node {n} out of range for a graph of {graph.n_nodes} nodes")
    settings = settings or RenderSettings()
    renderer = StreetViewRenderer(build_world(graph, seed=world_seed), settings)
    names = {node: name for name, node in graph.landmarks.items()}

    shrink = 2 if settings.width > 320 else 1
    tw, th = settings.width // shrink, settings.height // shrink
    gap, header = 6, 30
    sheet_w = 4 * tw + 5 * gap
    rows = []
    for node in nodes:
        views = renderer.render_node(node, rng=rng)
        row = np.empty((header + th + gap, sheet_w, 3), dtype=np.uint8)
        row[...] = _BACKGROUND
        title = f"node {node}" + (f"  {names[node]}" if node in names else "")
        cv2.putText(row, title, (gap, header - 9), cv2.FONT_HERSHEY_SIMPLEX, 0.65, _INK, 1, cv2.LINE_AA)
        for d, view in enumerate(views):
            thumb = cv2.resize(view, (tw, th), interpolation=cv2.INTER_AREA) if shrink > 1 else view
            thumb = np.ascontiguousarray(thumb)
            _label(thumb, f"{_COMPASS[d]} {round(renderer.view_bearing(node, d)) % 360:03d}", (8, 24))
            x = gap + d * (tw + gap)
            row[header : header + th, x : x + tw] = thumb
        rows.append(row)
    board = draw_map(graph, size=sheet_w - 2 * gap, goal=nodes)
    map_row = np.empty((board.shape[0] + 2 * gap, sheet_w, 3), dtype=np.uint8)
    map_row[...] = _BACKGROUND
    map_row[gap : gap + board.shape[0], gap : gap + board.shape[1]] = board
    sheet = np.concatenate([*rows, map_row], axis=0)
    write_png(path, sheet)
    return path


def main(argv: Sequence[str] | None = None) -> int:
    """``campusnav-views``: write a contact sheet of street views of the built-in (or a generated) campus."""
    parser = argparse.ArgumentParser(prog="campusnav-views", description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=Path("campusnav_views.png"), help="output PNG file")
    parser.add_argument("--nodes", type=int, nargs="+", default=None, help="nodes to show (default: landmarks)")
    parser.add_argument("--n-nodes", type=int, default=3, help="how many landmark nodes when --nodes is not given")
    parser.add_argument("--seed", type=int, default=None, help="campus generator seed (default: the built-in campus)")
    parser.add_argument("--world-seed", type=int, default=0, help="seed of buildings, trees and fields")
    parser.add_argument("--time-of-day", type=float, default=None, help="hour in [0, 24] (default: fixed noon)")
    parser.add_argument("--cars", action="store_true", help="draw passing cars")
    parser.add_argument("--rng-seed", type=int, default=0, help="seed of the time-of-day and car variation")
    args = parser.parse_args(argv)
    from campusnav_env.maps.campus import default_campus, generate_campus

    graph = default_campus() if args.seed is None else generate_campus(seed=args.seed)
    try:
        settings = RenderSettings(time_of_day=args.time_of_day, cars=args.cars)
    except ValueError as error:
        parser.error(str(error))
    out = write_contact_sheet(
        args.out,
        graph=graph,
        nodes=args.nodes,
        settings=settings,
        n_nodes=args.n_nodes,
        world_seed=args.world_seed,
        rng=np.random.default_rng(args.rng_seed),
    )
    print(out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
