"""Specification of the world around a road graph (buildings, trees, fields) and of the street-view renderer."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from campusnav_env.maps.campus import default_campus, generate_campus
from campusnav_env.rendering.street_view import RenderSettings, StreetViewRenderer
from campusnav_env.rendering.world import World, build_world

# Most behaviour does not depend on the image size: small views keep the tests fast.
SMALL = RenderSettings(width=160, height=120)


@pytest.fixture(scope="module")
def graph():
    return default_campus()


@pytest.fixture(scope="module")
def world(graph) -> World:
    return build_world(graph, seed=0)


@pytest.fixture(scope="module")
def renderer(world) -> StreetViewRenderer:
    return StreetViewRenderer(world, SMALL)


def _thumb(image: np.ndarray) -> np.ndarray:
    return cv2.resize(image, (32, 24), interpolation=cv2.INTER_AREA).astype(np.float64)


def _difference(a: np.ndarray, b: np.ndarray) -> float:
    """Mean absolute difference of 32x24 thumbnails (0..255)."""
    return float(np.abs(_thumb(a) - _thumb(b)).mean())


def _bearing(vector: np.ndarray) -> float:
    return math.degrees(math.atan2(vector[0], vector[1])) % 360.0


def _circular(a: float, b: float) -> float:
    """Absolute circular difference of two bearings in degrees, in [0, 180]."""
    d = abs(a - b) % 360.0
    return min(d, 360.0 - d)


def _view_towards(renderer: StreetViewRenderer, node: int, bearing: float) -> int:
    """The view of ``node`` whose view bearing (the road in its slot, else the compass) is nearest ``bearing``."""
    return int(np.argmin([_circular(b, bearing) for b in renderer.view_bearings[node]]))


# --------------------------------------------------------------------------------------------------------------------
# World
# --------------------------------------------------------------------------------------------------------------------


def test_world_is_deterministic_and_its_fingerprint_tracks_seed_and_graph(graph, world):
    again = build_world(graph, seed=0)
    assert again.fingerprint() == world.fingerprint()
    assert len(again.buildings) == len(world.buildings)
    assert all(np.array_equal(a.footprint, b.footprint) for a, b in zip(again.buildings, world.buildings, strict=True))
    assert build_world(graph, seed=1).fingerprint() != world.fingerprint()
    other = generate_campus(n_nodes=30, width=900.0, height=700.0, seed=3)
    assert build_world(other, seed=0).fingerprint() != world.fingerprint()


def test_world_holds_a_campus_mix_of_buildings_trees_and_fields(graph, world):
    assert world.road_width == pytest.approx(12.0)
    assert len(world.buildings) > 300
    heights = np.array([b.height for b in world.buildings])
    assert heights.min() >= 6.0 and heights.max() <= 40.0
    assert np.ptp(heights) > 20.0  # low halls and towers
    assert len({b.facade_rgb for b in world.buildings}) >= 8
    for b in world.buildings:
        assert b.footprint.ndim == 2 and b.footprint.shape[1] == 2 and len(b.footprint) in (4, 6)
        x, y = b.footprint[:, 0], b.footprint[:, 1]
        assert 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 50.0  # counter-clockwise, not degenerate
    assert len(world.trees) > 200
    kinds = [f.kind for f in world.fields]
    assert "park" in kinds
    sports = [f for f in world.fields if f.kind == "sports"]
    assert [f.name for f in sports] == ["Intramural fields"]
    assert len(sports[0].lines) >= 3  # pitch boundary, halfway line, centre circle, ...
    assert any(s.text == "Intramural fields" for s in world.signs)


def test_every_landmark_building_is_distinctive_and_faces_its_intersection(graph, world):
    names = [n for n in graph.landmarks if n != "Intramural fields"]
    colours = {world.landmark_building(n).facade_rgb for n in names}
    assert len(colours) == len(names)  # each landmark has its own colour
    ordinary = {b.facade_rgb for b in world.buildings if b.name is None}
    assert not colours & ordinary
    areas = []
    for name in names:
        b = world.landmark_building(name)
        assert b.node == graph.landmarks[name]
        node = graph.positions[b.node]
        # The sign wall is the wall nearest to the intersection, and it faces it.
        k = b.sign_wall
        a, c = b.footprint[k], b.footprint[(k + 1) % len(b.footprint)]
        outward = np.array([c[1] - a[1], a[0] - c[0]])
        assert outward @ (node - (a + c) / 2) > 0
        assert np.linalg.norm(b.footprint.mean(axis=0) - node) < 90.0
        x, y = b.footprint[:, 0], b.footprint[:, 1]
        areas.append(0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    typical = np.median([np.ptp(b.footprint[:, 0]) * np.ptp(b.footprint[:, 1]) for b in world.buildings if not b.name])
    assert np.median(areas) > typical  # landmarks are bigger than the typical building
    with pytest.raises(KeyError, match="Nowhere"):
        world.landmark_building("Nowhere")


def test_buildings_keep_clear_of_roads_and_of_each_other(graph, world):
    starts = np.concatenate([g[:-1] for g in graph.geometries])
    ends = np.concatenate([g[1:] for g in graph.geometries])
    limit = world.road_width / 2 + world.verge_width  # asphalt and verge stay free; sidewalks are the margin
    for b in world.buildings:
        # Dense samples along the outline (every 0.5 m) against every nearby road segment, brute force.
        f = b.footprint
        samples = np.concatenate(
            [
                a + np.linspace(0, 1, max(2, int(np.linalg.norm(c - a) / 0.5)))[:, None] * (c - a)
                for a, c in zip(f, np.roll(f, -1, axis=0), strict=True)
            ]
        )
        center, radius = f.mean(axis=0), np.linalg.norm(f - f.mean(axis=0), axis=1).max()
        seg = ends - starts
        t0 = np.clip(((center - starts) * seg).sum(-1) / np.maximum((seg * seg).sum(-1), 1e-9), 0, 1)
        near = np.linalg.norm(starts + t0[:, None] * seg - center, axis=1) < radius + 30
        a, c = starts[near], ends[near]
        ac = c - a
        t = np.clip(((samples[:, None] - a) * ac).sum(-1) / np.maximum((ac * ac).sum(-1), 1e-9), 0, 1)
        d = np.linalg.norm(a + t[..., None] * ac - samples[:, None], axis=-1)
        assert d.size == 0 or d.min() > limit, f"building {b.name or ''} at {center} is {d.min():.1f} m from a road"
        # No road segment lies wholly inside the footprint either: none of their end points is inside.
        contour = f.astype(np.float32)
        for p in np.concatenate([a, c]):
            assert cv2.pointPolygonTest(contour, (float(p[0]), float(p[1])), False) < 0
    lo = np.min([b.footprint.min(axis=0) for b in world.buildings], axis=0) - 5
    hi = np.max([b.footprint.max(axis=0) for b in world.buildings], axis=0) + 5
    canvas = np.zeros((int(hi[1] - lo[1]) + 1, int(hi[0] - lo[0]) + 1), dtype=np.uint8)
    for b in world.buildings:
        mask = np.zeros_like(canvas)
        cv2.fillPoly(mask, [np.round(b.footprint - lo).astype(np.int32)], 1)
        assert not (canvas & mask).any(), "two footprints overlap"
        canvas |= mask


def test_build_world_is_fast_and_checks_its_seed(graph):
    import time

    start = time.process_time()
    build_world(graph, seed=5)
    assert time.process_time() - start < 5.0
    with pytest.raises(ValueError, match="seed"):
        build_world(graph, seed="zero")


# --------------------------------------------------------------------------------------------------------------------
# Street views
# --------------------------------------------------------------------------------------------------------------------


def test_full_size_view_is_a_640x480_street_scene(world):
    renderer = StreetViewRenderer(world)
    node = world.graph.landmarks["Dreese Lab"]
    view = renderer.render_view(node, 0)
    assert view.shape == (480, 640, 3) and view.dtype == np.uint8
    assert len(np.unique(view.reshape(-1, 3), axis=0)) > 500
    sky, ground = view[:40].reshape(-1, 3).astype(float), view[-40:].reshape(-1, 3).astype(float)
    # Noon: the top of the image is mostly blue sky, the bottom rows are road and grass (no blue cast).
    assert np.mean(sky[:, 2] > sky[:, 0] + 20) > 0.3
    assert np.mean(ground[:, 2] > ground[:, 0] + 20) < 0.05
    assert np.abs(sky.mean(axis=0) - ground.mean(axis=0)).sum() > 60


def test_render_node_gives_four_distinct_views(renderer, graph):
    node = graph.landmarks["Cinema"]
    views = renderer.render_node(node)
    assert views.shape == (4, 120, 160, 3) and views.dtype == np.uint8
    for d in range(4):
        np.testing.assert_array_equal(views[d], renderer.render_view(node, d))
    for i in range(4):
        for j in range(i + 1, 4):
            assert _difference(views[i], views[j]) > 4.0


def test_rendering_is_deterministic_across_renderers(graph, renderer):
    fresh = StreetViewRenderer(build_world(graph, seed=0), SMALL)
    for node, d in ((0, 1), (50, 2), (100, 3)):
        np.testing.assert_array_equal(fresh.render_view(node, d), renderer.render_view(node, d))


def test_neighbours_along_a_straight_road_see_more_alike_than_far_apart_nodes(graph, renderer):
    positions = graph.positions
    views: dict[tuple[int, int], np.ndarray] = {}

    def view(node: int, d: int) -> np.ndarray:
        if (node, d) not in views:
            views[node, d] = renderer.render_view(node, d)
        return views[node, d]

    closer = total = 0
    for u, v in graph.roads:
        d = int(np.flatnonzero(graph.slots[u] == v)[0])  # view d of u looks down the road to v
        bearing = renderer.view_bearings[u, d]
        ahead = _view_towards(renderer, v, bearing)
        if _circular(renderer.view_bearings[v, ahead], bearing) >= 15:  # only where v has a view looking on ahead
            continue
        far = int(np.argmax(np.linalg.norm(positions - positions[u], axis=1)))
        far_view = view(far, _view_towards(renderer, far, bearing))
        closer += _difference(view(u, d), view(v, ahead)) < _difference(view(u, d), far_view)
        total += 1
    assert total >= 50
    # The same buildings and districts seen from one street: most neighbouring pairs look more alike (79% now).
    assert closer / total > 0.65, f"only {closer} of {total} neighbouring pairs were more alike than far-apart nodes"


def _colour_share(view: np.ndarray, rgb: tuple[int, int, int], tol: float = 0.04) -> float:
    """Share of pixels whose chromaticity (r, g, b) / (r + g + b) is within ``tol`` of ``rgb``'s."""
    pixels = view.reshape(-1, 3).astype(float)
    chroma = pixels / np.maximum(pixels.sum(axis=1, keepdims=True), 1.0)
    target = np.asarray(rgb, dtype=float) / sum(rgb)
    close = np.abs(chroma - target).max(axis=1) < tol
    return float(np.mean(close & (pixels.sum(axis=1) > 60)))


