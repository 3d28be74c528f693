"""Specification of the top-down map (env.render()) and of the street-view contact sheet."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from campusnav_env.maps.campus import default_campus, generate_city
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.rendering.contact_sheet import default_nodes, main, write_contact_sheet
from campusnav_env.rendering.map_view import (
    AGENT_RGB,
    CLOSED_RGB,
    DENSITY_NODES,
    GOAL_RGB,
    PATH_RGB,
    ROUTE_COLOURS,
    draw_map,
    map_layout,
    map_size,
)
from campusnav_env.rendering.palette import ROAD_RGB
from campusnav_env.rendering.street_view import RenderSettings


@pytest.fixture()
def graph() -> NavigationGraph:
    return NavigationGraph(default_campus())


def _share(image: np.ndarray, rgb: tuple[int, int, int], tol: int = 12) -> float:
    return float(np.mean(np.abs(image.astype(int) - np.asarray(rgb)).max(axis=-1) <= tol))


def test_map_is_rgb_with_the_aspect_of_the_road_network(graph):
    image = draw_map(graph, size=600)
    assert image.dtype == np.uint8 and image.ndim == 3 and image.shape[2] == 3
    height, width = image.shape[:2]
    assert max(height, width) == 600
    points = np.concatenate(graph.map.geometries)
    span = np.ptp(points, axis=0)
    assert width / height == pytest.approx(span[0] / span[1], rel=0.08)
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 20  # roads, nodes, landmark colours, text


def test_closing_a_road_marks_it_red(graph):
    before = draw_map(graph)
    assert _share(before, CLOSED_RGB) == 0.0
    u, v = graph.map.roads[len(graph.map.roads) // 2]
    graph.close_road(u, v, force=True)
    after = draw_map(graph)
    assert _share(after, CLOSED_RGB) > 0.0005
    assert not np.array_equal(before, after)
    graph.reopen_road(u, v)
    np.testing.assert_array_equal(draw_map(graph), before)


def test_agent_heading_goal_and_path_are_drawn(graph):
    goal = graph.landmarks["Dreese Lab"]
    start = 0
    path = graph.shortest_path(start, goal)
    plain = draw_map(graph, labels=False)
    here = draw_map(graph, agent=path[0], heading=0, goal=goal, path=path[:1], labels=False)
    moved = draw_map(graph, agent=path[2], heading=0, goal=goal, path=path[:3], labels=False)
    turned = draw_map(graph, agent=path[2], heading=1, goal=goal, path=path[:3], labels=False)
    assert not np.array_equal(here, moved)
    assert not np.array_equal(moved, turned)
    assert _share(here, GOAL_RGB) > 0 and _share(plain, GOAL_RGB) == 0
    assert _share(moved, PATH_RGB) > _share(here, PATH_RGB)
    several = draw_map(graph, goal=[graph.landmarks[n] for n in ("Cinema", "Town house")], labels=False)
    assert _share(several, GOAL_RGB) > 0


def _routes_after_closing(graph: NavigationGraph, *roads: tuple[int, int]) -> dict[str, list[int]]:
    """The learned route from node 21 to Dreese Lab, then the roads closed and the route re-planned around them."""
    goal = graph.landmarks["Dreese Lab"]
    learned = graph.shortest_path(21, goal)
    for u, v in roads:
        graph.close_road(u, v, force=True)
    return {"learned route (before)": learned, "re-routed": graph.shortest_path(21, goal)}


def _box_pixels(mask: np.ndarray, box: tuple[float, float, float, float]) -> int:
    x0, y0, x1, y1 = (int(np.floor(box[0])), int(np.floor(box[1])), int(np.ceil(box[2])), int(np.ceil(box[3])))
    return int(mask[max(0, y0) : y1, max(0, x0) : x1].sum())


def _overlap(a: tuple[float, ...], b: tuple[float, ...]) -> bool:
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def _colour_mask(image: np.ndarray, colours: list[tuple[int, int, int]], tol: int = 40) -> np.ndarray:
    return np.any([np.abs(image.astype(int) - np.asarray(c)).max(axis=-1) <= tol for c in colours], axis=0)


def test_route_pictures_have_a_legend_of_routes_start_goal_closed_roads_and_landmarks(graph):
    routes = _routes_after_closing(graph, (69, 81))
    options = dict(agent=21, heading=0, goal=graph.landmarks["Dreese Lab"], routes=routes)
    layout = map_layout(graph, **options)
    texts = [entry.text for entry in layout.legend]
    assert texts == [
        "learned route (before)",
        "re-routed",
        "start",
        "goal",
        "closed road",
        "landmark (named on the map)",
    ]
    assert [entry.symbol for entry in layout.legend] == ["line", "line", "start", "goal", "closed", "landmark"]
    assert [entry.rgb for entry in layout.legend[:2]] == list(ROUTE_COLOURS[:2])
    # A band below the map: it hides nothing of the map, and every entry lies in it, clear of the others
    assert layout.legend_box is not None and layout.legend_box[1] >= layout.map_box[3]
    assert layout.shape == (round(layout.legend_box[3]), round(layout.map_box[2]))
    for i, entry in enumerate(layout.legend):
        assert layout.legend_box[1] <= entry.box[1] and entry.box[3] <= layout.legend_box[3]
        assert all(not _overlap(entry.box, other.box) for other in layout.legend[i + 1 :])
    image = draw_map(graph, **options)
    band = image[round(layout.legend_box[1]) :]
    for colour in (*ROUTE_COLOURS[:2], AGENT_RGB, GOAL_RGB, CLOSED_RGB):
        assert _share(band, colour, tol=6) > 0.0005
    # A route that never moves has no line to show: the legend says so
    stuck = map_layout(graph, **{**options, "routes": {**routes, "re-routed": [21, 21, 21]}})
    assert stuck.legend[1].text == "re-routed (never leaves node 21)"
    # Without labels on the map the legend names the landmarks by colour
    unlabelled = map_layout(graph, **options, labels=False)
    assert [e.text for e in unlabelled.legend if e.symbol == "landmark"] == sorted(graph.landmarks)
    assert not [label for label in unlabelled.labels if label.kind == "landmark"]
    # Plain maps (env.render()) keep to the map: no legend, no bands
    plain = map_layout(graph, agent=21, heading=0, path=[21, 20])
    assert plain.legend == () and plain.legend_box is None and plain.title_box is None
    assert plain.shape == (round(plain.map_box[3]), round(plain.map_box[2]))


def test_the_learned_route_shows_where_the_re_routed_one_follows_it(graph):
    # Closing 81-82 leaves the way from 21 as it was: the re-routed line lies exactly on the learned one
    routes = _routes_after_closing(graph, (81, 82))
    assert routes["learned route (before)"] == routes["re-routed"]
    layout = map_layout(graph, routes=routes, labels=False)
    image = draw_map(graph, routes=routes, labels=False)
    top, bottom = round(layout.map_box[1]), round(layout.map_box[3])
    learned, rerouted = (_share(image[top:bottom], colour, tol=6) for colour in ROUTE_COLOURS[:2])
    assert learned > 0.002 and rerouted > 0.002
    # Drawn wider underneath, and the legend says so with the same widths
    assert layout.legend[0].width > layout.legend[1].width


def test_labels_keep_clear_of_routes_closed_roads_and_each_other(graph):
    # Dreese Lab's closed road 81-82 runs east of it, where a label goes first when it is free (the old placement
    # wrote "Dreese Lab" over it); the route from 21 reaches it from the south
    routes = _routes_after_closing(graph, (81, 82))
    options = dict(size=800, agent=21, heading=0, goal=graph.landmarks["Dreese Lab"], routes=routes)
    layout = map_layout(graph, **options)
    bare = draw_map(graph, **options, labels=False)  # the same lines, without names
    lines = _colour_mask(bare, [*ROUTE_COLOURS[:2], CLOSED_RGB])
    dreese = layout.nodes[graph.landmarks["Dreese Lab"]]
    east_of_dreese = (dreese[0] + 10, dreese[1] - 8, dreese[0] + 90, dreese[1] + 8)
    assert _box_pixels(lines, east_of_dreese) > 50

    labels = [label for label in layout.labels if label.kind in ("landmark", "start")]
    assert sorted(label.text for label in labels) == sorted([*graph.landmarks, "start 21"])
    for i, label in enumerate(labels):
        assert _box_pixels(lines, label.box) == 0, label
        assert all(not _overlap(label.box, other.box) for other in labels[i + 1 :]), label
        x0, y0, x1, y1 = label.box
        assert (
            layout.map_box[0] <= x0 and layout.map_box[1] <= y0 and x1 <= layout.map_box[2] and y1 <= layout.map_box[3]
        )
        # Each name is nearer its own node than any other named node
        named = [graph.landmarks[n] for n in graph.landmarks] + [21]
        own = _distance_to_box(layout.nodes[label.node], label.box)
        assert all(own <= _distance_to_box(layout.nodes[n], label.box) for n in named if n != label.node), label

    # The text drawn stays inside the boxes (and the leader lines): the layout is what was drawn
    image = draw_map(graph, **options)
    top, bottom = round(layout.map_box[1]), round(layout.map_box[3])
    changed = np.any(image[top:bottom] != bare[top:bottom], axis=-1)
    allowed = np.zeros(changed.shape, dtype=np.uint8)
    for label in layout.labels:
        x0, y0, x1, y1 = label.box
        cv2.rectangle(
            allowed, (int(x0) - 1, int(y0) - 1 - top), (int(np.ceil(x1)) + 1, int(np.ceil(y1)) + 1 - top), 1, -1
        )
        if label.leader is not None:
            a, b = np.round(label.leader[:2]).astype(int), np.round(label.leader[2:]).astype(int)
            cv2.line(allowed, (a[0], a[1] - top), (b[0], b[1] - top), 1, 3)
    assert changed.any() and not (changed & (allowed == 0)).any()


def _distance_to_box(point: np.ndarray, box: tuple[float, float, float, float]) -> float:
    dx = max(box[0] - point[0], 0.0, point[0] - box[2])
    dy = max(box[1] - point[1], 0.0, point[1] - box[3])
    return float(np.hypot(dx, dy))


def test_node_ids_are_written_beside_their_intersections(graph):
    routes = _routes_after_closing(graph, (69, 81))
    options = dict(agent=21, heading=0, goal=graph.landmarks["Dreese Lab"], routes=routes)
    layout = map_layout(graph, **options, node_ids=True)
    ids = [label for label in layout.labels if label.kind == "node id"]
    assert [label.text for label in ids] == [str(n) for n in range(graph.n_nodes)]
    assert map_layout(graph, **options).labels == tuple(label for label in layout.labels if label.kind != "node id")
    names = [label for label in layout.labels if label.kind != "node id"]
    size = np.array([[label.box[2] - label.box[0], label.box[3] - label.box[1]] for label in ids])
    names_h = min(label.box[3] - label.box[1] for label in names)
    assert size[:, 1].max() < names_h  # small print
    bare = draw_map(graph, **options, labels=False)
    lines = _colour_mask(bare, [*ROUTE_COLOURS[:2], CLOSED_RGB])
    clear = 0
    for i, label in enumerate(ids):
        assert _distance_to_box(layout.nodes[label.node], label.box) < 2 * size[i, 1]  # beside its node
        assert not any(_overlap(label.box, name.box) for name in names)  # names stay readable
        others = [other for other in ids if other is not label]
        clear += _box_pixels(lines, label.box) == 0 and not any(_overlap(label.box, o.box) for o in others)
    assert clear >= 0.95 * len(ids)
    assert not np.array_equal(draw_map(graph, **options, node_ids=True), draw_map(graph, **options))


def test_a_title_band_goes_above_the_map(graph):
    routes = _routes_after_closing(graph, (69, 81))
    options = dict(agent=21, heading=0, goal=graph.landmarks["Dreese Lab"], routes=routes)
    title = "start 21 -> Dreese Lab (81) | closed: 69-81 | success 0.99, SPL 0.98\nDCQN, 20000 steps"
    untitled = map_layout(graph, **options)
    layout = map_layout(graph, **options, title=title)
    assert layout.title == ("start 21 -> Dreese Lab (81) | closed: 69-81 | success 0.99, SPL 0.98", "DCQN, 20000 steps")
    assert layout.title_box is not None and layout.title_box[1] == 0 and layout.title_box[3] == layout.map_box[1]
    band = round(layout.map_box[1])
    assert layout.shape == (untitled.shape[0] + band, untitled.shape[1])
    # Everything else moves down by the band
    for moved, plain in zip(layout.labels, untitled.labels, strict=True):
        assert moved.box == pytest.approx((plain.box[0], plain.box[1] + band, plain.box[2], plain.box[3] + band))
    image, plain_image = draw_map(graph, **options, title=title), draw_map(graph, **options)
    np.testing.assert_array_equal(image[band:], plain_image)
    assert _share(image[:band], (255, 255, 255), tol=0) > 0.7 and _share(image[:band], (30, 30, 34), tol=60) > 0.01
    # A line too long for the width breaks at its " | " separators
    narrow = map_layout(graph, **options, size=300, title=title)
    assert len(narrow.title) > 2 and " | ".join(narrow.title[:-1]) == title.splitlines()[0]


def test_maps_are_deterministic_and_layouts_take_only_draw_map_options(graph):
    routes = _routes_after_closing(graph, (69, 81))
    options = dict(agent=21, heading=0, goal=graph.landmarks["Dreese Lab"], routes=routes, node_ids=True, title="t")
    np.testing.assert_array_equal(draw_map(graph, **options), draw_map(graph, **options))
    assert map_layout(graph, **options) == map_layout(graph, **options)
    assert map_layout(graph, **options).shape == draw_map(graph, **options).shape[:2]
    with pytest.raises(TypeError, match="legend"):
        map_layout(graph, legend=True)


def test_map_rejects_bad_input(graph):
    with pytest.raises(ValueError, match="size"):
        draw_map(graph, size=10)
    with pytest.raises(ValueError, match="agent 999"):
        draw_map(graph, agent=999)
    with pytest.raises(ValueError, match="heading"):
        draw_map(graph, agent=0, heading=4)
    with pytest.raises(ValueError, match="path node -1"):
        draw_map(graph, path=[0, -1])


def test_contact_sheet_is_a_readable_png_of_views_above_the_map(tmp_path, graph):
    small = RenderSettings(width=160, height=120)
    nodes = default_nodes(graph.map, 2)
    assert nodes == [graph.landmarks["Dreese Lab"], graph.landmarks["Town house"]]
    out = write_contact_sheet(tmp_path / "sheet.png", graph=graph.map, nodes=nodes, settings=small)
    image = cv2.imread(str(out))
    assert image is not None
    assert image.shape[1] == 4 * 160 + 5 * 6  # four views per row with gaps
    assert image.shape[0] > 2 * 120 + 300  # two rows of views and the map
    assert [p.name for p in tmp_path.iterdir()] == ["sheet.png"]  # no temp file left behind
    with pytest.raises(FileNotFoundError, match="missing"):
        write_contact_sheet(tmp_path / "missing" / "sheet.png", graph=graph.map, nodes=nodes, settings=small)
    with pytest.raises(ValueError, match="node 500"):
        write_contact_sheet(tmp_path / "bad.png", graph=graph.map, nodes=[500], settings=small)


def test_contact_sheet_command_line(tmp_path, capsys):
    out = tmp_path / "views.png"
    assert main(["--out", str(out), "--nodes", "3", "--time-of-day", "19", "--cars"]) == 0
    assert capsys.readouterr().out.strip() == str(out)
    image = cv2.imread(str(out))
    assert image is not None and image.shape[1] == 4 * 320 + 5 * 6


def _arrow_bearing(image: np.ndarray) -> float:
    """
    Bearing (degrees clockwise from north) the agent's triangle points to: from its centroid to its farthest pixel,
    the tip (the tip is 1.07 r from the centroid, the base corners 0.8 r).
    """
    rows, cols = np.nonzero(np.abs(image.astype(int) - np.asarray(AGENT_RGB)).max(axis=-1) <= 12)
    pixels = np.stack([cols, rows], axis=1).astype(float)
    offsets = pixels - pixels.mean(axis=0)
    east, south = offsets[np.argmax(np.linalg.norm(offsets, axis=1))]
    return float(np.degrees(np.arctan2(east, -south)) % 360.0)


def test_agent_arrow_points_where_its_forward_view_looks(graph):
    # Node 42's road to 43 leaves at 81 degrees but sits in slot S: heading S, forward takes it and the view looks
    # along it, so the arrow points east-north-east rather than south. Empty slots keep their compass bearing.
    road_map = graph.map
    assert road_map.slots[42, 2] == 43
    image = draw_map(graph, agent=42, heading=2, labels=False)
    assert abs(_arrow_bearing(image) - road_map.slot_bearings[42, 2]) < 10.0
    dead_end = int(np.flatnonzero((road_map.slots >= 0).sum(axis=1) == 1)[0])
    empty = int(np.flatnonzero(road_map.slots[dead_end] < 0)[0])
    image = draw_map(graph, agent=dead_end, heading=empty, labels=False)
    off = abs(_arrow_bearing(image) - 90.0 * empty) % 360.0
    assert min(off, 360.0 - off) < 10.0


def test_routes_take_the_colours_given_by_name(graph):
    path = graph.shortest_path(0, graph.landmarks["Dreese Lab"])
    teal, orange = (23, 190, 207), ROUTE_COLOURS[0]
    routes = {"shortest path": path, "learned route": path}
    image = draw_map(graph, routes=routes, labels=False, colours={"shortest path": teal, "learned route": orange})
    layout = map_layout(graph, routes=routes, labels=False, colours={"shortest path": teal, "learned route": orange})
    assert [(e.text, e.rgb) for e in layout.legend[:2]] == [("shortest path", teal), ("learned route", orange)]
    assert _share(image, teal, tol=6) > 0.001 and _share(image, orange, tol=6) > 0.001
    # A route without a colour takes the first of ROUTE_COLOURS that no other route was given
    only = map_layout(graph, routes={"a": path, "b": path}, labels=False, colours={"b": orange})
    assert [e.rgb for e in only.legend[:2]] == [ROUTE_COLOURS[1], orange]
    with pytest.raises(ValueError, match=r"colours given for routes that are not drawn: \['c'\]"):
        draw_map(graph, routes={"a": path}, colours={"c": orange})


def test_a_closed_road_is_drawn_over_the_route_that_travels_it(graph):
    path = graph.shortest_path(0, graph.landmarks["Dreese Lab"])
    u, v = path[len(path) // 2], path[len(path) // 2 + 1]
    graph.close_road(u, v, force=True)
    layout = map_layout(graph, routes={"learned route": path}, labels=False)
    image = draw_map(graph, routes={"learned route": path}, labels=False)
    geometry = graph.map.geometries[graph.map.road_id(u, v)]
    # Along the road (its middle 60%), the closed road's red shows through the wide orange route drawn under it
    points = layout.nodes[[u, v]]
    along = [points[0] + (points[1] - points[0]) * t for t in np.linspace(0.2, 0.8, 9)]
    assert len(geometry) == 2  # a straight road: its pixels are on the line between the nodes
    windows = [image[round(y) - 3 : round(y) + 4, round(x) - 3 : round(x) + 4] for x, y in along]
    assert all(_share(w[2:5, 2:5], CLOSED_RGB, 30) > 0 for w in windows)
    # ... in a light casing: the route's orange does not show along the closed road
    assert max(_share(w, ROUTE_COLOURS[0], 40) for w in windows) == 0.0


def test_dense_maps_are_drawn_larger_and_with_thinner_lines():
    assert map_size(DENSITY_NODES) == map_size(16) == 600
    assert map_size(1000) == 1600 and map_size(10_000) == 1600  # at most the cap
    assert 600 < map_size(300) < 1600
    with pytest.raises(ValueError, match="n_nodes must be a positive int"):
        map_size(0)
    city = generate_city(1000, seed=0)
    campus = default_campus()
    # Roads cover about as much of a 1,000-intersection city drawn at its size as of the campus at 600 pixels
    # (lines a fixed share of the canvas would cover several times more and merge)
    shares = [_share(draw_map(g, size=map_size(g.n_nodes), labels=False), ROAD_RGB, 20) for g in (campus, city)]
    assert shares[1] < 1.4 * shares[0]
