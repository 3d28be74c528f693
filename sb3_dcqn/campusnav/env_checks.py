"""The env named on the ``dcqn-campusnav`` command line: a registered CampusNav id, its ``env_kwargs``, the encoder
and views, the map (:mod:`~sb3_dcqn.campusnav.map_checks`), all read from the flags, else from what a model was saved
with, else from the defaults (:func:`env_settings`); and an env that could not be built, in the flags' words
(:func:`env_error`).

Importing this module is cheap (no torch, no CampusNav): each check imports what it needs.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_dcqn.campusnav.entries import conf_entry
from sb3_dcqn.campusnav.errors import CommandError, note, said
from sb3_dcqn.campusnav.map_checks import check_map, goal_refused, goals_source
from sb3_dcqn.campusnav.output_paths import check_cache
from sb3_dcqn.campusnav.requests import Request
from sb3_dcqn.campusnav.settings import DEFAULT_ENCODER, DEFAULT_ENV, EnvSettings

if TYPE_CHECKING:
    from sb3_dcqn.zoo_entry import ZooEntry

__all__ = ["env_creator", "env_error", "env_settings"]


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
        entry = conf_entry(request.conf, env_id) if entry is None else entry
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
        check_map(request.command, env_id, creator, map_path, map_coords, env_kwargs, flag, bool(goals))
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


def env_error(settings: EnvSettings, error: Exception, request: Request) -> CommandError:
    """
    An env that could not be built, in the flags' words: a goal not on the map names the landmarks nearest it and the
    flag that gave it; otherwise ``--map`` where the map is one's own, else ``--env``.
    """
    from campusnav_env.env import GoalNodeError, UnknownGoalError
    from campusnav_env.maps.refusals import Refusal

    if isinstance(error, (UnknownGoalError, GoalNodeError)):
        source = goals_source(request.command, settings.env_id, settings.env_kwargs, bool(request.goals))
        where = "" if settings.map_path is None else f"--map {settings.map_path}: "
        return goal_refused(error, source, request.command, where)
    message = said(error) if isinstance(error, Refusal) else str(error)
    if settings.map_path is None:
        return CommandError(f"--env {settings.env_id}: {message}")
    return CommandError(f"--map {settings.map_path}: the env cannot be built on this map ({message})")
