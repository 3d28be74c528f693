"""The RL Zoo's hyperparameter files: the shipped ones, and the zoo's rules for their strings.

What the zoo turns into objects goes through rl_zoo3's own public functions where it is installed (``rl_zoo3.utils``:
``linear_schedule``, ``get_class_by_name``, ``get_callback_list``; strings evaluated in the names of its
``exp_manager``), else through the few lines below, which read the same files the same way (``tests/test_zoo_files.py``
compares both with rl_zoo3's ``ExperimentManager``). rl_zoo3 is imported lazily: it is the optional ``zoo`` extra.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import yaml
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.her.her_replay_buffer import HerReplayBuffer

# Keys whose string values are schedules, and those whose strings the zoo evaluates as Python (rl_zoo3 2.9's
# ExperimentManager reads both so)
SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf", "delta_std")
SCHEDULE_PREFIX = "lin_"
EVALUATED_KEYS = ("policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs", "normalize", "monitor_kwargs")


def default_hyperparams_path() -> Path:
    """Path of the ``dcqn.yml`` hyperparameter file shipped with the package."""
    return Path(str(resources.files("sb3_dcqn") / "hyperparams" / "dcqn.yml"))


def paper_hyperparams_path() -> Path:
    """Path of ``dcqn_paper.yml``: the paper's settings for CampusNav (lr 1e-4, gamma 0.95, replay buffer 412)."""
    return Path(str(resources.files("sb3_dcqn") / "hyperparams" / "dcqn_paper.yml"))


def describe_yaml_error(error: yaml.YAMLError) -> str:
    """Where a YAML file fails to parse, in words: ``"line 3, column 7: mapping values are not allowed here"``."""
    mark = getattr(error, "problem_mark", None)
    problem = getattr(error, "problem", None) or str(error)
    return problem if mark is None else f"line {mark.line + 1}, column {mark.column + 1}: {problem}"


def _zoo_utils() -> Any:
    """``rl_zoo3.utils``, or ``None`` where the zoo extra is not installed."""
    try:
        from rl_zoo3 import utils
    except ImportError:
        return None
    return utils


def to_object(key: str, text: str) -> Any:
    """
    A setting's string as the zoo makes it an object: ``lin_<value>`` of :data:`SCHEDULE_KEYS` a linear schedule from
    the value to 0 (the zoo's ``linear_schedule``), any other string Python evaluated in the zoo's names and those of
    :func:`hyperparams_namespace` (which :func:`sb3_dcqn.zoo.register_dcqn` adds to the zoo's).

    :raises Exception: what the reading raises (``ValueError``, ``NameError``, ``SyntaxError``, ...)
    """
    utils = _zoo_utils()
    if key in SCHEDULE_KEYS:
        start = float(text.removeprefix(SCHEDULE_PREFIX))
        return LinearSchedule(start, 0.0, 1.0) if utils is None else utils.linear_schedule(start)
    names = {} if utils is None else dict(vars(importlib.import_module("rl_zoo3.exp_manager")))
    return eval(text, {**names, **hyperparams_namespace()})  # the zoo's convention


def class_by_path(path: str) -> Any:
    """``"package.module.Name"`` -> the object (rl_zoo3's ``get_class_by_name`` where installed, its rule else).

    :raises ImportError, AttributeError: if the module or the name is missing
    :raises ValueError: if ``path`` has no module part
    """
    module_name, _, name = path.rpartition(".")
    if not module_name:
        raise ValueError(f"{path!r} is not a dotted path (module.Class)")
    utils = _zoo_utils()
    return getattr(importlib.import_module(module_name), name) if utils is None else utils.get_class_by_name(path)


def make_callbacks(specs: Sequence[tuple[str, dict[str, Any]]]) -> list[Any]:
    """New callbacks from ``(class path, keyword arguments)`` pairs (rl_zoo3's ``get_callback_list`` if installed)."""
    utils = _zoo_utils()
    if utils is None:
        return [class_by_path(path)(**kwargs) for path, kwargs in specs]
    return utils.get_callback_list({"callback": [{path: dict(kwargs)} for path, kwargs in specs]})


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
