"""
Figures of the dynamic-routing experiments, as RGB images: route panels per closure and training curves.

- :func:`closure_route_panels` (the paper's Fig. 7 and 9): one map per closure with the route the agent learned from
  one start before the closure and the route it took after recovering (or at the end of the closure's window if it
  never did), every road closed so far in red, start and goal marked, a legend, and a title per panel (the change and
  the recovery, start, goal, closed roads, steps and score), tiled in a grid; :func:`closure_panels` gives what each
  panel shows, as data.
- :func:`training_curves` (the paper's Fig. 8): episode reward and episode length against training episodes, smoothed,
  with a vertical line per closure, and optionally the route evaluations' success rate and SPL.
- :func:`pick_route` chooses the route a picture shows (for these panels and for the command line's pictures), and
  :func:`route_steps` / :func:`route_text` give a route as text: its nodes and the turn taken at each (forward,
  right, back, left), with the intersections' names.
- :func:`tile_panels` lays pictures out in a grid; :func:`write_figure` writes an image as a PNG, atomically.

Colours mean the same in every picture: orange is the learned route (the greedy policy's; before the closure in the
closure panels), purple the route after a closure, cyan the shortest path, red a closed road (drawn over the routes).

The inputs are what :class:`~campusnav_env.callbacks.RoadClosureCallback` and
:class:`~campusnav_env.callbacks.RouteEvaluationCallback` produce (``records``, ``recoveries``, ``evaluations``) and
what a :class:`~stable_baselines3.common.monitor.Monitor` records per episode::

    rgb = closure_route_panels(env.graph.map, evaluation.evaluations, closures.recoveries)
    write_figure("runs/routes_per_closure.png", rgb)
    rgb = training_curves(monitor.get_episode_rewards(), monitor.get_episode_lengths(), closures.recoveries,
                          evaluation.evaluations)
    write_figure("runs/training_curves.png", rgb)

Matplotlib draws on its own ``Figure`` with an Agg canvas, so no global backend (``pyplot``) is touched.
"""

from __future__ import annotations

import itertools
import math
import textwrap
from collections.abc import Collection, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from campusnav_env.atomic_files import write_png
from campusnav_env.maps.compass import ACTION_NAMES, COMPASS
from campusnav_env.maps.navigation import NavigationGraph
from campusnav_env.maps.road_graph import RoadGraph, road_key
from campusnav_env.recovery import ClosureRecord, Recovery, RouteEvaluation
from campusnav_env.rendering.map_view import draw_map, title_band
from campusnav_env.rendering.palette import (
    BORDER_RGB,
    CLOSED_RGB,
    LEARNED_ROUTE_RGB,
    PAGE_RGB,
    RECOVERED_RGB,
    REROUTED_RGB,
    TEXT_RGB,
)
from campusnav_env.route_evaluation import Route

if TYPE_CHECKING:
    import matplotlib.figure

__all__ = [
    "CURRICULUM_NOTE",
    "ClosurePanel",
    "RouteStep",
    "closure_panels",
    "closure_route_panels",
    "panel_title",
    "pick_route",
    "route_steps",
    "route_text",
    "tile_panels",
    "training_curves",
    "write_figure",
]

COMPASS_LETTERS = COMPASS
# The training curves' note when a start curriculum runs: its episodes start near the goal, the evaluations anywhere
CURRICULUM_NOTE = (
    "episode reward and length: training episodes, from the start curriculum's starts (near the goal first); "
    "route evaluation: from every start"
)
_SHADE = {True: "tab:green", False: "tab:red"}  # training span after a closure: recovered or not
Road = tuple[int, int]


# ------------------------------------------------------------------------------------------------ route panels
def _roads_text(roads: Sequence[Road], limit: int = 3) -> str:
    names = [f"{u}-{v}" for u, v in roads]
    if len(names) > limit:
        names = [*names[:limit], f"+{len(names) - limit} more"]
    return ("road " if len(roads) == 1 else "roads ") + ", ".join(names)


