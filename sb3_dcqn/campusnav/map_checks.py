"""The map and the places named on the ``dcqn-campusnav`` command line: a GraphML road network the env can be built
on (``--map``), goals that are on the map (``--goals``, ``--goal``: a misspelt name gets the landmarks nearest it) and a
start node that reaches the goal.

Importing this module is cheap (no torch, no CampusNav): each check imports what it needs.
"""

from __future__ import annotations

import difflib
import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_dcqn.campusnav.errors import PROG, CommandError, note, said

if TYPE_CHECKING:
    from campusnav_env import CampusNavEnv
    from campusnav_env.env import GoalNodeError, UnknownGoalError

__all__ = ["check_goal", "check_map", "check_start", "goal_refused", "goals_source"]


def goals_source(command: str, env_id: str, env_kwargs: dict[str, Any], goals_given: bool) -> str:
    """Where an env's goals come from, in words: the flag that gave them, the entry's ``env_kwargs``, or the default."""
    if goals_given:
        return "--goal" if command == "draw" else "--goals"
    return f"the env_kwargs of {env_id}" if "goals" in env_kwargs else f"the default of {env_id}"


def _goals_fix(command: str, n_nodes: int) -> str:
    """How to name goals on the map, in the flags of the subcommand at hand."""
    ids = f"node ids 0..{n_nodes - 1}"
    if command in ("train", "demo"):
        return f"pass --goals with landmark names or {ids}"
    if command == "draw":
        return f"pass --goal with a landmark name or one of {ids}"
    if command == "roads":
        return "pass a node id of the map"
    return f"use a model trained on this map ('{PROG} train --map FILE --goals ...', landmark names or {ids})"


def goal_refused(error: UnknownGoalError | GoalNodeError, source: str, command: str, where: str = "") -> CommandError:
    """
    A goal that is not on the map (the env's refusal, :func:`campusnav_env.env.resolve_goals`), in the command
    line's words: the goal and what gave it, the landmarks nearest a misspelt name, and how to name goals.

    :param source: What gave the goal (:func:`goals_source`)
    :param where: What to name first, e.g. ``"--map town.graphml: "`` (the map's own name otherwise)
    """
    from campusnav_env.env import GoalNodeError

    the_map = "the map" if where else f"the map {error.map_name!r}"
    if isinstance(error, GoalNodeError):
        return CommandError(
            f"{where}goal node {error.goal} ({source}) is not on {the_map} (node ids 0..{error.n_nodes - 1})"
        )
    nearest = f"nearest: {', '.join(error.nearest)}; " if error.nearest else ""
    return CommandError(
        f"{where}goal {error.goal!r} ({source}) is not a landmark of {the_map} ({nearest}its named nodes: "
        f"{', '.join(error.landmarks) or 'none'}); {_goals_fix(command, error.n_nodes)}"
    )


def check_map(
    command: str,
    env_id: str,
    creator: Any,
    path: str,
    coords: str,
    env_kwargs: dict[str, Any],
    flag: str,
    goals_given: bool,
) -> None:
    """
    A GraphML road network that the env can be built on (``world=``), with the env's goals on it; checked before any
    work, else the error comes from deep inside ``gym.make``.
    """
    from xml.etree.ElementTree import ParseError

    from campusnav_env.env import GoalNodeError, UnknownGoalError, resolve_goals
    from campusnav_env.maps.extent import MapExtentError, check_map_extent
    from campusnav_env.maps.osm import CoordinatesError, CoordinatesWarning
    from campusnav_env.maps.road_graph import require_networkx
    from sb3_dcqn.campusnav.settings import load_map

    if not Path(path).is_file():
        raise CommandError(f"{flag} {path}: file not found")
    generating = sorted(key for key in ("world", "n_intersections", "map_seed") if key in env_kwargs)
    if generating:
        raise CommandError(
            f"{flag} {path}: the env_kwargs of {env_id} already choose a map ({', '.join(generating)}); "
            "drop them from the --conf entry or leave out --map"
        )
    nx = require_networkx()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", CoordinatesWarning)
            graph = load_map(path, coords)
        for warning in caught:
            shown = said(warning.message) if isinstance(warning.message, CoordinatesWarning) else warning.message
            note(f"warning: {flag} {shown}")
    except CoordinatesError as error:
        raise CommandError(f"{flag} {path}: not a GraphML road network ({said(error)})") from None
    except (ParseError, nx.NetworkXError, KeyError, ValueError, TypeError) as error:
        message = error.args[0] if isinstance(error, KeyError) and error.args else str(error)
        raise CommandError(f"{flag} {path}: not a GraphML road network ({message})") from None
    try:
        check_map_extent(graph, source=path)
    except MapExtentError as error:  # a view build that could not finish: refused before it starts
        raise CommandError(said(error, where=f"{flag} {path}")) from None
    goals = env_kwargs.get("goals", _default_goals(creator, env_id))
    if goals is None:  # a goal env: every intersection
        return
    try:
        resolve_goals(graph, goals)
    except (UnknownGoalError, GoalNodeError) as error:
        source = goals_source(command, env_id, env_kwargs, goals_given)
        raise goal_refused(error, source, command, where=f"{flag} {path}: ") from None


def _default_goals(creator: Any, env_id: str) -> Any:
    """The goals an env id makes by default: its registration's, else its class's default (``None``: every node)."""
    import inspect

    import gymnasium as gym

    default = inspect.signature(creator).parameters.get("goals")
    return gym.spec(env_id).kwargs.get("goals", None if default is None else default.default)


def check_goal(nav: CampusNavEnv, goal: str | None) -> str:
    """The goal named by ``--goal`` (a goal name, or an intersection's id), else the first goal pictured."""
    from sb3_dcqn.campusnav.pictures import picture_goals

    if goal is None:
        return picture_goals(nav)[0]
    if goal in nav.goal_names:
        return goal
    if goal.isdigit() and int(goal) in nav.goal_nodes:
        return nav.goal_names[nav.goal_nodes.index(int(goal))]
    landmarks = [name for name in nav.goal_names if not name.startswith("node ")]
    choices = ", ".join(landmarks)
    if len(landmarks) < len(nav.goal_names):  # a goal env: any intersection, by its id
        choices += f"{', or' if landmarks else ''} any intersection as 'node K' or K ({len(nav.goal_names)} goals)"
    nearest = difflib.get_close_matches(goal, landmarks, n=3, cutoff=0.5)
    hint = f"nearest: {', '.join(nearest)}; " if nearest else ""
    raise CommandError(f"--goal {goal!r}: not a goal of this env ({hint}goals: {choices})")


def check_start(nav: CampusNavEnv, start: int | None, goal: str) -> None:
    """``--start``: a node of the map from which the goal can be reached."""
    if start is None:
        return
    try:
        nav.graph.map.check_node(start, "start")
    except ValueError as error:
        raise CommandError(f"--start: {error}") from None
    if nav.node_distances(nav.goal_nodes[nav.goal_names.index(goal)])[start] <= 0:
        raise CommandError(f"--start {start}: the goal {goal!r} cannot be reached from it (or it is the goal)")
