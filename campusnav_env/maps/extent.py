"""
How large a road map may be: the extent that street views are built for, checked before any view is built.

Building a map's street views places buildings, trees and parks along every metre of road and over the whole area
(:mod:`campusnav_env.rendering.placement`), so the build's time grows with the total road length and the area, not
with the number of intersections: 10 intersections read with the wrong units (metres over 0-100 taken for degrees:
8,132 x 8,896 km, 58,362 km of road) sat at "encoding views 0/10" for as long as anyone watched (the area alone asks
for 43 million parks). The limits below are well above the largest maps the product
builds (the 56,000-intersection city: 55 x 36 km, 17,871 km of road; the 10,000-intersection city: 23 x 15 km,
3,180 km; the 1,000-intersection city, 301 km of road, builds its world in 13 s on one core of a 2-core EPYC) and far
below a mistake of units:

- :data:`MAX_MAP_SPAN_M`: the map's bounding box is at most 100 km on either side;
- :data:`MAX_ROAD_NETWORK_M`: its roads add up to at most 40,000 km (about twice the largest city's).

:func:`check_map_extent` refuses a map beyond them with :class:`MapExtentError`, naming the map, its longest road,
the figures and the limits. The same span is what makes a coordinate guess plausible on import
(:mod:`campusnav_env.maps.osm`).
"""

from __future__ import annotations

import numpy as np

from campusnav_env.maps.refusals import RefusedInput, Setting
from campusnav_env.maps.road_graph import RoadGraph

__all__ = ["MAX_MAP_SPAN_M", "MAX_ROAD_NETWORK_M", "MapExtentError", "check_map_extent", "describe_length", "span_m"]

MAX_MAP_SPAN_M = 100_000.0
MAX_ROAD_NETWORK_M = 40_000_000.0


class MapExtentError(RefusedInput):
    """
    A map too large for its street views to be built (most often: coordinates read in the wrong units); its ``fix``
    is ``coords='projected'`` (the env's ``map_coords``), its ``where`` the map.
    """


def span_m(points: np.ndarray) -> tuple[float, float]:
    """Width (east-west) and height (north-south) of the bounding box of ``(n, 2)`` points, in their units."""
    points = np.asarray(points, dtype=np.float64)
    width, height = np.ptp(points, axis=0) if len(points) else (0.0, 0.0)
    return float(width), float(height)


def check_map_extent(graph: RoadGraph, source: str | None = None) -> None:
    """
    Refuse a map whose street views could not be built in reasonable time (see the module docstring).

    :param graph: The road map
    :param source: What to call it in the error (e.g. the GraphML file); default: the map's name
    :raises MapExtentError: if the map spans more than :data:`MAX_MAP_SPAN_M` or its roads add up to more than
        :data:`MAX_ROAD_NETWORK_M`
    """
    width, height = span_m(graph.positions)
    total = float(np.sum(graph.lengths))
    if max(width, height) <= MAX_MAP_SPAN_M and total <= MAX_ROAD_NETWORK_M:
        return
    longest = int(np.argmax(graph.lengths))
    u, v = graph.roads[longest]
    km = describe_length
    raise MapExtentError(
        f"too large to build its street views: it spans {km(width)} x {km(height)} and its roads add up to "
        f"{km(total)} (the longest, road {u}-{v}, {km(float(graph.lengths[longest]))}); the limits are "
        f"{km(MAX_MAP_SPAN_M)} across and {km(MAX_ROAD_NETWORK_M)} of road",
        "If x/y are metres read as longitude/latitude, load the map with {fix}",
        fix=Setting("coords", "projected", note="the env's map_coords"),
        where=f"map {source or graph.name!r}",
        separator=". ",
    )


def describe_length(metres: float) -> str:
    """A length as people say it: ``"8,896 km"``, ``"2.3 km"``, ``"80 m"``."""
    if metres >= 10_000:
        return f"{metres / 1000:,.0f} km"
    return f"{metres / 1000:.1f} km" if metres >= 1000 else f"{metres:.0f} m"
