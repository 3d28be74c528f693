"""The command line's route pictures: the map with its closures, the goal, the shortest path and a greedy route.

A run's ``routes.png`` pictures a few goals (:func:`picture_goals`): every goal of an env with at most
:data:`PICTURED_GOALS`; of an env with more (``CampusNavGoal-v0``: every intersection) the paper's four landmark goals
(:data:`campusnav_env.maps.campus.GOALS`) where it has them, else its first landmark goals, else its first goals.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from campusnav_env import COMPASS, CampusNavEnv, RouteReport
from campusnav_env.figures import closure_route_panels
from campusnav_env.maps.campus import GOALS
from campusnav_env.recovery import Recovery, RouteEvaluation
from campusnav_env.rendering.map_view import draw_map
from campusnav_env.rendering.palette import PAGE_RGB
from campusnav_env.route_evaluation import Route

__all__ = ["PICTURED_GOALS", "pick_route", "picture_goals", "route_picture", "route_title", "routes_figure"]

# Most goals a run's routes.png pictures (one row each)
PICTURED_GOALS = 4


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


def picture_goals(nav: CampusNavEnv, count: int = PICTURED_GOALS) -> list[str]:
    """
    The goals a run pictures, and the default goal of a picture (the first).

    :param nav: The env
    :param count: Most goals
    :return: every goal of an env with at most ``count``; else the paper's landmark goals among the env's goals,
        else its landmark goals, else its first goals (at most ``count``)
    """
    names = list(nav.goal_names)
    if len(names) <= count:
        return names
    landmarks = nav.graph.landmarks
    for choice in ([g for g in GOALS if g in names], [g for g in names if g in landmarks], names):
        if choice:
            return choice[:count]
    raise ValueError("the env has no goals")


def routes_figure(
    nav: CampusNavEnv,
    evaluations: Sequence[RouteEvaluation],
    recoveries: Sequence[Recovery],
    goals: Sequence[str],
    size: int = 800,
) -> np.ndarray | None:
    """
    A run's ``routes.png``: a row per goal, with a panel per closure (the route learned before it and the route after
    recovery, :func:`~campusnav_env.figures.closure_route_panels`), or without closures the last evaluation's route
    (:func:`route_picture`).

    :param nav: The env (its map and current closures)
    :param evaluations: Every route evaluation of the run
    :param recoveries: One per closure
    :param goals: The goals pictured (:func:`picture_goals`); closure panels name goals by landmark, so goals
        without one are pictured on the last evaluation only
    :param size: Longer side of each map in pixels (600 for closure panels)
    :return: the picture, or ``None`` without evaluations
    """
    if not evaluations:
        return None
    landmark_goals = [goal for goal in goals if goal in nav.graph.landmarks]
    if recoveries and landmark_goals:
        rows = [closure_route_panels(nav.graph, evaluations, recoveries, goal=goal) for goal in landmark_goals]
    else:
        report = evaluations[-1].report
        rows = [
            route_picture(nav, goal, pick_route(report, goal, None, None), None, size, score=report) for goal in goals
        ]
    return _stack(rows)


def _stack(rows: Sequence[np.ndarray]) -> np.ndarray:
    """Pictures one under the other, left-aligned on the page colour (their widths may differ)."""
    if len(rows) == 1:
        return rows[0]
    page = np.full((sum(row.shape[0] for row in rows), max(row.shape[1] for row in rows), 3), PAGE_RGB, np.uint8)
    top = 0
    for row in rows:
        page[top : top + row.shape[0], : row.shape[1]] = row
        top += row.shape[0]
    return page
