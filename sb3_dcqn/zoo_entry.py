"""One entry of a zoo-format hyperparameter file, checked: what ``dcqn-zoo`` and ``dcqn-campusnav`` read.

:func:`load_zoo_entry` reads an env's entry once, ``-params`` overrides applied first (as the zoo applies them), into a
frozen :class:`ZooEntry`; its strings become objects through the zoo's own functions (:mod:`sb3_dcqn.zoo_files`:
``learning_rate: lin_0.001`` is a linear schedule from 0.001 to 0). The zoo's env-building keys (:data:`ZOO_ENV_KEYS`)
are checked and kept as written. :func:`read_params` reads ``-params`` for both command lines. Every key is checked
before anything is built, stricter than the zoo where it fails later or guesses (a count is a whole number; a schedule
is ``lin_<initial value>``: the zoo reads any ``word_<number>`` as linear): a bad setting raises :class:`EntryError`,
one line naming the file, the entry, the key and the value.
"""

from __future__ import annotations

import difflib
import inspect
import math
import re
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import ReplayBuffer

from sb3_dcqn.dcqn import DCQN
from sb3_dcqn.route_memory.layer import algorithm_class_for, memory_settings
from sb3_dcqn.zoo_files import (
    EVALUATED_KEYS,
    SCHEDULE_KEYS,
    SCHEDULE_PREFIX,
    class_by_path,
    describe_yaml_error,
    hyperparams_namespace,
    make_callbacks,
    to_object,
)

__all__ = [
    "VALUE_CHECKS",
    "ZOO_ENV_KEYS",
    "ClassSpec",
    "EntryError",
    "ZooEntry",
    "check_params",
    "load_zoo_entry",
    "read_entry",
    "read_params",
    "unknown_keyword",
    "value_problem",
]

# A class named by its dotted path, with its keyword arguments: the zoo's form of callback and env_wrapper items
ClassSpec = tuple[str, dict[str, Any]]
# Keys that only the zoo's env building applies (VecNormalize, VecFrameStack, wrappers, its Monitor)
ZOO_ENV_KEYS = ("normalize", "frame_stack", "env_wrapper", "vec_env_wrapper", "monitor_kwargs")
# Arguments of a replay buffer that the algorithm passes itself (not replay_buffer_kwargs keys)
_BUFFER_ARGUMENTS = ("buffer_size", "observation_space", "action_space", "env", "device", "n_envs")
_PARAMS_FORM = "expected key:value (e.g. learning_rate:0.001 buffer_size:10000)"


class EntryError(ValueError):
    """
    A setting of a hyperparameter entry that cannot be used, and where it is. ``str()`` is one line:
    ``"dcqn.yml: entry 'CartPole-v1': gamma: expected a number in [0, 1], got 1.5"``, or for a ``-params`` override
    ``"-params gamma: expected a number in [0, 1], got 1.5"``.

    :param problem: What is wrong, and the fix where there is one
    :param file: The hyperparameter file (``None``: settings given alone)
    :param entry: The entry read (the env id, or the ``default`` entry the env fell back to)
    :param key: The setting (``None``: the file or the entry as a whole)
    :param value: The value given
    :param from_params: The key's value came from ``-params``, not from the file
    """

    def __init__(
        self,
        problem: str,
        file: Path | None = None,
        entry: str | None = None,
        key: str | None = None,
        value: Any = None,
        from_params: bool = False,
    ) -> None:
        super().__init__(problem)
        self.problem, self.file, self.entry, self.key, self.value = problem, file, entry, key, value
        self.from_params = from_params

    def __str__(self) -> str:
        where = [] if self.from_params else [str(self.file)] * (self.file is not None)
        where += [] if self.from_params or self.entry is None else [f"entry {self.entry!r}"]
        where += [] if self.key is None else [f"-params {self.key}" if self.from_params else self.key]
        return ": ".join([*where, self.problem])