def test_landmark_building_appears_in_the_view_from_its_node_towards_it(graph, world, renderer):
    for name, node in graph.landmarks.items():
        if name == "Intramural fields":
            continue
        building = world.landmark_building(name)
        bearing = _bearing(building.footprint.mean(axis=0) - graph.positions[node])
        # The views look along the node's roads: take the one looking most nearly towards the building, and away
        off = [_circular(b, bearing) for b in renderer.view_bearings[node]]
        d, opposite = int(np.argmin(off)), int(np.argmax(off))
        towards = _colour_share(renderer.render_view(node, d), building.facade_rgb)
        away = _colour_share(renderer.render_view(node, opposite), building.facade_rgb)
        assert towards > 0.03, f"{name} not visible from its node {node} looking {'NESW'[d]}"
        assert towards > 3 * away


def test_time_of_day_and_cars_change_views_reproducibly(world, renderer, graph):
    node = graph.landmarks["Town house"]
    noon = renderer.render_node(node)
    evening = StreetViewRenderer(world, RenderSettings(width=160, height=120, time_of_day=21.0))
    night_a = evening.render_node(node, rng=np.random.default_rng(7))
    np.testing.assert_array_equal(night_a, evening.render_node(node, rng=np.random.default_rng(7)))
    assert night_a.mean() < noon.mean() - 40  # night is darker
    assert _difference(night_a[0], noon[0]) > 20
    morning = StreetViewRenderer(world, RenderSettings(width=160, height=120, time_of_day=9.0))
    a, b = (morning.render_view(node, 0, rng=np.random.default_rng(s)) for s in (1, 2))
    assert not np.array_equal(a, b)  # weather and exposure vary with the rng
    traffic = StreetViewRenderer(world, RenderSettings(width=160, height=120, cars=True))
    cars_a = traffic.render_node(node, rng=np.random.default_rng(3))
    np.testing.assert_array_equal(cars_a, traffic.render_node(node, rng=np.random.default_rng(3)))
    assert not np.array_equal(cars_a, noon)  # cars show up; light is unchanged without time_of_day
    assert not np.array_equal(cars_a, traffic.render_node(node, rng=np.random.default_rng(4)))
    # Without an rng the variation is still deterministic (seeded by the world seed and the node).
    np.testing.assert_array_equal(traffic.render_node(node), traffic.render_node(node))


def test_settings_key_and_bad_input():
    key = RenderSettings().key()
    assert key == RenderSettings().key()
    for field in ("width", "height", "fov_deg", "eye_height", "time_of_day", "cars"):
        assert field in key
    keys = {
        key,
        RenderSettings(width=320, height=240).key(),
        RenderSettings(time_of_day=18.0).key(),
        RenderSettings(cars=True).key(),
        RenderSettings(fov_deg=60.0).key(),
    }
    assert len(keys) == 5
    with pytest.raises(ValueError, match="width"):
        RenderSettings(width=4)
    with pytest.raises(ValueError, match="fov_deg"):
        RenderSettings(fov_deg=179.0)
    with pytest.raises(ValueError, match="time_of_day"):
        RenderSettings(time_of_day=25.0)


def test_render_rejects_bad_nodes_and_directions(renderer):
    with pytest.raises(ValueError, match="node 101"):
        renderer.render_view(101, 0)
    with pytest.raises(ValueError, match="direction"):
        renderer.render_view(0, 4)
    with pytest.raises(TypeError, match="World"):
        StreetViewRenderer("campus")  # type: ignore[arg-type]
