"""The roads named on the ``dcqn-campusnav`` command line: the closures asked for (``--closures`` or the closure
flags), checked against the map before any training, and ``--close`` roads closed in an env. A road that is not on the
map says why (no such node, or no road between two nodes that are) and where road ids are found.

Importing this module is cheap (no torch, no CampusNav): each check imports what it needs.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

from sb3_dcqn.campusnav.errors import PROG, CommandError, note, said
from sb3_dcqn.campusnav.requests import Request

if TYPE_CHECKING:
    from campusnav_env import CampusNavEnv
    from campusnav_env.maps.refusals import Refusal
    from sb3_dcqn.campusnav.experiments import ClosurePlan

__all__ = ["ROADS_HINT", "check_plan", "close_roads", "closure_plan", "plan_source", "road_refused"]

# How to find road ids, for every message about a road
ROADS_HINT = f"'{PROG} roads NODE' lists the roads of an intersection, '{PROG} draw --node-ids' draws the ids"


def road_refused(refusal: Refusal) -> str:
    """A road the map refused (not on it, closed already, cutting a goal off), in the command line's words."""
    return f"{said(refusal)} ({ROADS_HINT})"


def close_roads(nav: CampusNavEnv, roads: Sequence[Sequence[int]], restored: Sequence[tuple[int, int]] = ()) -> None:
    """Close ``--close`` roads in an env (evaluate, draw, roads); those ``restored`` from the model are closed."""
    from campusnav_env.maps.refusals import Refusal

    already = {frozenset(road) for road in restored}
    for u, v in roads:
        if frozenset((int(u), int(v))) in already:
            note(f"note: --close {u} {v}: closed already (saved with the model)")
            continue
        try:
            nav.close_road(int(u), int(v))
        except Refusal as error:  # not on the map, closed already, cutting a goal off
            raise CommandError(f"--close {u} {v}: {road_refused(error)}") from None


def closure_plan(request: Request) -> ClosurePlan:
    """The closures asked for by ``--closures`` or by the closure flags."""
    import yaml

    from campusnav_env.closures import ClosureEvent, ClosureSchedule
    from sb3_dcqn.campusnav.experiments import ClosurePlan
    from sb3_dcqn.zoo_files import describe_yaml_error

    if request.closures is not None:
        if request.closure_flags_given or request.close_at is not None:
            raise CommandError(
                "--closures: a schedule file cannot be combined with --close, --close-random, --close-on-route or "
                "--close-at"
            )
        try:
            return ClosurePlan(scheduled=ClosureSchedule.from_yaml(request.closures))
        except yaml.YAMLError as error:
            raise CommandError(
                f"--closures: {request.closures}: not valid YAML ({describe_yaml_error(error)})"
            ) from None
        except (FileNotFoundError, ValueError, KeyError, TypeError) as error:
            raise CommandError(f"--closures: {error.args[0] if isinstance(error, KeyError) else error}") from None
    events: list[dict[str, Any]] = []
    if request.close:
        events.append({"close": list(request.close)})
    if request.close_random:
        events.append({"close_random": request.close_random, "seed": request.seed})
    events += [{"close_on_route": where} for where in request.close_on_route]
    if request.close_at is not None:
        if request.close_at < 0:
            raise CommandError(f"--close-at: expected a step >= 0, got {request.close_at}")
        if not events:
            raise CommandError("--close-at: give the roads to close (--close, --close-random or --close-on-route)")
        return ClosurePlan(
            scheduled=ClosureSchedule([ClosureEvent(at=request.close_at, unit="step", **e) for e in events])
        )
    return ClosurePlan(later=[ClosureEvent(at=0, unit="step", **e) for e in events])


def check_plan(plan: ClosurePlan, nav: CampusNavEnv, source: str, restored: Sequence[tuple[int, int]] = ()) -> None:
    """
    Check the closures against the map (with the roads closed now) before training; errors name the flag or file.

    :param restored: Roads closed again from the saved model (a closure of one of them says so)
    """
    from campusnav_env.closures import ClosureSchedule
    from campusnav_env.maps.navigation import RoadStateError
    from campusnav_env.maps.refusals import Refusal

    events = plan.scheduled.events or plan.later
    for event in events:
        for u, v in event.close:
            try:
                nav.graph.map.road_id(u, v)
            except KeyError as error:  # NoSuchRoadError
                raise CommandError(f"{source}: road {u}-{v}: {road_refused(error)}") from None
    try:
        ClosureSchedule(list(events)).validate(nav.graph, nav.goal_nodes)
    except Refusal as error:  # closed already, cutting a goal off
        restored_roads = {(min(u, v), max(u, v)) for u, v in restored}
        if isinstance(error, RoadStateError) and error.closed and error.road in restored_roads:
            why = "closed when the model was saved (--open-map: the open map)"
            raise CommandError(f"{source}: {said(error)}; {why}") from None
        raise CommandError(f"{source}: {road_refused(error)}") from None
    except (KeyError, ValueError) as error:  # a random draw that cannot be met, a bad start node
        raise CommandError(f"{source}: {error.args[0] if isinstance(error, KeyError) else error}") from None


def plan_source(request: Request) -> str:
    """The flags (or file) a run's closures come from, for messages."""
    if request.command == "demo":
        return "closures"
    if request.closures is not None:
        return f"--closures {request.closures}"
    names = [
        ("--close", request.close),
        ("--close-random", request.close_random),
        ("--close-on-route", request.close_on_route),
    ]
    return "/".join(name for name, given in names if given) or "closures"
