"""
Top-down RGB map of a road graph: roads, closures, landmarks, agent, goals, the route so far and extra routes.

Used by ``CampusNavEnv.render()`` and for route pictures (learned vs re-routed). Drawn with OpenCV onto a light
background, anti-aliased, north up; the longer side of the map is ``size`` pixels and the other follows the map. A
title band (``title``) goes above the map and, with ``routes``, a legend band below it, so that neither hides the map.

Text is placed greedily, in order of importance (start and goal, landmark names, node ids): each label takes the
candidate position around its node that covers no route, closed road, marker or earlier label where one exists, and
otherwise the least; among free ones it prefers near positions that cover few plain roads. :func:`map_layout` says
where everything went.
"""

from __future__ import annotations

import inspect
import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np

from campusnav_env.maps.compass import view_bearings
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.rendering.palette import (
    AGENT_RGB,
    BACKGROUND_RGB,
    CLOSED_RGB,
    GOAL_RGB,
    NODE_ID_RGB,
    NODE_RGB,
    PAGE_RGB,
    PATH_RGB,
    ROAD_RGB,
    ROUTE_COLOURS,
    TEXT_RGB,
    landmark_colour,
)

if TYPE_CHECKING:
    from campusnav_env.maps.road_graph import RoadGraph

__all__ = [
    "DENSITY_NODES",
    "ROUTE_COLOURS",
    "LegendEntry",
    "MapLabel",
    "MapLayout",
    "draw_map",
    "map_layout",
    "map_size",
    "title_band",
]

# Intersections of the built-in campus: a map of more is denser on the same canvas, so its lines are drawn thinner
# (:class:`_Canvas`) and its pictures are drawn larger (:func:`map_size`)
DENSITY_NODES = 101
_SHIFT = 4  # fractional bits of the drawing coordinates (sub-pixel accuracy)
_FONT = cv2.FONT_HERSHEY_SIMPLEX
RGB = tuple[int, int, int]
Box = tuple[float, float, float, float]  # x0, y0, x1, y1 in image pixels


@dataclass(frozen=True)
class MapLabel:
    """
    A text written on the map.

    :param text: What it says
    :param kind: ``"start"``, ``"goal"``, ``"landmark"`` or ``"node id"``
    :param node: The node it names
    :param box: ``(x0, y0, x1, y1)``: the image pixels the text and its halo cover
    :param leader: ``(x0, y0, x1, y1)``: the thin line from the node to a label placed away from it, else ``None``
    """

    text: str
    kind: str
    node: int
    box: Box
    leader: Box | None = None


@dataclass(frozen=True)
class LegendEntry:
    """
    One legend entry: a symbol and what it stands for.

    :param symbol: ``"line"`` (a route), ``"start"``, ``"goal"``, ``"closed"`` (a closed road) or ``"landmark"``
    :param text: Its text
    :param rgb: Colour of the symbol
    :param width: Line width of a route as drawn on the map (pixels); 0 for the other symbols
    :param box: ``(x0, y0, x1, y1)``: the image pixels of symbol and text
    """

    symbol: str
    text: str
    rgb: RGB
    width: float
    box: Box


@dataclass(frozen=True)
class MapLayout:
    """
    Where :func:`draw_map` put things, in pixels of the image it returns.

    :param shape: ``(height, width)`` of the image
    :param map_box: The map itself
    :param title: Lines of the title band (empty without a title)
    :param title_box: The title band above the map, or ``None``
    :param legend: The legend's entries, in order
    :param legend_box: The legend band below the map, or ``None``
    :param labels: Every text on the map, in the order placed
    :param nodes: ``(n_nodes, 2)`` pixel position (x, y) of every node
    """

    shape: tuple[int, int]
    map_box: Box
    title: tuple[str, ...]
    title_box: Box | None
    legend: tuple[LegendEntry, ...]
    legend_box: Box | None
    labels: tuple[MapLabel, ...]
    nodes: np.ndarray = field(compare=False, repr=False)


