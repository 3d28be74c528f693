"""
The shared 2D scene around a road graph: buildings, trees, open fields and landmark signs.

:func:`build_world` places, deterministically from a seed, everything a street-view camera at an intersection can see
besides the roads themselves:

- **Buildings**: rectangles and L-shapes aligned with the nearest road, set back behind the verge and sidewalk, in one
  or two rows per block side, with a campus mix of heights (6-40 m), facade colours and window patterns. No footprint
  comes closer to a road centreline than half the road width plus the verge and sidewalk (checked exactly, segment to
  segment), and footprints keep a gap between them (checked on an occupancy raster).
- **Landmarks**: every ``graph.landmarks`` entry gets a bigger building in a distinctive colour in the widest free
  sector at its intersection, its front facing the intersection and carrying the name as a sign. Landmarks whose name
  says field/park/green get an open field instead (sports pitch with white lines) and a monument sign by the road.
- **Trees** along the verges and scattered in a few parks.

The same :class:`World` feeds every view, so a building seen from two intersections is the same building.
"""

from __future__ import annotations

import hashlib
import itertools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from campusnav_env.maps.road_graph import RoadGraph

__all__ = [
    "Building",
    "Field",
    "Sign",
    "SpatialIndex",
    "Tree",
    "World",
    "build_world",
    "landmark_colour",
    "point_segment_distances",
    "polygon_segment_distances",
]

RGB = tuple[int, int, int]

# Bump when placement rules change: the world fingerprint (and so every feature cache key) depends on it.
WORLD_VERSION = 2

ROAD_WIDTH = 12.0  # asphalt, both lanes (m)
VERGE_WIDTH = 2.0  # grass strip with street trees between asphalt and sidewalk (m)
SIDEWALK_WIDTH = 2.5  # (m)

# Distinctive facade colours of the named places (saturated, unlike the muted palette of ordinary buildings).
LANDMARK_COLOURS: dict[str, RGB] = {
    "Dreese Lab": (176, 28, 46),
    "Town house": (226, 122, 24),
    "Cinema": (118, 38, 156),
    "Library": (36, 78, 170),
    "Stadium": (24, 128, 116),
    "Student union": (214, 170, 20),
    "Hospital": (70, 170, 215),
    "Museum": (150, 96, 40),
    "Train station": (112, 120, 30),
    "Chapel": (200, 60, 130),
    "Bookstore": (40, 150, 60),
}
FACADE_PALETTE: tuple[RGB, ...] = (
    (150, 78, 62),  # red brick
    (132, 66, 52),  # dark brick
    (198, 184, 156),  # beige
    (176, 172, 162),  # concrete
    (150, 150, 148),  # grey
    (220, 216, 206),  # white render
    (190, 160, 118),  # sandstone
    (118, 96, 78),  # brown
    (168, 140, 110),  # tan
)
WINDOW_PALETTE: tuple[RGB, ...] = ((52, 64, 80), (70, 92, 112), (40, 48, 56), (96, 120, 136), (60, 80, 76))
ROOF_PALETTE: tuple[RGB, ...] = ((90, 90, 92), (110, 104, 98), (70, 72, 76))
CROWN_PALETTE: tuple[RGB, ...] = ((52, 96, 40), (64, 110, 46), (44, 84, 44), (78, 118, 52), (58, 92, 34))
SPORTS_GREEN: RGB = (76, 150, 60)
PARK_GREEN: RGB = (92, 136, 70)
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


@dataclass(frozen=True, eq=False)
class Building:
    """
    An extruded footprint with a facade pattern.

    :param footprint: ``(k, 2)`` counter-clockwise polygon (metres); wall ``i`` runs from vertex ``i`` to ``i + 1``
    :param height: Roof height (m)
    :param facade_rgb: Wall colour
    :param window_rgb: Glass colour
    :param roof_rgb: Roof colour (top-down map and pictures)
    :param floor_height: Storey height (m); windows repeat with it vertically
    :param window_spacing: Horizontal window pitch along a wall (m)
    :param window_width: Share of the pitch that is glass (1.0 = ribbon windows)
    :param window_height: Share of the storey that is glass
    :param name: Landmark name shown as a sign, or ``None``
    :param node: The landmark's intersection, or ``None``
    :param sign_wall: Index of the wall carrying the sign (the one facing ``node``), or ``None``
    """

    footprint: np.ndarray
    height: float
    facade_rgb: RGB
    window_rgb: RGB
    roof_rgb: RGB
    floor_height: float = 3.5
    window_spacing: float = 3.0
    window_width: float = 0.5
    window_height: float = 0.55
    name: str | None = None
    node: int | None = None
    sign_wall: int | None = None