def _change_text(closure: ClosureRecord) -> str:
    parts = []
    if closure.closed:
        parts.append(_roads_text(closure.closed) + " closed")
    if closure.reopened:
        parts.append(_roads_text(closure.reopened) + " reopened")
    return "; ".join(parts) or "nothing changed"


def _status_text(recovery: Recovery) -> str:
    if not recovery.recovered:
        return "not recovered"
    episodes = round(recovery.episodes)
    return f"recovered after {episodes} episode{'' if episodes == 1 else 's'} / {recovery.seconds:.1f} s"


def panel_title(number: int, recovery: Recovery) -> str:
    """
    First title line of a route panel, e.g. ``"closure 2: road 81-82 closed; recovered after 35 episodes / 4.1 s"``.

    :param number: Number of the closure (1 for the first)
    :param recovery: The closure and how the agent fared after it
    :return: the title
    """
    return f"closure {number}: {_change_text(recovery.closure)}; {_status_text(recovery)}"


def _route_from(evaluation: RouteEvaluation | None, goal: str, start: int, heading: int) -> Route | None:
    if evaluation is None:
        return None
    return next(
        (r for r in evaluation.report.routes if (r.goal, r.start, r.heading) == (goal, start, heading)),
        None,
    )


def _before(evaluations: Sequence[RouteEvaluation], closure: ClosureRecord) -> RouteEvaluation | None:
    """The last evaluation made before the closure (its routes are the learned ones)."""
    index = closure.evaluation_index - 1
    return evaluations[index] if 0 <= index < len(evaluations) else None


def _uses(route: Route, roads: set[Road]) -> bool:
    return any(u != v and road_key(u, v) in roads for u, v in itertools.pairwise(route.nodes))


def pick_route(
    routes: Iterable[Route],
    *,
    goal: str | None = None,
    start: int | None = None,
    heading: int | None = None,
    roads: Collection[Road] = (),
) -> Route | None:
    """
    The route a picture shows, among those to ``goal`` from ``start`` at ``heading`` (each: any, when ``None``).

    In order of preference: the longest route that travels one of ``roads`` (the roads a closure is about to close,
    so that the picture shows what the closure changes), a failed route from the farthest start (what went wrong),
    the route from the farthest start. Ties go to the longer route, then the lower start and heading.

    :param routes: Evaluated routes (``RouteReport.routes``)
    :param goal: Goal name of the route
    :param start: Its start node
    :param heading: Its start heading (0 N, 1 E, 2 S, 3 W)
    :param roads: Roads ``(u, v)`` that a route travelling them is preferred for (either order)
    :return: the route, or ``None`` if none matches
    """
    matching = [
        r
        for r in routes
        if (goal is None or r.goal == goal)
        and (start is None or r.start == start)
        and (heading is None or r.heading == heading)
    ]
    if not matching:
        return None
    using = [r for r in matching if _uses(r, {road_key(u, v) for u, v in roads})] if roads else []
    if using:
        return max(using, key=lambda r: (len(r.nodes), -r.start, -r.heading))
    failed = [r for r in matching if not r.success]
    return max(failed or matching, key=lambda r: (r.shortest, len(r.nodes), -r.start, -r.heading))


@dataclass(frozen=True)
class RouteStep:
    """
    One step of a route, as :func:`route_steps` reads it from the nodes.

    :param node: Where the step starts
    :param heading: The heading there (0 N, 1 E, 2 S, 3 W)
    :param action: ``"forward"``, ``"right"``, ``"back"`` or ``"left"``; ``"blocked"`` for a move that stayed put
        (a closed road, or no road that way: which action it was, the nodes do not say)
    :param to: Where it ends
    :param to_heading: The heading there
    """

    node: int
    heading: int
    action: str
    to: int
    to_heading: int


