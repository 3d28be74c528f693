"""Specification of the top-down map (env.render()) and of the street-view contact sheet."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from campusnav_env.maps.campus import default_campus
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.rendering.contact_sheet import default_nodes, main, write_contact_sheet
from campusnav_env.rendering.map_view import AGENT_RGB, CLOSED_RGB, GOAL_RGB, PATH_RGB, ROUTE_COLOURS, draw_map
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


def test_named_routes_get_distinct_colours_and_a_legend(graph):
    original = graph.shortest_path(0, graph.landmarks["Cinema"])
    detour = graph.shortest_path(graph.n_nodes - 1, graph.landmarks["Cinema"])
    image = draw_map(graph, routes={"original": original, "re-routed": detour})
    for colour in ROUTE_COLOURS[:2]:
        assert _share(image, colour, tol=6) > 0.001
    with_legend = image[: image.shape[0] // 6, : image.shape[1] // 4]
    assert _share(with_legend, (255, 255, 255), tol=0) > 0.05  # the legend box


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