@dataclass(frozen=True)
class ZooEntry:
    """
    One env's entry of a zoo-format hyperparameter file, read (:func:`load_zoo_entry`) and ready for the algorithm.

    :param n_timesteps: Training steps (``n_timesteps``; :meth:`budget` refuses one below 1 when it is used)
    :param hyperparams: The algorithm's keyword arguments (``policy`` included; schedules built, ``policy_kwargs``
        and the replay buffer strings evaluated; ``route_memory`` too: the memory-wearing class takes it)
    :param env_kwargs: Keyword arguments for ``gym.make`` (``env_kwargs``)
    :param n_envs: Number of training envs (``n_envs``, default 1)
    :param callbacks: The ``callback`` key, as the zoo reads it: ``(class path, keyword arguments)`` pairs (e.g.
        ``("campusnav_env.callbacks.StartCurriculumCallback", {"initial": 2})``), built by :meth:`make_callbacks`
    :param zoo_settings: The keys of :data:`ZOO_ENV_KEYS` the entry sets, as written (checked, not applied here:
        the zoo's env building applies them)
    :param file: The file it was read from (``None``: made in code)
    :param name: The entry read (the env id, or the ``default`` entry)
    :param params: The keys that ``-params`` overrides gave
    """

    n_timesteps: int
    hyperparams: dict[str, Any]
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    n_envs: int = 1
    callbacks: tuple[ClassSpec, ...] = ()
    zoo_settings: dict[str, Any] = field(default_factory=dict)
    file: Path | None = None
    name: str | None = None
    params: tuple[str, ...] = ()

    @property
    def source(self) -> str:
        """What messages name the entry by: ``"dcqn.yml: entry 'CartPole-v1'"``."""
        return ": ".join([*([str(self.file)] if self.file else []), f"entry {self.name!r}"])

    def error(self, key: str | None, problem: str, value: Any = None) -> EntryError:
        """An :class:`EntryError` about one of this entry's keys (or the entry as a whole)."""
        return _errors(self.file, self.name, self.params)(key, problem, value)

    def algorithm_class(self) -> type[BaseAlgorithm]:
        """The algorithm the entry's hyperparameters are for: DCQN, wearing the route memory where the entry sets
        ``route_memory`` (:func:`~sb3_dcqn.route_memory.layer.algorithm_class_for`; the model's
        ``wears_route_memory`` says whether the memory is on)."""
        return algorithm_class_for(DCQN, self.hyperparams)

    def make_model(self, env: Any, **kwargs: Any) -> BaseAlgorithm:
        """A new model of the entry's algorithm on ``env``; ``kwargs`` replace the entry's arguments."""
        return self.algorithm_class()(env=env, **{**self.hyperparams, **kwargs})

    def budget(self, steps: int | None = None) -> int:
        """
        The steps to train: ``steps`` where a command line gives them (``-n``, ``--timesteps``), else ``n_timesteps``.

        :raises EntryError: if ``n_timesteps`` is used and is not positive
        """
        if steps is not None:
            return steps
        if self.n_timesteps < 1:
            raise self.error("n_timesteps", f"expected a positive integer, got {self.n_timesteps}", self.n_timesteps)
        return self.n_timesteps

    def make_callbacks(self) -> list[Any]:
        """New instances of the entry's callbacks (SB3 ``BaseCallback``), one per call: a callback trains one model."""
        return make_callbacks(self.callbacks)


