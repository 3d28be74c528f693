"""The RL Zoo's hyperparameter files: read an env's entry as ``rl_zoo3`` reads it; check it before anything is built.

A zoo-format YAML file maps env ids to settings. :func:`load_zoo_entry` does what rl_zoo3 2.9's
``ExperimentManager.read_hyperparameters`` and ``_preprocess_hyperparams`` do with an entry (``-params`` overrides
first, then schedules, ``train_freq``, ``normalize``, the evaluated strings, ``monitor_kwargs``, ``env_kwargs``,
``n_envs``, ``n_timesteps``, ``frame_stack``, a custom ``policy``, ``env_wrapper``, ``vec_env_wrapper`` and
``callback``), so that ``dcqn-campusnav`` and ``dcqn-zoo`` read one file the same way: ``learning_rate: lin_0.001``
is a linear schedule from 0.001 to 0 under both. Two differences, both refusals where the zoo fails later or guesses:
a count must be a whole number, and a schedule string is ``lin_<initial value>`` (the zoo reads any ``word_<number>``
as linear; :func:`check_values` refuses other strings). Constant numbers stay numbers (SB3 makes them constant
schedules, as the zoo does).

:func:`check_hyperparams` checks an entry's keys and values against the algorithm, its policy and its replay buffer,
naming the file, the entry and the key, where the constructor would raise a ``TypeError`` from deep inside SB3.

Reads YAML with PyYAML; otherwise needs SB3 alone, like the algorithm modules.
"""

from __future__ import annotations

import difflib
import importlib
import inspect
import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

from sb3_dcqn.dcqn import DCQN

# Keys whose string values are schedules (rl_zoo3's ExperimentManager._preprocess_schedules)
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf", "delta_std")
SCHEDULE_PREFIX = "lin_"
# Keys whose string values the zoo evaluates as Python (rl_zoo3's ExperimentManager._preprocess_hyperparams)
_EVALUATED_KEYS = ("policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs")
# Keys that configure the zoo's env and its wrappers, not the algorithm (ZooEntry.zoo_only_settings)
_ZOO_ONLY_KEYS = ("normalize", "frame_stack", "env_wrapper", "vec_env_wrapper", "monitor_kwargs")
# Arguments of a replay buffer that the algorithm passes itself (not replay_buffer_kwargs keys)
_BUFFER_ARGUMENTS = ("buffer_size", "observation_space", "action_space", "env", "device", "n_envs")

# A class named by its dotted path, with its keyword arguments: the zoo's form of callback and env_wrapper items
ClassSpec = tuple[str, dict[str, Any]]


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
    :param hyperparams: Algorithm keyword arguments (``policy`` included; schedules built, ``policy_kwargs`` and the
        replay buffer strings evaluated)
    :param env_kwargs: Keyword arguments for ``gym.make`` (``env_kwargs``)
    :param n_envs: Number of training envs (``n_envs``, default 1)
    :param callbacks: The entry's ``callback`` key, as the zoo reads it: ``(class path, keyword arguments)`` pairs
        (e.g. ``("campusnav_env.callbacks.StartCurriculumCallback", {"initial": 2})``), built by
        :meth:`make_callbacks`
    :param normalize: ``VecNormalize``'s keyword arguments when the entry normalizes (``normalize: true``, a mapping
        or a ``dict(...)`` string; ``gamma`` the entry's), else ``None``
    :param frame_stack: Frames stacked by ``VecFrameStack`` (``frame_stack``), else ``None``
    :param env_wrappers: The ``env_wrapper`` key as ``(class path, keyword arguments)`` pairs, applied by
        :meth:`wrap_env`
    :param vec_env_wrappers: The ``vec_env_wrapper`` key, in the same form
    :param monitor_kwargs: Keyword arguments of the zoo's ``Monitor`` (``monitor_kwargs``)
    :param source: What messages name the entry by, e.g. ``"dcqn.yml: entry 'CartPole-v1'"``
    """

    n_timesteps: int
    hyperparams: dict[str, Any]
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    n_envs: int = 1
    callbacks: tuple[ClassSpec, ...] = ()
    normalize: dict[str, Any] | None = None
    frame_stack: int | None = None
    env_wrappers: tuple[ClassSpec, ...] = ()
    vec_env_wrappers: tuple[ClassSpec, ...] = ()
    monitor_kwargs: dict[str, Any] = field(default_factory=dict)
    source: str = ""

    def make_callbacks(self) -> list[Any]:
        """New instances of the entry's callbacks (SB3 ``BaseCallback``), one per call: a callback trains one model."""
        return [_class_by_path(path)(**kwargs) for path, kwargs in self.callbacks]

    def wrap_env(self, env: Any) -> Any:
        """``env`` inside the entry's ``env_wrapper`` classes, first one innermost (the zoo's ``get_wrapper_class``)."""
        for path, kwargs in self.env_wrappers:
            env = _class_by_path(path)(env, **kwargs)
        return env

    @property
    def zoo_only_settings(self) -> tuple[str, ...]:
        """The keys the entry sets that only the zoo's env building applies (``normalize``, ``frame_stack``, ...)."""
        given = {
            "normalize": self.normalize is not None,
            "frame_stack": self.frame_stack is not None,
            "env_wrapper": bool(self.env_wrappers),
            "vec_env_wrapper": bool(self.vec_env_wrappers),
            "monitor_kwargs": bool(self.monitor_kwargs),
        }
        return tuple(key for key in _ZOO_ONLY_KEYS if given[key])


