"""RL Baselines3 Zoo integration: make ``--algo dcqn`` available to the zoo's commands.

``rl_zoo3`` has no plugin hook, so :func:`register_dcqn` adds DCQN to the zoo's algorithm table, its hyperparameter
sampler and converter tables (for ``-optimize``), and the names used in ``policy_kwargs`` and replay buffer strings of
``hyperparams/dcqn.yml`` to the namespace in which the zoo evaluates them. The console script ``dcqn-zoo`` registers
and then runs one of the zoo's commands, named as in the zoo's own ``rl_zoo3`` CLI (``train`` when the first argument
is an option, as before)::

    dcqn-zoo train --algo dcqn --env CartPole-v1 -f logs/                  # -conf defaults to the shipped dcqn.yml
    dcqn-zoo --algo dcqn --env CartPole-v1 -optimize --storage dcqn.log     # train without the command word
    dcqn-zoo enjoy --algo dcqn --env CartPole-v1 -f logs/ -n 1000 --no-render
    dcqn-zoo record_video --algo dcqn --env CartPole-v1 -f logs/ -n 500 -o videos/
    dcqn-zoo plot_train -a dcqn -e CartPole-v1 -f logs/ -w 20 -o curve.png
    dcqn-zoo all_plots -a dcqn -e CartPole-v1 -f logs/ -o results --no-display
    dcqn-zoo plot_from_file -i results.pkl -o results.svg

``dcqn-zoo COMMAND -h`` shows the zoo's options of a command, ``dcqn-zoo -h`` the commands and those of ``train``.
``-o FILE`` of ``plot_train`` is this script's own (the zoo's ``plot_train`` only shows the figure): the figure is
saved to FILE with matplotlib's Agg backend. The plot commands need seaborn and scipy (in our ``zoo`` extra);
``all_plots`` reads the evaluations that ``train --eval-freq N`` writes, and ``plot_from_file`` needs two runs or more.
``enjoy`` renders in a pygame window (``--no-render`` without pygame or a display; CampusNav's ``rgb_array`` frames are
shown through gymnasium's ``HumanRendering``); ``record_video`` needs an env with ``rgb_array`` rendering (CartPole's
needs pygame) and writes MP4 files with moviepy.

Three problems of rl_zoo3 2.9 are worked around here: ``enjoy`` imports ``requests`` (for Hub downloads) without
declaring it; ``record_video`` ignores the ``env_kwargs`` saved in the run's ``config.yml`` (CampusNav's
``view_dim``), so the model's observation space would not match the env's; and ``train`` makes the evaluation envs
(``--eval-freq``, ``-optimize``'s trials) without the entry's ``env_kwargs``, which now reach them unless
``--eval-env-kwargs`` is given.

This module works with any Gymnasium env and registers none: the ``dcqn-zoo`` console script
(:mod:`sb3_dcqn.campusnav.zoo`) registers the CampusNav ids first; for other packages' envs pass the zoo's
``--gym-packages``.

Requires the ``zoo`` extra: ``pip install "sb3-dcqn[zoo]"``.
"""

from __future__ import annotations

import difflib
import importlib
import inspect
import math
import re
import runpy
import sys
import types
from collections.abc import Callable, Collection
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

from sb3_dcqn.dcqn import DCQN

ALGO_NAME = "dcqn"
# Keys of a zoo entry that configure the zoo's env and wrappers rather than the algorithm (n_envs and env_kwargs are
# kept in ZooEntry; the others are not supported outside the zoo and are dropped)
_ZOO_ONLY_KEYS = ("normalize", "env_wrapper", "frame_stack", "vec_env_wrapper")
# Keys whose string values the zoo evaluates as Python (rl_zoo3's ExperimentManager._preprocess_hyperparams)
_EVALUATED_KEYS = ("policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs")
# Arguments of a replay buffer that the algorithm passes itself (not replay_buffer_kwargs keys)
_BUFFER_ARGUMENTS = ("buffer_size", "observation_space", "action_space", "env", "device", "n_envs")


def default_hyperparams_path() -> Path:
    """Path of the ``dcqn.yml`` hyperparameter file shipped with the package."""
    return Path(str(resources.files("sb3_dcqn") / "hyperparams" / "dcqn.yml"))


def paper_hyperparams_path() -> Path:
    """Path of ``dcqn_paper.yml``: the paper's settings for CampusNav (lr 1e-4, gamma 0.95, replay buffer 412)."""
    return Path(str(resources.files("sb3_dcqn") / "hyperparams" / "dcqn_paper.yml"))