@dataclass(frozen=True, eq=False)
class Tree:
    """A street or park tree: a trunk and a round crown."""

    position: np.ndarray
    radius: float
    height: float
    crown_rgb: RGB = CROWN_PALETTE[0]


@dataclass(frozen=True, eq=False)
class Field:
    """An open ground area drawn on the ground plane: ``kind`` is ``"sports"`` (with white ``lines``) or ``"park"``."""

    polygon: np.ndarray
    rgb: RGB
    kind: str = "park"
    name: str | None = None
    lines: tuple[np.ndarray, ...] = ()


@dataclass(frozen=True, eq=False)
class Sign:
    """
    A free-standing monument sign: a board of ``width`` x ``height`` m whose bottom is ``elevation`` m up.

    The board stands at ``position`` across the direction ``bearing`` (degrees clockwise from north) that its face
    points to; the text reads correctly from either side.
    """

    position: np.ndarray
    text: str
    bearing: float
    width: float = 8.0
    height: float = 1.6
    elevation: float = 0.8
    board_rgb: RGB = (28, 52, 40)
    text_rgb: RGB = (245, 245, 235)


@dataclass(eq=False)
class World:
    """
    Everything around a road graph that the street-view renderer draws.

    :param graph: The road network (closures do not change the world)
    :param buildings: Building footprints, landmarks first
    :param trees: Street and park trees
    :param fields: Sports fields and parks (ground-level areas)
    :param signs: Monument signs of landmarks without a building
    :param road_width: Asphalt width of every road (m)
    :param verge_width: Grass strip between asphalt and sidewalk on each side (m)
    :param sidewalk_width: Sidewalk width on each side (m)
    :param seed: The placement seed
    """

    graph: RoadGraph
    buildings: tuple[Building, ...]
    trees: tuple[Tree, ...]
    fields: tuple[Field, ...]
    signs: tuple[Sign, ...] = ()
    road_width: float = ROAD_WIDTH
    verge_width: float = VERGE_WIDTH
    sidewalk_width: float = SIDEWALK_WIDTH
    seed: int = 0
    _fingerprint: str | None = field(default=None, repr=False)

    @property
    def clearance(self) -> float:
        """Distance from a road centreline that buildings never enter: half the road plus verge and sidewalk."""
        return self.road_width / 2 + self.verge_width + self.sidewalk_width

    def landmark_building(self, name: str) -> Building:
        """The building carrying landmark ``name``'s sign (``KeyError`` naming it if it has none)."""
        for building in self.buildings:
            if building.name == name:
                return building
        raise KeyError(f"no landmark building named {name!r} in this world")

    def fingerprint(self) -> str:
        """sha256 hex of the road graph's fingerprint, the placement parameters and every object in the world."""
        if self._fingerprint is None:
            digest = hashlib.sha256(f"campusnav-world-v{WORLD_VERSION}|{self.graph.fingerprint()}".encode())
            digest.update(repr((self.road_width, self.verge_width, self.sidewalk_width, self.seed)).encode())
            for b in self.buildings:
                digest.update(np.ascontiguousarray(b.footprint, dtype=np.float64).tobytes())
                digest.update(
                    repr(
                        (
                            b.height,
                            b.facade_rgb,
                            b.window_rgb,
                            b.roof_rgb,
                            b.floor_height,
                            b.window_spacing,
                            b.window_width,
                            b.window_height,
                            b.name,
                            b.node,
                            b.sign_wall,
                        )
                    ).encode()
                )
            for t in self.trees:
                digest.update(np.ascontiguousarray(t.position, dtype=np.float64).tobytes())
                digest.update(repr((t.radius, t.height, t.crown_rgb)).encode())
            for f in self.fields:
                digest.update(np.ascontiguousarray(f.polygon, dtype=np.float64).tobytes())
                digest.update(repr((f.rgb, f.kind, f.name, len(f.lines))).encode())
                for line in f.lines:
                    digest.update(np.ascontiguousarray(line, dtype=np.float64).tobytes())
            for s in self.signs:
                digest.update(np.ascontiguousarray(s.position, dtype=np.float64).tobytes())
                digest.update(repr((s.text, s.bearing, s.width, s.height, s.elevation, s.board_rgb)).encode())
            self._fingerprint = digest.hexdigest()
        return self._fingerprint


