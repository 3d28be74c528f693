"""The command line's route pictures: the map with its closures, the goal, the shortest path and a learned route.

A run's ``routes.png`` pictures a few goals (:func:`picture_goals`): every goal of an env with at most
:data:`PICTURED_GOALS`; of an env with more (``CampusNavGoal-v0``: every intersection) the paper's four landmark goals
(:data:`campusnav_env.maps.campus.GOALS`) where it has them, else its first landmark goals, else its first goals.
Each goal's picture is as large as the map needs (:func:`~campusnav_env.rendering.map_view.map_size`: 600 pixels on
the campus, 1,600 at 1,000 intersections), and the goals' pictures are laid out in a grid (four goals: 2 x 2).

Colours mean the same in every picture: orange is the route the agent learned (its greedy route), purple the route
after a closure, cyan the shortest path, red a closed road.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from campusnav_env import COMPASS, CampusNavEnv, RouteReport
from campusnav_env.figures import closure_route_panels, pick_route, tile_panels
from campusnav_env.maps.campus import GOALS
from campusnav_env.recovery import Recovery, RouteEvaluation
from campusnav_env.rendering.map_view import draw_map, map_size
from campusnav_env.rendering.palette import LEARNED_ROUTE_RGB, SHORTEST_PATH_RGB
from campusnav_env.route_evaluation import Route

__all__ = ["PICTURED_GOALS", "picture_goals", "route_picture", "route_title", "routes_figure"]

# Most goals a run's routes.png pictures (one picture or row of closure panels each)
PICTURED_GOALS = 4


def route_title(
    nav: CampusNavEnv, goal: str, route: Route | None, start: int | None, score: RouteReport | None = None
) -> str:
    """
    A picture's title: start, goal, closures and score, e.g. ``"from node 17 facing N to Dreese Lab (node 44);
    closed: 81-82; learned route: 12 steps (shortest 10); all routes to Dreese Lab: success 0.995, SPL 0.970"``.

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
        parts.append(f"learned route: {outcome} (shortest {route.shortest})")
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
    The map (closures in red, over the routes), the goal, the shortest path from the start (cyan, wide underneath)
    and the learned route, if any (orange), titled with :func:`route_title`.

    :param score: The route evaluation the route comes from (for the title)
    :param node_ids: Write every intersection's id
    """
    goal_node = nav.goal_nodes[nav.goal_names.index(goal)]
    routes: dict[str, list[int]] = {}
    colours = {}
    origin = route.start if route is not None else start
    if origin is not None and origin != goal_node and nav.node_distances(goal_node)[origin] > 0:
        shortest = nav.graph.shortest_path(origin, goal_node)
        name = f"shortest path ({len(shortest) - 1} steps)"
        routes[name], colours[name] = shortest, SHORTEST_PATH_RGB
    if route is not None:
        outcome = f"{route.steps} steps" if route.success else "fails"
        name = f"learned route ({outcome})"
        routes[name], colours[name] = list(route.nodes), LEARNED_ROUTE_RGB
    return draw_map(
        nav.graph,
        size=size,
        goal=goal_node,
        agent=origin,
        heading=None if route is None else route.heading,
        routes=routes or None,
        node_ids=node_ids,
        title=route_title(nav, goal, route, start, score),
        colours=colours,
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
    size: int | None = None,
) -> np.ndarray | None:
    """
    A run's ``routes.png``: per goal, a panel per closure (the route learned before it and the route after recovery,
    :func:`~campusnav_env.figures.closure_route_panels`), or without closures the last evaluation's route
    (:func:`route_picture`); the goals' pictures in a grid as close to square as they allow
    (:func:`~campusnav_env.figures.tile_panels`: four single panels 2 x 2, four rows of several panels one above
    the other).

    :param nav: The env (its map and current closures)
    :param evaluations: Every route evaluation of the run
    :param recoveries: One per closure
    :param goals: The goals pictured (:func:`picture_goals`); closure panels name goals by landmark, so goals
        without one are pictured on the last evaluation only
    :param size: Longer side of each map in pixels (default: :func:`~campusnav_env.rendering.map_view.map_size` of
        the map, 600 on the campus, more on larger maps, at most 1,600)
    :return: the picture, or ``None`` without evaluations
    """
    if not evaluations:
        return None
    size = map_size(nav.graph.n_nodes) if size is None else size
    landmark_goals = [goal for goal in goals if goal in nav.graph.landmarks]
    if recoveries and landmark_goals:
        blocks = [
            closure_route_panels(nav.graph, evaluations, recoveries, goal=goal, size=size) for goal in landmark_goals
        ]
    else:
        report = evaluations[-1].report
        blocks = [
            route_picture(nav, goal, pick_route(report.routes, goal=goal), None, size, score=report) for goal in goals
        ]
    if len(blocks) == 1:
        return blocks[0]
    # Closure panels come framed on their page; a single route picture gets a frame of its own
    return tile_panels(blocks, gap=max(8, size // 40), frame=not (recoveries and landmark_goals))