# ------------------------------------------------------------------------------------------------ reading
def load_zoo_entry(
    path: str | Path,
    env_id: str,
    overrides: Mapping[str, Any] | None = None,
    fallbacks: Iterable[str] = ("default",),
    algorithm: type[BaseAlgorithm] = DCQN,
) -> ZooEntry:
    """
    Read and check one env's entry of a zoo-format hyperparameter file, as ``rl_zoo3`` reads it.

    :param path: The YAML file
    :param env_id: The env id (top-level key)
    :param overrides: Settings that replace the entry's before it is read (``-params``, as :func:`read_params`
        reads them)
    :param fallbacks: Entries used, in order, when the file has none for ``env_id`` (the zoo's ``default``; it tries
        ``atari`` first for Atari envs)
    :param algorithm: The algorithm whose arguments the entry's other keys are
    :raises EntryError: naming the file (not found, not valid YAML, not a table, no entry for ``env_id``), the entry
        (not a mapping, no ``n_timesteps``) or the key, as :func:`read_entry`
    """
    path = Path(path)
    if not path.is_file():
        raise EntryError(f"hyperparameter file not found: {path}")
    try:
        table = yaml.safe_load(path.read_text()) or {}
    except yaml.YAMLError as error:
        raise EntryError(f"not valid YAML ({describe_yaml_error(error)})", path) from None
    if not isinstance(table, dict):
        raise EntryError("not a zoo-format hyperparameter file (expected env ids mapped to their settings)", path)
    name = next((key for key in (env_id, *fallbacks) if key in table), None)
    if name is None:
        raise EntryError(f"no entry for {env_id!r} (entries: {sorted(map(str, table))})", path)
    if not isinstance(table[name], dict):
        raise EntryError("not a mapping of hyperparameters", path, name)
    return read_entry({**table[name], **(overrides or {})}, path, name, tuple(overrides or ()), algorithm)


def read_entry(
    settings: Mapping[str, Any],
    file: Path | None = None,
    name: str | None = None,
    params: tuple[str, ...] = (),
    algorithm: type[BaseAlgorithm] = DCQN,
) -> ZooEntry:
    """
    One entry's settings, checked (see :func:`load_zoo_entry`).

    :param settings: The entry, overrides applied
    :param file: Its file, ``name``: its name, ``params``: the keys overrides gave (for messages)
    :raises EntryError: on the first setting that cannot be used
    """
    error = _errors(file, name, params)
    entry = dict(settings)
    if "n_timesteps" not in entry:
        raise error(None, "no 'n_timesteps' (the zoo needs it, -n or not)")
    n_timesteps = entry.pop("n_timesteps")
    if not _is_number(n_timesteps) or n_timesteps != int(n_timesteps):
        raise error("n_timesteps", f"expected a whole number, got {n_timesteps!r}{_number_hint(n_timesteps)}")
    n_envs, env_kwargs, callback = (
        entry.pop("n_envs", 1),
        entry.pop("env_kwargs", None) or {},
        entry.pop("callback", None),
    )
    zoo_settings = {key: entry.pop(key) for key in ZOO_ENV_KEYS if key in entry}
    # The zoo's own keys in the forms its ExperimentManager takes, named before the zoo fails on them
    for key, value in (("n_envs", n_envs), ("frame_stack", zoo_settings.get("frame_stack", 1))):
        if problem := VALUE_CHECKS[key](value):
            raise error(key, problem, value)
    for key, value in [("env_kwargs", env_kwargs), *((k, zoo_settings.get(k, {})) for k in _EVALUATED_ENV_KEYS)]:
        value = _as_object(key, value, error)
        if not isinstance(value, dict) and not (key == "normalize" and isinstance(value, bool)):
            expected = "true, false or a mapping of VecNormalize's arguments" if key == "normalize" else "a mapping"
            raise error(key, f"expected {expected}, got {value!r}", value)
    for key in ("env_wrapper", "vec_env_wrapper"):
        _class_specs(zoo_settings.get(key), key, error)
    return ZooEntry(
        int(n_timesteps),
        _algorithm_settings(entry, algorithm, error),
        dict(env_kwargs),
        n_envs,
        callbacks=_class_specs(callback, "callback", error),
        zoo_settings=zoo_settings,
        file=file,
        name=name,
        params=params,
    )


