"""
How :func:`~campusnav_env.rendering.world.build_world` places things: road clearance queries, an occupancy raster that
keeps footprints apart, district styles, and the shapes it places (rectangles, pitch lines).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from campusnav_env.maps.geometry import point_segment_distances, polygon_segment_distances
from campusnav_env.rendering.spatial_index import SpatialIndex

if TYPE_CHECKING:
    from campusnav_env.maps.road_graph import RoadGraph

_FIELD_WORDS = ("field", "park", "green", "quad", "garden")


@dataclass(frozen=True)
class _Style:
    """Building style of a district: facade colours (indices into FACADE_PALETTE), height range, ribbon windows."""

    facades: tuple[int, ...]
    heights: tuple[float, float]
    ribbon_share: float


DISTRICT_STYLES = (
    _Style(facades=(0, 1, 7), heights=(8.0, 22.0), ribbon_share=0.05),  # old brick halls
    _Style(facades=(3, 4, 5), heights=(12.0, 40.0), ribbon_share=0.6),  # modern concrete and glass
    _Style(facades=(2, 6, 8), heights=(6.0, 16.0), ribbon_share=0.1),  # low sandstone
    _Style(facades=tuple(range(9)), heights=(6.0, 30.0), ribbon_share=0.25),  # mixed
)


def _road_segments(graph: RoadGraph, max_len: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    """All road polylines cut into pieces no longer than ``max_len`` (shorter pieces keep the grid index tight)."""
    starts, ends = [], []
    for geometry in graph.geometries:
        g = np.asarray(geometry, dtype=np.float64)
        for a, b in itertools.pairwise(g):
            n = max(1, int(np.ceil(np.linalg.norm(b - a) / max_len)))
            t = np.linspace(0.0, 1.0, n + 1)[:, None]
            pts = a + t * (b - a)
            starts.append(pts[:-1])
            ends.append(pts[1:])
    if not starts:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.concatenate(starts), np.concatenate(ends)


class _RoadClearance:
    """Exact distance queries from polygons and points to the road network (grid-indexed, vectorised)."""

    def __init__(self, graph: RoadGraph, reach: float = 40.0, cell: float = 128.0) -> None:
        # cell >= the largest polygon radius (~75 m fields) + reach, so that 3x3 neighbouring cells see every road.
        self.a, self.b = _road_segments(graph)
        lo = np.minimum(self.a, self.b)
        hi = np.maximum(self.a, self.b)
        self.reach = reach
        self.index = SpatialIndex(lo, hi, cell=cell)

    def polygon_distances(self, polygons: np.ndarray) -> np.ndarray:
        """Min distance from each ``(P, k, 2)`` polygon to any road (``inf`` when none is within ``reach``)."""
        out = np.full(len(polygons), np.inf)
        if len(polygons) == 0 or self.index.n == 0:
            return out
        centers = polygons.mean(axis=1)
        radius = np.linalg.norm(polygons - centers[:, None, :], axis=-1).max(axis=1)
        pid, sid = self.index.pairs(centers, self.reach)
        # Cheap reject first: a segment farther than the polygon's radius + reach from its centre cannot matter.
        near = point_segment_distances(centers[pid], self.a[sid], self.b[sid]) < radius[pid] + self.reach
        pid, sid = pid[near], sid[near]
        d = polygon_segment_distances(polygons[pid], self.a[sid], self.b[sid])
        np.minimum.at(out, pid, d)
        return out

    def point_distances(self, points: np.ndarray) -> np.ndarray:
        """Min distance from each ``(n, 2)`` point to any road (``inf`` beyond ``reach``)."""
        out = np.full(len(points), np.inf)
        if len(points) == 0 or self.index.n == 0:
            return out
        pid, sid = self.index.pairs(points, self.reach)
        d = point_segment_distances(points[pid], self.a[sid], self.b[sid])
        np.minimum.at(out, pid, d)
        return out


class _Occupancy:
    """Raster of occupied ground used to keep footprints apart (cheap exact-enough overlap test)."""

    def __init__(self, lo: np.ndarray, hi: np.ndarray) -> None:
        area = float(np.prod(hi - lo))
        self.res = max(1.5, float(np.sqrt(area / 12e6)))  # at most ~12 M cells, even for huge maps
        self.lo = lo
        shape = np.ceil((hi - lo) / self.res).astype(int) + 1
        self.grid = np.zeros((shape[1], shape[0]), dtype=np.uint8)

    def try_place(self, polygon: np.ndarray, margin: float) -> bool:
        """Mark ``polygon`` grown by ``margin`` if that area is still free; return whether it was."""
        p = (polygon - self.lo) / self.res
        pad = margin / self.res + 2
        x0, y0 = np.floor(p.min(axis=0) - pad).astype(int)
        x1, y1 = np.ceil(p.max(axis=0) + pad).astype(int)
        h, w = self.grid.shape
        if x0 < 0 or y0 < 0 or x1 >= w or y1 >= h:
            return False
        mask = np.zeros((y1 - y0 + 1, x1 - x0 + 1), dtype=np.uint8)
        local = np.round((p - [x0, y0]) * 4).astype(np.int32)
        cv2.fillPoly(mask, [local], 1, cv2.LINE_8, 2)
        if margin > 0:
            cv2.polylines(mask, [local], True, 1, max(1, round(2 * margin / self.res)), cv2.LINE_8, 2)
        window = self.grid[y0 : y1 + 1, x0 : x1 + 1]
        if np.any(window & mask):
            return False
        window |= mask
        return True

    def free(self, points: np.ndarray) -> np.ndarray:
        """Whether each point's cell is unoccupied (points off the raster count as occupied)."""
        idx = np.round((points - self.lo) / self.res).astype(int)
        h, w = self.grid.shape
        ok = (idx[:, 0] >= 0) & (idx[:, 1] >= 0) & (idx[:, 0] < w) & (idx[:, 1] < h)
        out = np.zeros(len(points), dtype=bool)
        out[ok] = self.grid[idx[ok, 1], idx[ok, 0]] == 0
        return out