def route_steps(road_graph: RoadGraph | NavigationGraph, route: Route) -> list[RouteStep]:
    """
    The turns of a route: from its start and heading, the action that takes each node to the next (the map's move
    rule, :attr:`RoadGraph.transitions`, on the open map: a closed road only blocks).

    :param road_graph: The map the route was driven on
    :param route: The route (``Route.nodes`` starts at ``Route.start``)
    :return: one step per move
    :raises ValueError: a route whose start is not its first node, or with a move no action makes
    """
    graph = road_graph.map if isinstance(road_graph, NavigationGraph) else road_graph
    nodes = [int(n) for n in route.nodes]
    if not nodes or nodes[0] != route.start:
        raise ValueError(f"route from node {route.start}: its nodes must start there, got {nodes[:3]}")
    state = graph.state_index(route.start, route.heading)
    steps = []
    for u, v in itertools.pairwise(nodes):
        heading = int(graph.state_headings[state])
        if u == v:
            steps.append(RouteStep(u, heading, "blocked", v, heading))
            continue
        targets = graph.transitions[state]
        actions = [a for a in range(graph.n_actions) if targets[a] >= 0 and graph.state_nodes[targets[a]] == v]
        if not actions:
            raise ValueError(
                f"route from node {route.start}: no action leads from node {u} facing {COMPASS[heading]} to node {v}"
            )
        state = int(targets[actions[0]])
        name = ACTION_NAMES[actions[0]] if actions[0] < len(ACTION_NAMES) else f"action {actions[0]}"
        steps.append(RouteStep(u, heading, name, v, int(graph.state_headings[state])))
    return steps


def route_text(road_graph: RoadGraph | NavigationGraph, route: Route) -> str:
    """
    A route as text: a headline, its nodes, and one line per step with the turn taken, e.g.::

        route from node 21 facing N to Dreese Lab: reached in 3 steps (shortest 3)
        nodes: 21 15 16 81
          1. 21 facing N: forward -> 15 facing N
          2. 15 facing N: right -> 16 (Library) facing E
          3. 16 (Library) facing E: left -> 81 (Dreese Lab) facing N

    :param road_graph: The map the route was driven on
    :param route: The route
    :return: the text, lines ending in newlines
    """
    graph = road_graph.map if isinstance(road_graph, NavigationGraph) else road_graph
    names: dict[int, list[str]] = {}
    for name, node in sorted(graph.landmarks.items()):
        names.setdefault(node, []).append(name)

    def place(node: int) -> str:
        return f"{node} ({', '.join(names[node])})" if node in names else str(node)

    moves = sum(u != v for u, v in itertools.pairwise(route.nodes))
    # A failed route is scored as the step limit (RouteReport); why it stopped, where the evaluation recorded it
    why = {
        "blocked": f"stuck at node {place(route.nodes[-1])}: a move into a closed road or no road, again and again",
        "loop": f"goes round a loop (back at node {place(route.nodes[-1])} facing the same way)",
        "step limit": "the step limit reached",
    }.get(route.ended, "a loop, blocked or the step limit")
    outcome = (
        f"reached in {route.steps} steps"
        if route.success
        else f"fails after {moves} move{'' if moves == 1 else 's'} ({why}; scored as {route.steps} steps)"
    )
    shortest = route.shortest if route.shortest >= 0 else "-"
    lines = [
        f"route from node {place(route.start)} facing {COMPASS[route.heading]} to {route.goal}: {outcome} "
        f"(shortest {shortest})",
        "nodes: " + " ".join(str(int(n)) for n in route.nodes),
    ]
    width = len(str(len(route.nodes)))
    for k, step in enumerate(route_steps(graph, route), start=1):
        lines.append(
            f"  {k:>{width}}. {place(step.node)} facing {COMPASS[step.heading]}: {step.action} -> "
            f"{place(step.to)} facing {COMPASS[step.to_heading]}"
        )
    return "\n".join(lines) + "\n"


def _route_steps(route: Route | None) -> str:
    if route is None:
        return "-"
    return f"{route.steps} steps" if route.success else "fails"


def _closed_text(roads: Sequence[Road], limit: int = 4) -> str:
    names = [f"{u}-{v}" for u, v in sorted(roads)]
    if len(names) > limit:
        names = [*names[:limit], f"+{len(names) - limit} more"]
    return ", ".join(names) or "none"


