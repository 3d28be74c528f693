"""The ``dcqn-campusnav`` input checks: every flag, file, key and road looked at before any work.

Each check raises :class:`CommandError` with a message that names what is wrong (the flag, the file, the key or the
road) and, where there is one, the fix; the command line prints it on one line and exits with status 2. Importing this
module is cheap (no torch, no CampusNav): each check imports what it needs.
"""

from __future__ import annotations

import os
import re
import tempfile
import warnings
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_dcqn.campusnav.errors import PROG, CommandError, Interrupted, note, one_line_warning
from sb3_dcqn.campusnav.requests import Request
from sb3_dcqn.campusnav.settings import DEFAULT_ENCODER, DEFAULT_ENV, EnvSettings

if TYPE_CHECKING:
    from campusnav_env import CampusNavEnv
    from sb3_dcqn.campusnav.experiments import ClosurePlan
    from sb3_dcqn.campusnav.model_files import SavedRun
    from sb3_dcqn.zoo_entry import ZooEntry

__all__ = [
    "DEFAULT_OUT",
    "PROG",
    "CommandError",
    "Interrupted",
    "check_cache",
    "check_folder",
    "check_goal",
    "check_plan",
    "check_start",
    "close_roads",
    "closure_plan",
    "env_creator",
    "env_settings",
    "find_model",
    "free_folder",
    "free_picture",
    "holds_results",
    "moved_note",
    "note",
    "one_line_warning",
    "plan_source",
    "road_error",
]

MODEL_NAME = "dcqn_campusnav"
# Each training subcommand's own output folder, so that one never replaces another's results
DEFAULT_OUT = {"demo": "runs/campusnav-demo", "train": "runs/campusnav-train"}
PICTURE_SUFFIXES = (".png",)  # what campusnav_env.figures.write_figure writes
# How to find road ids, for every message about a road
ROADS_HINT = f"'{PROG} roads NODE' lists the roads of an intersection, '{PROG} draw --node-ids' draws the ids"
MODEL_FILES = f"give a {MODEL_NAME}.zip saved by train, demo or readapt (or by DCQN.save)"
# The files a run writes into its folder: a folder holding any of them holds an earlier run's results
RESULT_NAMES = (
    "summary.json",
    "summary.md",
    "tb",
    "routes.png",
    "curves.png",
    "checkpoints",
    f"{MODEL_NAME}.zip",
    f"{MODEL_NAME}.env.json",
    f"{MODEL_NAME}_replay_buffer.pkl",
)


# ------------------------------------------------------------------------------------------------ paths
def check_folder(folder: Path, flag: str, given: Path | None = None) -> None:
    """
    An output folder that can be made: no part of it is a file, and its nearest existing folder is writable.

    :param given: The path the flag gave, for the message (default: ``folder``; a file's path for its folder)
    """
    given = folder if given is None else given
    for part in (folder, *folder.parents):
        if part.exists() or part.is_symlink():
            if not part.is_dir():
                where = "is a file" if part == given else f"is inside {part}, a file"
                raise CommandError(f"{flag} {given}: {where}, not a folder")
            if not os.access(part, os.W_OK | os.X_OK):
                raise CommandError(f"{flag} {given}: cannot write in {part}")
            try:  # access() says yes to root everywhere, /proc included: try it
                os.rmdir(tempfile.mkdtemp(prefix=".dcqn-campusnav-", dir=part))
            except OSError as error:
                raise CommandError(f"{flag} {given}: cannot write in {part} ({error.strerror or error})") from None
            return


def holds_results(folder: Path) -> bool:
    """Whether a folder holds a run's results (any file a run writes: :data:`RESULT_NAMES`)."""
    return folder.is_dir() and any((folder / name).exists() for name in RESULT_NAMES)


def _numbered(path: Path, number: int) -> Path:
    """``runs/fixed`` -> ``runs/fixed_2``; ``map.png`` -> ``map_2.png``."""
    return path.with_name(f"{path.stem}_{number}{path.suffix}")


def _first_free(path: Path, taken: Callable[[Path], bool]) -> Path:
    """The first numbered path after ``path`` (``_2``, ``_3``, ...) that is not ``taken``."""
    number = 2
    while taken(_numbered(path, number)):
        number += 1
    return _numbered(path, number)


def free_folder(out: Path, force: bool, flag: str = "--out") -> Path:
    """
    The folder a run writes to: ``out``, or where it holds an earlier run's results the first free numbered folder
    next to it (``runs/fixed`` -> ``runs/fixed_2``, as the RL Zoo numbers its runs; :func:`moved_note` says so once
    the input is checked); ``--force`` writes into ``out`` all the same.
    """
    if force or not holds_results(out):
        check_folder(out, flag)
        return out
    out = Path(os.path.abspath(out)) if not out.name else out  # "." has no name to number
    numbered = re.fullmatch(r"(.+)_\d+", out.name)
    if numbered and out.with_name(numbered.group(1)).is_dir():  # runs/x_2 taken: runs/x_3, not runs/x_2_2
        out = out.with_name(numbered.group(1))
    free = _first_free(out, holds_results)
    check_folder(free, flag, given=free)
    return free