class _Canvas:
    """World-to-pixel transform plus the image it draws on and the masks of what text must keep clear of."""

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
        # Line width unit in pixels: a fixed share of the canvas on the campus, thinner on denser maps (the street
        # spacing on screen shrinks with the square root of the node count), so that roads do not merge
        density = math.sqrt(max(1.0, graph.n_nodes / DENSITY_NODES))
        self.unit = max(1.0, size / 400.0 / density)
        # Text and markers thin out more slowly: a few names among many streets stay readable
        self.text_unit = max(1.0, size / 400.0 / math.sqrt(density))
        self.image = np.empty((self.height, self.width, 3), dtype=np.uint8)
        self.image[...] = BACKGROUND_RGB
        # Text must not cover `hard` pixels (routes, closed roads, markers) and had better not cover `soft` ones
        # (plain roads 1, intersections more)
        self.hard = np.zeros((self.height, self.width), dtype=np.uint8)
        self.soft = np.zeros((self.height, self.width), dtype=np.uint8)

    def px(self, points: np.ndarray) -> np.ndarray:
        """Float pixel coordinates of world points (north up)."""
        p = np.asarray(points, dtype=np.float64)
        out = np.empty(p.shape)
        out[..., 0] = self.margin + (p[..., 0] - self.lo[0]) * self.scale
        out[..., 1] = self.margin + (self.hi[1] - p[..., 1]) * self.scale
        return out

    def lines(
        self, polylines: Sequence[np.ndarray], rgb: RGB, width: float, mask: np.ndarray | None = None, value: int = 1
    ) -> None:
        """World polylines; ``mask`` (if any) gets ``value`` a pixel wider on each side than the drawn line."""
        _polylines(self.image, [self.px(line) for line in polylines], rgb, width, mask, value)

    def mask_disc(self, mask: np.ndarray, pixel: np.ndarray, radius: float, value: int = 1) -> None:
        cv2.circle(mask, _point(pixel), round((radius + 1.5) * (1 << _SHIFT)), value, -1, cv2.LINE_8, _SHIFT)


def _fixed(pixels: np.ndarray) -> np.ndarray:
    """Fixed-point pixel coordinates for OpenCV's ``shift``."""
    return np.round(np.asarray(pixels) * (1 << _SHIFT)).astype(np.int32)


def _point(pixel: np.ndarray) -> tuple[int, int]:
    x, y = _fixed(pixel)
    return int(x), int(y)


def _polylines(
    image: np.ndarray,
    polylines: Sequence[np.ndarray],
    rgb: RGB,
    width: float,
    mask: np.ndarray | None = None,
    value: int = 1,
) -> None:
    """Pixel polylines, anti-aliased; ``mask`` (if any) gets ``value`` a pixel wider on each side."""
    if polylines:
        pts = [_fixed(line) for line in polylines]
        thick = max(1, round(width))
        cv2.polylines(image, pts, False, rgb, thick, cv2.LINE_AA, _SHIFT)
        if mask is not None:
            cv2.polylines(mask, pts, False, value, thick + 2, cv2.LINE_8, _SHIFT)


def _disc(image: np.ndarray, pixel: np.ndarray, radius: float, rgb: RGB, outline: RGB) -> None:
    r = max(1, round(radius * (1 << _SHIFT)))
    cv2.circle(image, _point(pixel), r, rgb, -1, cv2.LINE_AA, _SHIFT)
    cv2.circle(image, _point(pixel), r, outline, 1, cv2.LINE_AA, _SHIFT)


def _polygon(image: np.ndarray, pixels: np.ndarray, rgb: RGB) -> None:
    """A filled polygon with a dark outline (goal star, agent triangle)."""
    pts = _fixed(pixels)
    cv2.fillPoly(image, [pts], rgb, cv2.LINE_AA, _SHIFT)
    cv2.polylines(image, [pts], True, TEXT_RGB, 1, cv2.LINE_AA, _SHIFT)


def _text_box(text: str, scale: float) -> tuple[float, float, int]:
    """Width and height of ``text`` with its halo, and the baseline offset (what :func:`_put_text` draws)."""
    (w, h), base = cv2.getTextSize(text, _FONT, scale, _thickness(scale) + 2)
    return float(w), float(h + base), base


def _thickness(scale: float) -> int:
    return max(1, round(scale * 1.6))


def _put_text(image: np.ndarray, box: np.ndarray, text: str, scale: float, rgb: RGB, halo: RGB) -> None:
    """Text with a halo (so that it stays legible over roads) in the box :func:`_text_box` measured."""
    thick = _thickness(scale)
    base = _text_box(text, scale)[2]
    at = (round(float(box[0])), round(float(box[3])) - base)
    cv2.putText(image, text, at, _FONT, scale, halo, thick + 2, cv2.LINE_AA)
    cv2.putText(image, text, at, _FONT, scale, rgb, thick, cv2.LINE_AA)