def read_zoo_table(path: str | Path) -> dict[Any, Any]:
    """
    The table of a zoo-format hyperparameter file (env ids mapped to their settings).

    :raises FileNotFoundError: if the file does not exist
    :raises ValueError: if it is not valid YAML (naming the line) or not a table of entries
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
    return table


def load_zoo_entry(
    path: str | Path,
    env_id: str,
    overrides: Mapping[str, Any] | None = None,
    fallbacks: Sequence[str] = ("default",),
) -> ZooEntry:
    """
    Read one env's entry of a zoo-format hyperparameter file, as ``rl_zoo3`` reads it.

    :param path: The YAML file
    :param env_id: The env id (top-level key)
    :param overrides: Settings that replace the entry's before it is read (the zoo's ``-params key:value``)
    :param fallbacks: Entries used, in order, when the file has none for ``env_id`` (the zoo's ``default``; it tries
        ``atari`` first for Atari envs)
    :return: the entry; ``policy_kwargs``, ``replay_buffer_class`` and ``replay_buffer_kwargs`` strings are evaluated
        with the names the zoo sees (:func:`hyperparams_namespace`), so that ``replay_buffer_class: HerReplayBuffer``
        is SB3's class; ``lin_<value>`` schedules are SB3 ``LinearSchedule`` s from the value to 0
    :raises FileNotFoundError: if the file does not exist
    :raises KeyError: if the env has no entry, or the entry no ``n_timesteps`` (which the zoo needs, ``-n`` or not)
    :raises ValueError: naming the file, the entry and the key: not valid YAML, not a table, a count that is not a
        whole number, a bad schedule string, a string that cannot be evaluated, a class path that cannot be imported
    """
    path = Path(path)
    table = read_zoo_table(path)
    name = next((key for key in (env_id, *fallbacks) if key in table), None)
    if name is None:
        raise KeyError(f"{path}: no entry for {env_id!r} (entries: {sorted(map(str, table))})")
    if not isinstance(table[name], dict):
        raise ValueError(f"{path}: entry {name!r} is not a mapping of hyperparameters")
    where = f"{path}: entry {name!r}" + (f" with -params {', '.join(map(str, overrides))}" if overrides else "")
    return preprocess_entry({**table[name], **(overrides or {})}, where)


def preprocess_entry(settings: Mapping[str, Any], where: str) -> ZooEntry:
    """
    One entry's settings as rl_zoo3's ``ExperimentManager._preprocess_hyperparams`` turns them into the algorithm's
    arguments and the zoo's env settings (see :func:`load_zoo_entry`).

    :param settings: The entry, overrides applied
    :param where: What to name in messages, e.g. ``"dcqn.yml: entry 'CartPole-v1'"``
    """
    entry = dict(settings)
    if "n_timesteps" not in entry:
        raise KeyError(f"{where}: no 'n_timesteps' (the zoo needs it, -n or not)")
    n_envs = _whole_number(entry.pop("n_envs", 1), f"{where}: n_envs")
    entry = preprocess_hyperparams(entry, where)
    n_timesteps = _whole_number(entry.pop("n_timesteps"), f"{where}: n_timesteps")
    normalize = _normalize_kwargs(entry, where)
    namespace = {"dict": dict, **hyperparams_namespace()}
    monitor_kwargs = _evaluated(entry.pop("monitor_kwargs", None) or {}, namespace, f"{where}: monitor_kwargs")
    env_kwargs = entry.pop("env_kwargs", None) or {}
    for key, value in (("env_kwargs", env_kwargs), ("monitor_kwargs", monitor_kwargs)):
        if not isinstance(value, dict):
            raise ValueError(f"{where}: {key} must be a mapping, got {value!r}")
    frame_stack = entry.pop("frame_stack", None)
    if frame_stack is not None:
        frame_stack = _whole_number(frame_stack, f"{where}: frame_stack")
    if isinstance(entry.get("policy"), str) and "." in entry["policy"]:  # a custom policy, by its class path
        entry["policy"] = _imported(entry["policy"], f"{where}: policy")
    return ZooEntry(
        n_timesteps,
        entry,
        dict(env_kwargs),
        n_envs,
        callbacks=_class_specs(entry.pop("callback", None), f"{where}: callback"),
        normalize=normalize,
        frame_stack=frame_stack,
        env_wrappers=_class_specs(entry.pop("env_wrapper", None), f"{where}: env_wrapper"),
        vec_env_wrappers=_class_specs(entry.pop("vec_env_wrapper", None), f"{where}: vec_env_wrapper"),
        monitor_kwargs=dict(monitor_kwargs),
        source=where,
    )


def preprocess_hyperparams(settings: Mapping[str, Any], where: str) -> dict[str, Any]:
    """
    The algorithm's arguments among ``settings`` as the zoo turns them into values: ``lin_<value>`` schedules, a
    ``train_freq`` list as a tuple, ``policy_kwargs`` and replay-buffer strings evaluated (both command lines'
    ``-params`` go through here too).

    :raises ValueError: naming ``where`` and the key, for a bad schedule or a string that cannot be evaluated
    """
    entry = dict(settings)
    for key in SCHEDULE_KEYS:  # other strings are left to check_values, which names them with a hint
        if isinstance(entry.get(key), str) and entry[key].startswith(SCHEDULE_PREFIX):
            entry[key] = linear_schedule(entry[key], f"{where}: {key}")
    if isinstance(entry.get("train_freq"), list):  # YAML has no tuples: the zoo reads [4, "episode"] as (4, "episode")
        entry["train_freq"] = tuple(entry["train_freq"])
    namespace = {"dict": dict, **hyperparams_namespace()}
    for key in _EVALUATED_KEYS:
        if isinstance(entry.get(key), str):
            entry[key] = _evaluated(entry[key], namespace, f"{where}: {key}")
    return entry


def linear_schedule(text: str, where: str) -> Callable[[float], float]:
    """
    ``"lin_0.001"`` as the zoo reads it: from 0.001 at the start of training (progress remaining 1) to 0 at the end.

    :raises ValueError: naming ``where``, when the rest is not a finite number
    """
    try:
        start = float(text.removeprefix(SCHEDULE_PREFIX))
    except ValueError:
        start = math.nan
    if not text.startswith(SCHEDULE_PREFIX) or not math.isfinite(start):
        raise ValueError(
            f"{where}: expected a linear schedule {SCHEDULE_PREFIX}<initial value> (e.g. lin_0.001), got {text!r}"
        )
    return LinearSchedule(start, 0.0, 1.0)


def _normalize_kwargs(entry: dict[str, Any], where: str) -> dict[str, Any] | None:
    """Pop ``normalize`` (a boolean, a mapping or a ``dict(...)`` string): ``VecNormalize``'s arguments, or ``None``."""
    value = entry.pop("normalize", False)
    if isinstance(value, str):
        value = _evaluated(value, {"dict": dict}, f"{where}: normalize")
    if value is False:
        return None
    if value is not True and not isinstance(value, dict):
        raise ValueError(f"{where}: normalize: expected true, false or a mapping of VecNormalize's arguments")
    kwargs = dict(value) if isinstance(value, dict) else {}
    if "gamma" in entry:  # the zoo discounts the normalized reward with the algorithm's gamma
        kwargs["gamma"] = entry["gamma"]
    return kwargs