@dataclass(frozen=True)
class ClosurePanel:
    """
    What one panel of :func:`closure_route_panels` shows.

    :param number: Number of the closure (1 for the first)
    :param recovery: The closure and how the agent fared after it
    :param start: Start node of both routes
    :param heading: Start heading (0 N, 1 E, 2 S, 3 W)
    :param goal: Goal name
    :param goal_node: Its node
    :param closed: Roads closed at the time (all closures so far, minus reopened roads), sorted
    :param learned: The route from the last evaluation before the closure, if any
    :param after: The route at recovery (or at the last evaluation of the window), if any
    :param after_evaluation: The evaluation ``after`` comes from, if any
    :param shortest: Hops of the shortest path from ``start`` with ``closed`` closed (-1: cut off)
    """

    number: int
    recovery: Recovery
    start: int
    heading: int
    goal: str
    goal_node: int
    closed: tuple[Road, ...]
    learned: Route | None
    after: Route | None
    after_evaluation: RouteEvaluation | None
    shortest: int

    @property
    def after_name(self) -> str:
        """Name of the route after the closure in the legend and the title."""
        return "re-routed" if self.recovery.recovered else "at end of window"

    @property
    def title(self) -> tuple[str, str, str]:
        """
        The panel's three title lines: :func:`panel_title`; start, goal and the roads closed; the steps of both
        routes against the shortest path, and the score (success rate and SPL of the evaluation the second route is
        from), e.g.::

            closure 1: road 69-81 closed; recovered after 55 episodes / 1.6 s
            start 21 facing N -> Dreese Lab (81) | closed: 69-81
            learned 17 steps | re-routed 17 steps | shortest 17 | success 0.99, SPL 0.98
        """
        shortest = self.shortest if self.shortest >= 0 else "-"
        score = self.after_evaluation
        return (
            panel_title(self.number, self.recovery),
            f"start {self.start} facing {COMPASS_LETTERS[self.heading]} -> {self.goal} ({self.goal_node}) | "
            f"closed: {_closed_text(self.closed)}",
            f"learned {_route_steps(self.learned)} | {self.after_name} {_route_steps(self.after)} | "
            f"shortest {shortest} | "
            + (f"success {score.success_rate:.2f}, SPL {score.spl:.2f}" if score is not None else "no evaluation"),
        )


def closure_panels(
    road_graph: RoadGraph | NavigationGraph,
    evaluations: Sequence[RouteEvaluation],
    recoveries: Sequence[Recovery],
    start: int | None = None,
    heading: int | None = None,
    *,
    goal: str | None = None,
) -> list[ClosurePanel]:
    """
    What :func:`closure_route_panels` draws, one :class:`ClosurePanel` per closure (same arguments).

    :return: the panels, in the order of ``recoveries``
    :raises ValueError: no recoveries, a bad start, heading or goal
    :raises TypeError: a map that is neither a ``RoadGraph`` nor a ``NavigationGraph``
    """
    graph = road_graph.map if isinstance(road_graph, NavigationGraph) else road_graph
    if not isinstance(graph, RoadGraph):
        raise TypeError(f"road_graph must be a RoadGraph or NavigationGraph, got {type(road_graph).__name__}")
    if not recoveries:
        raise ValueError("closure_route_panels needs at least one recovery (one panel per closure)")
    if heading is not None and (isinstance(heading, bool) or heading not in (0, 1, 2, 3)):
        raise ValueError(f"heading must be 0 (N), 1 (E), 2 (S), 3 (W) or None, got {heading!r}")
    if start is not None:
        start = graph.check_node(start, "start")

    if goal is None:
        goal = next((r.goal for e in evaluations for r in e.report.routes), None)
        if goal is None:
            raise ValueError("no routes in the evaluations: pass goal=... (a landmark name)")
    if goal not in graph.landmarks:
        raise ValueError(f"goal {goal!r} is not a landmark of the map ({sorted(graph.landmarks)})")
    goal_node = graph.landmarks[goal]
    if start is not None and start == goal_node:
        raise ValueError(f"start {start} is the goal {goal!r}: there is no route to draw")

    # The start (and heading) is chosen once, on the routes learned before the first closure, and kept for all panels
    if start is None or heading is None:
        first = recoveries[0].closure
        learned = _before(evaluations, first)
        chosen = pick_route(learned.report.routes if learned else [], goal=goal, start=start, roads=first.closed)
        if chosen is not None:
            start = chosen.start if start is None else start
            heading = chosen.heading if heading is None else heading
        else:
            if start is None:
                hops = NavigationGraph(graph).hops_to(goal_node)
                start = int(np.argmax(hops))
            heading = 0 if heading is None else heading
    assert start is not None and heading is not None

    panels = []
    closed: set[Road] = set()
    for number, recovery in enumerate(recoveries, start=1):
        closure = recovery.closure
        closed |= {road_key(u, v) for u, v in closure.closed}
        closed -= {road_key(u, v) for u, v in closure.reopened}
        end = recovery.recovered_at if recovery.recovered_at is not None else recovery.last
        panels.append(
            ClosurePanel(
                number=number,
                recovery=recovery,
                start=start,
                heading=heading,
                goal=goal,
                goal_node=goal_node,
                closed=tuple(sorted(closed)),
                learned=_route_from(_before(evaluations, closure), goal, start, heading),
                after=_route_from(end, goal, start, heading),
                after_evaluation=end,
                shortest=int(NavigationGraph(graph, sorted(closed)).hops_to(goal_node)[start]),
            )
        )
    return panels