# Where a label may go around its node, in order of preference: right, left, the four diagonals, above, below.
_DIRECTIONS = ((1, 0), (-1, 0), (1, -1), (1, 1), (-1, -1), (-1, 1), (0, -1), (0, 1))


class _LabelPlacer:
    """
    Greedy placement of text boxes: each new box goes to the cheapest of its candidate positions.

    Cost, most important first: leaving the map, covering ``hard`` pixels or earlier boxes (per pixel), then the
    share of ``soft`` pixels covered and the distance from the node.
    """

    def __init__(self, canvas: _Canvas) -> None:
        self.width, self.height = canvas.width, canvas.height
        self.hard = cv2.integral(canvas.hard, sdepth=cv2.CV_32S)
        self.soft = cv2.integral(canvas.soft, sdepth=cv2.CV_32S)
        self.taken = np.empty((0, 4))

    @staticmethod
    def candidates(anchor: np.ndarray, w: float, h: float, gap: float, step: float, rings: int) -> np.ndarray:
        """Boxes ``(n, 4)`` beside, above and below ``anchor``, ring after ring of growing distance."""
        x, y = float(anchor[0]), float(anchor[1])
        boxes = []
        for ring in range(rings):
            for dx, dy in _DIRECTIONS:
                r = gap + ring * step
                r = r * 0.75 if dx and dy else r  # corners sit closer than the sides
                x0 = x + r if dx > 0 else x - r - w if dx < 0 else x - w / 2
                y0 = y + r if dy > 0 else y - r - h if dy < 0 else y - h / 2
                boxes.append((x0, y0, x0 + w, y0 + h))
        return np.array(boxes)

    def _sums(self, table: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        x0 = np.clip(np.floor(boxes[:, 0]).astype(int), 0, self.width)
        y0 = np.clip(np.floor(boxes[:, 1]).astype(int), 0, self.height)
        x1 = np.clip(np.ceil(boxes[:, 2]).astype(int), 0, self.width)
        y1 = np.clip(np.ceil(boxes[:, 3]).astype(int), 0, self.height)
        return (table[y1, x1] - table[y0, x1] - table[y1, x0] + table[y0, x0]).astype(np.float64)

    def place(self, boxes: np.ndarray, rings: int, anchor: np.ndarray, others: np.ndarray) -> tuple[np.ndarray, int]:
        """
        The cheapest of ``boxes`` (from :meth:`candidates` around ``anchor`` with ``rings`` rings) and its ring; it is
        taken. A box nearer to one of the ``others`` points (pixels ``(n, 2)``) than to its anchor, or within a text
        height of one, might name the wrong node, so it costs more.
        """
        area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
        outside = (boxes[:, 0] < 1) | (boxes[:, 1] < 1) | (boxes[:, 2] > self.width - 1)
        outside |= boxes[:, 3] > self.height - 1
        lo = np.maximum(boxes[:, None, :2], self.taken[None, :, :2])
        hi = np.minimum(boxes[:, None, 2:], self.taken[None, :, 2:])
        overlap = np.clip(hi - lo, 0.0, None).prod(axis=2).sum(axis=1)
        blocked = self._sums(self.hard, boxes) + overlap
        ring = np.repeat(np.arange(rings), len(_DIRECTIONS))
        order = np.tile(np.arange(len(_DIRECTIONS)), rings)
        cost = 1e9 * outside + 1e6 * (blocked > 0) + 1e3 * blocked
        cost += 100.0 * self._sums(self.soft, boxes) / area + 30.0 * ring + 0.5 * order
        own = _box_distance(boxes, anchor[None])[:, 0]
        height = boxes[:, 3] - boxes[:, 1]
        cost += 80.0 * (_box_distance(boxes, others).min(axis=1, initial=np.inf) < np.maximum(own, height))
        best = int(np.argmin(cost))
        self.taken = np.vstack([self.taken, boxes[best] + (-1.0, -1.0, 1.0, 1.0)])  # a pixel of air around text
        return boxes[best], int(ring[best])


def _box_distance(boxes: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Distances ``(n_boxes, n_points)`` from each box ``(x0, y0, x1, y1)`` to each point (0 inside)."""
    lo, hi = boxes[:, None, :2], boxes[:, None, 2:]
    return np.linalg.norm(np.maximum(np.maximum(lo - points[None], points[None] - hi), 0.0), axis=2)


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


def _cross(mid: np.ndarray, direction: np.ndarray, arm: float) -> list[np.ndarray]:
    """The two strokes of the X that marks a closed road at ``mid`` (pixels), turned to the road's ``direction``."""
    strokes = []
    for angle in (math.pi / 4, -math.pi / 4):
        c, s = math.cos(angle), math.sin(angle)
        d = np.array([direction[0] * c - direction[1] * s, direction[0] * s + direction[1] * c]) * arm
        strokes.append(np.stack([mid - d, mid + d]))
    return strokes


def _star(center: np.ndarray, radius: float) -> np.ndarray:
    angles = -np.pi / 2 + np.arange(10) * np.pi / 5
    r = np.where(np.arange(10) % 2 == 0, radius, radius * 0.45)
    return center + np.stack([np.cos(angles) * r, np.sin(angles) * r], axis=1)


def _triangle(center: np.ndarray, ahead: np.ndarray, radius: float) -> np.ndarray:
    side = np.array([-ahead[1], ahead[0]])
    r = radius
    return np.array(
        [center + ahead * r, center - ahead * r * 0.6 + side * r * 0.6, center - ahead * r * 0.6 - side * r * 0.6]
    )


_CLOSED_WIDTH = 3.0  # closed road's line width, in units
_CROSS_ARM = 6.0  # half the span of its X, in units


def _route_colours(names: Sequence[str], given: Mapping[str, RGB]) -> list[RGB]:
    """The colour of each route: the one given for its name, else the next of ``ROUTE_COLOURS`` not given."""
    unknown = sorted(set(given) - set(names))
    if unknown:
        raise ValueError(f"colours given for routes that are not drawn: {unknown} (routes: {list(names)})")
    free = [rgb for rgb in ROUTE_COLOURS if rgb not in given.values()] or list(ROUTE_COLOURS)
    others = itertools.cycle(free)
    return [tuple(int(c) for c in given[name]) if name in given else next(others) for name in names]  # type: ignore[misc]


def _route_widths(n_routes: int, unit: float) -> list[float]:
    """Earlier routes are drawn wider, underneath, so that each shows on both sides of the later ones it shares a
    road with."""
    return [(3.0 + 2.75 * min(n_routes - 1 - i, 3)) * unit for i in range(n_routes)]


def map_size(n_nodes: int, base: int = 600, cap: int = 1600) -> int:
    """
    Longer side of a map picture that keeps the campus's street spacing on screen: ``base`` pixels for a map of up
    to :data:`DENSITY_NODES` intersections, growing with the square root of the node count beyond, at most ``cap``.

    :param n_nodes: Intersections of the map
    :param base: Size at the campus's density
    :param cap: Largest size returned
    :return: the size for :func:`draw_map` (e.g. 600 on the campus, 1600 at 1,000 intersections)
    :raises ValueError: a node count below 1, or a cap below the base
    """
    if isinstance(n_nodes, bool) or not isinstance(n_nodes, (int, np.integer)) or n_nodes < 1:
        raise ValueError(f"n_nodes must be a positive int, got {n_nodes!r}")
    if cap < base:
        raise ValueError(f"cap ({cap}) must be at least base ({base})")
    return min(int(cap), round(base * math.sqrt(max(1.0, int(n_nodes) / DENSITY_NODES))))


def title_band(width: int, lines: Sequence[tuple[str, RGB]], scale: float) -> np.ndarray:
    """
    A white band with one line of text per entry, shrunk where a line would not fit the width.

    The band's height depends on ``scale`` and the number of lines only, so that panels whose titles were shrunk line
    up with the others.

    :param width: Width of the band (pixels)
    :param lines: Text and colour of each line; the first is the title, the others (details) are a little smaller
    :param scale: OpenCV font scale of the first line
    :return: ``(H, width, 3)`` uint8 RGB image
    """
    pad = max(4, round(8 * scale))
    rows = []
    for i, (text, rgb) in enumerate(lines):
        nominal = scale if i == 0 else scale * 0.85  # the detail line is smaller than the title
        s, thick = nominal, max(1, round(nominal * 2))
        # OpenCV renders text in steps of size, so shrink until what it measures fits
        while cv2.getTextSize(text, _FONT, s, thick)[0][0] > width - 2 * pad and s > 0.15:
            s *= 0.95
            thick = max(1, round(s * 2))
        (_, h), base = cv2.getTextSize("Ag", _FONT, nominal, max(1, round(nominal * 2)))
        rows.append((text, rgb, s, thick, h + base, base))
    band = np.full((pad * (len(rows) + 1) + sum(r[4] for r in rows), width, 3), PAGE_RGB, dtype=np.uint8)
    y = pad
    for text, rgb, s, thick, height, base in rows:
        cv2.putText(band, text, (pad, y + height - base), _FONT, s, rgb, thick, cv2.LINE_AA)
        y += height + pad
    return band


def _wrap_title(title: str, width: int, scale: float) -> list[str]:
    """The lines of ``title``; a line too long for ``width`` is broken at its ``" | "`` separators."""
    pad = max(4, round(8 * scale))
    lines: list[str] = []
    for line in title.splitlines() or [""]:
        current = ""
        for part in line.split(" | "):
            joined = f"{current} | {part}" if current else part
            s = scale if not lines else scale * 0.85  # the sizes title_band draws
            if current and cv2.getTextSize(joined, _FONT, s, max(1, round(s * 2)))[0][0] > width - 2 * pad:
                lines.append(current)
                current = part
            else:
                current = joined
        lines.append(current)
    return lines


@dataclass(frozen=True)
class _Symbol:
    symbol: str
    text: str
    rgb: RGB
    width: float = 0.0


def _legend_band(width: int, symbols: Sequence[_Symbol], unit: float, scale: float) -> tuple[np.ndarray, list[Box]]:
    """A white band with the legend's entries in rows, left to right, and the box of each entry in the band."""
    pad, swatch, space = 6.0 * unit, 18.0 * unit, 12.0 * unit
    row_h = max(_text_box("Ag", scale)[1], 10.0 * unit) + 3.0 * unit
    boxes, x, y = [], pad, pad
    for entry in symbols:
        w = swatch + 4.0 * unit + _text_box(entry.text, scale)[0]
        if x > pad and x + w > width - pad:
            x, y = pad, y + row_h
        boxes.append((x, y, x + w, y + row_h))
        x += w + space
    band = np.full((round(y + row_h + pad), width, 3), PAGE_RGB, dtype=np.uint8)
    cv2.line(band, (0, 0), (width - 1, 0), ROAD_RGB, 1)
    for entry, (x0, y0, _, y1) in zip(symbols, boxes, strict=True):
        centre = np.array([x0 + swatch / 2, (y0 + y1) / 2])
        if entry.symbol in ("line", "closed"):
            half = np.array([max(swatch - entry.width, 2.0) / 2, 0.0])  # round caps reach half a width further
            ends = [np.array([centre - half, centre + half])]
            _polylines(band, ends, entry.rgb, entry.width)
            if entry.symbol == "closed":
                _polylines(band, _cross(centre, np.array([1.0, 0.0]), _CROSS_ARM * unit), entry.rgb, 2.5 * unit)
        elif entry.symbol == "start":
            _polygon(band, _triangle(centre + np.array([0.0, unit]), np.array([0.0, -1.0]), 6.0 * unit), entry.rgb)
        elif entry.symbol == "goal":
            _polygon(band, _star(centre, 6.0 * unit), entry.rgb)
        else:
            _disc(band, centre, 3.0 * unit, entry.rgb, TEXT_RGB)
        text_w, text_h, _ = _text_box(entry.text, scale)
        top = (y0 + y1 - text_h) / 2
        text_box = np.array([x0 + swatch + 4.0 * unit, top, x0 + swatch + 4.0 * unit + text_w, top + text_h])
        _put_text(band, text_box, entry.text, scale, TEXT_RGB, PAGE_RGB)
    return band, boxes


def _place_labels(
    canvas: _Canvas,
    graph: RoadGraph,
    nodes_px: np.ndarray,
    goal_nodes: Sequence[int],
    agent: int | None,
    route_picture: bool,
    labels: bool,
    node_ids: bool,
    text_scale: float,
    id_scale: float,
) -> list[MapLabel]:
    """
    Place the texts, most important first: the start and a goal that is no landmark (route pictures only), the
    landmark names (the goal's first), the node ids. Boxes are in map pixels.
    """
    unit, mark = canvas.unit, canvas.text_unit
    placer = _LabelPlacer(canvas)
    placed: list[MapLabel] = []
    marked = sorted({*goal_nodes, *([] if agent is None else [agent]), *graph.landmarks.values()})

    def place(text: str, kind: str, node: int, scale: float, gap: float, rings: int, leaders: bool) -> None:
        w, h, _ = _text_box(text, scale)
        anchor = nodes_px[node]
        # Names must not look as if they named another marked node, ids another intersection
        rivals = np.array([n for n in (range(graph.n_nodes) if kind == "node id" else marked) if n != node], dtype=int)
        box, ring = placer.place(placer.candidates(anchor, w, h, gap, h * 0.9, rings), rings, anchor, nodes_px[rivals])
        leader = None
        if leaders and ring >= 2:  # far from its node: a thin line shows which node it names
            nearest = np.clip(anchor, box[:2], box[2:])
            start = anchor + (nearest - anchor) * min(1.0, gap * 0.6 / max(np.linalg.norm(nearest - anchor), 1e-9))
            leader = (float(start[0]), float(start[1]), float(nearest[0]), float(nearest[1]))
        placed.append(MapLabel(text, kind, node, (float(box[0]), float(box[1]), float(box[2]), float(box[3])), leader))

    if route_picture and agent is not None:
        place(f"start {agent}", "start", agent, text_scale, 7.5 * mark, 6, True)
    if route_picture:
        for node in goal_nodes:
            if node not in graph.landmarks.values():
                place(f"goal {node}", "goal", node, text_scale, 7.5 * mark, 6, True)
    if labels:
        for name, node in sorted(graph.landmarks.items(), key=lambda item: (item[1] not in goal_nodes, *item[::-1])):
            big = node in goal_nodes or node == agent
            place(name, "landmark", node, text_scale, (7.5 if big else 4.5) * mark, 6, True)  # star/arrow > dot
    if node_ids:
        for node in range(graph.n_nodes):
            place(str(node), "node id", node, id_scale, 2.0 * unit, 3, False)
    return placed


def _moved_down(label: MapLabel, by: float) -> MapLabel:
    x0, y0, x1, y1 = label.box
    leader = (
        None if label.leader is None else (label.leader[0], label.leader[1] + by, label.leader[2], label.leader[3] + by)
    )
    return MapLabel(label.text, label.kind, label.node, (x0, y0 + by, x1, y1 + by), leader)


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
    node_ids: bool = False,
    title: str | None = None,
    colours: Mapping[str, RGB] | None = None,
) -> np.ndarray:
    """
    Draw a road graph from above.

    :param graph: The road network; a ``NavigationGraph``'s closed roads are drawn in red with an X at their midpoint
    :param size: Length of the longer side of the map (pixels); the title and legend bands add to its height
    :param agent: Node of the agent: a triangle pointing where its forward view looks (along the road in the slot of
        ``heading``, see :func:`~campusnav_env.rendering.street_view.view_bearings`), a disc if the heading is ``None``
    :param heading: Compass heading of the agent (0 N, 1 E, 2 S, 3 W)
    :param goal: Goal node or nodes (stars)
    :param path: Nodes visited so far, drawn as a blue route along the roads
    :param labels: Write the landmark names (without them, the legend names the landmarks by colour)
    :param routes: Extra named routes (name -> node sequence) in distinct colours. Each is drawn wider than the next,
        underneath it, so that a route still shows where a later one follows it. With routes, the map is a route
        picture: ``agent`` is labelled as the start (``"start 12"``), a goal that is no landmark as ``"goal 81"``, and
        a legend band below the map explains the routes, start, goal, closed roads and landmarks
    :param node_ids: Write every intersection's id beside it in small print (to find the roads for a closure)
    :param title: Text of a band above the map; one line per line of ``title``, and a line too long for the width is
        broken at its ``" | "`` separators, e.g. ``"start 12 -> Dreese Lab (81) | closed: 69-81 | SPL 0.98"``
    :param colours: Colour of a route by its name in ``routes`` (e.g. ``LEARNED_ROUTE_RGB``), so that a colour
        means the same in every picture; the other routes take the ``ROUTE_COLOURS`` not given here, in order
    :return: ``(H, W, 3)`` uint8 RGB image
    :raises ValueError: on a bad size or heading, a node out of range, or a colour for a route not in ``routes``
    """
    return _draw(
        graph,
        size=size,
        agent=agent,
        heading=heading,
        goal=goal,
        path=path,
        labels=labels,
        routes=routes,
        node_ids=node_ids,
        title=title,
        colours=colours,
    )[0]


def map_layout(graph: RoadGraph | NavigationGraph, **options: Any) -> MapLayout:
    """
    Where :func:`draw_map` puts its labels, legend and title for the same arguments.

    :param graph: The road network
    :param options: Keyword arguments of :func:`draw_map`
    :return: the layout, in pixels of the image ``draw_map(graph, **options)`` returns
    :raises TypeError: an option that ``draw_map`` does not take
    """
    bound = inspect.signature(draw_map).bind(graph, **options)
    bound.apply_defaults()
    return _draw(**bound.arguments)[1]


def _draw(
    graph: RoadGraph | NavigationGraph,
    *,
    size: int,
    agent: int | None,
    heading: int | None,
    goal: int | Sequence[int] | None,
    path: Sequence[int],
    labels: bool,
    routes: Mapping[str, Sequence[int]] | None,
    node_ids: bool,
    title: str | None,
    colours: Mapping[str, RGB] | None,
) -> tuple[np.ndarray, MapLayout]:
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or size < 64:
        raise ValueError(f"size must be an int >= 64 pixels, got {size!r}")
    if heading is not None and (isinstance(heading, bool) or heading not in (0, 1, 2, 3)):
        raise ValueError(f"heading must be 0 (N), 1 (E), 2 (S), 3 (W) or None, got {heading!r}")
    closed_roads = graph.closed_roads if isinstance(graph, NavigationGraph) else frozenset()
    graph = graph.map if isinstance(graph, NavigationGraph) else graph
    canvas = _Canvas(graph, int(size))
    unit, mark = canvas.unit, canvas.text_unit  # lines; markers and text
    goals = [] if goal is None else [goal] if isinstance(goal, (int, np.integer)) else list(goal)
    goal_nodes = [graph.check_node(g, "goal") for g in goals]
    if agent is not None:
        agent = graph.check_node(agent, "agent")
    route_lines = [
        (str(name), [int(n) for n in nodes], _route_polyline(graph, list(nodes), f"route {name!r} node"))
        for name, nodes in (routes or {}).items()
    ]
    path_line = _route_polyline(graph, list(path), "path node")
    route_colours = _route_colours([name for name, _, _ in route_lines], colours or {})

    # Lines, bottom to top: plain roads, routes (widest first), the path, closed roads with their X
    closed = {graph.road_id(u, v) for u, v in closed_roads}
    canvas.lines([g for i, g in enumerate(graph.geometries) if i not in closed], ROAD_RGB, 2.0 * unit, canvas.soft)
    symbols: list[_Symbol] = []
    widths = _route_widths(len(route_lines), unit)
    for (name, nodes, line), width, colour in zip(route_lines, widths, route_colours, strict=True):
        if line is not None:
            canvas.lines([line], colour, width, canvas.hard)
        elif nodes:  # nodes, but no line to see (every move blocked): say so, or the legend names an invisible route
            name = f"{name} (never leaves node {nodes[0]})"
        symbols.append(_Symbol("line", name, colour, width))
    if path_line is not None:
        canvas.lines([path_line], PATH_RGB, 2.5 * unit, canvas.hard)
        symbols.append(_Symbol("line", "route so far", PATH_RGB, 2.5 * unit))
    # A closed road goes over the routes that use it, in a light casing and with a large X, so that a route drawn wide
    # along it (the learned one, before the closure) does not hide it
    for road in sorted(closed):
        geometry = np.asarray(graph.geometries[road], dtype=np.float64)
        canvas.lines([geometry], BACKGROUND_RGB, _CLOSED_WIDTH * unit + 2.0 * unit)
        canvas.lines([geometry], CLOSED_RGB, _CLOSED_WIDTH * unit, canvas.hard)
        mid, direction = _midpoint(canvas.px(geometry))
        cross = _cross(mid, direction, _CROSS_ARM * unit)
        _polylines(canvas.image, cross, BACKGROUND_RGB, 2.5 * unit + 2.0 * unit)
        _polylines(canvas.image, cross, CLOSED_RGB, 2.5 * unit, canvas.hard)

    nodes_px = canvas.px(graph.positions)
    for p in nodes_px:
        cv2.circle(canvas.image, _point(p), round(1.2 * unit * (1 << _SHIFT)), NODE_RGB, -1, cv2.LINE_AA, _SHIFT)
        canvas.mask_disc(canvas.soft, p, 1.2 * unit, value=8)  # node ids had better not hide other intersections
    markers = [(n, 7.0 * mark) for n in goal_nodes] + ([] if agent is None else [(agent, 7.0 * mark)])
    markers += [(n, 3.0 * mark) for n in graph.landmarks.values()]
    for node, radius in markers:
        canvas.mask_disc(canvas.hard, nodes_px[node], radius)

    text_scale = max(0.35, 0.32 * canvas.text_unit)  # OpenCV font scales; smaller than these is unreadable
    id_scale = max(0.3, 0.24 * unit)
    route_picture = routes is not None
    placed = _place_labels(
        canvas, graph, nodes_px, goal_nodes, agent, route_picture, labels, node_ids, text_scale, id_scale
    )

    # Draw: leader lines, landmark dots, goal stars and the agent over the lines, then the text over everything
    for label in placed:
        if label.leader is not None:
            x0, y0, x1, y1 = label.leader
            _polylines(canvas.image, [np.array([[x0, y0], [x1, y1]])], NODE_RGB, 1.0)
    for name, node in sorted(graph.landmarks.items(), key=lambda item: (item[1], item[0])):
        _disc(canvas.image, nodes_px[node], 3.0 * mark, landmark_colour(name), TEXT_RGB)
    for node in goal_nodes:
        _polygon(canvas.image, _star(nodes_px[node], 7.0 * mark), GOAL_RGB)
    if agent is not None:
        p = nodes_px[agent]
        if heading is None:
            _disc(canvas.image, p, 4.5 * mark, AGENT_RGB, TEXT_RGB)
        else:
            # The agent faces where its forward view looks: the road in slot ``heading`` (its compass bearing if empty)
            bearing = math.radians(view_bearings(graph)[agent, heading])
            ahead = np.array([math.sin(bearing), -math.cos(bearing)])  # image y points south
            _polygon(canvas.image, _triangle(p, ahead, 7.0 * mark), AGENT_RGB)
    for label in placed:
        small = label.kind == "node id"
        scale, rgb = (id_scale, NODE_ID_RGB) if small else (text_scale, TEXT_RGB)
        _put_text(canvas.image, np.asarray(label.box), label.text, scale, rgb, BACKGROUND_RGB)

    # Bands: the title above the map, the legend below it
    parts, top = [], 0
    title_lines: list[str] = []
    title_box = None
    if title is not None:
        title_scale = min(0.75, max(0.4, size / 1200))  # grows with the map, but not to a headline
        title_lines = _wrap_title(str(title), canvas.width, title_scale)
        band = title_band(canvas.width, [(line, TEXT_RGB) for line in title_lines], title_scale)
        parts.append(band)
        top = band.shape[0]
        title_box = (0.0, 0.0, float(canvas.width), float(top))
    parts.append(canvas.image)
    legend: list[LegendEntry] = []
    legend_box = None
    if route_picture:
        if agent is not None:
            symbols.append(_Symbol("start", "start", AGENT_RGB))
        if goal_nodes:
            symbols.append(_Symbol("goal", "goal" if len(goal_nodes) == 1 else "goals", GOAL_RGB))
        if closed:
            symbols.append(_Symbol("closed", "closed road", CLOSED_RGB, _CLOSED_WIDTH * unit))
        if labels:
            if graph.landmarks:
                symbols.append(_Symbol("landmark", "landmark (named on the map)", PAGE_RGB))
        else:
            symbols += [_Symbol("landmark", name, landmark_colour(name)) for name in sorted(graph.landmarks)]
        band, boxes = _legend_band(canvas.width, symbols, canvas.text_unit, text_scale)
        below = top + canvas.height
        legend = [
            LegendEntry(s.symbol, s.text, s.rgb, s.width, (b[0], b[1] + below, b[2], b[3] + below))
            for s, b in zip(symbols, boxes, strict=True)
        ]
        legend_box = (0.0, float(below), float(canvas.width), float(below + band.shape[0]))
        parts.append(band)
    image = np.concatenate(parts) if len(parts) > 1 else canvas.image
    layout = MapLayout(
        shape=(int(image.shape[0]), int(image.shape[1])),
        map_box=(0.0, float(top), float(canvas.width), float(top + canvas.height)),
        title=tuple(title_lines),
        title_box=title_box,
        legend=tuple(legend),
        legend_box=legend_box,
        labels=tuple(_moved_down(label, top) for label in placed),
        nodes=nodes_px + np.array([0.0, top]),
    )
    return image, layout