def read_params(items: Iterable[str]) -> dict[str, Any]:
    """
    ``-params key:value ...`` as both command lines read them: a value as the zoo reads it (Python, evaluated in the
    names of :func:`~sb3_dcqn.zoo_files.hyperparams_namespace`: ``1e-3``, ``'MlpPolicy'``, ``dict(net_arch=[64])``,
    ``True``), and one that Python cannot read (a bare word: ``lin_3e-4``, ``MlpPolicy``, ``true``, ``[2, step]``)
    as YAML reads it.

    :raises EntryError: naming ``-params`` and the key, for an item without ``key:`` or a value Python fails on
    """
    params: dict[str, Any] = {}
    for item in items:
        key, colon, text = item.partition(":")
        key, text = key.strip(), text.strip()
        if not colon or not key:
            raise EntryError(_PARAMS_FORM, key=item, value=item, from_params=True)
        try:
            params[key] = eval(text, dict(hyperparams_namespace()))  # the zoo's StoreDict reads values so
        except (NameError, SyntaxError):
            try:
                params[key] = yaml.safe_load(text)
            except yaml.YAMLError:
                params[key] = text
        except Exception as raised:
            problem = f"cannot evaluate {text!r} ({type(raised).__name__}: {raised})"
            raise EntryError(problem, key=key, value=text, from_params=True) from None
    return params


def check_params(settings: Mapping[str, Any], algorithm: type[BaseAlgorithm] = DCQN) -> dict[str, Any]:
    """
    ``-params`` given alone (e.g. for a loaded model), checked and made objects as an entry's keys are.

    :return: the algorithm's keyword arguments
    :raises EntryError: naming ``-params`` and the key
    """
    return _algorithm_settings(dict(settings), algorithm, _errors(None, None, all_params=True))


_ErrorFactory = Callable[..., EntryError]
# The zoo's env keys whose strings it evaluates as Python, besides env_kwargs
_EVALUATED_ENV_KEYS = ("monitor_kwargs", "normalize")


def _errors(file: Path | None, name: str | None, params: Iterable[str] = (), all_params: bool = False) -> _ErrorFactory:
    """``error(key, problem, value=None)``: an :class:`EntryError` about a key of this entry (``None``: the whole)."""
    params = tuple(params)
    return lambda key, problem, value=None: EntryError(problem, file, name, key, value, all_params or key in params)


def _algorithm_settings(settings: dict[str, Any], algorithm: type, error: _ErrorFactory) -> dict[str, Any]:
    """The algorithm's keys: each taken by ``algorithm``, its value checked, its string made an object; then the
    policy, ``policy_kwargs`` and the replay buffer checked together."""
    unknown = _unknown_keyword(settings, algorithm_class_for(algorithm, settings), skip=("env",))
    if unknown is not None:
        raise error(unknown[0], f"unknown {algorithm.__name__} hyperparameter{unknown[1]}", settings[unknown[0]])
    booleans = {
        name
        for name, parameter in inspect.signature(algorithm.__init__).parameters.items()
        if isinstance(parameter.default, bool)
    }
    hyperparams = {}
    for key, value in settings.items():
        if problem := value_problem(key, value, booleans):
            raise error(key, problem, value)
        hyperparams[key] = _as_object(key, value, error)
    if isinstance(hyperparams.get("train_freq"), list):  # YAML has no tuples: the zoo reads [4, "episode"] so
        hyperparams["train_freq"] = tuple(hyperparams["train_freq"])
    _check_policy(hyperparams, algorithm, error)
    _check_replay_buffer(hyperparams, algorithm, error)
    return hyperparams


def _as_object(key: str, value: Any, error: _ErrorFactory) -> Any:
    """A value as the zoo makes it an object: a schedule or a Python string (:func:`~sb3_dcqn.zoo_files.to_object`;
    a number stays a number, which SB3 makes the constant schedule the zoo makes), a custom policy's class path."""
    if key == "policy" and isinstance(value, str) and "." in value:
        return _imported(value, key, error)
    if key not in SCHEDULE_KEYS + EVALUATED_KEYS or not isinstance(value, str):
        return value
    try:
        return to_object(key, value)
    except Exception as raised:
        raise error(key, f"cannot evaluate {value!r} ({type(raised).__name__}: {raised})", value) from None


