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

import itertools
from typing import TYPE_CHECKING

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
from campusnav_env.rendering.placement import (
    DISTRICT_STYLES,
    _ccw,
    _incident_bearings,
    _is_field_name,
    _nearest,
    _Occupancy,
    _pitch_lines,
    _place_outward,
    _rectangle,
    _road_segments,
    _RoadClearance,
    _unit,
    _widest_gap_bearing,
)
from campusnav_env.rendering.scene import (
    ROAD_WIDTH,
    SIDEWALK_WIDTH,
    VERGE_WIDTH,
    WORLD_VERSION,
    Building,
    Field,
    Sign,
    Tree,
    World,
    footprint_walls,
)
from campusnav_env.rendering.spatial_index import SpatialIndex

if TYPE_CHECKING:
    from campusnav_env.maps.road_graph import RoadGraph

# The scene types, the spatial index, the geometry helpers and the landmark palette lived here: still importable
__all__ = [
    "WORLD_VERSION",
    "Building",
    "Field",
    "Sign",
    "SpatialIndex",
    "Tree",
    "World",
    "build_world",
    "footprint_walls",
    "landmark_colour",
    "point_segment_distances",
    "polygon_segment_distances",
]


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
