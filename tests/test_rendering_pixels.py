"""
Rendered pixels and placed worlds stay what they were: golden views and maps in ``tests/data/render_golden.npz``,
golden placed worlds in ``tests/data/world_golden.npz``.

The views were written by this module's ``__main__`` block at commit d2f9cd7, before the renderer was split into parts
(camera, ground, buildings, props), and check that refactoring the renderer or ``build_world`` changes no pixel and no
placement. Whoever changes the drawing on purpose bumps ``RENDERER_VERSION`` (or ``BARRIER_VERSION`` /
``WORLD_VERSION``) and rewrites both files from the repository root::

    PYTHONPATH=$PWD python tests/test_rendering_pixels.py

Rendering is numpy + OpenCV; SIMD paths differ slightly between CPUs (ARM, x86), and OpenCV releases rasterise
anti-aliased edges and text differently, so views are compared with a tolerance: at least
:data:`MIN_SHARE_WITHIN_ONE` of the values within 1 of the golden value and a mean absolute difference of at most
:data:`MAX_MEAN_DIFF` (maps, mostly lines and labels: :data:`MAP_MIN_SHARE_WITHIN_ONE`, :data:`MAP_MAX_MEAN_DIFF`).
Measured against the golden file written with opencv-python-headless 5.0.0: with 5.1.0 the views are at worst 99.50%
within 1 (mean difference 0.17), the maps 94.8% (mean 4.7). On the machine and OpenCV that wrote the file they are
byte-identical.

Placed worlds are not bit-identical across machines either: ``np.linalg.norm`` of a 2-vector is a BLAS ``ddot``, whose
OpenBLAS SkylakeX kernel (AVX-512 CPUs) fuses a multiply-add that its Haswell, Zen, Nehalem and ARM kernels round
twice, and numpy's AVX-512 ``arctan2`` (SVML) differs from libm's by 1 ulp. Both move building corners by at most
2.3e-13 m. So counts, vertex counts, names, kinds, colours and landmark nodes are compared exactly, and positions,
sizes, shares and bearings to :data:`WORLD_ATOL`.
"""

from __future__ import annotations

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
GOLDEN_WORLDS = Path(__file__).parent / "data" / "world_golden.npz"
# Positions and sizes of placed objects may differ by this much (m) from the golden ones; between the BLAS kernels and
# numpy SIMD paths measured (OpenBLAS SkylakeX / Haswell, numpy with and without X86_V4) they differ by <= 2.3e-13 m.
WORLD_ATOL = 1e-6
MIN_SHARE_WITHIN_ONE = 0.99  # share of pixel values within 1 of the golden value (views)
MAX_MEAN_DIFF = 0.3  # mean absolute difference over all pixel values (views)
MAP_MIN_SHARE_WITHIN_ONE = 0.92  # the same for top-down maps: OpenCV 5.1 draws their lines and labels differently
MAP_MAX_MEAN_DIFF = 7.0

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


def _rgb(colours: list[tuple[int, int, int]], n: int) -> np.ndarray:
    return np.asarray(colours, dtype=np.int64).reshape(n, -1)


def _points(arrays: list[np.ndarray]) -> np.ndarray:
    """Every ``(k, 2)`` array in ``arrays`` stacked into one ``(sum k, 2)`` float array."""
    return np.concatenate([np.asarray(a, dtype=np.float64).reshape(-1, 2) for a in arrays] or [np.zeros((0, 2))])