def _class_specs(value: Any, key: str, error: _ErrorFactory) -> tuple[ClassSpec, ...]:
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
            raise error(key, f"{item!r} is not a class path or {{class path: keyword arguments}}", item)
        _imported(path, key, error)
        specs.append((path, kwargs))
    return tuple(specs)


def _imported(path: str, key: str, error: _ErrorFactory) -> Any:
    try:
        return class_by_path(path)
    except (ImportError, AttributeError, ValueError) as raised:
        raise error(key, f"{path!r} cannot be imported ({raised})", path) from None


# ------------------------------------------------------------------------------------------------ values
def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_number(value: Any) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def _number_hint(value: Any) -> str:
    """Why a value is not a number, in YAML's words: PyYAML reads ``1e-3`` (no dot) as a string."""
    if isinstance(value, bool):
        return " (a boolean)"
    if not isinstance(value, str) or not _is_float_text(value):
        return ""
    if "e" not in value.lower() or "." in value:
        return f" (a string: write {value} without quotes)"
    number = float(value)
    written = int(number) if number.is_integer() else number
    return f" (YAML reads {value} as a string: write {written!r} or !!float {value})"


def _is_float_text(text: str) -> bool:
    """Whether ``text`` is a finite number as Python writes one (``"1e-3"``; not ``"inf"``, ``"1_0"``)."""
    try:
        return "_" not in text and math.isfinite(float(text))
    except ValueError:
        return False


def _integer(minimum: int | None, expected: str, also: tuple[Any, ...] = ()) -> Callable[[Any], str | None]:
    """A check that a value is an integer >= ``minimum`` (or one of ``also``); ``expected`` says so in words."""

    def check(value: Any) -> str | None:
        if _is_int(value) and (minimum is None or value >= minimum):
            return None
        if (value is None or _is_int(value)) and value in also:
            return None
        whole = isinstance(value, float) and value.is_integer() and (minimum is None or value >= minimum)
        return f"expected {expected}, got {value!r}" + (f" (write {int(value)})" if whole else _number_hint(value))

    return check


def _number(expected: str, within: Callable[[float], bool]) -> Callable[[Any], str | None]:
    """A check that a value is a finite number ``within`` a range; ``expected`` says which in words."""

    def check(value: Any) -> str | None:
        if _is_number(value) and within(value):
            return None
        return f"expected {expected}, got {value!r}{_number_hint(value)}"

    return check


def _learning_rate(value: Any) -> str | None:
    if isinstance(value, str) and value.startswith(SCHEDULE_PREFIX):
        start = value.removeprefix(SCHEDULE_PREFIX)
        if _is_float_text(start) and float(start) > 0:
            return None
        return f"expected a linear schedule {SCHEDULE_PREFIX}<initial value> (e.g. lin_0.001), got {value!r}"
    if callable(value) or (_is_number(value) and value > 0):
        return None
    tried = isinstance(value, str) and ("_" in value or value.startswith("lin"))  # exp_0.001, lin0.001
    hint = f" (a linear schedule is written {SCHEDULE_PREFIX}<initial value>, e.g. lin_0.001)" if tried else ""
    return "expected a positive number or a schedule (a callable of the remaining progress), got " + (
        f"{value!r}{_number_hint(value) or hint}"
    )


_TRAIN_FREQ_UNITS = ("step", "episode")


def _train_freq(value: Any) -> str | None:
    if _is_int(value) and value >= 1:
        return None
    if isinstance(value, list | tuple) and len(value) == 2:
        frequency, unit = value
        if not (_is_int(frequency) and frequency >= 1):
            return f"expected a positive frequency, got {frequency!r} in {value!r}"
        if unit not in _TRAIN_FREQ_UNITS:
            hint = _did_you_mean(unit, _TRAIN_FREQ_UNITS, "; did you mean {!r}?")
            return f"unknown unit {unit!r} in {value!r} (units: {', '.join(_TRAIN_FREQ_UNITS)}{hint})"
        return None
    return f"expected a positive integer or a (frequency, unit) tuple, got {value!r}{_number_hint(value)}"


