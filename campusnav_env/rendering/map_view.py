"""
Top-down RGB map of a road graph: roads, closures, landmarks, agent, goals, the route so far and extra routes.

Used by ``CampusNavEnv.render()`` and for route pictures (original vs re-routed). Drawn with OpenCV onto a light
background, anti-aliased, north up; the longer side of the image is ``size`` pixels and the other follows the map.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import cv2
import numpy as np

from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.rendering.street_view import view_bearings
from campusnav_env.rendering.world import landmark_colour

if TYPE_CHECKING:
    from campusnav_env.maps.road_graph import RoadGraph

__all__ = ["ROUTE_COLOURS", "draw_map", "title_band"]

BACKGROUND_RGB = (246, 245, 240)
ROAD_RGB = (168, 168, 172)
NODE_RGB = (96, 96, 100)
CLOSED_RGB = (220, 30, 36)
PATH_RGB = (30, 100, 220)
AGENT_RGB = (0, 150, 80)
GOAL_RGB = (250, 196, 20)
TEXT_RGB = (30, 30, 34)
PAGE_RGB = (255, 255, 255)
# Distinct colours of extra routes (matplotlib's tab10 without the path blue and the closure red).
ROUTE_COLOURS = (
    (255, 127, 14),
    (148, 103, 189),
    (44, 160, 44),
    (140, 86, 75),
    (227, 119, 194),
    (23, 190, 207),
    (188, 189, 34),
    (127, 127, 127),
)
_SHIFT = 4  # fractional bits of the drawing coordinates (sub-pixel accuracy)


class _Canvas:
    """World-to-pixel transform plus the image it draws on."""

    def __init__(self, graph: RoadGraph, size: int) -> None:
        points = np.concatenate(
            [np.asarray(graph.positions, dtype=np.float64).reshape(-1, 2)]
            + [np.asarray(g, dtype=np.float64) for g in graph.geometries]
        )
        lo, hi = points.min(axis=0), points.max(axis=0)
        span = np.maximum(hi - lo, 1.0)
        self.margin = max(12, round(size * 0.04))
        self.scale = (size - 2 * self.margin) / float(span.max())
        self.width = round(span[0] * self.scale) + 2 * self.margin
        self.height = round(span[1] * self.scale) + 2 * self.margin
        self.lo, self.hi = lo, hi
        self.unit = max(1.0, size / 400.0)  # line width unit in pixels
        self.image = np.empty((self.height, self.width, 3), dtype=np.uint8)
        self.image[...] = BACKGROUND_RGB

    def px(self, points: np.ndarray) -> np.ndarray:
        """Float pixel coordinates of world points (north up)."""
        p = np.asarray(points, dtype=np.float64)
        out = np.empty(p.shape)
        out[..., 0] = self.margin + (p[..., 0] - self.lo[0]) * self.scale
        out[..., 1] = self.margin + (self.hi[1] - p[..., 1]) * self.scale
        return out

    def fixed(self, pixels: np.ndarray) -> np.ndarray:
        return np.round(np.asarray(pixels) * (1 << _SHIFT)).astype(np.int32)

    def point(self, pixel: np.ndarray) -> tuple[int, int]:
        x, y = self.fixed(pixel)
        return int(x), int(y)

    def lines(self, polylines: Sequence[np.ndarray], rgb: tuple[int, int, int], width: float) -> None:
        if polylines:
            pts = [self.fixed(self.px(line)) for line in polylines]
            cv2.polylines(self.image, pts, False, rgb, max(1, round(width)), cv2.LINE_AA, _SHIFT)

    def disc(self, pixel: np.ndarray, radius: float, rgb: tuple[int, int, int], outline: tuple[int, int, int]) -> None:
        r = max(1, round(radius * (1 << _SHIFT)))
        cv2.circle(self.image, self.point(pixel), r, rgb, -1, cv2.LINE_AA, _SHIFT)
        cv2.circle(self.image, self.point(pixel), r, outline, 1, cv2.LINE_AA, _SHIFT)

    def text(self, origin: np.ndarray, text: str, scale: float, rgb: tuple[int, int, int] = TEXT_RGB) -> None:
        """Text with a light halo (``origin`` = bottom-left of the text) so that it stays legible over roads."""
        thick = max(1, round(scale * 1.6))
        at = (round(float(origin[0])), round(float(origin[1])))
        cv2.putText(self.image, text, at, cv2.FONT_HERSHEY_SIMPLEX, scale, BACKGROUND_RGB, thick + 2, cv2.LINE_AA)
        cv2.putText(self.image, text, at, cv2.FONT_HERSHEY_SIMPLEX, scale, rgb, thick, cv2.LINE_AA)

    def label(self, anchor: np.ndarray, text: str, scale: float, gap: float, taken: list[np.ndarray]) -> None:
        """
        Write ``text`` next to a dot at ``anchor``, in the first of eight places around it that lies inside the image
        and overlaps no earlier label or marker (``taken`` boxes, updated).
        """
        thick = max(1, round(scale * 1.6))
        (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick + 2)
        x, y = float(anchor[0]), float(anchor[1])
        options = [(x + gap, y + h / 2), (x - gap - w, y + h / 2), (x + gap, y - gap), (x + gap, y + gap + h)]
        options += [(x - w / 2, y - gap), (x - w / 2, y + gap + h), (x - gap - w, y - gap), (x - gap - w, y + gap + h)]
        boxes = [np.array([ox, oy - h, ox + w, oy + base]) for ox, oy in options]
        inside = [b for b in boxes if b[0] >= 1 and b[1] >= 1 and b[2] <= self.width - 1 and b[3] <= self.height - 1]
        free = [b for b in inside if all(_disjoint(b, t) for t in taken)]
        box = (free or inside or boxes)[0]
        taken.append(box)
        self.text(np.array([box[0], box[3] - base]), text, scale)


def _disjoint(a: np.ndarray, b: np.ndarray) -> bool:
    return bool(a[2] < b[0] or b[2] < a[0] or a[3] < b[1] or b[3] < a[1])


def _route_polyline(graph: RoadGraph, nodes: Sequence[int], what: str) -> np.ndarray | None:
    """World polyline of a node sequence, following each road's geometry (straight where nodes are not adjacent)."""
    nodes = [graph.check_node(n, what) for n in nodes]
    # Staying put (a blocked move) adds nothing to the drawn route.
    nodes = [n for i, n in enumerate(nodes) if i == 0 or n != nodes[i - 1]]
    if len(nodes) < 2:
        return None
    parts = [np.asarray(graph.positions[nodes[0]], dtype=np.float64)[None]]
    for u, v in itertools.pairwise(nodes):
        try:
            geometry = np.asarray(graph.geometries[graph.road_id(u, v)], dtype=np.float64)
        except KeyError:
            geometry = np.asarray(graph.positions[[u, v]], dtype=np.float64)
        if not np.allclose(geometry[0], graph.positions[u]):
            geometry = geometry[::-1]
        parts.append(geometry[1:])
    return np.concatenate(parts)


