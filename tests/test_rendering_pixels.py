"""
Rendered pixels and placed worlds stay what they were: golden views, maps and world digests in
``tests/data/render_golden.npz``.

The golden file was written by this module's ``__main__`` block at commit d2f9cd7, before the renderer was split into
parts (camera, ground, buildings, props), and checks that refactoring the renderer or ``build_world`` changes no pixel
and no placement. Whoever changes the drawing on purpose bumps ``RENDERER_VERSION`` (or ``BARRIER_VERSION`` /
``WORLD_VERSION``) and rewrites the file from the repository root::

    PYTHONPATH=$PWD python tests/test_rendering_pixels.py

Rendering is numpy + OpenCV; SIMD paths differ slightly between CPUs (ARM, x86), so views are compared with a
tolerance: at least :data:`MIN_SHARE_WITHIN_ONE` of the values within 1 of the golden value and a mean absolute
difference of at most :data:`MAX_MEAN_DIFF`. On the machine that wrote the file they are byte-identical.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from campusnav_env.maps.campus import default_campus, generate_campus
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.map_view import draw_map
from campusnav_env.rendering.street_view import RenderSettings, StreetViewRenderer
from campusnav_env.rendering.world import World, build_world

GOLDEN = Path(__file__).parent / "data" / "render_golden.npz"
MIN_SHARE_WITHIN_ONE = 0.999  # share of pixel values within 1 of the golden value
MAX_MEAN_DIFF = 0.05  # mean absolute difference over all pixel values

SMALL = RenderSettings(width=160, height=120)
FULL = RenderSettings()
# Every appearance change RenderSettings offers, at the small size
APPEARANCES = {
    "dusk": RenderSettings(width=160, height=120, time_of_day=18.5),
    "dawn-cars": RenderSettings(width=160, height=120, time_of_day=6.0, cars=True),
    "cars": RenderSettings(width=160, height=120, cars=True),
    "night": RenderSettings(width=160, height=120, time_of_day=22.0),
    "narrow-high": RenderSettings(width=160, height=120, fov_deg=60.0, eye_height=4.0),
}


def _graphs() -> dict[str, RoadGraph]:
    return {"campus": default_campus(), "generated200": generate_campus(200, seed=3), "small16": generate_campus(16)}


def _worlds(graphs: dict[str, RoadGraph]) -> dict[str, World]:
    return {
        "campus-seed0": build_world(graphs["campus"], seed=0),
        "campus-seed1": build_world(graphs["campus"], seed=1),
        "generated200-seed3": build_world(graphs["generated200"], seed=3),
        "small16-seed0": build_world(graphs["small16"], seed=0),
    }


def placement_digest(world: World) -> str:
    """sha256 of every placed object (buildings, trees, fields, signs) and the road dimensions, field by field."""
    digest = hashlib.sha256()

    def add(*values: object) -> None:
        for value in values:
            if isinstance(value, np.ndarray):
                digest.update(np.ascontiguousarray(value, dtype=np.float64).tobytes())
            else:
                digest.update(repr(value).encode())

    add(world.road_width, world.verge_width, world.sidewalk_width, world.seed, world.clearance)
    add(len(world.buildings), len(world.trees), len(world.fields), len(world.signs))
    for b in world.buildings:
        add(b.footprint, b.height, b.facade_rgb, b.window_rgb, b.roof_rgb, b.floor_height, b.window_spacing)
        add(b.window_width, b.window_height, b.name, b.node, b.sign_wall)
    for t in world.trees:
        add(t.position, t.radius, t.height, t.crown_rgb)
    for f in world.fields:
        add(f.polygon, f.rgb, f.kind, f.name, len(f.lines), *f.lines)
    for s in world.signs:
        add(s.position, s.text, s.bearing, s.width, s.height, s.elevation, s.board_rgb, s.text_rgb)
    return digest.hexdigest()


def _first_road(graph: RoadGraph, node: int, avoid: int = -1) -> tuple[int, tuple[int, int]]:
    """The first compass slot of ``node`` with a road (not to ``avoid``) and that road."""
    slot = int(np.flatnonzero((graph.slots[node] >= 0) & (graph.slots[node] != avoid))[0])
    return slot, (node, int(graph.slots[node, slot]))


def golden_cases() -> Iterator[tuple[str, Callable[[], np.ndarray]]]:
    """``(name, draw)`` of every golden image: street views through the renderer's public entry points, and maps."""
    graphs = _graphs()
    worlds = _worlds(graphs)
    campus, generated = graphs["campus"], graphs["generated200"]
    small = StreetViewRenderer(worlds["campus-seed0"], SMALL)
    # Landmark nodes (Dreese Lab, Town house, Cinema, the Intramural fields with their monument sign), plain nodes
    for node in (81, 29, 75, 25, 0, 50):
        yield f"campus/small/node{node}", lambda node=node: small.render_node(node)
    yield "campus-seed1/small/node81", lambda: StreetViewRenderer(worlds["campus-seed1"], SMALL).render_node(81)
    for (name, settings), node in zip(APPEARANCES.items(), (81, 29, 44, 75, 27), strict=True):
        renderer = StreetViewRenderer(worlds["campus-seed0"], settings)
        # With an rng from the caller and with the renderer's own (seeded by the world seed and the node)
        yield f"campus/{name}/node{node}/rng", lambda r=renderer, n=node: r.render_node(n, rng=np.random.default_rng(n))
        yield f"campus/{name}/node{node}/own-rng", lambda r=renderer, n=node: r.render_node(n)
        yield f"campus/{name}/node{node}/view2", lambda r=renderer, n=node: r.render_view(n, 2)[None]
    # Closure barriers: the closed road straight ahead, with and without appearance changes
    slot, road = _first_road(campus, 81)
    yield "campus/small/node81/closed", lambda: small.render_node(81, closed_roads=[road])
    _, other_road = _first_road(campus, road[1], avoid=81)
    yield (
        "campus/small/neighbour/closed-both",
        lambda: small.render_node(road[1], closed_roads=[road[::-1], other_road]),
    )
    dusk_cars = StreetViewRenderer(worlds["campus-seed0"], RenderSettings(160, 120, time_of_day=17.0, cars=True))
    yield (
        "campus/dusk-cars/node81/closed",
        lambda: dusk_cars.render_node(81, closed_roads=[road], rng=np.random.default_rng(5)),
    )
    full = StreetViewRenderer(worlds["campus-seed0"], FULL)
    yield "campus/full/node81/view0", lambda: full.render_view(81, 0)[None]
    yield f"campus/full/node81/view{slot}/closed", lambda: full.render_view(81, slot, closed_roads=[road])[None]
    # A generated campus and its own world
    gen_renderer = StreetViewRenderer(worlds["generated200-seed3"], SMALL)
    for node in (0, 100, 199):
        yield f"generated200/small/node{node}", lambda node=node: gen_renderer.render_node(node)
    _, gen_road = _first_road(generated, 100)
    yield "generated200/small/node100/closed", lambda: gen_renderer.render_node(100, closed_roads=[gen_road])
    # The 2D map: agent, heading, goals, path and a closed road; a generated map with a route legend
    navigation = NavigationGraph(campus, closed_roads=[other_road])
    path = [81, road[1]]
    yield (
        "campus/map",
        lambda: draw_map(navigation, size=400, agent=road[1], heading=1, goal=[29, 75], path=path)[None],
    )
    route = [100, gen_road[1]]
    yield "generated200/map", lambda: draw_map(generated, size=300, agent=100, labels=False, routes={"a": route})[None]


