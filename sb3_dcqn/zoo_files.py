"""The RL Zoo's hyperparameter files: the shipped ones, their table of entries, and the zoo's rule for their strings.

A zoo-format YAML file maps env ids to settings. :func:`read_zoo_table` reads one; :mod:`sb3_dcqn.zoo_entry` reads an
entry of it into a typed, checked :class:`~sb3_dcqn.zoo_entry.ZooEntry`. The few settings whose strings the zoo turns
into objects (``lin_`` schedules; ``policy_kwargs``, replay buffer, ``normalize`` and ``monitor_kwargs`` strings
evaluated as Python) go through :func:`to_object`: rl_zoo3's own code where it is installed, else
:func:`_without_zoo`, which reads the same strings the same way (``tests/test_zoo_files.py`` compares the two on one
file through rl_zoo3's ``ExperimentManager``).

Reads YAML with PyYAML; otherwise needs SB3 alone, like the algorithm modules (rl_zoo3, an optional extra, lazily).
"""

from __future__ import annotations

import functools
import importlib
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

# Keys whose string values are schedules (rl_zoo3's ExperimentManager._preprocess_schedules)
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf", "delta_std")
SCHEDULE_PREFIX = "lin_"
# Keys whose string values the zoo evaluates as Python (rl_zoo3's ExperimentManager._preprocess_hyperparams)
EVALUATED_KEYS = ("policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs", "normalize", "monitor_kwargs")


def default_hyperparams_path() -> Path:
    """Path of the ``dcqn.yml`` hyperparameter file shipped with the package."""
    return Path(str(resources.files("sb3_dcqn") / "hyperparams" / "dcqn.yml"))


def paper_hyperparams_path() -> Path:
    """Path of ``dcqn_paper.yml``: the paper's settings for CampusNav (lr 1e-4, gamma 0.95, replay buffer 412)."""
    return Path(str(resources.files("sb3_dcqn") / "hyperparams" / "dcqn_paper.yml"))


def read_zoo_table(path: Path) -> dict[Any, Any]:
    """
    The table of a zoo-format hyperparameter file (env ids mapped to their settings).

    :raises FileNotFoundError: if the file does not exist
    :raises yaml.YAMLError: if it is not valid YAML (:func:`describe_yaml_error` says where)
    :raises TypeError: if it is not a table of entries
    """
    if not path.is_file():
        raise FileNotFoundError(f"hyperparameter file not found: {path}")
    with open(path) as file:
        table = yaml.safe_load(file) or {}
    if not isinstance(table, dict):
        raise TypeError("not a zoo-format hyperparameter file (expected env ids mapped to their settings)")
    return table


def describe_yaml_error(error: yaml.YAMLError) -> str:
    """Where a YAML file fails to parse, in words: ``"line 3, column 7: mapping values are not allowed here"``."""
    mark = getattr(error, "problem_mark", None)
    problem = getattr(error, "problem", None) or str(error)
    return problem if mark is None else f"line {mark.line + 1}, column {mark.column + 1}: {problem}"


def to_object(key: str, text: str) -> Any:
    """
    The string of a setting of :data:`SCHEDULE_KEYS` (``lin_0.001``) or :data:`EVALUATED_KEYS` (``"dict(...)"``) as
    the zoo turns it into an object: with rl_zoo3 installed, its own ``ExperimentManager._preprocess_schedules`` and
    evaluation in its experiment manager's names (DCQN's added, as :func:`sb3_dcqn.zoo.register_dcqn` adds them);
    without it, :func:`_without_zoo`.

    :raises Exception: what the zoo's reading raises (``ValueError``, ``NameError``, ``SyntaxError``, ...)
    """
    try:
        from rl_zoo3 import exp_manager
    except ImportError:
        return _without_zoo(key, text)
    if key in SCHEDULE_KEYS:
        return exp_manager.ExperimentManager._preprocess_schedules({key: text})[key]
    vars(exp_manager).update(hyperparams_namespace())
    return eval(text, dict(vars(exp_manager)))  # the zoo's convention


def _without_zoo(key: str, text: str) -> Any:
    """The zoo's reading of a setting's string where rl_zoo3 is not installed: ``lin_<value>`` a linear schedule from
    the value to 0, any other string Python evaluated in the names of :func:`hyperparams_namespace`."""
    if key in SCHEDULE_KEYS:
        return LinearSchedule(float(text.removeprefix(SCHEDULE_PREFIX)), 0.0, 1.0)
    return eval(text, dict(hyperparams_namespace()))


def class_by_path(path: str) -> Any:
    """``"package.module.Name"`` -> the object (the rule of rl_zoo3's ``get_class_by_name``).

    :raises ImportError, AttributeError: if the module or the name is missing
    :raises ValueError: if ``path`` has no module part
    """
    module_name, _, name = path.rpartition(".")
    if not module_name:
        raise ValueError(f"{path!r} is not a dotted path (module.Class)")
    return getattr(importlib.import_module(module_name), name)


@functools.cache
def hyperparams_namespace() -> dict[str, Any]:
    """
    Names that the zoo's strings may use (it evaluates them in its ``exp_manager`` module, where ``th``, ``nn``,
    ``np``, ``HerReplayBuffer`` and ``RMSpropTFLike`` are imported): those, the fusion extractor and DCQN's replay
    buffers (its bases and every combination of variants, by class name: ``LeanNStepDictReplayBuffer``).
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