def world_reference(world: World) -> dict[str, np.ndarray]:
    """
    Every placed object (buildings, trees, fields, signs) and the road dimensions of ``world`` as named arrays.

    Keys under ``exact/`` hold what must not change at all (counts, vertex counts, names, kinds, colours, landmark
    nodes); keys under ``metres/`` hold positions, sizes, shares and bearings, compared to :data:`WORLD_ATOL`.
    """
    b, t, f, s = world.buildings, world.trees, world.fields, world.signs
    lines = [line for field_ in f for line in field_.lines]
    return {
        "exact/counts": np.array([len(b), len(t), len(f), len(s)]),
        "exact/seed": np.array(world.seed),
        "exact/building_vertices": np.array([len(x.footprint) for x in b], dtype=np.int64),
        "exact/building_rgb": _rgb([c for x in b for c in (x.facade_rgb, x.window_rgb, x.roof_rgb)], len(b)),
        "exact/building_names": np.array([x.name or "" for x in b], dtype=str),
        "exact/building_nodes": np.array([-1 if x.node is None else x.node for x in b], dtype=np.int64),
        "exact/building_sign_walls": np.array([-1 if x.sign_wall is None else x.sign_wall for x in b], dtype=np.int64),
        "exact/tree_rgb": _rgb([x.crown_rgb for x in t], len(t)),
        "exact/field_vertices": np.array([len(x.polygon) for x in f], dtype=np.int64),
        "exact/field_rgb": _rgb([x.rgb for x in f], len(f)),
        "exact/field_kinds": np.array([x.kind for x in f], dtype=str),
        "exact/field_names": np.array([x.name or "" for x in f], dtype=str),
        "exact/field_lines": np.array([len(x.lines) for x in f], dtype=np.int64),
        "exact/line_vertices": np.array([len(line) for line in lines], dtype=np.int64),
        "exact/sign_texts": np.array([x.text for x in s], dtype=str),
        "exact/sign_rgb": _rgb([c for x in s for c in (x.board_rgb, x.text_rgb)], len(s)),
        "metres/road": np.array([world.road_width, world.verge_width, world.sidewalk_width, world.clearance]),
        "metres/building_footprints": _points([x.footprint for x in b]),
        # height, storey height, window pitch (m); window width and height (shares of pitch and storey)
        "metres/building_sizes": np.array(
            [(x.height, x.floor_height, x.window_spacing, x.window_width, x.window_height) for x in b]
        ).reshape(len(b), 5),
        "metres/trees": np.array([(*x.position, x.radius, x.height) for x in t]).reshape(len(t), 4),
        "metres/field_polygons": _points([x.polygon for x in f]),
        "metres/field_lines": _points(lines),
        # position (m), bearing (degrees), width, height, elevation (m)
        "metres/signs": np.array([(*x.position, x.bearing, x.width, x.height, x.elevation) for x in s]).reshape(
            len(s), 6
        ),
    }


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


def golden_worlds() -> dict[str, np.ndarray]:
    """:func:`world_reference` of every golden world, flattened to ``"<world>/<key>"``."""
    return {
        f"{name}/{key}": value
        for name, world in _worlds(_graphs()).items()
        for key, value in world_reference(world).items()
    }


def _load(path: Path) -> dict[str, np.ndarray]:
    with np.load(path) as data:
        return {key: data[key] for key in data.files}


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    return _load(GOLDEN)


@pytest.fixture(scope="module")
def golden_world_arrays() -> dict[str, np.ndarray]:
    return _load(GOLDEN_WORLDS)


def test_golden_files_list_every_case(
    golden: dict[str, np.ndarray], golden_world_arrays: dict[str, np.ndarray]
) -> None:
    assert set(golden) == {f"view:{name}" for name, _ in golden_cases()}
    assert set(golden_world_arrays) == set(golden_worlds())


def test_worlds_place_the_same_objects(golden_world_arrays: dict[str, np.ndarray]) -> None:
    for key, value in golden_worlds().items():
        expected = golden_world_arrays[key]
        assert value.shape == expected.shape, (
            f"build_world placed different objects: {key} {value.shape} != {expected.shape}"
        )
        if "/exact/" in key:
            assert np.array_equal(value, expected), f"build_world placed different objects: {key} differs"
        else:
            worst = float(np.abs(value - expected).max(initial=0.0))
            assert worst <= WORLD_ATOL, f"build_world moved or resized objects: {key} differs by up to {worst:.3g} m"


def test_views_and_maps_are_pixel_identical_to_the_golden_ones(golden: dict[str, np.ndarray]) -> None:
    for name, draw in golden_cases():
        image, expected = draw(), golden[f"view:{name}"]
        assert image.dtype == np.uint8 and image.shape == expected.shape, name
        diff = np.abs(image.astype(np.int16) - expected.astype(np.int16))
        within_one = float((diff <= 1).mean())
        is_map = name.endswith("/map")
        min_share = MAP_MIN_SHARE_WITHIN_ONE if is_map else MIN_SHARE_WITHIN_ONE
        max_mean = MAP_MAX_MEAN_DIFF if is_map else MAX_MEAN_DIFF
        assert within_one >= min_share, f"{name}: only {within_one:.4%} of values within 1"
        assert float(diff.mean()) <= max_mean, f"{name}: mean difference {diff.mean():.3f}"


def _save(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write ``arrays`` to ``path`` atomically."""
    path.parent.mkdir(exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez_compressed(tmp, **arrays)
    tmp.replace(path)
    print(f"wrote {len(arrays)} entries, {path.stat().st_size / 1e6:.2f} MB to {path}")


def _write_golden() -> None:
    """Render every case and place every world with the current code and write both golden files."""
    _save(GOLDEN, {f"view:{name}": draw() for name, draw in golden_cases()})
    _save(GOLDEN_WORLDS, golden_worlds())


if __name__ == "__main__":
    _write_golden()