# --------------------------------------------------------------------------------------------------------------------
# Geometry helpers (vectorised; shapes broadcast)
# --------------------------------------------------------------------------------------------------------------------


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def point_segment_distances(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` to segments ``a``-``b`` (all ``(..., 2)``, broadcast)."""
    ab = b - a
    denom = np.maximum((ab * ab).sum(-1), 1e-12)
    t = np.clip(((p - a) * ab).sum(-1) / denom, 0.0, 1.0)
    return np.linalg.norm(a + t[..., None] * ab - p, axis=-1)


def _segment_segment_distances(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Distance between segments ``p1-p2`` and ``q1-q2`` (0 where they cross); inputs ``(..., 2)``, broadcast."""
    d = np.minimum(
        np.minimum(point_segment_distances(p1, q1, q2), point_segment_distances(p2, q1, q2)),
        np.minimum(point_segment_distances(q1, p1, p2), point_segment_distances(q2, p1, p2)),
    )
    o1 = _cross(p2 - p1, q1 - p1)
    o2 = _cross(p2 - p1, q2 - p1)
    o3 = _cross(q2 - q1, p1 - q1)
    o4 = _cross(q2 - q1, p2 - q1)
    crossing = (o1 * o2 < 0) & (o3 * o4 < 0)
    return np.where(crossing, 0.0, d)


def polygon_segment_distances(polygons: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """
    Distance from each polygon to the segment paired with it (0 if the segment enters it).

    :param polygons: ``(P, k, 2)`` closed polygons (the last vertex connects to the first)
    :param a: ``(P, 2)`` segment starts
    :param b: ``(P, 2)`` segment ends
    :return: ``(P,)`` distances
    """
    v1 = polygons
    v2 = np.roll(polygons, -1, axis=1)
    dist = _segment_segment_distances(v1, v2, a[:, None, :], b[:, None, :]).min(axis=1)
    # A segment wholly inside the polygon crosses no edge: test its start point (even-odd ray casting).
    py, px = a[:, None, 1], a[:, None, 0]
    y1, y2 = v1[..., 1], v2[..., 1]
    straddle = (y1 > py) != (y2 > py)
    x_at = v1[..., 0] + (py - y1) * (v2[..., 0] - v1[..., 0]) / np.where(y2 == y1, 1.0, y2 - y1)
    inside = (straddle & (px < x_at)).sum(axis=1) % 2 == 1
    return np.where(inside, 0.0, dist)


class SpatialIndex:
    """
    Uniform-grid lookup of axis-aligned boxes: which items may lie within a radius of a point.

    :param lo: ``(n, 2)`` lower corners of the items' bounding boxes
    :param hi: ``(n, 2)`` upper corners
    :param cell: Grid cell size (m)
    """

    def __init__(self, lo: np.ndarray, hi: np.ndarray, cell: float = 100.0) -> None:
        lo = np.asarray(lo, dtype=np.float64).reshape(-1, 2)
        hi = np.asarray(hi, dtype=np.float64).reshape(-1, 2)
        self.cell = float(cell)
        self.n = len(lo)
        if self.n == 0:
            self._keys = np.zeros(0, dtype=np.int64)
            self._items = np.zeros(0, dtype=np.int64)
            return
        i0 = np.floor(lo / self.cell).astype(np.int64)
        i1 = np.floor(hi / self.cell).astype(np.int64)
        counts = (i1 - i0 + 1).prod(axis=1)
        items = np.repeat(np.arange(self.n), counts)
        # Enumerate the cells under each box: offset within the box, row-major.
        start = np.repeat(np.cumsum(counts) - counts, counts)
        k = np.arange(counts.sum()) - start
        nx = (i1 - i0 + 1)[items, 0]
        cx = i0[items, 0] + k % nx
        cy = i0[items, 1] + k // nx
        keys = self._key(cx, cy)
        order = np.argsort(keys, kind="stable")
        self._keys = keys[order]
        self._items = items[order]

    @staticmethod
    def _key(cx: np.ndarray, cy: np.ndarray) -> np.ndarray:
        return (cx + (1 << 20)) * (1 << 21) + (cy + (1 << 20))

    def query(self, center: np.ndarray, radius: float) -> np.ndarray:
        """Sorted unique ids of items whose box overlaps the square of half-side ``radius`` around ``center``."""
        if self.n == 0:
            return np.zeros(0, dtype=np.int64)
        c0 = np.floor((np.asarray(center) - radius) / self.cell).astype(np.int64)
        c1 = np.floor((np.asarray(center) + radius) / self.cell).astype(np.int64)
        gx, gy = np.meshgrid(np.arange(c0[0], c1[0] + 1), np.arange(c0[1], c1[1] + 1), indexing="ij")
        keys = self._key(gx.ravel(), gy.ravel())
        left = np.searchsorted(self._keys, keys, side="left")
        right = np.searchsorted(self._keys, keys, side="right")
        if (right - left).sum() == 0:
            return np.zeros(0, dtype=np.int64)
        idx = np.concatenate([self._items[lo:hi] for lo, hi in zip(left, right, strict=True) if hi > lo])
        return np.unique(idx)

    def pairs(self, points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """
        Candidate (point id, item id) pairs: every point within ``radius`` (at most one cell) of an item's box.

        Candidates come from the 3x3 cells around each point, so some pairs are farther apart; callers measure.

        :param points: ``(n, 2)`` query points
        :param radius: Search radius (m), at most one grid cell
        :return: ``(point_ids, item_ids)``, equally long int64 arrays
        :raises ValueError: if ``radius`` exceeds the grid cell
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if self.n == 0 or len(points) == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        if radius > self.cell:
            raise ValueError(f"radius {radius} exceeds the grid cell {self.cell}")
        base = np.floor(points / self.cell).astype(np.int64)
        point_ids, item_ids = [], []
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                keys = self._key(base[:, 0] + dx, base[:, 1] + dy)
                left = np.searchsorted(self._keys, keys, side="left")
                right = np.searchsorted(self._keys, keys, side="right")
                counts = right - left
                pid = np.repeat(np.arange(len(points)), counts)
                offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
                point_ids.append(pid)
                item_ids.append(self._items[np.repeat(left, counts) + offset])
        pid = np.concatenate(point_ids)
        iid = np.concatenate(item_ids)
        # A box spanning several neighbouring cells yields the same pair more than once.
        key = np.unique(pid * self.n + iid)
        return key // self.n, key % self.n


def landmark_colour(name: str) -> RGB:
    """Facade colour of a landmark: fixed for the campus names, a saturated colour hashed from the name otherwise."""
    if name in LANDMARK_COLOURS:
        return LANDMARK_COLOURS[name]
    hue = int(hashlib.sha256(name.encode()).hexdigest()[:4], 16) % 180
    hsv = np.array([[[hue, 200, 190]]], dtype=np.uint8)
    r, g, b = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0]
    return (int(r), int(g), int(b))


# --------------------------------------------------------------------------------------------------------------------
# Placement
# --------------------------------------------------------------------------------------------------------------------


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


def build_world(graph: RoadGraph, *, seed: int = 0) -> World:
    """
    Place buildings, landmarks, fields, parks and trees around ``graph``, deterministically from ``seed``.

    :param graph: The road network (any :class:`~campusnav_env.maps.road_graph.RoadGraph`)
    :param seed: Placement seed; the same graph and seed always give the same world
    :return: The :class:`World`
    :raises ValueError: if ``seed`` is not an int
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool):
        raise ValueError(f"seed must be an int, got {seed!r}")
    rng = np.random.default_rng([int(seed), 0xCA4905])
    positions = np.asarray(graph.positions, dtype=np.float64)
    seg_a, seg_b = _road_segments(graph)
    all_pts = np.concatenate([positions, seg_a, seg_b]) if len(seg_a) else positions
    lo = all_pts.min(axis=0) - 150.0
    hi = all_pts.max(axis=0) + 150.0
    clearance = ROAD_WIDTH / 2 + VERGE_WIDTH + SIDEWALK_WIDTH
    clear = _RoadClearance(graph)
    occupancy = _Occupancy(lo, hi)

    buildings: list[Building] = []
    fields: list[Field] = []
    signs: list[Sign] = []
    trees: list[Tree] = []

    # 1. Landmarks: they claim their ground first so that they always exist.
    for name, node in sorted(graph.landmarks.items(), key=lambda kv: (kv[1], kv[0])):
        pos = positions[node]
        bearing = _widest_gap_bearing(_incident_bearings(graph, node))
        if _is_field_name(name):
            placed = _place_outward(pos, bearing, 120.0, 80.0, clear, occupancy, clearance + 3.0)
            if placed is None:
                continue
            poly, _ = placed
            # Long side first so that the pitch lines run along it.
            poly = (
                poly if np.linalg.norm(poly[1] - poly[0]) >= np.linalg.norm(poly[3] - poly[0]) else poly[[1, 2, 3, 0]]
            )
            fields.append(Field(poly, SPORTS_GREEN, kind="sports", name=name, lines=_pitch_lines(poly)))
            sign_pos = pos + _unit(bearing) * (clearance + 1.5)
            if clear.point_distances(sign_pos[None])[0] > ROAD_WIDTH / 2 + VERGE_WIDTH:
                signs.append(Sign(sign_pos, name, bearing=(bearing + 180.0) % 360.0, width=max(6.0, 0.75 * len(name))))
            continue
        big = name.lower() in ("stadium", "hospital", "train station")
        width, depth = (70.0, 50.0) if big else (46.0, 30.0)
        placed = _place_outward(pos, bearing, width, depth, clear, occupancy, clearance + 1.0)
        if placed is None:
            continue
        poly, _ = placed
        buildings.append(
            Building(
                footprint=poly,
                height=float(rng.uniform(16.0, 28.0)),
                facade_rgb=landmark_colour(name),
                window_rgb=(38, 46, 58),
                roof_rgb=(80, 80, 84),
                floor_height=4.0,
                window_spacing=float(rng.uniform(3.0, 4.0)),
                window_width=float(rng.uniform(0.45, 0.7)),
                window_height=0.55,
                name=name,
                node=int(node),
                sign_wall=0,
            )
        )

    # 2. Parks: a few lawns with trees, in places no road crosses.
    area_km2 = float(np.prod(hi - lo)) / 1e6
    n_parks = max(1, round(area_km2 * 0.6))
    for _ in range(n_parks):
        for _attempt in range(40):
            center = rng.uniform(lo + 150.0, hi - 150.0)
            w, d = rng.uniform(70.0, 140.0), rng.uniform(50.0, 100.0)
            along = _unit(float(rng.uniform(0.0, 180.0)))
            poly = _rectangle(center, along, w, d)
            if clear.polygon_distances(poly[None])[0] <= clearance + 2.0:
                continue
            if not occupancy.try_place(poly, 3.0):
                continue
            fields.append(Field(poly, PARK_GREEN, kind="park"))
            n_trees = int(w * d / 450.0)
            local = rng.uniform(-0.42, 0.42, size=(n_trees, 2)) * [w, d]
            across = np.array([-along[1], along[0]])
            for p in center + local[:, :1] * along + local[:, 1:] * across:
                trees.append(
                    Tree(
                        p,
                        radius=float(rng.uniform(2.5, 4.5)),
                        height=float(rng.uniform(7.0, 13.0)),
                        crown_rgb=CROWN_PALETTE[int(rng.integers(len(CROWN_PALETTE)))],
                    )
                )
            break

    # 3. Ordinary buildings: rows along both sides of every road segment. Their style follows the district they
    # stand in (nearest of a few random district centres), so that nearby streets look alike, as on a real campus.
    n_districts = max(len(DISTRICT_STYLES), round(area_km2 * 1.6))
    districts = rng.uniform(lo, hi, size=(n_districts, 2))
    district_style = np.arange(n_districts) % len(DISTRICT_STYLES)
    rng.shuffle(district_style)
    cand_polys: list[np.ndarray] = []
    cand_tier: list[int] = []
    for geometry in graph.geometries:
        g = np.asarray(geometry, dtype=np.float64)
        for a, b in itertools.pairwise(g):
            seg = b - a
            seg_len = float(np.linalg.norm(seg))
            if seg_len < 20.0:
                continue
            along = seg / seg_len
            normal = np.array([-along[1], along[0]])
            for side in (-1.0, 1.0):
                for tier in (0, 1):
                    pos = float(rng.uniform(0.0, 12.0))
                    setback = clearance + float(rng.uniform(2.5, 9.0)) + (tier * rng.uniform(38.0, 55.0))
                    while True:
                        w = float(rng.uniform(16.0, 44.0))
                        d = float(rng.uniform(13.0, 30.0)) if tier == 0 else float(rng.uniform(16.0, 40.0))
                        if pos + w > seg_len:
                            break
                        center = a + along * (pos + w / 2) + side * normal * (setback + d / 2)
                        poly = _rectangle(center, along, w, d)
                        if side < 0:  # keep vertex 0-1 on the road side for both sides (for L-shape cut-outs)
                            poly = poly[[2, 3, 0, 1]]
                        if rng.random() < 0.25:
                            # L-shape: cut a back corner (vertices 2..3 are the back wall).
                            fw, fd = float(rng.uniform(0.35, 0.6)), float(rng.uniform(0.35, 0.6))
                            p0, p1, p2, p3 = poly
                            if rng.random() < 0.5:
                                q = p2 + (p3 - p2) * fw
                                r = p2 + (p1 - p2) * fd
                                poly = np.array([p0, p1, r, r + (q - p2), q, p3])
                            else:
                                q = p3 + (p2 - p3) * fw
                                r = p3 + (p0 - p3) * fd
                                poly = np.array([p0, p1, p2, q, q + (r - p3), r])
                        else:
                            poly = np.concatenate(
                                [poly, np.full((2, 2), np.nan)]
                            )  # pad to 6 vertices to stack with L-shapes
                        if rng.random() > 0.18:  # leave some lots empty: lawns and gaps
                            cand_polys.append(poly)
                            cand_tier.append(tier)
                        pos += w + float(rng.uniform(4.0, 14.0))

    if cand_polys:
        polys = np.stack(cand_polys)
        tiers = np.asarray(cand_tier)
        filled = np.where(np.isnan(polys), polys[:, :1, :], polys)  # repeat vertex 0 for the padded rectangles
        ok = clear.polygon_distances(filled) > clearance + 0.5
        order = np.lexsort((rng.random(len(polys)), tiers))
        for i in order:
            if not ok[i]:
                continue
            poly = polys[i][~np.isnan(polys[i, :, 0])]
            if not occupancy.try_place(poly, 3.0):
                continue
            style = DISTRICT_STYLES[district_style[_nearest(districts, poly.mean(axis=0))]]
            if rng.random() < 0.2:  # a fifth of the buildings ignore their district: campuses are never uniform
                style = DISTRICT_STYLES[int(rng.integers(len(DISTRICT_STYLES)))]
            low, high = style.heights
            ribbon = rng.random() < style.ribbon_share
            buildings.append(
                Building(
                    footprint=_ccw(poly),
                    height=float(np.clip(low + (high - low) * rng.beta(1.3, 2.2), 6.0, 40.0)),
                    facade_rgb=FACADE_PALETTE[style.facades[int(rng.integers(len(style.facades)))]],
                    window_rgb=WINDOW_PALETTE[int(rng.integers(len(WINDOW_PALETTE)))],
                    roof_rgb=ROOF_PALETTE[int(rng.integers(len(ROOF_PALETTE)))],
                    floor_height=float(rng.uniform(3.2, 4.0)),
                    window_spacing=float(rng.uniform(2.4, 4.2)),
                    window_width=float(rng.uniform(0.85, 0.95)) if ribbon else float(rng.uniform(0.35, 0.65)),
                    window_height=float(rng.uniform(0.4, 0.65)),
                )
            )

    # 4. Street trees on the verges, away from intersections, buildings and other roads.
    tree_pts = []
    offset = ROAD_WIDTH / 2 + VERGE_WIDTH / 2 + 0.2
    for geometry in graph.geometries:
        g = np.asarray(geometry, dtype=np.float64)
        seg_lens = np.linalg.norm(np.diff(g, axis=0), axis=1)
        total = float(seg_lens.sum())
        if total < 40.0:
            continue
        s = np.arange(16.0 + rng.uniform(0, 6), total - 16.0, 14.0)
        cum = np.concatenate([[0.0], np.cumsum(seg_lens)])
        k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg_lens) - 1)
        t = (s - cum[k]) / np.maximum(seg_lens[k], 1e-9)
        along = (g[k + 1] - g[k]) / np.maximum(seg_lens[k], 1e-9)[:, None]
        normal = np.stack([-along[:, 1], along[:, 0]], axis=1)
        base = g[k] + t[:, None] * (g[k + 1] - g[k])
        for side in (-1.0, 1.0):
            pts = base + side * normal * offset
            keep = rng.random(len(pts)) < 0.7
            tree_pts.append(pts[keep])
    if tree_pts:
        pts = np.concatenate(tree_pts)
        far_from_nodes = np.ones(len(pts), dtype=bool)
        node_index = SpatialIndex(positions, positions, cell=64.0)
        pid, nid = node_index.pairs(pts, 18.0)
        close = np.linalg.norm(pts[pid] - positions[nid], axis=1) < 18.0
        far_from_nodes[pid[close]] = False
        ok = far_from_nodes & (clear.point_distances(pts) > ROAD_WIDTH / 2 + 0.6) & occupancy.free(pts)
        for p in pts[ok]:
            trees.append(
                Tree(
                    p,
                    radius=float(rng.uniform(2.0, 3.6)),
                    height=float(rng.uniform(6.0, 11.0)),
                    crown_rgb=CROWN_PALETTE[int(rng.integers(len(CROWN_PALETTE)))],
                )
            )

    return World(
        graph=graph,
        buildings=tuple(buildings),
        trees=tuple(trees),
        fields=tuple(fields),
        signs=tuple(signs),
        road_width=ROAD_WIDTH,
        verge_width=VERGE_WIDTH,
        sidewalk_width=SIDEWALK_WIDTH,
        seed=int(seed),
    )


def _nearest(centres: np.ndarray, point: np.ndarray) -> int:
    return int(np.argmin(((centres - point) ** 2).sum(axis=1)))


def _ccw(polygon: np.ndarray) -> np.ndarray:
    """The polygon with counter-clockwise vertex order (positive signed area)."""
    x, y = polygon[:, 0], polygon[:, 1]
    area = 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))
    return polygon if area > 0 else polygon[::-1].copy()


def footprint_walls(buildings: Sequence[Building]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every wall of every footprint as segments: starts ``(M, 2)``, ends ``(M, 2)`` and building ids ``(M,)``."""
    starts, ends, owner = [], [], []
    for i, b in enumerate(buildings):
        f = np.asarray(b.footprint, dtype=np.float64)
        starts.append(f)
        ends.append(np.roll(f, -1, axis=0))
        owner.append(np.full(len(f), i, dtype=np.int64))
    if not starts:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
    return np.concatenate(starts), np.concatenate(ends), np.concatenate(owner)