def closure_route_panels(
    road_graph: RoadGraph | NavigationGraph,
    evaluations: Sequence[RouteEvaluation],
    recoveries: Sequence[Recovery],
    start: int | None = None,
    heading: int | None = None,
    *,
    goal: str | None = None,
    size: int = 600,
    columns: int = 3,
    labels: bool = True,
    title: str | None = None,
) -> np.ndarray:
    """
    One map per closure with the route before it and the route after recovery, tiled in a grid.

    Every panel shows the routes from one fixed start (and heading): the *learned route* in orange (from the last
    evaluation before the closure, ``evaluations[closure.evaluation_index - 1]``), drawn wide underneath so that it
    shows where the other follows it, and in purple the route at recovery (or, if the agent never recovered, at the
    last evaluation of the closure's window), the roads closed so far (all closures up to this one, minus reopened
    roads) in red with an X, drawn over the routes,
    the start (a triangle facing the heading) and the goal (a star), with a legend below. Its three title lines
    (:attr:`ClosurePanel.title`) name the change and the recovery, the start, goal and closed roads, and the steps and
    score.

    :param road_graph: The map (a ``NavigationGraph``'s own closures are ignored: they come from the records)
    :param evaluations: All route evaluations in the order they were made (``RouteEvaluationCallback.evaluations``)
    :param recoveries: One per closure, in order (``RoadClosureCallback.recoveries``); one panel each
    :param start: Start node of the routes shown. Default: that of the learned route :func:`pick_route` picks with the
        first closure's roads (the longest that travelled one, else a failed one, else the one from the farthest
        start); without learned routes, the start farthest from the goal
    :param heading: Start heading (0 N, 1 E, 2 S, 3 W). Default: that of the learned route chosen as above (among the
        routes from ``start`` when it is given)
    :param goal: Goal name of the routes (default: the goal of the first route in the evaluations)
    :param size: Longer side of each map panel in pixels
    :param columns: Panels per row at most
    :param labels: Write the landmark names on the maps (placed clear of routes and closed roads; without them the
        legend names the landmarks by colour)
    :param title: Text of a band above all panels (e.g. the run), none by default
    :return: ``(H, W, 3)`` uint8 RGB image
    :raises ValueError: no recoveries, a bad start, heading, goal, size or column count
    :raises TypeError: a map that is neither a ``RoadGraph`` nor a ``NavigationGraph``
    """
    if isinstance(columns, bool) or not isinstance(columns, (int, np.integer)) or columns < 1:
        raise ValueError(f"columns must be a positive int, got {columns!r}")
    graph = road_graph.map if isinstance(road_graph, NavigationGraph) else road_graph
    scale = min(0.75, max(0.4, size / 1200))  # the title's font: grows with the panel, but not to a headline
    images = []
    for panel in closure_panels(road_graph, evaluations, recoveries, start, heading, goal=goal):
        # Both always in the legend, so that every panel has the same colours
        learned, after = panel.learned, panel.after
        learned_name = "learned route (before)" if learned else "learned route: none"
        after_name = panel.after_name if after else f"{panel.after_name}: none"
        routes = {
            learned_name: list(learned.nodes) if learned else [],
            after_name: list(after.nodes) if after else [],
        }
        image = draw_map(
            NavigationGraph(graph, panel.closed),
            size=size,
            agent=panel.start,
            heading=panel.heading,
            goal=panel.goal_node,
            routes=routes,
            labels=labels,
            colours={learned_name: LEARNED_ROUTE_RGB, after_name: REROUTED_RGB},
        )
        first, *details = panel.title
        colour = RECOVERED_RGB if panel.recovery.recovered else CLOSED_RGB
        header = title_band(image.shape[1], [(first, colour), *((d, TEXT_RGB) for d in details)], scale)
        images.append(np.concatenate([header, image]))
    page = tile_panels(images, int(columns), gap=max(8, size // 40))
    if title is None:
        return page
    return np.concatenate([title_band(page.shape[1], [(str(title), TEXT_RGB)], scale * 1.2), page])


def tile_panels(
    panels: Sequence[np.ndarray], columns: int | None = None, gap: int = 12, frame: bool = True
) -> np.ndarray:
    """
    Pictures in a grid of rows, each framed, on a white page; cells are as large as the largest picture.

    :param panels: ``(H, W, 3)`` uint8 RGB pictures, in reading order
    :param columns: Pictures per row at most; ``None``: the count that makes the page closest to square (four
        pictures of a map wider than tall: 2 x 2; four wide rows: one column)
    :param gap: Pixels between pictures and around the page
    :param frame: Frame each picture (pictures that are pages of framed panels already need none)
    :return: ``(H, W, 3)`` uint8 RGB image
    :raises ValueError: no pictures, or a bad column count
    """
    if not panels:
        raise ValueError("tile_panels needs at least one picture")
    if columns is None:
        width = max(p.shape[1] for p in panels)
        height = max(p.shape[0] for p in panels)

        def squareness(c: int) -> float:
            return abs(math.log((c * width) / (math.ceil(len(panels) / c) * height)))

        columns = min(range(1, len(panels) + 1), key=squareness)
    if isinstance(columns, bool) or not isinstance(columns, (int, np.integer)) or columns < 1:
        raise ValueError(f"columns must be a positive int or None, got {columns!r}")
    columns = min(int(columns), len(panels))
    rows = math.ceil(len(panels) / columns)
    width = max(p.shape[1] for p in panels)
    height = max(p.shape[0] for p in panels)
    page = np.full((rows * (height + gap) + gap, columns * (width + gap) + gap, 3), PAGE_RGB, dtype=np.uint8)
    for k, panel in enumerate(panels):
        y, x = gap + (k // columns) * (height + gap), gap + (k % columns) * (width + gap)
        page[y : y + panel.shape[0], x : x + panel.shape[1]] = panel
        if frame:
            cv2.rectangle(page, (x - 1, y - 1), (x + panel.shape[1], y + panel.shape[0]), BORDER_RGB, 1)
    return page


# ------------------------------------------------------------------------------------------------ training curves
def _moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Trailing mean over the last ``window`` values (fewer at the start, so the curve starts at the first point)."""
    sums = np.cumsum(np.concatenate([[0.0], values]))
    ends = np.arange(1, values.size + 1)
    starts = np.maximum(0, ends - window)
    return (sums[ends] - sums[starts]) / (ends - starts)


def _episode_array(values: Sequence[float] | np.ndarray, name: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64)
    if array.ndim != 1:
        raise ValueError(f"{name} must be one value per episode (1-D), got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"{name} must be finite")
    return array


def training_curves(
    episode_rewards: Sequence[float] | np.ndarray,
    episode_lengths: Sequence[float] | np.ndarray,
    closures: Sequence[ClosureRecord | Recovery] = (),
    evaluations: Sequence[RouteEvaluation] = (),
    *,
    window: int = 50,
    size: tuple[int, int] | None = None,
    title: str | None = None,
    note: str | None = None,
) -> np.ndarray:
    """
    Episode reward and length against training episodes, with the closures marked (the paper's Fig. 8).

    Each curve is a trailing moving average over ``window`` episodes drawn over the raw values (faint). Every closure
    that changed the network is a red vertical line at its episode, numbered as in :func:`closure_route_panels` and
    labelled with its roads; events that changed nothing (refused) are grey dotted lines. Given recoveries, the
    episodes from each closure to its recovery are shaded. Given evaluations, a third panel shows their success rate
    and SPL against episodes.

    Episode numbers are those of the callbacks (training episodes since the closure callback started); they match a
    ``Monitor``'s episodes when both count from the same start of training.

    :param episode_rewards: Return of every training episode, in order (``Monitor.get_episode_rewards()``)
    :param episode_lengths: Steps of every training episode (``Monitor.get_episode_lengths()``)
    :param closures: ``RoadClosureCallback.records`` or ``.recoveries`` (the latter also shade the recovery)
    :param evaluations: ``RouteEvaluationCallback.evaluations``
    :param window: Episodes in the moving average
    :param size: ``(width, height)`` in pixels (default: 1100 wide, 560 high, 780 with evaluations)
    :param title: Title above the panels
    :param note: A line under the panels, e.g. :data:`CURRICULUM_NOTE` when training episodes start elsewhere
        than the route evaluations (a start curriculum: episode reward then runs ahead of route success)
    :return: ``(H, W, 3)`` uint8 RGB image of exactly ``size``
    :raises ValueError: rewards and lengths of different lengths, non-finite values, a bad window or size
    """
    # Imported here: matplotlib is only needed for this figure
    from matplotlib.figure import Figure

    rewards = _episode_array(episode_rewards, "episode_rewards")
    lengths = _episode_array(episode_lengths, "episode_lengths")
    if rewards.size != lengths.size:
        raise ValueError(
            f"episode_rewards and episode_lengths must have one value per episode each, got {rewards.size} "
            f"rewards and {lengths.size} lengths"
        )
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1:
        raise ValueError(f"window must be a positive int, got {window!r}")
    evaluations = list(evaluations)
    if size is None:
        size = (1100, 780 if evaluations else 560)
    if (
        len(size) != 2
        or any(isinstance(s, bool) or not isinstance(s, (int, np.integer)) for s in size)
        or min(size) < 200
    ):
        raise ValueError(f"size must be (width, height) in whole pixels, each at least 200, got {size!r}")
    width, height = int(size[0]), int(size[1])

    dpi = 100
    figure = Figure(figsize=(width / dpi, height / dpi), dpi=dpi, layout="constrained")
    n_panels = 3 if evaluations else 2
    axes = figure.subplots(n_panels, 1, sharex=True)
    episodes = np.arange(1, rewards.size + 1)
    for ax, values, label, colour in (
        (axes[0], rewards, "episode reward", "tab:blue"),
        (axes[1], lengths, "episode length (steps)", "tab:orange"),
    ):
        if values.size:
            # Raw points faint and small: thousands of episodes would otherwise hide the trend
            ax.scatter(episodes, values, s=3, color=colour, alpha=0.18, linewidths=0, rasterized=True)
            ax.plot(episodes, _moving_average(values, int(window)), color=colour, lw=1.6, label=f"mean of {window}")
            ax.legend(loc="lower right" if ax is axes[0] else "upper right", fontsize=8, framealpha=0.85)
        ax.set_ylabel(label)
        ax.grid(True, alpha=0.3)

    if evaluations:
        ax = axes[2]
        at = [e.episode for e in evaluations]
        ax.plot(at, [e.success_rate for e in evaluations], "o-", color="tab:green", ms=3, lw=1.2, label="success rate")
        ax.plot(at, [e.spl for e in evaluations], "s--", color="tab:purple", ms=3, lw=1.2, label="SPL")
        ax.set_ylim(-0.03, 1.05)
        ax.set_ylabel("route evaluation")
        ax.legend(loc="lower right", fontsize=8, framealpha=0.85)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("training episode")
    last = max([rewards.size, *(e.episode for e in evaluations), 1])

    number = 0
    key: list[str] = []  # one line per numbered closure, shown beside the panels
    shades: dict[bool, bool] = {}
    for item in closures:
        recovery = item if isinstance(item, Recovery) else None
        closure = item.closure if isinstance(item, Recovery) else item
        if not isinstance(closure, ClosureRecord):
            raise TypeError(f"closures must be ClosureRecord or Recovery objects, got {type(item).__name__}")
        last = max(last, closure.episode)
        if not closure.changed:
            for ax in axes:
                ax.axvline(closure.episode, color="0.55", ls=":", lw=1.0)
            continue
        number += 1
        for ax in axes:
            ax.axvline(closure.episode, color="tab:red", ls="--", lw=1.1, alpha=0.9)
        text = f"{number}: {_change_text(closure)}"
        if recovery is not None:
            end = recovery.recovered_at if recovery.recovered_at is not None else recovery.last
            if end is not None and end.episode > closure.episode:
                for ax in axes:
                    ax.axvspan(closure.episode, end.episode, color=_SHADE[recovery.recovered], alpha=0.1, lw=0)
                shades[recovery.recovered] = True
            text += ", " + (f"back after {round(recovery.episodes)} ep." if recovery.recovered else "not recovered")
        key.append(text)
        # The number above the top panel, where it covers no data; the key says what it was
        axes[0].annotate(
            str(number),
            xy=(closure.episode, 1.0),
            xycoords=("data", "axes fraction"),
            xytext=(0, 3),
            textcoords="offset points",
            ha="center",
            va="bottom",
            fontsize=8,
            color="white",
            bbox={"boxstyle": "round,pad=0.25", "fc": "tab:red", "ec": "none"},
        )
    if key or shades:
        from matplotlib.lines import Line2D
        from matplotlib.patches import Patch

        handles: list[Line2D | Patch] = [Line2D([], [], color="tab:red", ls="--", lw=1.1)]
        names = ["closures"]
        handles += [Line2D([], [], lw=0) for _ in key]
        names += key
        for recovered, label in ((True, "until recovered"), (False, "not recovered")):
            if recovered in shades:
                handles.append(Patch(color=_SHADE[recovered], alpha=0.2, lw=0))
                names.append(label)
        figure.legend(
            handles, names, loc="outside right upper", fontsize=8, handlelength=1.6, frameon=False, borderaxespad=0.2
        )
    axes[-1].set_xlim(0, last * 1.01 + 1)
    if title:
        figure.suptitle(title, fontsize=11)
    if note:  # under the panels, where neither the closures' key (upper right) nor the closure numbers are
        figure.supxlabel(textwrap.fill(str(note), width=max(40, width // 7)), fontsize=9, color="0.25")

    image = figure_image(figure)
    if image.shape[:2] != (height, width):  # rounding of the figure size: pad or crop to the size asked for
        out = np.full((height, width, 3), 255, dtype=np.uint8)
        h, w = min(height, image.shape[0]), min(width, image.shape[1])
        out[:h, :w] = image[:h, :w]
        image = out
    return image


# ------------------------------------------------------------------------------------------------ output


def figure_image(figure: matplotlib.figure.Figure) -> np.ndarray:
    """
    Draw a Matplotlib figure (made with ``Figure``, not ``pyplot``) into an RGB array.

    :param figure: The figure
    :return: ``(H, W, 3)`` uint8 RGB image
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    canvas = figure.canvas if isinstance(figure.canvas, FigureCanvasAgg) else FigureCanvasAgg(figure)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def write_figure(path: str | Path, image: np.ndarray) -> Path:
    """
    Write an RGB figure as a PNG, atomically (the folder is created if needed).

    :param path: Where to write it
    :param image: ``(H, W, 3)`` uint8 RGB image
    :return: the path written
    :raises ValueError: if the image is not RGB uint8
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"a figure is an (H, W, 3) uint8 RGB image, got {image.dtype} of shape {image.shape}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return write_png(path, np.ascontiguousarray(image))