def golden_worlds() -> dict[str, str]:
    """Placement digest of every golden world."""
    return {name: placement_digest(world) for name, world in _worlds(_graphs()).items()}


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    with np.load(GOLDEN) as data:
        return {key: data[key] for key in data.files}


def test_golden_file_lists_every_case(golden: dict[str, np.ndarray]) -> None:
    names = {f"view:{name}" for name, _ in golden_cases()} | {f"world:{name}" for name in golden_worlds()}
    assert set(golden) == names


def test_worlds_place_the_same_objects(golden: dict[str, np.ndarray]) -> None:
    for name, digest in golden_worlds().items():
        assert digest == str(golden[f"world:{name}"]), f"build_world placed different objects in {name}"


def test_views_and_maps_are_pixel_identical_to_the_golden_ones(golden: dict[str, np.ndarray]) -> None:
    for name, draw in golden_cases():
        image, expected = draw(), golden[f"view:{name}"]
        assert image.dtype == np.uint8 and image.shape == expected.shape, name
        diff = np.abs(image.astype(np.int16) - expected.astype(np.int16))
        within_one = float((diff <= 1).mean())
        assert within_one >= MIN_SHARE_WITHIN_ONE, f"{name}: only {within_one:.4%} of values within 1"
        assert float(diff.mean()) <= MAX_MEAN_DIFF, f"{name}: mean difference {diff.mean():.3f}"


def _write_golden() -> None:
    """Render every case with the current code and write the golden file (atomically)."""
    arrays: dict[str, np.ndarray] = {f"view:{name}": draw() for name, draw in golden_cases()}
    arrays |= {f"world:{name}": np.array(digest) for name, digest in golden_worlds().items()}
    GOLDEN.parent.mkdir(exist_ok=True)
    tmp = GOLDEN.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(GOLDEN)
    print(f"wrote {len(arrays)} entries, {GOLDEN.stat().st_size / 1e6:.2f} MB to {GOLDEN}")


if __name__ == "__main__":
    _write_golden()
