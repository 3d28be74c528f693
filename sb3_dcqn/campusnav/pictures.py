"""The command line's route pictures: the map with its closures, the goal, the shortest path and a greedy route."""

from __future__ import annotations

import numpy as np

from campusnav_env import COMPASS, CampusNavEnv, RouteReport
from campusnav_env.rendering.map_view import draw_map
from campusnav_env.route_evaluation import Route

__all__ = ["pick_route", "route_picture", "route_title"]


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


def route_title(
    nav: CampusNavEnv, goal: str, route: Route | None, start: int | None, score: RouteReport | None = None
) -> str:
    """
    A picture's title: start, goal, closures and score, e.g. ``"from node 17 facing N to Dreese Lab (node 44);
    closed: 81-82; greedy route: 12 steps (shortest 10); all routes to Dreese Lab: success 0.995, SPL 0.970"``.

    :param score: The route evaluation the route comes from (its scores for the goal go in the title)
    """
    goal_node = nav.goal_nodes[nav.goal_names.index(goal)]
    origin = route.start if route is not None else start
    parts = [f"to {goal} (node {goal_node})"]
    if origin is not None:
        facing = "" if route is None else f" facing {COMPASS[route.heading]}"
        parts[0] = f"from node {origin}{facing} {parts[0]}"
    closed = ", ".join(f"{u}-{v}" for u, v in sorted(nav.closed_roads))
    parts.append(f"closed: {closed or 'none'}")
    if route is not None:
        outcome = f"{route.steps} steps" if route.success else "fails"
        parts.append(f"greedy route: {outcome} (shortest {route.shortest})")
    if score is not None:
        for_goal = score.for_goal(goal)
        parts.append(f"all routes to {goal}: success {for_goal.success_rate:.3f}, SPL {for_goal.spl:.3f}")
    return "; ".join(parts)


def route_picture(
    nav: CampusNavEnv,
    goal: str,
    route: Route | None,
    start: int | None,
    size: int,
    *,
    score: RouteReport | None = None,
    node_ids: bool = False,
) -> np.ndarray:
    """
    The map (closures in red), the goal, the shortest path from the start and the route, if any, titled with
    :func:`route_title`.

    :param score: The route evaluation the route comes from (for the title)
    :param node_ids: Write every intersection's id
    """
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
        node_ids=node_ids,
        title=route_title(nav, goal, route, start, score),
    )