def _midpoint(polyline: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Point halfway along a polyline and the unit direction there."""
    seg = np.diff(polyline, axis=0)
    lengths = np.linalg.norm(seg, axis=1)
    half = lengths.sum() / 2
    cum = np.cumsum(lengths)
    k = min(int(np.searchsorted(cum, half)), len(seg) - 1)
    before = cum[k] - lengths[k]
    t = (half - before) / max(lengths[k], 1e-9)
    return polyline[k] + t * seg[k], seg[k] / max(lengths[k], 1e-9)


def _legend_corner(canvas: _Canvas, size: np.ndarray, markers: np.ndarray, landmarks: np.ndarray) -> np.ndarray:
    """The box ``[x0, y0, x1, y1]`` of the legend in the map corner that hides the fewest markers (goals and agent
    first, then landmarks); ties go to top left, top right, bottom left, bottom right."""
    inset = canvas.margin * 0.6
    x_options = (inset, canvas.width - inset - size[0])
    y_options = (inset, canvas.height - inset - size[1])
    boxes = [np.array([x, y, x + size[0], y + size[1]]) for y in y_options for x in x_options]

    reach = 8.0 * canvas.unit  # a star or arrow reaches this far from its node

    def hidden(box: np.ndarray, points: np.ndarray) -> int:
        px = canvas.px(points.reshape(-1, 2))
        lo, hi = box[:2] - reach, box[2:] + reach
        return int(np.sum(np.all((px >= lo) & (px <= hi), axis=1)))

    return min(boxes, key=lambda box: (hidden(box, markers), hidden(box, landmarks)))


def title_band(width: int, lines: Sequence[tuple[str, tuple[int, int, int]]], scale: float) -> np.ndarray:
    """
    A white band with one line of text per entry, shrunk where a line would not fit the width.

    The band's height depends on ``scale`` only, so that panels whose titles were shrunk line up with the others.
    """
    font = cv2.FONT_HERSHEY_SIMPLEX
    pad = max(4, round(8 * scale))
    rows = []
    for i, (text, rgb) in enumerate(lines):
        nominal = scale if i == 0 else scale * 0.85  # the detail line is smaller than the title
        s, thick = nominal, max(1, round(nominal * 2))
        # OpenCV renders text in steps of size, so shrink until what it measures fits
        while cv2.getTextSize(text, font, s, thick)[0][0] > width - 2 * pad and s > 0.15:
            s *= 0.95
            thick = max(1, round(s * 2))
        (_, h), base = cv2.getTextSize("Ag", font, nominal, max(1, round(nominal * 2)))
        rows.append((text, rgb, s, thick, h + base, base))
    band = np.full((pad * (len(rows) + 1) + sum(r[4] for r in rows), width, 3), PAGE_RGB, dtype=np.uint8)
    y = pad
    for text, rgb, s, thick, height, base in rows:
        cv2.putText(band, text, (pad, y + height - base), font, s, rgb, thick, cv2.LINE_AA)
        y += height + pad
    return band


def _star(center: np.ndarray, radius: float) -> np.ndarray:
    angles = -np.pi / 2 + np.arange(10) * np.pi / 5
    r = np.where(np.arange(10) % 2 == 0, radius, radius * 0.45)
    return center + np.stack([np.cos(angles) * r, np.sin(angles) * r], axis=1)


def draw_map(
    graph: RoadGraph | NavigationGraph,
    *,
    size: int = 800,
    agent: int | None = None,
    heading: int | None = None,
    goal: int | Sequence[int] | None = None,
    path: Sequence[int] = (),
    labels: bool = True,
    routes: Mapping[str, Sequence[int]] | None = None,
) -> np.ndarray:
    """
    Draw a road graph from above.

    :param graph: The road network; a ``NavigationGraph``'s closed roads are drawn in red with an X at their midpoint
    :param size: Length of the longer image side (pixels)
    :param agent: Node of the agent: a triangle pointing where its forward view looks (along the road in the slot of
        ``heading``, see :func:`~campusnav_env.rendering.street_view.view_bearings`), a disc if the heading is ``None``
    :param heading: Compass heading of the agent (0 N, 1 E, 2 S, 3 W)
    :param goal: Goal node or nodes (stars)
    :param path: Nodes visited so far, drawn as a blue route along the roads
    :param labels: Write the landmark names
    :param routes: Extra named routes (name -> node sequence) in distinct colours, with a legend
    :return: ``(H, W, 3)`` uint8 RGB image
    :raises ValueError: on a bad size or heading, or a node out of range
    """
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 64:
        raise ValueError(f"size must be an int >= 64 pixels, got {size!r}")
    if heading is not None and (isinstance(heading, bool) or heading not in (0, 1, 2, 3)):
        raise ValueError(f"heading must be 0 (N), 1 (E), 2 (S), 3 (W) or None, got {heading!r}")
    closed_roads = graph.closed_roads if isinstance(graph, NavigationGraph) else frozenset()
    graph = graph.map if isinstance(graph, NavigationGraph) else graph
    canvas = _Canvas(graph, int(size))
    unit = canvas.unit

    closed = {graph.road_id(u, v) for u, v in closed_roads}
    canvas.lines([g for i, g in enumerate(graph.geometries) if i not in closed], ROAD_RGB, 2.0 * unit)

    legend: list[tuple[str, tuple[int, int, int]]] = []
    for i, (name, nodes) in enumerate((routes or {}).items()):
        line = _route_polyline(graph, list(nodes), f"route {name!r} node")
        colour = ROUTE_COLOURS[i % len(ROUTE_COLOURS)]
        legend.append((str(name), colour))
        if line is not None:
            canvas.lines([line], colour, 3.0 * unit)

    line = _route_polyline(graph, list(path), "path node")
    if line is not None:
        canvas.lines([line], PATH_RGB, 2.5 * unit)

    for road in sorted(closed):
        geometry = np.asarray(graph.geometries[road], dtype=np.float64)
        canvas.lines([geometry], CLOSED_RGB, 2.5 * unit)
        mid, direction = _midpoint(canvas.px(geometry))
        arm = 4.0 * unit
        for angle in (math.pi / 4, -math.pi / 4):
            c, s = math.cos(angle), math.sin(angle)
            d = np.array([direction[0] * c - direction[1] * s, direction[0] * s + direction[1] * c]) * arm
            cv2.line(
                canvas.image,
                canvas.point(mid - d),
                canvas.point(mid + d),
                CLOSED_RGB,
                max(1, round(1.5 * unit)),
                cv2.LINE_AA,
                _SHIFT,
            )

    for p in canvas.px(graph.positions):
        cv2.circle(canvas.image, canvas.point(p), round(1.2 * unit * (1 << _SHIFT)), NODE_RGB, -1, cv2.LINE_AA, _SHIFT)

    text_scale = 0.32 * unit
    taken: list[np.ndarray] = []
    goals = [] if goal is None else [goal] if isinstance(goal, (int, np.integer)) else list(goal)
    goal_nodes = [graph.check_node(g, "goal") for g in goals]
    if agent is not None:
        agent = graph.check_node(agent, "agent")
    legend_box = None
    if legend:
        row = 11.0 * unit
        box_w = 24 * unit + max(cv2.getTextSize(n, cv2.FONT_HERSHEY_SIMPLEX, text_scale, 1)[0][0] for n, _ in legend)
        size_xy = np.array([box_w + 6 * unit, row * (len(legend) - 0.4) + 6 * unit])
        markers = [*goal_nodes, *([] if agent is None else [agent])]
        landmarks = graph.positions[list(graph.landmarks.values())]
        legend_box = _legend_corner(canvas, size_xy, graph.positions[markers], landmarks)
        x, y = legend_box[0] + 3 * unit, legend_box[1] + 6 * unit
        taken.append(legend_box)
    for node in [*goal_nodes, *([] if agent is None else [agent])]:
        # Labels keep clear of the goal stars, the agent marker and the landmark dots too.
        p = canvas.px(graph.positions[node])
        taken.append(np.concatenate([p - 7.0 * unit, p + 7.0 * unit]))
    for node in graph.landmarks.values():
        p = canvas.px(graph.positions[node])
        taken.append(np.concatenate([p - 3.5 * unit, p + 3.5 * unit]))
    for name, node in sorted(graph.landmarks.items(), key=lambda item: (item[1], item[0])):
        p = canvas.px(graph.positions[node])
        canvas.disc(p, 3.0 * unit, landmark_colour(name), TEXT_RGB)
        if labels:
            marked = node in goal_nodes or node == agent  # the star or arrow is bigger than the dot
            canvas.label(p, name, text_scale, (7.5 if marked else 4.5) * unit, taken)

    for node in goal_nodes:
        p = canvas.px(graph.positions[node])
        star = canvas.fixed(_star(p, 7.0 * unit))
        cv2.fillPoly(canvas.image, [star], GOAL_RGB, cv2.LINE_AA, _SHIFT)
        cv2.polylines(canvas.image, [star], True, TEXT_RGB, 1, cv2.LINE_AA, _SHIFT)

    if agent is not None:
        p = canvas.px(graph.positions[agent])
        if heading is None:
            canvas.disc(p, 4.5 * unit, AGENT_RGB, TEXT_RGB)
        else:
            # The agent faces where its forward view looks: the road in slot ``heading`` (its compass bearing if empty)
            bearing = math.radians(view_bearings(graph)[agent, heading])
            ahead = np.array([math.sin(bearing), -math.cos(bearing)])  # image y points south
            side = np.array([-ahead[1], ahead[0]])
            r = 7.0 * unit
            tri = canvas.fixed(
                np.array([p + ahead * r, p - ahead * r * 0.6 + side * r * 0.6, p - ahead * r * 0.6 - side * r * 0.6])
            )
            cv2.fillPoly(canvas.image, [tri], AGENT_RGB, cv2.LINE_AA, _SHIFT)
            cv2.polylines(canvas.image, [tri], True, TEXT_RGB, 1, cv2.LINE_AA, _SHIFT)

    if legend_box is not None:
        top_left = (round(legend_box[0]), round(legend_box[1]))
        bottom_right = (round(legend_box[2]), round(legend_box[3]))
        cv2.rectangle(canvas.image, top_left, bottom_right, (255, 255, 255), -1)
        cv2.rectangle(canvas.image, top_left, bottom_right, NODE_RGB, 1)
        for i, (name, colour) in enumerate(legend):
            yy = y + i * row
            cv2.line(
                canvas.image,
                (round(x), round(yy)),
                (round(x + 16 * unit), round(yy)),
                colour,
                max(1, round(3 * unit)),
                cv2.LINE_AA,
            )
            canvas.text(np.array([x + 20 * unit, yy + 3 * unit]), name, text_scale)
    return canvas.image