@dataclass(frozen=True)
class ZooEntry:
    """
    One env's entry of a zoo-format hyperparameter file, ready for an SB3 algorithm's constructor.

    :param n_timesteps: Training steps (``n_timesteps``)
    :param hyperparams: Algorithm keyword arguments (``policy`` included; ``policy_kwargs`` evaluated)
    :param env_kwargs: Keyword arguments for ``gym.make`` (``env_kwargs``)
    :param n_envs: Number of training envs (``n_envs``, default 1)
    :param callbacks: The entry's ``callback`` key, as the zoo reads it: ``(class path, keyword arguments)`` pairs
        (e.g. ``("campusnav_env.callbacks.StartCurriculumCallback", {"initial": 2})``), built by
        :meth:`make_callbacks`
    """

    n_timesteps: int
    hyperparams: dict[str, Any]
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    n_envs: int = 1
    callbacks: tuple[tuple[str, dict[str, Any]], ...] = ()

    def make_callbacks(self) -> list[Any]:
        """New instances of the entry's callbacks (SB3 ``BaseCallback``), one per call: a callback trains one model."""
        return [_class_by_path(path)(**kwargs) for path, kwargs in self.callbacks]


def load_zoo_entry(path: str | Path, env_id: str) -> ZooEntry:
    """
    Read one env's entry of a zoo-format hyperparameter file (as ``rl_zoo3`` reads it).

    :param path: The YAML file
    :param env_id: The env id (top-level key)
    :return: the entry; ``policy_kwargs``, ``replay_buffer_class`` and ``replay_buffer_kwargs`` strings are evaluated
        with the names the zoo sees (:func:`hyperparams_namespace`), so that ``replay_buffer_class: HerReplayBuffer``
        is SB3's class
    :raises FileNotFoundError: if the file does not exist
    :raises KeyError: if the env has no entry, or the entry no ``n_timesteps``
    :raises ValueError: if the file is not valid YAML (naming the line) or not a table of entries, if one of those
        strings cannot be evaluated or ``env_kwargs`` is not a mapping
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"hyperparameter file not found: {path}")
    try:
        with open(path) as file:
            table = yaml.safe_load(file) or {}
    except yaml.YAMLError as error:
        raise ValueError(f"{path}: not valid YAML ({describe_yaml_error(error)})") from None
    if not isinstance(table, dict):
        raise ValueError(f"{path}: not a zoo-format hyperparameter file (expected env ids mapped to their settings)")
    if env_id not in table:
        raise KeyError(f"{path}: no entry for {env_id!r} (entries: {sorted(map(str, table))})")
    if not isinstance(table[env_id], dict):
        raise ValueError(f"{path}: entry {env_id!r} is not a mapping of hyperparameters")
    entry = dict(table[env_id])
    if "n_timesteps" not in entry:
        raise KeyError(f"{path}: entry {env_id!r} has no 'n_timesteps'")
    n_timesteps = _whole_number(entry.pop("n_timesteps"), f"{path}: {env_id!r}: n_timesteps")
    n_envs = _whole_number(entry.pop("n_envs", 1), f"{path}: {env_id!r}: n_envs")
    if isinstance(entry.get("train_freq"), list):  # YAML has no tuples: the zoo reads [4, "episode"] as (4, "episode")
        entry["train_freq"] = tuple(entry["train_freq"])
    env_kwargs = entry.pop("env_kwargs", None) or {}
    if not isinstance(env_kwargs, dict):
        raise ValueError(f"{path}: {env_id!r}: env_kwargs must be a mapping, got {env_kwargs!r}")
    for key in _ZOO_ONLY_KEYS:
        entry.pop(key, None)
    callbacks = _callback_specs(entry.pop("callback", None), f"{path}: {env_id!r}")
    namespace = {"dict": dict, **hyperparams_namespace()}
    for key in _EVALUATED_KEYS:
        if isinstance(entry.get(key), str):
            try:
                entry[key] = eval(entry[key], namespace)  # the zoo's convention
            except Exception as error:
                raise ValueError(f"{path}: {env_id!r}: cannot evaluate {key} {entry[key]!r}") from error
    return ZooEntry(n_timesteps, entry, dict(env_kwargs), n_envs, callbacks)


def _whole_number(value: Any, where: str) -> int:
    """A count from YAML (``3e4`` written ``!!float 3e4`` is a float), or an error naming the key."""
    if isinstance(value, bool) or not _is_number(value) or value != int(value):
        hint = " (YAML reads 3e4 as a string: write 30000 or !!float 3e4)" if isinstance(value, str) else ""
        raise ValueError(f"{where}: expected a whole number, got {value!r}{hint}")
    return int(value)


def _callback_specs(value: Any, where: str) -> tuple[tuple[str, dict[str, Any]], ...]:
    """
    The ``callback`` key in the zoo's forms (``rl_zoo3.utils.get_callback_list``): a class path, a one-key mapping
    ``{class path: keyword arguments}``, or a list of those; every class is imported now, so a misspelt path fails
    on loading, naming the entry.
    """
    if value is None:
        return ()
    specs = []
    for item in value if isinstance(value, list) else [value]:
        if isinstance(item, str):
            path, kwargs = item, {}
        elif isinstance(item, dict) and len(item) == 1 and isinstance(next(iter(item.values())), dict | None):
            path, kwargs = next(iter(item.items()))
            kwargs = dict(kwargs or {})
        else:
            raise ValueError(f"{where}: callback {item!r} is not a class path or {{class path: keyword arguments}}")
        try:
            _class_by_path(path)
        except (ImportError, AttributeError, ValueError) as error:
            raise ValueError(f"{where}: callback {path!r} cannot be imported ({error})") from None
        specs.append((path, kwargs))
    return tuple(specs)


def _class_by_path(path: str) -> Any:
    """``"package.module.Name"`` -> the object (the zoo's ``get_class_by_name``)."""
    module_name, _, name = path.rpartition(".")
    if not module_name:
        raise ValueError(f"{path!r} is not a dotted path (module.Class)")
    return getattr(importlib.import_module(module_name), name)


def describe_yaml_error(error: yaml.YAMLError) -> str:
    """Where a YAML file fails to parse, in words: ``"line 3, column 7: mapping values are not allowed here"``."""
    mark = getattr(error, "problem_mark", None)
    problem = getattr(error, "problem", None) or str(error)
    return problem if mark is None else f"line {mark.line + 1}, column {mark.column + 1}: {problem}"


def check_hyperparams(hyperparams: dict[str, Any], algo: type, where: str) -> None:
    """
    Check an entry's keys against what the algorithm and its policy take, before anything is built (a misspelt key
    would otherwise be a ``TypeError`` from deep inside the constructor).

    :param hyperparams: ``ZooEntry.hyperparams`` (``policy`` and ``policy_kwargs`` included)
    :param algo: The algorithm class (e.g. ``DCQN``)
    :param where: What to name in the message, e.g. ``"dcqn.yml: entry 'CampusNav-v0'"``
    :raises ValueError: naming ``where``, the key and the closest known name
    """
    check_keywords(hyperparams, algo, where, f"{algo.__name__} hyperparameter", skip=("env",))
    check_values(hyperparams, algo, where)
    policy = hyperparams.get("policy")
    aliases = getattr(algo, "policy_aliases", {})
    if isinstance(policy, str) and policy not in aliases:
        raise ValueError(f"{where}: unknown policy {policy!r} (policies: {', '.join(aliases)})")
    policy_class = aliases.get(policy, policy) if isinstance(policy, str) else policy
    policy_kwargs = hyperparams.get("policy_kwargs")
    if isinstance(policy_class, type) and isinstance(policy_kwargs, dict):
        skip = ("observation_space", "action_space", "lr_schedule")
        check_keywords(policy_kwargs, policy_class, where, "policy_kwargs key", skip=skip)
    _check_replay_buffer(hyperparams, algo, where)


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _number_hint(value: Any) -> str:
    """Why a value is not a number, in YAML's words: PyYAML reads ``1e-3`` (no dot) as a string."""
    if isinstance(value, str):
        try:
            number = float(value)
        except ValueError:
            return ""
        return f" (YAML reads {value} as a string: write {number!r} or !!float {value})"
    if isinstance(value, bool):
        return " (a boolean)"
    return ""


def _positive_int(value: Any) -> str | None:
    if _is_int(value) and value >= 1:
        return None
    if isinstance(value, float) and value.is_integer() and value >= 1:
        return f"expected a positive integer, got {value!r} (write {int(value)})"
    return f"expected a positive integer, got {value!r}{_number_hint(value)}"


def _non_negative_int(value: Any) -> str | None:
    if _is_int(value) and value >= 0:
        return None
    return f"expected an integer >= 0, got {value!r}{_number_hint(value)}"


def _fraction(value: Any) -> str | None:
    if _is_number(value) and 0 <= value <= 1:
        return None
    return f"expected a number in [0, 1], got {value!r}{_number_hint(value)}"


def _positive_number(value: Any) -> str | None:
    if _is_number(value) and value > 0:
        return None
    return f"expected a positive number, got {value!r}{_number_hint(value)}"


def _learning_rate(value: Any) -> str | None:
    if callable(value) or (_is_number(value) and value > 0):
        return None
    return f"expected a positive number or a schedule (a callable of the remaining progress), got {value!r}" + (
        _number_hint(value)
    )


def _gradient_steps(value: Any) -> str | None:
    if _is_int(value) and (value >= 1 or value == -1):
        return None
    return f"expected a positive integer, or -1 (as many as env steps), got {value!r}{_number_hint(value)}"


_TRAIN_FREQ_UNITS = ("step", "episode")


def _train_freq(value: Any) -> str | None:
    if _is_int(value) and value >= 1:
        return None
    if isinstance(value, tuple) and len(value) == 2:
        frequency, unit = value
        if not (_is_int(frequency) and frequency >= 1):
            return f"expected a positive frequency, got {frequency!r} in {value!r}"
        if unit not in _TRAIN_FREQ_UNITS:
            close = difflib.get_close_matches(str(unit), _TRAIN_FREQ_UNITS, n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            return f"unknown unit {unit!r} in {value!r} (units: {', '.join(_TRAIN_FREQ_UNITS)}{hint})"
        return None
    return f"expected a positive integer or a (frequency, unit) tuple, got {value!r}{_number_hint(value)}"


_DEVICES = ("auto", "cpu", "cuda", "mps")


def _device(value: Any) -> str | None:
    import torch as th

    if not isinstance(value, str):
        return None if isinstance(value, th.device) else f"expected a device name, got {value!r}"
    if value in _DEVICES or re.fullmatch(r"cuda:\d+", value):
        return None
    close = difflib.get_close_matches(value, _DEVICES, n=1)
    hint = f"; did you mean {close[0]!r}?" if close else ""
    return f"unknown device {value!r} (devices: {', '.join(_DEVICES)} or cuda:N{hint})"


def _seed(value: Any) -> str | None:
    return None if value is None or _is_int(value) else f"expected an integer or null, got {value!r}"


# What the off-policy constructors (SB3's DQN, DCQN) need of each value; booleans are checked by their defaults
_VALUE_CHECKS: dict[str, Callable[[Any], str | None]] = {
    "learning_rate": _learning_rate,
    "buffer_size": _positive_int,
    "learning_starts": _non_negative_int,
    "batch_size": _positive_int,
    "tau": _fraction,
    "gamma": _fraction,
    "train_freq": _train_freq,
    "gradient_steps": _gradient_steps,
    "n_steps": _positive_int,
    "target_update_interval": _positive_int,
    "exploration_fraction": _fraction,
    "exploration_initial_eps": _fraction,
    "exploration_final_eps": _fraction,
    "max_grad_norm": _positive_number,
    "stats_window_size": _positive_int,
    "verbose": _non_negative_int,
    "seed": _seed,
    "device": _device,
}
_BOOLEAN_WORDS = {"true": True, "yes": True, "on": True, "false": False, "no": False, "off": False}


def check_values(hyperparams: dict[str, Any], algo: type, where: str) -> None:
    """
    Check an entry's values against what the algorithm's constructor needs, before anything is built (a bad value
    would otherwise be an ``AssertionError`` from SB3, or fail only once training reaches it: ``batch_size: -64``
    after ``learning_starts`` steps).

    Checked: the ranges and types of SB3's off-policy hyperparameters (``learning_rate`` a positive number or a
    schedule, ``buffer_size`` and ``batch_size`` positive integers, ``gamma`` and ``tau`` in [0, 1], ``train_freq`` an
    integer or a ``(frequency, "step" | "episode")`` tuple, ...) and every argument of ``algo`` whose default is a
    boolean.

    :param hyperparams: ``ZooEntry.hyperparams``
    :param algo: The algorithm class (its arguments with boolean defaults must be booleans)
    :param where: What to name in the message, e.g. ``"dcqn.yml: entry 'CampusNav-v0'"``
    :raises ValueError: naming ``where``, the key, the value and what it should be (with "did you mean" for a string
        close to a valid one)
    """
    booleans = {
        name
        for name, parameter in inspect.signature(algo.__init__).parameters.items()
        if isinstance(parameter.default, bool)
    }
    for key, value in hyperparams.items():
        problem = None
        if key in _VALUE_CHECKS:
            problem = _VALUE_CHECKS[key](value)
        elif key in booleans and not isinstance(value, bool):
            word = _BOOLEAN_WORDS.get(str(value).lower()) if isinstance(value, str) else None
            hint = f" (write {str(word).lower()}, without quotes)" if word is not None else ""
            problem = f"expected true or false, got {value!r}{hint}"
        if problem is not None:
            raise ValueError(f"{where}: {key}: {problem}")


def _check_replay_buffer(hyperparams: dict[str, Any], algo: type, where: str) -> None:
    """
    ``replay_buffer_class`` is a replay buffer class, ``replay_buffer_kwargs`` are arguments of the one built, and
    (for DCQN) its variants combine with ``n_steps`` and ``blocked_action_target``.
    """
    from stable_baselines3.common.buffers import ReplayBuffer

    from sb3_dcqn.replay.combine import resolve_replay_buffer

    buffer_class = hyperparams.get("replay_buffer_class")
    if buffer_class is not None and not (isinstance(buffer_class, type) and issubclass(buffer_class, ReplayBuffer)):
        names = ", ".join(name for name, value in hyperparams_namespace().items() if _is_buffer_class(value))
        raise ValueError(f"{where}: replay_buffer_class {buffer_class!r} is not a replay buffer class (known: {names})")
    buffer_kwargs = hyperparams.get("replay_buffer_kwargs")
    if buffer_kwargs is not None and not isinstance(buffer_kwargs, dict):
        raise ValueError(f"{where}: replay_buffer_kwargs must be a mapping, got {buffer_kwargs!r}")
    if buffer_class is None or not issubclass(algo, DCQN):
        if buffer_class is not None and buffer_kwargs:
            check_keywords(buffer_kwargs, buffer_class, where, "replay_buffer_kwargs key", skip=_BUFFER_ARGUMENTS)
        return  # without a class, the algorithm picks one from the observation space: its arguments are unknown here
    try:  # what DCQN builds (Dict or Box observations alike for a given class)
        built, _ = resolve_replay_buffer(
            buffer_class,
            buffer_kwargs or {},
            is_dict=True,
            n_steps=int(hyperparams.get("n_steps", 1)),
            gamma=float(hyperparams.get("gamma", 0.99)),
            blocked_action_target=bool(hyperparams.get("blocked_action_target", False)),
        )
    except ValueError as error:
        raise ValueError(f"{where}: {error}") from None
    if buffer_kwargs and built is not None:
        check_keywords(buffer_kwargs, built, where, "replay_buffer_kwargs key", skip=_BUFFER_ARGUMENTS)


def _is_buffer_class(value: Any) -> bool:
    from stable_baselines3.common.buffers import ReplayBuffer

    return isinstance(value, type) and issubclass(value, ReplayBuffer)


def check_keywords(given: dict[str, Any], cls: type, where: str, what: str, skip: tuple[str, ...] = ()) -> None:
    """
    Check that every key of ``given`` is a keyword argument of ``cls(...)`` (following ``**kwargs`` up its base
    classes; a class that takes any keyword passes).

    :param given: The keyword arguments
    :param cls: The class they are for
    :param where: What to name in the message
    :param what: What a key is, in words (``"DCQN hyperparameter"``)
    :param skip: Arguments that may not be given this way
    :raises ValueError: naming ``where``, the key and the closest known name
    """
    known = _keywords(cls)
    if known is None:
        return
    known -= {"self", *skip}
    for key in given:
        if key not in known:
            close = difflib.get_close_matches(str(key), sorted(known), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ValueError(f"{where}: unknown {what} {key!r}{hint}")


def _keywords(cls: type) -> set[str] | None:
    """The keyword arguments ``cls(...)`` takes, following ``**kwargs`` up the base classes (``None``: any)."""
    names: set[str] = set()
    for klass in cls.__mro__:
        if "__init__" not in vars(klass):
            continue
        parameters = inspect.signature(vars(klass)["__init__"]).parameters.values()
        names |= {p.name for p in parameters if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        if not any(p.kind is p.VAR_KEYWORD for p in parameters):
            return names
    return None


def _import_zoo() -> Any:
    try:
        import rl_zoo3  # noqa: F401
        from rl_zoo3 import exp_manager, hyperparams_opt, utils
    except ImportError as error:
        raise ImportError(
            'The RL Zoo integration needs rl_zoo3: install it with `pip install "sb3-dcqn[zoo]"`'
        ) from error
    return exp_manager, hyperparams_opt, utils


def sample_dcqn_params(trial: Any, n_actions: int, n_envs: int, additional_args: dict) -> dict[str, Any]:
    """
    Optuna sampler for DCQN: the zoo's DQN search space (DCQN has the same hyperparameters).

    :param trial: Optuna trial
    :param n_actions: Number of actions of the env
    :param n_envs: Number of envs
    :param additional_args: The zoo's extra sampler arguments
    :return: DCQN keyword arguments
    """
    _, hyperparams_opt, _ = _import_zoo()
    return hyperparams_opt.sample_dqn_params(trial, n_actions, n_envs, additional_args)


def hyperparams_namespace() -> dict[str, Any]:
    """
    Names that ``policy_kwargs``, ``replay_buffer_class`` and ``replay_buffer_kwargs`` strings in ``dcqn.yml`` may
    use (the zoo evaluates those strings): the fusion extractor, ``nn``, SB3's ``HerReplayBuffer`` and DCQN's replay
    buffers (its bases and every combination of variants, by class name: ``LeanNStepDictReplayBuffer``).
    """
    from torch import nn

    from sb3_dcqn import replay
    from sb3_dcqn.fusion import EmbeddingFusionExtractor

    return {
        "EmbeddingFusionExtractor": EmbeddingFusionExtractor,
        "nn": nn,
        "HerReplayBuffer": HerReplayBuffer,
        **{cls.__name__: cls for cls in replay.all_replay_buffer_classes()},
    }


# The former name (the namespace once served policy_kwargs alone)
policy_kwargs_namespace = hyperparams_namespace


def register_dcqn() -> None:
    """Add DCQN to the RL Zoo's algorithm, sampler and converter tables (idempotent)."""
    exp_manager, hyperparams_opt, utils = _import_zoo()
    # The zoo's modules import these dicts by name: mutating them in place reaches every user
    utils.ALGOS[ALGO_NAME] = DCQN
    hyperparams_opt.HYPERPARAMS_SAMPLER[ALGO_NAME] = sample_dcqn_params
    hyperparams_opt.HYPERPARAMS_CONVERTER[ALGO_NAME] = hyperparams_opt.convert_offpolicy_params
    # The experiment manager eval()s policy_kwargs and replay buffer strings in its own module globals
    vars(exp_manager).update(hyperparams_namespace())


# The zoo's commands, named as in rl_zoo3/cli.py (which lacks record_video: the zoo runs it as a module)
COMMANDS: dict[str, str] = {
    "train": "train (or -optimize) an agent; the default when the first argument is an option",
    "enjoy": "run a trained agent and print its episode rewards (rl_zoo3.enjoy)",
    "record_video": "record a video of a trained agent (rl_zoo3.record_video)",
    "plot_train": "plot the training episode rewards from the monitor logs (rl_zoo3.plots.plot_train; -o FILE saves)",
    "plot_from_file": "plot results post-processed by all_plots (rl_zoo3.plots.plot_from_file)",
    "all_plots": "plot the evaluations of runs and tabulate them (rl_zoo3.plots.all_plots)",
}
_HELP_FLAGS = ("-h", "--help")
# The zoo's commands that take --env and --num-threads
_THREADED_COMMANDS = ("train", "enjoy")
_PLOT_OUTPUT_FLAGS = ("-o", "--output")


def usage() -> str:
    """The overview of ``dcqn-zoo``'s commands (printed by ``dcqn-zoo -h`` and on an unknown command)."""
    width = max(map(len, COMMANDS))
    lines = [
        "usage: dcqn-zoo [COMMAND] [OPTIONS ...]",
        "",
        "Runs a command of the RL Baselines3 Zoo with DCQN registered (--algo dcqn).",
        "",
        "commands:",
        *(f"  {name:<{width}}  {text}" for name, text in COMMANDS.items()),
        "",
        "'dcqn-zoo COMMAND -h' shows the options of a command.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None, single_thread_envs: Collection[str] = ()) -> None:
    """
    Entry point of ``dcqn-zoo``: registers DCQN, then runs the zoo command named by the first argument.

    Without a command word (first argument an option) the command is ``train``, whose ``-conf`` defaults to the
    shipped ``dcqn.yml``. ``train`` gives the evaluation envs (``--eval-freq``, and the trials of ``-optimize``) the
    entry's ``env_kwargs`` unless ``--eval-env-kwargs`` is given (see :func:`_evaluate_with_the_entrys_env_kwargs`).

    :param argv: The arguments (default: ``sys.argv[1:]``)
    :param single_thread_envs: Env ids for which ``train`` and ``enjoy`` use one torch thread (``--num-threads 1``)
        unless the arguments give ``--num-threads``: envs whose small networks run slower on more threads
    :raises SystemExit: with code 2 on a missing or unknown command, and as the zoo's commands exit (``-h``, errors)
    """
    args = list(sys.argv[1:] if argv is None else argv)
    if not args:
        print(usage(), file=sys.stderr)
        raise SystemExit(2)
    if args[0].startswith("-"):
        command, prog = "train", "dcqn-zoo"
        if any(arg in _HELP_FLAGS for arg in args):
            print(usage(), end="\n\n", flush=True)  # then the zoo's train help
    else:
        command, args, prog = args[0], args[1:], f"dcqn-zoo {args[0]}"
        if command not in COMMANDS:
            print(usage(), file=sys.stderr)
            print(
                f"\ndcqn-zoo: error: unknown command {command!r} (choose from {', '.join(COMMANDS)})", file=sys.stderr
            )
            raise SystemExit(2)
    register_dcqn()
    runner, args = _prepare(command, _with_default_threads(command, args, single_thread_envs))
    saved_argv = sys.argv
    sys.argv = [prog, *args]  # argparse takes its usage line's program name from sys.argv[0]
    try:
        runner()
    finally:
        sys.argv = saved_argv


def _with_default_threads(command: str, args: list[str], single_thread_envs: Collection[str]) -> list[str]:
    """``args`` with ``--num-threads 1`` added for an env of ``single_thread_envs`` (none given, command takes it)."""
    env_id = (_option_value(args, "--env") or "").rpartition(":")[2]  # "module:EnvId" names EnvId too
    wanted = command in _THREADED_COMMANDS and env_id in single_thread_envs
    if wanted and not _gives_option(args, "--num-threads", shortest="--nu"):
        return [*args, "--num-threads", "1"]
    return args


def _prepare(command: str, args: list[str]) -> tuple[Callable[[], None], list[str]]:
    """The function that runs ``command`` (it parses ``sys.argv``) and the arguments to give it."""
    if command == "train":
        from rl_zoo3.train import train

        if not _has_conf_option(args):
            args = [*args, "-conf", str(default_hyperparams_path())]
        return (lambda: _evaluate_with_the_entrys_env_kwargs(train)), args
    if command == "enjoy":
        _allow_enjoy_without_requests()
        from rl_zoo3.enjoy import enjoy

        return enjoy, args
    if command == "record_video":
        return _record_video, args
    if command == "plot_train":
        output, args = _pop_plot_output(args)
        if output is not None:
            import matplotlib

            matplotlib.use("Agg")  # no window: the figure goes to the file
        return (lambda: _plot_train(_import_plots().plot_train, output)), args
    return getattr(_import_plots(), command), args


def _has_conf_option(args: list[str]) -> bool:
    """Whether the train arguments give ``-conf``/``--conf-file`` (``=value`` and argparse's prefixes included)."""
    return _gives_option(args, "--conf-file", shortest="--conf", alias="-conf")


def _gives_option(args: list[str], name: str, shortest: str, alias: str | None = None) -> bool:
    """
    Whether ``args`` give the option ``name`` (``--name value`` or ``--name=value``), as argparse reads them.

    :param args: The command's arguments
    :param name: The option's long name
    :param shortest: Its shortest prefix that argparse takes for it (no other option of the command starts so)
    :param alias: Its short name, if any
    """
    for arg in args:
        given = arg.split("=", 1)[0]
        if given == alias or (given.startswith(shortest) and name.startswith(given)):
            return True
    return False


def _option_value(args: list[str], name: str) -> str | None:
    """The value given to option ``name`` (``--name value`` or ``--name=value``; the last one wins), else None."""
    value = None
    for i, arg in enumerate(args):
        if arg == name and i + 1 < len(args):
            value = args[i + 1]
        elif arg.startswith(f"{name}="):
            value = arg.split("=", 1)[1]
    return value


def _evaluate_with_the_entrys_env_kwargs(train: Callable[[], None]) -> None:
    """
    Run the zoo's ``train`` with evaluation envs made with the training env's ``env_kwargs`` (the entry's, or
    ``--env-kwargs``, which replace them) unless ``--eval-env-kwargs`` is given.

    rl_zoo3 2.9's ``ExperimentManager`` copies only ``--env-kwargs`` to the evaluation envs: the ``env_kwargs`` of the
    hyperparameter file's entry (CampusNav's ``view_dim: 64``) reach the training env alone, so the eval env of
    ``--eval-freq`` and of every ``-optimize`` trial had another observation space than the model and evaluation failed.
    """
    from rl_zoo3.exp_manager import ExperimentManager

    preprocess = ExperimentManager._preprocess_hyperparams

    def preprocess_and_share_env_kwargs(self: Any, hyperparams: dict[str, Any]) -> Any:
        processed = preprocess(self, hyperparams)  # sets self.env_kwargs from the entry or the command line
        if self._eval_env_kwargs_args is None:  # no --eval-env-kwargs
            self.eval_env_kwargs = self.env_kwargs
        return processed

    ExperimentManager._preprocess_hyperparams = preprocess_and_share_env_kwargs  # train.py makes its own manager
    try:
        train()
    finally:
        ExperimentManager._preprocess_hyperparams = preprocess


def _download_needs_requests(*args: Any, **kwargs: Any) -> None:
    raise ModuleNotFoundError(
        "Downloading a pretrained agent from the Hugging Face Hub needs `requests` (pip install requests), "
        "which rl_zoo3 imports without declaring it; pass -f with the folder of your trained agents",
        name="requests",
    )


def _allow_enjoy_without_requests() -> None:
    """
    Let ``rl_zoo3.enjoy`` be imported where ``requests`` is not installed.

    ``rl_zoo3.enjoy`` (2.9) imports ``rl_zoo3.load_from_hub``, which imports ``requests``: not a dependency of rl_zoo3,
    and no longer brought in by ``huggingface_hub`` (which moved to httpx), so ``enjoy`` fails at import. Then a
    stand-in module takes its place whose ``download_from_hub`` explains: enjoy only calls it to fetch a pretrained
    agent missing from ``rl-trained-agents/``, never for the agents trained here.
    """
    try:
        import rl_zoo3.load_from_hub  # noqa: F401
    except ModuleNotFoundError as error:
        if error.name != "requests":
            raise
        stand_in = types.ModuleType("rl_zoo3.load_from_hub", "Stand-in without requests (see sb3_dcqn.zoo)")
        stand_in.download_from_hub = _download_needs_requests  # type: ignore[attr-defined]
        sys.modules["rl_zoo3.load_from_hub"] = stand_in


def _record_video() -> None:
    """Run ``rl_zoo3.record_video`` (a script: its code is under ``if __name__ == "__main__"``)."""
    from rl_zoo3 import utils

    create_test_env = utils.create_test_env

    def create_with_saved_env_kwargs(*args: Any, hyperparams: dict[str, Any], **kwargs: Any) -> Any:
        # rl_zoo3.record_video (2.9) ignores the env_kwargs saved in config.yml, which enjoy applies: an env trained
        # with env_kwargs from the hyperparameter file (CampusNav's view_dim) would be made with the default
        # observation space, and loading the model would fail. The command line's (and args.yml's) still win.
        saved = hyperparams.pop("env_kwargs", None) or {}
        kwargs["env_kwargs"] = {**saved, **(kwargs.get("env_kwargs") or {})}
        return create_test_env(*args, hyperparams=hyperparams, **kwargs)

    utils.create_test_env = create_with_saved_env_kwargs  # record_video imports it by name when it runs
    try:
        runpy.run_module("rl_zoo3.record_video", run_name="__main__")
    finally:
        utils.create_test_env = create_test_env


def _pop_plot_output(args: list[str]) -> tuple[str | None, list[str]]:
    """Split ``-o FILE``/``--output FILE``/``--output=FILE`` (this script's option of ``plot_train``) from ``args``."""
    output, rest = None, []
    items = iter(args)
    for arg in items:
        if arg in _PLOT_OUTPUT_FLAGS:
            output = next(items, None)
            if output is None:
                raise SystemExit(f"dcqn-zoo plot_train: error: {arg} needs a file name")
        elif arg.startswith("--output="):
            output = arg.split("=", 1)[1]
        else:
            rest.append(arg)
    return output, rest


def _import_plots() -> types.ModuleType:
    """``rl_zoo3.plots``, or an error naming the packages of the zoo's ``plots`` extra that it imports."""
    try:
        from rl_zoo3 import plots
    except ModuleNotFoundError as error:
        # rl_zoo3.plots imports all three plot scripts, so each command needs seaborn and scipy
        raise SystemExit(
            f"dcqn-zoo: the plot commands need the packages of the zoo's plots extra, {error.name!r} is missing: "
            "pip install seaborn scipy (and rliable for plot_from_file -r)"
        ) from error
    return plots


def _plot_train(plot_train: Callable[[], None], output: str | None) -> None:
    """Run the zoo's ``plot_train``; with ``output``, save the figure there instead of showing it."""
    if output is None:
        plot_train()
        return
    from matplotlib import pyplot as plt

    show = plt.show
    plt.show = lambda *args, **kwargs: plt.savefig(output)  # plot_train ends with plt.show()
    try:
        plot_train()
    finally:
        plt.show = show
    print(f"Saved the figure to {output}")


if __name__ == "__main__":
    main()
