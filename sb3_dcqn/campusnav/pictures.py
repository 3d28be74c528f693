"""The command line's route pictures: the map with its closures, the goal, the shortest path and a greedy route."""

from __future__ import annotations

import numpy as np

from campusnav_env import CampusNavEnv, RouteReport
from campusnav_env.rendering.map_view import draw_map
from campusnav_env.route_evaluation import Route

__all__ = ["pick_route", "route_picture"]


def pick_route(report: RouteReport, goal: str, start: int | None, heading: int | None) -> Route | None:
    """The route from ``start``/``heading`` if given, else a failed one from the farthest start, else the longest."""
    routes = [
        r
        for r in report.routes
        if r.goal == goal and (start is None or r.start == start) and (heading is None or r.heading == heading)
    ]
    if not routes:
        return None
    failed = [r for r in routes if not r.success]
    return max(failed or routes, key=lambda r: (r.shortest, len(r.nodes), -r.start, -r.heading))


def route_picture(nav: CampusNavEnv, goal: str, route: Route | None, start: int | None, size: int) -> np.ndarray:
    """The map (closures in red), the goal, the shortest path from the start and the route, if any."""
    goal_node = nav.goal_nodes[nav.goal_names.index(goal)]
    routes: dict[str, list[int]] = {}
    origin = route.start if route is not None else start
    if origin is not None and origin != goal_node and nav.node_distances(goal_node)[origin] > 0:
        routes["shortest path"] = nav.graph.shortest_path(origin, goal_node)
    if route is not None:
        outcome = f"{route.steps} steps" if route.success else "fails"
        routes[f"greedy route ({outcome})"] = list(route.nodes)
    return draw_map(
        nav.graph,
        size=size,
        goal=goal_node,
        agent=origin,
        heading=None if route is None else route.heading,
        routes=routes or None,
    )