def _rectangle(center: np.ndarray, along: np.ndarray, width: float, depth: float) -> np.ndarray:
    """Counter-clockwise rectangle of ``width`` along the unit vector ``along`` and ``depth`` across it."""
    across = np.array([-along[1], along[0]])
    hw, hd = width / 2, depth / 2
    return np.array(
        [
            center - along * hw - across * hd,
            center + along * hw - across * hd,
            center + along * hw + across * hd,
            center - along * hw + across * hd,
        ]
    )


def _incident_bearings(graph: RoadGraph, node: int) -> np.ndarray:
    """Initial bearings (degrees) of the roads leaving ``node``."""
    bearings = []
    for (u, v), geometry in zip(graph.roads, graph.geometries, strict=True):
        g = np.asarray(geometry, dtype=np.float64)
        if u == node:
            d = g[1] - g[0]
        elif v == node:
            d = g[-2] - g[-1]
        else:
            continue
        bearings.append(np.degrees(np.arctan2(d[0], d[1])) % 360.0)
    return np.sort(np.asarray(bearings))


def _widest_gap_bearing(bearings: np.ndarray) -> float:
    """Bearing in the middle of the widest sector free of roads."""
    if len(bearings) == 0:
        return 0.0
    if len(bearings) == 1:
        return float((bearings[0] + 180.0) % 360.0)
    gaps = np.diff(np.append(bearings, bearings[0] + 360.0))
    i = int(np.argmax(gaps))
    return float((bearings[i] + gaps[i] / 2) % 360.0)


def _unit(bearing: float) -> np.ndarray:
    rad = np.radians(bearing)
    return np.array([np.sin(rad), np.cos(rad)])


def _pitch_lines(polygon: np.ndarray) -> tuple[np.ndarray, ...]:
    """White lines of a football pitch inside a rectangle ``polygon`` (vertices 0-1 along the long side)."""
    p0, p1, _, p3 = polygon
    along = p1 - p0
    across = p3 - p0
    length, width = np.linalg.norm(along), np.linalg.norm(across)
    ua, uc = along / length, across / width
    inset = 4.0

    def pt(s: float, t: float) -> np.ndarray:
        return p0 + ua * s + uc * t

    lo_s, hi_s, lo_t, hi_t = inset, length - inset, inset, width - inset
    mid_s, mid_t = length / 2, width / 2
    lines = [
        np.array([pt(lo_s, lo_t), pt(hi_s, lo_t), pt(hi_s, hi_t), pt(lo_s, hi_t), pt(lo_s, lo_t)]),
        np.array([pt(mid_s, lo_t), pt(mid_s, hi_t)]),
    ]
    angle = np.linspace(0, 2 * np.pi, 33)
    circle_r = min(9.15, (hi_t - lo_t) / 4)
    lines.append(np.stack([pt(mid_s + circle_r * np.cos(a), mid_t + circle_r * np.sin(a)) for a in angle]))
    box_d, box_w = min(16.5, (hi_s - lo_s) / 6), min(40.0, (hi_t - lo_t) * 0.6)
    for s0, sgn in ((lo_s, 1.0), (hi_s, -1.0)):
        lines.append(
            np.array(
                [
                    pt(s0, mid_t - box_w / 2),
                    pt(s0 + sgn * box_d, mid_t - box_w / 2),
                    pt(s0 + sgn * box_d, mid_t + box_w / 2),
                    pt(s0, mid_t + box_w / 2),
                ]
            )
        )
    return tuple(lines)


def _is_field_name(name: str) -> bool:
    lowered = name.lower()
    return any(word in lowered for word in _FIELD_WORDS)


def _place_outward(
    graph_pos: np.ndarray,
    bearing: float,
    width: float,
    depth: float,
    clear: _RoadClearance,
    occupancy: _Occupancy,
    min_clear: float,
) -> tuple[np.ndarray, float] | None:
    """
    Slide a rectangle out from an intersection along ``bearing`` (front facing it) until it clears the roads.

    :return: The footprint (vertices 0-1 = the front wall, facing the intersection) and the front distance, or
        ``None`` where no place is free
    """
    direction = _unit(bearing)
    along = np.array([direction[1], -direction[0]])  # front wall runs across the bearing
    for scale in (1.0, 0.85, 0.7, 0.55):
        w, d = width * scale, depth * scale
        fronts = np.arange(min_clear, min_clear + 120.0, 3.0)
        polys = np.stack([_rectangle(graph_pos + direction * (f + d / 2), along, w, d) for f in fronts])
        # _rectangle's vertices 0-1 lie at -across = towards the intersection when across = +direction.
        dist = clear.polygon_distances(polys)
        for i in np.flatnonzero(dist > min_clear):
            if occupancy.try_place(polys[i], 4.0):
                return polys[i], float(fronts[i])
    return None


def _nearest(centres: np.ndarray, point: np.ndarray) -> int:
    return int(np.argmin(((centres - point) ** 2).sum(axis=1)))


def _ccw(polygon: np.ndarray) -> np.ndarray:
    """The polygon with counter-clockwise vertex order (positive signed area)."""
    x, y = polygon[:, 0], polygon[:, 1]
    area = 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return polygon if area > 0 else polygon[::-1].copy()