_DEVICES = ("auto", "cpu", "cuda", "mps")


def _device(value: Any) -> str | None:
    import torch as th

    if (
        isinstance(value, th.device)
        or value in _DEVICES
        or (isinstance(value, str) and re.fullmatch(r"cuda:\d+", value))
    ):
        return None
    if not isinstance(value, str):
        return f"expected a device name, got {value!r}"
    hint = _did_you_mean(value, _DEVICES, "; did you mean {!r}?")
    return f"unknown device {value!r} (devices: {', '.join(_DEVICES)} or cuda:N{hint})"


def _route_memory(value: Any) -> str | None:
    # The layer reads the setting (memory_settings): one meaning wherever it is given, its unknown settings named
    if not isinstance(value, bool | dict):
        return f"expected true, false or a mapping of the memory's settings, got {value!r}"
    try:
        memory_settings(value)
    except ValueError as error:
        return str(error).removeprefix("route_memory: ")
    return None


def _did_you_mean(given: Any, known: Iterable[str], form: str) -> str:
    """``form`` (e.g. ``" (did you mean {!r}?)"``) with the known name closest to ``given``; ``""`` if none is close."""
    close = difflib.get_close_matches(str(given), sorted(known), n=1)
    return form.format(close[0]) if close else ""


_POSITIVE = _integer(1, "a positive integer")
_FRACTION = _number("a number in [0, 1]", lambda x: 0 <= x <= 1)
# What the off-policy constructors (SB3's DQN, DCQN) and the zoo need of each value; booleans are checked by the
# algorithm's defaults
VALUE_CHECKS: dict[str, Callable[[Any], str | None]] = {
    "learning_rate": _learning_rate,
    "buffer_size": _POSITIVE,
    "learning_starts": _integer(0, "an integer >= 0"),
    "batch_size": _POSITIVE,
    "tau": _FRACTION,
    "gamma": _FRACTION,
    "train_freq": _train_freq,
    "gradient_steps": _integer(1, "a positive integer, or -1 (as many as env steps)", also=(-1,)),
    "n_steps": _POSITIVE,
    "target_update_interval": _POSITIVE,
    "exploration_fraction": _FRACTION,
    "exploration_initial_eps": _FRACTION,
    "exploration_final_eps": _FRACTION,
    "max_grad_norm": _number("a positive number", lambda x: x > 0),
    "stats_window_size": _POSITIVE,
    "verbose": _integer(0, "an integer >= 0"),
    "seed": _integer(None, "an integer or null", also=(None,)),
    "device": _device,
    "route_memory": _route_memory,
    "n_envs": _POSITIVE,
    "frame_stack": _POSITIVE,
}
_BOOLEAN_WORDS = {"true": True, "yes": True, "on": True, "false": False, "no": False, "off": False}


def value_problem(key: str, value: Any, booleans: Iterable[str] = ()) -> str | None:
    """
    What is wrong with a value of ``key`` (:data:`VALUE_CHECKS`; a key of ``booleans`` must be a boolean), in words
    with the fix where there is one (``"did you mean 'cuda'?"``), or ``None`` if it can be used.
    """
    if key in VALUE_CHECKS:
        return VALUE_CHECKS[key](value)
    if key in booleans and not isinstance(value, bool):
        word = _BOOLEAN_WORDS.get(value.lower()) if isinstance(value, str) else None
        hint = f" (write {str(word).lower()}, without quotes)" if word is not None else ""
        return f"expected true or false, got {value!r}{hint}"
    return None