def moved_note(asked: Path, free: Path, flag: str = "--out") -> None:
    """Say where a run writes instead of a folder that holds an earlier run's results (:func:`free_folder`)."""
    if free != asked:
        note(f"{flag} {asked} holds an earlier run's results (kept): writing to {free} (--force: write into {asked})")


def free_picture(path: str | None, force: bool, flag: str = "--picture") -> Path | None:
    """
    A picture path that can be written (checked before anything is computed): where the picture or its route text
    (``map.png``: ``map.txt``) exists, the first free numbered name (``map_2.png``), unless ``--force``.
    """
    if path is None:
        return None
    picture = Path(path)
    if picture.is_dir():
        raise CommandError(f"{flag} {picture}: is a folder; give a file name such as {picture / 'map.png'}")
    if picture.suffix.lower() not in PICTURE_SUFFIXES:
        raise CommandError(
            f"{flag} {picture}: pictures are written as PNG; give a name ending in {', '.join(PICTURE_SUFFIXES)} "
            f"(e.g. {picture.with_suffix('.png')})"
        )
    check_folder(picture.parent, flag, given=picture)

    def taken(candidate: Path) -> bool:
        return candidate.exists() or candidate.with_suffix(".txt").exists()

    if force or not taken(picture):
        return picture
    return _first_free(picture, taken)


def check_cache() -> None:
    """The feature cache's folder (``$CAMPUSNAV_CACHE``) can be made and written, before any view is rendered."""
    from campusnav_env.features.feature_cache import default_cache_dir

    check_folder(default_cache_dir(), "$CAMPUSNAV_CACHE")


# ------------------------------------------------------------------------------------------------ envs
def env_creator(env_id: str) -> Any:
    """The class (or function) a registered CampusNav id makes; an error names the flag otherwise."""
    import gymnasium as gym
    from gymnasium.envs.registration import load_env_creator

    import campusnav_env  # noqa: F401  (registers the CampusNav ids)
    from campusnav_env import CampusNavEnv

    try:
        spec = gym.spec(env_id)
    except gym.error.Error as error:
        raise CommandError(f"--env {env_id}: {error}") from None
    creator = spec.entry_point
    if isinstance(creator, str):
        try:
            creator = load_env_creator(creator)
        except (ImportError, AttributeError) as error:
            raise CommandError(f"--env {env_id}: cannot load {spec.entry_point!r} ({error})") from None
    if isinstance(creator, type) and not issubclass(creator, CampusNavEnv):
        raise CommandError(f"--env {env_id}: not a CampusNav env ({creator.__name__})")
    return creator


def _check_env_kwargs(creator: Any, env_kwargs: dict[str, Any], source: str) -> None:
    """Every ``env_kwargs`` key is an argument of the env (else a ``TypeError`` deep inside ``gym.make``)."""
    from sb3_dcqn.zoo_entry import unknown_keyword

    problem = unknown_keyword(env_kwargs, creator) if isinstance(creator, type) else None
    if problem is not None:
        raise CommandError(f"{source}: env_kwargs: {problem}")


def env_settings(
    request: Request, saved: EnvSettings | None = None, entry: ZooEntry | None = None, creator: Any = None
) -> EnvSettings:
    """
    The env to build: the flags given, else what the model was saved with, else the defaults.

    :param creator: The env id's :func:`env_creator`, where the caller has it already
    """
    env_id = request.env or (saved.env_id if saved else DEFAULT_ENV)
    creator = env_creator(env_id) if creator is None else creator
    if entry is None and saved is not None and env_id == saved.env_id and request.conf is None:
        env_kwargs, source = saved.env_kwargs, f"{env_id} (as saved with the model)"
    else:
        if entry is None:
            from sb3_dcqn.campusnav.entries import conf_entry

            entry = conf_entry(request.conf, env_id)
        env_kwargs, source = entry.env_kwargs, f"--conf: {entry.source}"
    goals = request.goals
    if goals:
        env_kwargs = {**env_kwargs, "goals": [int(goal) if goal.isdigit() else goal for goal in goals]}
    _check_env_kwargs(creator, env_kwargs, source)
    map_path = str(Path(request.map).resolve()) if request.map else (saved.map_path if saved else None)
    map_coords = request.map_coords or (saved.map_coords if saved and not request.map else "auto")
    if request.map_coords is not None and map_path is None:
        raise CommandError("--map-coords: it says how --map's x/y are read; give --map FILE.graphml too")
    if map_path is not None:
        flag = "--map" if request.map else f"{env_id} map"
        _check_map(request.command, env_id, creator, map_path, map_coords, env_kwargs, flag, bool(goals))
    encoder = request.encoder or (saved.encoder if saved else DEFAULT_ENCODER)
    weights = request.encoder_weights
    if weights is None and saved is not None and saved.encoder == encoder:
        weights = saved.encoder_weights
    if weights is not None and not Path(weights).is_file():
        raise CommandError(f"--encoder-weights: file not found: {weights}")
    random_init = _random_init(request, saved, encoder, weights)
    size = request.render_size or (saved.render_size if saved else None)
    if size is not None and min(size) < 16:
        raise CommandError(f"--render-size: width and height must be at least 16 pixels, got {size[0]} {size[1]}")
    check_cache()
    settings = EnvSettings(env_id, dict(env_kwargs), encoder, weights, size, map_path, random_init, map_coords)
    if saved is not None and settings != saved:
        note(f"warning: the model was trained on {saved.describe()}; now {settings.describe()}")
    return settings


