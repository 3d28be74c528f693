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

The same :class:`World` feeds every view, so a building seen from two intersections is the same building. The scene
types live in :mod:`campusnav_env.rendering.scene`, the placement steps in :mod:`campusnav_env.rendering.placement`;
this module keeps every name it had importable (the spatial index, the geometry helpers, the landmark palette).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from campusnav_env.maps.extent import check_map_extent
from campusnav_env.maps.geometry import point_segment_distances, polygon_segment_distances
from campusnav_env.rendering.palette import landmark_colour
from campusnav_env.rendering.placement import (
    PlacementSite,
    place_buildings,
    place_landmarks,
    place_parks,
    place_street_trees,
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
    :raises ~campusnav_env.maps.extent.MapExtentError: if the map is too large to build (its placement's work grows
        with the road length and the area, see :mod:`campusnav_env.maps.extent`)
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool):
        raise ValueError(f"seed must be an int, got {seed!r}")
    check_map_extent(graph)
    site = PlacementSite.around(graph, int(seed))
    # The order matters: each step claims ground the later ones must keep clear of, and draws from the same rng
    landmarks, sports_fields, signs = place_landmarks(site)
    parks, park_trees = place_parks(site)
    buildings = place_buildings(site)
    street_trees = place_street_trees(site)
    return World(
        graph=graph,
        buildings=(*landmarks, *buildings),
        trees=(*park_trees, *street_trees),
        fields=(*sports_fields, *parks),
        signs=tuple(signs),
        road_width=ROAD_WIDTH,
        verge_width=VERGE_WIDTH,
        sidewalk_width=SIDEWALK_WIDTH,
        seed=int(seed),
    )