# ------------------------------------------------------------------------------------------------ objects
def _check_policy(hyperparams: dict[str, Any], algorithm: type, error: _ErrorFactory) -> None:
    """A policy the algorithm knows, and ``policy_kwargs`` that are arguments of it."""
    policy = hyperparams.get("policy")
    aliases = getattr(algorithm, "policy_aliases", {})
    if isinstance(policy, str) and policy not in aliases:
        raise error("policy", f"unknown policy {policy!r} (policies: {', '.join(aliases)})", policy)
    policy_class = aliases.get(policy, policy) if isinstance(policy, str) else policy
    policy_kwargs = hyperparams.get("policy_kwargs")
    if policy_kwargs is not None and not isinstance(policy_kwargs, dict):
        raise error("policy_kwargs", f"expected a mapping, got {policy_kwargs!r}", policy_kwargs)
    if isinstance(policy_class, type) and policy_kwargs:
        skip = ("observation_space", "action_space", "lr_schedule")
        if problem := unknown_keyword(policy_kwargs, policy_class, skip):
            raise error("policy_kwargs", problem, policy_kwargs)


def _check_replay_buffer(hyperparams: dict[str, Any], algorithm: type, error: _ErrorFactory) -> None:
    """
    ``replay_buffer_class`` is a replay buffer class, ``replay_buffer_kwargs`` are arguments of the one built, and
    (for DCQN) its variants combine with ``n_steps`` and ``blocked_action_target``.
    """
    from sb3_dcqn.replay.combine import resolve_replay_buffer

    buffer_class = hyperparams.get("replay_buffer_class")
    if buffer_class is not None and not (isinstance(buffer_class, type) and issubclass(buffer_class, ReplayBuffer)):
        names = ", ".join(
            name
            for name, value in hyperparams_namespace().items()
            if isinstance(value, type) and issubclass(value, ReplayBuffer)
        )
        raise error("replay_buffer_class", f"{buffer_class!r} is not a replay buffer class (known: {names})")
    buffer_kwargs = hyperparams.get("replay_buffer_kwargs")
    if buffer_kwargs is not None and not isinstance(buffer_kwargs, dict):
        raise error("replay_buffer_kwargs", f"expected a mapping, got {buffer_kwargs!r}", buffer_kwargs)
    built = buffer_class
    if buffer_class is not None and issubclass(algorithm, DCQN):
        try:  # what DCQN builds (Dict or Box observations alike for a given class)
            built, _ = resolve_replay_buffer(
                buffer_class,
                buffer_kwargs or {},
                is_dict=True,
                n_steps=int(hyperparams.get("n_steps", 1)),
                gamma=float(hyperparams.get("gamma", 0.99)),
                blocked_action_target=bool(hyperparams.get("blocked_action_target", False)),
            )
        except ValueError as raised:
            raise error("replay_buffer_class", str(raised), buffer_class) from None
    # Without a class, the algorithm picks one from the observation space: its arguments are unknown here
    problem = unknown_keyword(buffer_kwargs, built, skip=_BUFFER_ARGUMENTS) if buffer_kwargs and built else None
    if problem is not None:
        raise error("replay_buffer_kwargs", problem, buffer_kwargs)


def unknown_keyword(given: Iterable[str], cls: type, skip: Iterable[str] = ()) -> str | None:
    """
    ``"unknown key 'view_dimm' of CampusNavEnv (did you mean 'view_dim'?)"`` for the first of ``given`` that is not a
    keyword argument of ``cls(...)`` (following ``**kwargs`` up its base classes; ``skip``: those that may not be given
    this way), else ``None``.
    """
    unknown = _unknown_keyword(given, cls, skip)
    return None if unknown is None else f"unknown key {unknown[0]!r} of {cls.__name__}{unknown[1]}"


def _unknown_keyword(given: Iterable[str], cls: type, skip: Iterable[str]) -> tuple[str, str] | None:
    """The first of ``given`` that ``cls(...)`` does not take, with a "did you mean" (``None``: all taken)."""
    known = _keywords(cls)
    if known is None:
        return None
    known -= {"self", *skip}
    for key in given:
        if key not in known:
            return key, _did_you_mean(key, known, " (did you mean {!r}?)")
    return None


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