def _goals_fix(command: str, n_nodes: int) -> str:
    """How to name goals on one's own map, in the flags of the subcommand at hand."""
    ids = f"node ids 0..{n_nodes - 1}"
    if command in ("train", "demo"):
        return f"pass --goals with landmark names or {ids}"
    if command == "draw":
        return f"pass --goal with a landmark name or one of {ids}"
    if command == "roads":
        return "pass a node id of the map"
    return f"use a model trained on this map ('{PROG} train --map FILE --goals ...', landmark names or {ids})"


def _as_flags(message: str) -> str:
    """A map-loading message in the command line's words: ``coords='projected'`` is ``--map-coords projected``."""
    return re.sub(r"coords='(\w+)'(?: \(the env's map_coords\))?", r"--map-coords \1", message)


def _check_map(
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
    from campusnav_env.maps.extent import MapExtentError, check_map_extent
    from campusnav_env.maps.osm import CoordinatesWarning

    nx = require_networkx()
    try:
        with warnings.catch_warnings(record=True) as said:
            warnings.simplefilter("always", CoordinatesWarning)
            graph = load_map(path, coords)
        for warning in said:
            note(f"warning: {flag} {_as_flags(str(warning.message))}")
    except (ParseError, nx.NetworkXError, KeyError, ValueError, TypeError) as error:
        message = error.args[0] if isinstance(error, KeyError) and error.args else str(error)
        raise CommandError(f"{flag} {path}: not a GraphML road network ({_as_flags(message)})") from None
    try:
        check_map_extent(graph, source=path)
    except MapExtentError as error:  # a view build that could not finish: refused before it starts
        detail = str(error).split("': ", 1)[-1]  # "map '<file>': ..." names the file the flag names already
        raise CommandError(f"{flag} {path}: {_as_flags(detail)}") from None
    if "goals" in env_kwargs:
        goals = env_kwargs["goals"]
        source = f"the env_kwargs of {env_id}"
        if goals_given:
            source = "--goal" if command == "draw" else "--goals"
    else:
        import inspect

        import gymnasium as gym

        default = inspect.signature(creator).parameters.get("goals")
        goals = gym.spec(env_id).kwargs.get("goals", None if default is None else default.default)
        source = f"the default of {env_id}"
    if goals is None:  # a goal env: every intersection
        return
    landmarks = ", ".join(sorted(graph.landmarks)) or "none"
    for goal in [goals] if isinstance(goals, (str, int)) else goals:
        if isinstance(goal, str) and goal not in graph.landmarks:
            raise CommandError(
                f"{flag} {path}: goal {goal!r} ({source}) is not a landmark of the map (its named nodes: {landmarks}); "
                f"{_goals_fix(command, graph.n_nodes)}"
            )
        if not isinstance(goal, str) and not 0 <= int(goal) < graph.n_nodes:
            raise CommandError(
                f"{flag} {path}: goal node {goal} ({source}) is not on the map (node ids 0..{graph.n_nodes - 1})"
            )


def _random_init(request: Request, saved: EnvSettings | None, encoder: str, weights: str | None) -> bool:
    """Whether ResNet-50 runs on random features: only when asked for (now, or by the run that saved the model)."""
    given = request.encoder_random_init
    asked = given or bool(
        saved is not None and saved.encoder == encoder and saved.encoder_random_init and weights is None
    )
    if asked and encoder != "resnet50":
        raise CommandError(f"--encoder-random-init: only for --encoder resnet50 (the encoder is {encoder})")
    if given and weights is not None:
        raise CommandError(f"--encoder-random-init: cannot be combined with --encoder-weights {weights}")
    if encoder == "resnet50" and weights is None and not asked:
        raise CommandError(
            "--encoder resnet50: needs --encoder-weights FILE (torchvision's ImageNet resnet50-*.pth, e.g. "
            "resnet50-0676ba61.pth); --encoder-random-init runs on random, not pretrained, features instead"
        )
    return asked


def env_error(settings: EnvSettings, error: Exception) -> CommandError:
    """An env that could not be built, in the flag's words: ``--map`` where the map is one's own, else ``--env``."""
    message = str(error)
    if settings.map_path is None:
        return CommandError(f"--env {settings.env_id}: {message}")
    return CommandError(f"--map {settings.map_path}: the env cannot be built on this map ({_as_flags(message)})")


# ------------------------------------------------------------------------------------------------ roads
def road_error(error: Exception) -> str:
    """A closure's error in the command line's words: the map's own advice (``force=True``) is not a flag here."""
    message = str(error.args[0] if isinstance(error, KeyError) else error)
    if "; pass force=True" in message:
        message = message.split("; pass force=True")[0] + "; close another road instead"
    return f"{message} ({ROADS_HINT})"


def close_roads(nav: CampusNavEnv, roads: Sequence[Sequence[int]], restored: Sequence[tuple[int, int]] = ()) -> None:
    """Close ``--close`` roads in an env (evaluate, draw, roads); those ``restored`` from the model are closed."""
    already = {frozenset(road) for road in restored}
    for u, v in roads:
        if frozenset((int(u), int(v))) in already:
            note(f"note: --close {u} {v}: closed already (saved with the model)")
            continue
        try:
            nav.close_road(int(u), int(v))
        except (KeyError, ValueError) as error:  # RoadClosureError is a ValueError
            raise CommandError(f"--close {u} {v}: {road_error(error)}") from None


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


def check_plan(plan: ClosurePlan, nav: CampusNavEnv, source: str) -> None:
    """Check the closures against the map before training; errors name the flag or file."""
    from campusnav_env.closures import ClosureSchedule

    events = plan.scheduled.events or plan.later
    for event in events:
        for u, v in event.close:
            try:
                nav.graph.map.road_id(u, v)
            except KeyError as error:
                raise CommandError(f"{source}: road {u}-{v}: {road_error(error)}") from None
    try:
        ClosureSchedule(list(events)).validate(nav.graph, nav.goal_nodes)
    except (KeyError, ValueError) as error:  # RoadClosureError is a ValueError
        raise CommandError(f"{source}: {road_error(error)}") from None


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


# ------------------------------------------------------------------------------------------------ goal and start
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
    raise CommandError(f"--goal {goal!r}: not a goal of this env (goals: {choices})")


def check_start(nav: CampusNavEnv, start: int | None, goal: str) -> None:
    if start is None:
        return
    try:
        nav.graph.map.check_node(start, "start")
    except ValueError as error:
        raise CommandError(f"--start: {error}") from None
    if nav.node_distances(nav.goal_nodes[nav.goal_names.index(goal)])[start] <= 0:
        raise CommandError(f"--start {start}: the goal {goal!r} cannot be reached from it (or it is the goal)")


# ------------------------------------------------------------------------------------------------ model files
def find_model(path: str, flag: str = "") -> Path:
    """
    The model zip named on the command line: it exists and is a readable model file (``runs/x/dcqn_campusnav`` names
    ``runs/x/dcqn_campusnav.zip``, as ``DCQN.load`` reads it).
    """
    from sb3_dcqn.campusnav.model_files import model_paths

    given = Path(path)
    named = f"{flag} {path}" if flag else path
    model = given if given.is_file() else model_paths(given)[0]
    if given.is_dir():
        inside = given / f"{MODEL_NAME}.zip"
        hint = f" (it holds {inside}: give that)" if inside.is_file() else ""
        raise CommandError(f"{named}: is a folder, not a model file{hint}; {MODEL_FILES}")
    if not model.is_file():
        raise CommandError(f"model file not found: {named}")
    if model.suffix != ".zip" and not zipfile.is_zipfile(model):
        raise CommandError(f"{named}: not a model zip (a model is a .zip file written by DCQN.save); {MODEL_FILES}")
    try:
        with zipfile.ZipFile(model) as archive:
            problem = None if "data" in archive.namelist() else "no 'data' entry"
    except (zipfile.BadZipFile, OSError) as error:
        problem = str(error)
    if problem is not None:
        raise CommandError(f"{model}: not a readable model file ({problem}); {MODEL_FILES}")
    return model


def saved_run(model: Path) -> SavedRun:
    """What was saved next to a model: env settings, training envs, closures, levers (``SavedRun()`` if nothing)."""
    from sb3_dcqn.campusnav.model_files import read_saved_run

    try:
        return read_saved_run(model)
    except ValueError as error:
        raise CommandError(str(error)) from None
