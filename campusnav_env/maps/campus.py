"""
Procedural campus: an irregular street network with named landmarks, deterministic for a seed.

The paper's CampusNav map is not available, so the default world is generated. The recipe:

1. **Grid.** ``cols x rows`` vertices with ``cols / rows`` close to the map's aspect ratio and about 8 % more
   vertices than requested. Column and row gaps are drawn unevenly (0.55 to 1.6 times the mean) so blocks have
   different sizes.
2. **Holes.** The surplus vertices are removed, no two of them 8-adjacent. Removing such a set keeps the grid
   connected (the 8 vertices around a hole still link its neighbours) and merges the four blocks around each hole into
   one large block, like an open field or a big building.
3. **Jitter.** Every vertex is moved by up to 15 % of its adjacent gaps on each axis (inwards only on the border), so
   that no street is straight across the map; the blocks stay convex.
4. **Streets.** A random spanning tree of the grid streets guarantees connectivity; the other grid streets are kept
   with probability 0.66 (merging blocks). 12 % of the spanning-tree leaves lose all their other streets and become
   dead ends (cul-de-sacs).
5. **Bends.** About 30 % of the grid streets get one or two intermediate points offset sideways by 5 to 12 % of their
   length (a curve or an S-bend), capped at 20 % of the grid gap so that long streets on a narrow map do not reach
   the parallel street.
6. **Diagonals.** 30 % of the blocks are offered a straight diagonal street between two opposite corners. It is
   built where both corners still have fewer than 4 streets, neither is a dead end, it crosses no street (checked
   against the polylines around the block) and passes no other intersection closely; about 5 % of the roads end up
   diagonal.
7. **Landmarks.** The four goals go one per quadrant, at the intersection (with at least 2 streets, so never a dead
   end) nearest a jittered point at the middle of the quadrant: *Dreese Lab* north-west, *Cinema* north-east,
   *Intramural fields* south-west, *Town house* south-east. Eight more named places follow at random intersections
   with at least 2 streets, spread by a minimum spacing that relaxes until they fit (dead ends only as a last
   resort). Small maps get as many names as they have intersections.

Node ids are the row-major order (south to north, then west to east) of the remaining grid vertices, so they are
stable for a seed. Everything is vectorised or local, so 10,000 intersections take about a second.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from campusnav_env.maps.disjoint_set import DisjointSet
from campusnav_env.maps.road_graph import RoadGraph, road_key

GOALS = ("Dreese Lab", "Town house", "Cinema", "Intramural fields")
PLACES = ("Library", "Stadium", "Student union", "Hospital", "Museum", "Train station", "Chapel", "Bookstore")
# Middle of the quadrant of each goal, as fractions of (width, height)
_GOAL_ANCHORS = {
    "Dreese Lab": (0.25, 0.75),
    "Town house": (0.75, 0.25),
    "Cinema": (0.75, 0.75),
    "Intramural fields": (0.25, 0.25),
}
_MIN_NODES = 8
_HOLE_FRACTION = 0.08
_GAP_RANGE = (0.55, 1.6)
_JITTER = 0.15
_KEEP_EXTRA_STREET = 0.66
_DEAD_END_LEAF_FRACTION = 0.12
_BEND_PROBABILITY = 0.3
_BEND_OFFSET = (0.05, 0.12)
_DIAGONAL_PROBABILITY = 0.3
_MARGIN_FRACTION = 0.05
# The built-in campus: its intersections and extent (metres, east-west x north-south) set the street density of cities
CAMPUS_NODES = 101
CAMPUS_EXTENT = (2500.0, 1700.0)


def generate_campus(
    n_nodes: int = CAMPUS_NODES, *, width: float = CAMPUS_EXTENT[0], height: float = CAMPUS_EXTENT[1], seed: int = 0
) -> RoadGraph:
    """
    Generate an irregular campus street network.

    :param n_nodes: Exact number of intersections (at least 8)
    :param width: Extent east-west in metres; everything lies in ``[0, width] x [0, height]`` with a 5 % margin
    :param height: Extent north-south in metres
    :param seed: Random seed; the same arguments always give the same graph
    :return: A connected :class:`RoadGraph` with at most 4 roads per intersection, bends, diagonals, dead ends and
        landmarks (the four :data:`GOALS` plus up to eight :data:`PLACES`)
    """
    if isinstance(n_nodes, bool) or not isinstance(n_nodes, (int, np.integer)):
        raise TypeError(f"n_nodes must be an int, got {type(n_nodes).__name__}")
    if n_nodes < _MIN_NODES:
        raise ValueError(f"n_nodes must be at least {_MIN_NODES} (room for the four goals), got {n_nodes}")
    for label, value in (("width", width), ("height", height)):
        if not (math.isfinite(value) and value > 0):
            raise ValueError(f"{label} must be a positive finite number of metres, got {value}")
    n_nodes = int(n_nodes)
    rng = np.random.default_rng(seed)
    margin = _MARGIN_FRACTION * min(width, height)
    box = (margin, margin, width - margin, height - margin)

    cols, rows, kept = _grid_with_holes(n_nodes, (box[2] - box[0]) / (box[3] - box[1]), rng)
    positions, node_of, gap = _jittered_vertices(cols, rows, kept, box, rng)
    edges, dead_ends = _grid_streets(node_of, rng)
    geometries = _bend(positions, edges, gap, (0.0, 0.0, width, height), rng)
    edges, geometries = _add_diagonals(positions, node_of, edges, geometries, dead_ends, rng)

    order = np.lexsort((edges[:, 1], edges[:, 0]))
    roads = [(int(u), int(v)) for u, v in edges[order]]
    degree = np.bincount(edges.ravel(), minlength=n_nodes)
    landmarks = _place_landmarks(positions, degree, width, height, rng)
    return RoadGraph(
        positions,
        roads,
        geometries=[geometries[i] for i in order],
        landmarks=landmarks,
        name=f"campus-n{n_nodes}-seed{seed}",
    )


@functools.lru_cache(maxsize=1)
def default_campus() -> RoadGraph:
    """
    The built-in campus, ``generate_campus()`` with the defaults (101 intersections, 2.5 km x 1.7 km, seed 0).

    Generated once per process and shared: a road graph never changes (closures live in a ``NavigationGraph``).
    """
    return generate_campus()


def generate_city(n_intersections: int, seed: int = 0) -> RoadGraph:
    """
    A generated city at the built-in campus's street density: :func:`generate_campus` over 2.5 km x 1.7 km times
    ``sqrt(n_intersections / 101)``, so that intersections lie as far apart at every size.

    ``generate_city(101, seed=0)`` is the built-in campus (:func:`default_campus`), road for road.

    :param n_intersections: Exact number of intersections (at least 8)
    :param seed: Random seed of the streets and landmarks
    :return: The road graph, with the four :data:`GOALS` among its landmarks
    """
    if isinstance(n_intersections, bool) or not isinstance(n_intersections, (int, np.integer)):
        raise TypeError(f"n_intersections must be an int, got {type(n_intersections).__name__}")
    scale = math.sqrt(max(int(n_intersections), 1) / CAMPUS_NODES)
    width, height = CAMPUS_EXTENT
    return generate_campus(int(n_intersections), width=width * scale, height=height * scale, seed=seed)


def _grid_with_holes(n_nodes: int, aspect: float, rng: np.random.Generator) -> tuple[int, int, np.ndarray]:
    """Choose the grid shape and the holes; return ``cols, rows`` and the kept-vertex mask ``(rows, cols)``."""
    target = n_nodes * (1.0 + _HOLE_FRACTION)
    shapes = []
    for cols in range(2, 2 * math.ceil(math.sqrt(target * aspect)) + 3):
        low = max(2, math.ceil(n_nodes / cols))
        for rows in (low, low + 1):
            surplus = cols * rows - n_nodes
            score = abs(math.log((cols - 1) / (rows - 1) / aspect)) + 4.0 * abs(surplus / (cols * rows) - 0.08)
            shapes.append((score, cols, rows))
    for _, cols, rows in sorted(shapes):
        for _attempt in range(4):
            holes = _scattered_holes(cols, rows, cols * rows - n_nodes, rng)
            if holes is not None:
                return cols, rows, ~holes
    raise RuntimeError(f"could not lay out a grid for {n_nodes} nodes")  # pragma: no cover - 2 x n always works


def _scattered_holes(cols: int, rows: int, count: int, rng: np.random.Generator) -> np.ndarray | None:
    """``count`` grid vertices, no two 8-adjacent, chosen greedily in random order; ``None`` if it fails."""
    holes = np.zeros((rows, cols), dtype=bool)
    if count == 0:
        return holes
    blocked = np.zeros((rows + 2, cols + 2), dtype=bool)  # padded: a hole blocks its 3x3 neighbourhood
    placed = 0
    for cell in rng.permutation(rows * cols).tolist():
        r, c = divmod(cell, cols)
        if blocked[r + 1, c + 1]:
            continue
        holes[r, c] = True
        blocked[r : r + 3, c : c + 3] = True
        placed += 1
        if placed == count:
            return holes
    return None


def _jittered_vertices(
    cols: int, rows: int, kept: np.ndarray, box: tuple[float, float, float, float], rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Positions of the kept vertices, the ``(rows, cols)`` map from grid vertex to node id (-1 for holes), and each
    node's smallest adjacent grid gap on either axis (how far its streets are from the parallel ones).
    """
    x_min, y_min, x_max, y_max = box
    axes = []
    gaps_per_axis = []
    for count, low, high in ((cols, x_min, x_max), (rows, y_min, y_max)):
        gaps = rng.uniform(*_GAP_RANGE, size=count - 1)
        coords = low + (high - low) * np.concatenate([[0.0], np.cumsum(gaps)]) / gaps.sum()
        # Largest jitter that keeps each vertex within 15 % of its smaller adjacent gap
        padded = np.concatenate([[np.inf], np.diff(coords), [np.inf]])
        nearest = np.minimum(padded[:-1], padded[1:])
        axes.append((coords, _JITTER * nearest))
        gaps_per_axis.append(nearest)
    (xs, x_reach), (ys, y_reach) = axes
    shift = rng.uniform(-1.0, 1.0, size=(rows, cols, 2))
    # Border vertices only move inwards, so that nothing leaves the box
    shift[:, 0, 0] = np.abs(shift[:, 0, 0])
    shift[:, -1, 0] = -np.abs(shift[:, -1, 0])
    shift[0, :, 1] = np.abs(shift[0, :, 1])
    shift[-1, :, 1] = -np.abs(shift[-1, :, 1])
    grid_x = xs[None, :] + shift[:, :, 0] * x_reach[None, :]
    grid_y = ys[:, None] + shift[:, :, 1] * y_reach[:, None]
    node_of = np.full((rows, cols), -1, dtype=np.int64)
    node_of[kept] = np.arange(int(kept.sum()))
    positions = np.stack([grid_x[kept], grid_y[kept]], axis=1)
    gap = np.minimum(gaps_per_axis[0][None, :], gaps_per_axis[1][:, None])[kept]
    return positions, node_of, gap


