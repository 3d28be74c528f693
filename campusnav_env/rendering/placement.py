"""
The placement steps of :func:`~campusnav_env.rendering.world.build_world`, in the order it runs them:

1. :func:`place_landmarks`: a building (or a sports field and a monument sign) per landmark, claimed first.
2. :func:`place_parks`: a few lawns with trees, where no road crosses.
3. :func:`place_buildings`: rows of ordinary buildings along the roads, styled by district.
4. :func:`place_street_trees`: trees on the verges.

They share a :class:`PlacementSite`: the random stream, exact distance queries to the roads and an occupancy raster
that keeps footprints apart.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import cv2
import numpy as np

from campusnav_env.maps.geometry import point_segment_distances, polygon_segment_distances
from campusnav_env.rendering.palette import (
    CROWN_PALETTE,
    FACADE_PALETTE,
    PARK_GREEN,
    ROOF_PALETTE,
    SPORTS_GREEN,
    WINDOW_PALETTE,
    landmark_colour,
)
from campusnav_env.rendering.scene import ROAD_WIDTH, SIDEWALK_WIDTH, VERGE_WIDTH, Building, Field, Sign, Tree
from campusnav_env.rendering.spatial_index import SpatialIndex

if TYPE_CHECKING:
    from campusnav_env.maps.road_graph import RoadGraph

__all__ = [
    "DISTRICT_STYLES",
    "PlacementSite",
    "place_buildings",
    "place_landmarks",
    "place_parks",
    "place_street_trees",
]

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


@dataclass(frozen=True)
class PlacementSite:
    """
    What the placement steps share: the graph, the random stream, the area, and the ground already taken.

    The steps draw from ``rng`` in a fixed order (landmarks, parks, buildings, street trees) and claim ground in
    ``occupancy``, so the same graph and seed always give the same world.

    :param graph: The road network
    :param rng: The placement's random stream
    :param lo: Lower corner of the area (m), 150 m beyond the roads
    :param hi: Upper corner of the area (m)
    :param clearance: Distance from a road centreline that buildings never enter (m)
    :param clear: Distance queries to the roads
    :param occupancy: Ground already taken by footprints, fields and parks
    """

    graph: RoadGraph
    rng: np.random.Generator
    lo: np.ndarray
    hi: np.ndarray
    clearance: float
    clear: _RoadClearance
    occupancy: _Occupancy

    @classmethod
    def around(cls, graph: RoadGraph, seed: int) -> PlacementSite:
        """The empty site around ``graph`` with the random stream of ``seed``."""
        positions = np.asarray(graph.positions, dtype=np.float64)
        seg_a, seg_b = _road_segments(graph)
        all_pts = np.concatenate([positions, seg_a, seg_b]) if len(seg_a) else positions
        lo = all_pts.min(axis=0) - 150.0
        hi = all_pts.max(axis=0) + 150.0
        return cls(
            graph=graph,
            rng=np.random.default_rng([int(seed), 0xCA4905]),
            lo=lo,
            hi=hi,
            clearance=ROAD_WIDTH / 2 + VERGE_WIDTH + SIDEWALK_WIDTH,
            clear=_RoadClearance(graph),
            occupancy=_Occupancy(lo, hi),
        )

    @property
    def positions(self) -> np.ndarray:
        """``(N, 2)`` intersection positions (m)."""
        return np.asarray(self.graph.positions, dtype=np.float64)

    @property
    def area_km2(self) -> float:
        """Size of the area (km^2): the number of parks and districts grows with it."""
        return float(np.prod(self.hi - self.lo)) / 1e6


def place_landmarks(site: PlacementSite) -> tuple[list[Building], list[Field], list[Sign]]:
    """
    Step 1: every landmark claims its ground first, so that it always exists: a building in a distinctive colour in
    the widest free sector at its intersection, front facing it; a sports field with a monument sign by the road for
    names that say field/park/green.

    :return: ``(buildings, fields, signs)`` of the landmarks
    """
    buildings: list[Building] = []
    fields: list[Field] = []
    signs: list[Sign] = []
    graph, rng, clearance = site.graph, site.rng, site.clearance
    positions = site.positions
    for name, node in sorted(graph.landmarks.items(), key=lambda kv: (kv[1], kv[0])):
        pos = positions[node]
        bearing = _widest_gap_bearing(_incident_bearings(graph, node))
        if _is_field_name(name):
            placed = _place_outward(pos, bearing, 120.0, 80.0, site.clear, site.occupancy, clearance + 3.0)
            if placed is None:
                continue
            poly, _ = placed
            # Long side first so that the pitch lines run along it.
            poly = (
                poly if np.linalg.norm(poly[1] - poly[0]) >= np.linalg.norm(poly[3] - poly[0]) else poly[[1, 2, 3, 0]]
            )
            fields.append(Field(poly, SPORTS_GREEN, kind="sports", name=name, lines=_pitch_lines(poly)))
            sign_pos = pos + _unit(bearing) * (clearance + 1.5)
            if site.clear.point_distances(sign_pos[None])[0] > ROAD_WIDTH / 2 + VERGE_WIDTH:
                signs.append(Sign(sign_pos, name, bearing=(bearing + 180.0) % 360.0, width=max(6.0, 0.75 * len(name))))
            continue
        big = name.lower() in ("stadium", "hospital", "train station")
        width, depth = (70.0, 50.0) if big else (46.0, 30.0)
        placed = _place_outward(pos, bearing, width, depth, site.clear, site.occupancy, clearance + 1.0)
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
    return buildings, fields, signs


def place_parks(site: PlacementSite) -> tuple[list[Field], list[Tree]]:
    """
    Step 2: a few lawns with trees (about 0.6 per km^2, at least one), in places no road crosses.

    :return: ``(fields, trees)`` of the parks
    """
    rng, lo, hi = site.rng, site.lo, site.hi
    fields: list[Field] = []
    trees: list[Tree] = []
    n_parks = max(1, round(site.area_km2 * 0.6))
    for _ in range(n_parks):
        for _attempt in range(40):
            center = rng.uniform(lo + 150.0, hi - 150.0)
            w, d = rng.uniform(70.0, 140.0), rng.uniform(50.0, 100.0)
            along = _unit(float(rng.uniform(0.0, 180.0)))
            poly = _rectangle(center, along, w, d)
            if site.clear.polygon_distances(poly[None])[0] <= site.clearance + 2.0:
                continue
            if not site.occupancy.try_place(poly, 3.0):
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
    return fields, trees


def place_buildings(site: PlacementSite) -> list[Building]:
    """
    Step 3: ordinary buildings in rows along both sides of every road segment (:func:`_building_lots`), clear of the
    roads and of each other. Their style follows the district they stand in (nearest of a few random district
    centres), so that nearby streets look alike, as on a real campus.

    :return: The buildings
    """
    rng = site.rng
    n_districts = max(len(DISTRICT_STYLES), round(site.area_km2 * 1.6))
    districts = rng.uniform(site.lo, site.hi, size=(n_districts, 2))
    district_style = np.arange(n_districts) % len(DISTRICT_STYLES)
    rng.shuffle(district_style)
    polys, tiers = _building_lots(site)
    buildings: list[Building] = []
    if len(polys) == 0:
        return buildings
    filled = np.where(np.isnan(polys), polys[:, :1, :], polys)  # repeat vertex 0 for the padded rectangles
    ok = site.clear.polygon_distances(filled) > site.clearance + 0.5
    order = np.lexsort((rng.random(len(polys)), tiers))  # the front row first
    for i in order:
        if not ok[i]:
            continue
        poly = polys[i][~np.isnan(polys[i, :, 0])]
        if not site.occupancy.try_place(poly, 3.0):
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
    return buildings


def _building_lots(site: PlacementSite) -> tuple[np.ndarray, np.ndarray]:
    """
    Candidate footprints in one or two rows (tiers) on both sides of every road segment of 20 m or more, a sixth of
    them L-shaped, some lots left empty; not yet checked against roads or each other.

    :return: ``(polygons, tiers)``: ``(P, 6, 2)`` footprints (rectangles padded with NaN vertices) and ``(P,)`` tiers
    """
    rng, clearance = site.rng, site.clearance
    cand_polys: list[np.ndarray] = []
    cand_tier: list[int] = []
    for geometry in site.graph.geometries:
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
    if not cand_polys:
        return np.zeros((0, 6, 2)), np.zeros(0, dtype=np.int64)
    return np.stack(cand_polys), np.asarray(cand_tier)


def place_street_trees(site: PlacementSite) -> list[Tree]:
    """
    Step 4: street trees on the verges every 14 m (70% of the spots), away from intersections, buildings and other
    roads.

    :return: The trees
    """
    rng = site.rng
    positions = site.positions
    tree_pts = []
    offset = ROAD_WIDTH / 2 + VERGE_WIDTH / 2 + 0.2
    for geometry in site.graph.geometries:
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
    trees: list[Tree] = []
    if not tree_pts:
        return trees
    pts = np.concatenate(tree_pts)
    far_from_nodes = np.ones(len(pts), dtype=bool)
    node_index = SpatialIndex(positions, positions, cell=64.0)
    pid, nid = node_index.pairs(pts, 18.0)
    close = np.linalg.norm(pts[pid] - positions[nid], axis=1) < 18.0
    far_from_nodes[pid[close]] = False
    ok = far_from_nodes & (site.clear.point_distances(pts) > ROAD_WIDTH / 2 + 0.6) & site.occupancy.free(pts)
    for p in pts[ok]:
        trees.append(
            Tree(
                p,
                radius=float(rng.uniform(2.0, 3.6)),
                height=float(rng.uniform(6.0, 11.0)),
                crown_rgb=CROWN_PALETTE[int(rng.integers(len(CROWN_PALETTE)))],
            )
        )
    return trees