def _evaluated(value: Any, namespace: dict[str, Any], where: str) -> Any:
    """A string of Python evaluated as the zoo evaluates it, with the names it sees; anything else as it is."""
    if not isinstance(value, str):
        return value
    try:
        return eval(value, dict(namespace))  # the zoo's convention
    except Exception as error:
        raise ValueError(f"{where}: cannot evaluate {value!r} ({type(error).__name__}: {error})") from None


def _whole_number(value: Any, where: str) -> int:
    """A count from YAML (``3e4`` written ``!!float 3e4`` is a float), or an error naming the key."""
    if isinstance(value, bool) or not _is_number(value) or value != int(value):
        hint = " (YAML reads 3e4 as a string: write 30000 or !!float 3e4)" if isinstance(value, str) else ""
        raise ValueError(f"{where}: expected a whole number, got {value!r}{hint}")
    return int(value)


def _class_specs(value: Any, where: str) -> tuple[ClassSpec, ...]:
    """
    A ``callback`` or ``env_wrapper`` key in the zoo's forms (``rl_zoo3.utils.get_callback_list``,
    ``get_wrapper_class``): a class path, a one-key mapping ``{class path: keyword arguments}``, or a list of those;
    every class is imported now, so a misspelt path fails on loading, naming the entry and the key.
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
            raise ValueError(f"{where}: {item!r} is not a class path or {{class path: keyword arguments}}")
        _imported(path, where)
        specs.append((path, kwargs))
    return tuple(specs)


def _imported(path: str, where: str) -> Any:
    """The object at a dotted path, or an error naming ``where`` and the path."""
    try:
        return _class_by_path(path)
    except (ImportError, AttributeError, ValueError) as error:
        raise ValueError(f"{where}: {path!r} cannot be imported ({error})") from None


def _class_by_path(path: str) -> Any:
    """``"package.module.Name"`` -> the object (the zoo's ``get_class_by_name``)."""
    module_name, _, name = path.rpartition(".")
    if not module_name:
        raise ValueError(f"{path!r} is not a dotted path (module.Class)")
    return getattr(importlib.import_module(module_name), name)


def hyperparams_namespace() -> dict[str, Any]:
    """
    Names that ``policy_kwargs``, ``replay_buffer_class``, ``replay_buffer_kwargs`` and ``monitor_kwargs`` strings may
    use (the zoo evaluates those strings in its ``exp_manager`` module, where ``th``, ``nn``, ``np``,
    ``HerReplayBuffer`` and ``RMSpropTFLike`` are imported): those, the fusion extractor and DCQN's replay buffers
    (its bases and every combination of variants, by class name: ``LeanNStepDictReplayBuffer``).
    """
    import numpy as np
    import torch as th
    from stable_baselines3.common.sb2_compat.rmsprop_tf_like import RMSpropTFLike
    from torch import nn

    from sb3_dcqn import replay
    from sb3_dcqn.fusion import EmbeddingFusionExtractor

    return {
        "th": th,
        "nn": nn,
        "np": np,
        "RMSpropTFLike": RMSpropTFLike,
        "HerReplayBuffer": HerReplayBuffer,
        "EmbeddingFusionExtractor": EmbeddingFusionExtractor,
        **{cls.__name__: cls for cls in replay.all_replay_buffer_classes()},
    }


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
        _number_hint(value) or _schedule_hint(value)
    )


def _schedule_hint(value: Any) -> str:
    """How a schedule string is written, for one that looks like an attempt (``exp_0.001``, ``lin0.001``)."""
    if isinstance(value, str) and ("_" in value or value.startswith("lin")):
        return f" (a linear schedule is written {SCHEDULE_PREFIX}<initial value>, e.g. lin_0.001)"
    return ""


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