def _grid_streets(node_of: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Spanning tree plus a random share of the other grid streets; returns ``(edges (E, 2), dead-end mask)``."""
    pairs = []
    for a, b in ((node_of[:, :-1], node_of[:, 1:]), (node_of[:-1, :], node_of[1:, :])):
        both = (a >= 0) & (b >= 0)
        pairs.append(np.stack([a[both], b[both]], axis=1))
    candidates = np.concatenate(pairs)
    n_nodes = int(node_of.max()) + 1
    # Random spanning tree: Kruskal over the candidate streets in random order
    components = DisjointSet(n_nodes)
    in_tree = np.zeros(len(candidates), dtype=bool)
    for i in rng.permutation(len(candidates)).tolist():
        in_tree[i] = components.union(int(candidates[i, 0]), int(candidates[i, 1]))
    tree_degree = np.bincount(candidates[in_tree].ravel(), minlength=n_nodes)
    leaves = np.flatnonzero(tree_degree == 1)
    dead_end = np.zeros(n_nodes, dtype=bool)
    dead_end[rng.choice(leaves, size=round(_DEAD_END_LEAF_FRACTION * leaves.size), replace=False)] = True
    keep = in_tree | (rng.random(len(candidates)) < _KEEP_EXTRA_STREET)
    keep &= in_tree | ~(dead_end[candidates[:, 0]] | dead_end[candidates[:, 1]])
    edges = np.sort(candidates[keep], axis=1)
    degree = np.bincount(edges.ravel(), minlength=n_nodes)
    return edges, degree == 1


def _bend(
    positions: np.ndarray,
    edges: np.ndarray,
    gap: np.ndarray,
    bounds: tuple[float, float, float, float],
    rng: np.random.Generator,
) -> list[np.ndarray]:
    """
    Straight polylines for the streets, a random share bent by one or two sideways-offset points.

    The offset is at most 5-12 % of the street's length and 20 % of the grid gap at its ends, so that long streets on
    a narrow map do not bend into the parallel street.
    """
    start, end = positions[edges[:, 0]], positions[edges[:, 1]]
    delta = end - start
    normal = np.stack([-delta[:, 1], delta[:, 0]], axis=1)  # perpendicular, same length as the street
    n_edges = len(edges)
    bent = rng.random(n_edges) < _BEND_PROBABILITY
    double = rng.random(n_edges) < 0.5
    # One bend point near the middle, or two (a curve or an S-bend); a single bend repeats its point
    t = rng.uniform([0.25, 0.6], [0.4, 0.75], size=(n_edges, 2))
    offset = rng.uniform(*_BEND_OFFSET, size=(n_edges, 2)) * rng.choice([-1.0, 1.0], size=(n_edges, 2))
    length = np.linalg.norm(delta, axis=1)
    limit = np.minimum(1.0, 0.2 * np.minimum(gap[edges[:, 0]], gap[edges[:, 1]]) / (_BEND_OFFSET[1] * length))
    offset *= limit[:, None]
    t[:, 0] = np.where(double, t[:, 0], rng.uniform(0.35, 0.65, size=n_edges))
    t[:, 1] = np.where(double, t[:, 1], t[:, 0])
    offset[:, 1] = np.where(double, offset[:, 1], offset[:, 0])
    points = start[:, None, :] + t[:, :, None] * delta[:, None, :] + offset[:, :, None] * normal[:, None, :]
    x_min, y_min, x_max, y_max = bounds

    def inside(p: np.ndarray) -> np.ndarray:
        return np.all((p[..., 0] >= x_min) & (p[..., 0] <= x_max) & (p[..., 1] >= y_min) & (p[..., 1] <= y_max), -1)

    # A bend that leaves the map is mirrored to the other side of the street, or dropped if that leaves it too
    mirrored = start[:, None, :] + t[:, :, None] * delta[:, None, :] - offset[:, :, None] * normal[:, None, :]
    points = np.where(inside(points)[:, None, None], points, mirrored)
    bent &= inside(points)
    geometries = []
    for i in range(n_edges):
        if not bent[i]:
            geometries.append(np.stack([start[i], end[i]]))
        elif double[i]:
            geometries.append(np.stack([start[i], points[i, 0], points[i, 1], end[i]]))
        else:
            geometries.append(np.stack([start[i], points[i, 0], end[i]]))
    return geometries


def _add_diagonals(
    positions: np.ndarray,
    node_of: np.ndarray,
    edges: np.ndarray,
    geometries: list[np.ndarray],
    dead_end: np.ndarray,
    rng: np.random.Generator,
) -> tuple[np.ndarray, list[np.ndarray]]:
    """Add straight diagonal streets across random blocks where they fit (degree, crossings, clearance)."""
    rows, cols = node_of.shape
    n_nodes = positions.shape[0]
    degree = np.bincount(edges.ravel(), minlength=n_nodes)
    incident: list[list[int]] = [[] for _ in range(n_nodes)]
    for i, (u, v) in enumerate(edges.tolist()):
        incident[u].append(i)
        incident[v].append(i)
    edge_list = edges.tolist()
    n_cells = (rows - 1) * (cols - 1)
    chosen = np.flatnonzero(rng.random(n_cells) < _DIAGONAL_PROBABILITY)
    rising = rng.random(n_cells) < 0.5
    for cell in rng.permutation(chosen).tolist():
        r, c = divmod(cell, cols - 1)
        if rising[cell]:
            u, v = int(node_of[r, c]), int(node_of[r + 1, c + 1])
        else:
            u, v = int(node_of[r, c + 1]), int(node_of[r + 1, c])
        if u < 0 or v < 0 or degree[u] >= 4 or degree[v] >= 4 or dead_end[u] or dead_end[v]:
            continue
        # Streets and intersections that can come near this block: those of the 4 x 4 vertices around it
        block = node_of[max(r - 1, 0) : r + 3, max(c - 1, 0) : c + 3].ravel()
        block = block[block >= 0]
        nearby = sorted({i for node in block.tolist() for i in incident[node]})
        segments = np.concatenate(
            [np.stack([geometries[i][:-1], geometries[i][1:]], axis=1) for i in nearby]
        )  # (S, 2, 2)
        a, b = positions[u], positions[v]
        if _crosses(a, b, segments):
            continue
        others = positions[block[(block != u) & (block != v)]]
        if others.size and _point_segment_distance(others, a, b).min() < 0.15 * np.linalg.norm(b - a):
            continue
        new = len(edge_list)
        edge_list.append(list(road_key(u, v)))
        geometries.append(np.stack([positions[min(u, v)], positions[max(u, v)]]))
        incident[u].append(new)
        incident[v].append(new)
        degree[u] += 1
        degree[v] += 1
    return np.array(edge_list, dtype=np.int64), geometries


def _crosses(a: np.ndarray, b: np.ndarray, segments: np.ndarray) -> bool:
    """Whether segment ``a-b`` properly crosses any of ``segments`` (touching at a shared end does not count)."""
    p, q = segments[:, 0], segments[:, 1]

    def orient(o: np.ndarray, s: np.ndarray, t: np.ndarray) -> np.ndarray:
        return (s[..., 0] - o[..., 0]) * (t[..., 1] - o[..., 1]) - (s[..., 1] - o[..., 1]) * (t[..., 0] - o[..., 0])

    d1, d2 = orient(p, q, a), orient(p, q, b)
    d3, d4 = orient(a, b, p), orient(a, b, q)
    return bool(np.any((d1 * d2 < 0) & (d3 * d4 < 0)))


def _point_segment_distance(points: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    ab = b - a
    t = np.clip(((points - a) @ ab) / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(points - (a + t[:, None] * ab), axis=1)


def _place_landmarks(
    positions: np.ndarray, degree: np.ndarray, width: float, height: float, rng: np.random.Generator
) -> dict[str, int]:
    """Goals one per quadrant, then the other places spread out; at most one name per intersection."""
    n_nodes = positions.shape[0]
    free = np.ones(n_nodes, dtype=bool)
    through = degree >= 2  # not a dead end
    landmarks: dict[str, int] = {}
    for goal in GOALS:
        fx, fy = _GOAL_ANCHORS[goal]
        target = np.array([fx * width, fy * height]) + rng.uniform(-0.08, 0.08, size=2) * (width, height)
        quadrant = ((positions[:, 0] >= width / 2) == (fx > 0.5)) & ((positions[:, 1] >= height / 2) == (fy > 0.5))
        distance = np.linalg.norm(positions - target, axis=1)
        for pool in (free & through & quadrant, free & through, free):
            if pool.any():
                node = int(np.flatnonzero(pool)[np.argmin(distance[pool])])
                break
        landmarks[goal] = node
        free[node] = False
    spacing = 0.6 * math.sqrt(width * height / (len(GOALS) + len(PLACES)))
    remaining = list(PLACES)
    order = rng.permutation(n_nodes)
    while remaining and free.any():
        for node in order.tolist():
            if not remaining:
                break
            if not free[node] or (not through[node] and spacing > 0):
                continue
            taken = positions[list(landmarks.values())]
            if np.linalg.norm(taken - positions[node], axis=1).min() >= spacing:
                landmarks[remaining.pop(0)] = node
                free[node] = False
        # Relax the spacing until everything fits; at zero spacing any free intersection will do
        spacing = spacing * 0.7 if spacing > 1.0 else 0.0
    return landmarks
