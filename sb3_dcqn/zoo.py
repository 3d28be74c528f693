"""RL Baselines3 Zoo integration: make ``--algo dcqn`` available to the zoo's ``train``.

``rl_zoo3`` has no plugin hook, so :func:`register_dcqn` adds DCQN to the zoo's algorithm table, its hyperparameter
sampler and converter tables (for ``-optimize``), and the names used in ``policy_kwargs`` strings of
``hyperparams/dcqn.yml`` to the namespace in which the zoo evaluates them. The console script ``dcqn-zoo`` registers
and then runs the zoo's training CLI::

    dcqn-zoo --algo dcqn --env CartPole-v1 -conf hyperparams/dcqn.yml
    dcqn-zoo --algo dcqn --env CartPole-v1 -conf hyperparams/dcqn.yml -optimize --storage dcqn.log

Requires the ``zoo`` extra: ``pip install "sb3-dcqn[zoo]"``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from sb3_dcqn.dcqn import DCQN

ALGO_NAME = "dcqn"
# Keys of a zoo entry that configure the zoo's env and wrappers rather than the algorithm (n_envs and env_kwargs are
# kept in ZooEntry; the others are not supported outside the zoo and are dropped)
_ZOO_ONLY_KEYS = ("normalize", "env_wrapper", "frame_stack", "callback", "vec_env_wrapper")


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
    """

    n_timesteps: int
    hyperparams: dict[str, Any]
    env_kwargs: dict[str, Any] = field(default_factory=dict)
    n_envs: int = 1


def load_zoo_entry(path: str | Path, env_id: str) -> ZooEntry:
    """
    Read one env's entry of a zoo-format hyperparameter file (as ``rl_zoo3`` reads it).

    :param path: The YAML file
    :param env_id: The env id (top-level key)
    :return: the entry; ``policy_kwargs`` strings are evaluated with the names the zoo sees
        (:func:`policy_kwargs_namespace`)
    :raises FileNotFoundError: if the file does not exist
    :raises KeyError: if the env has no entry, or the entry no ``n_timesteps``
    :raises ValueError: if ``policy_kwargs`` cannot be evaluated or ``env_kwargs`` is not a mapping
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"hyperparameter file not found: {path}")
    with open(path) as file:
        table = yaml.safe_load(file) or {}
    if env_id not in table:
        raise KeyError(f"{path}: no entry for {env_id!r} (entries: {sorted(table)})")
    entry = dict(table[env_id])
    if "n_timesteps" not in entry:
        raise KeyError(f"{path}: entry {env_id!r} has no 'n_timesteps'")
    n_timesteps = int(entry.pop("n_timesteps"))
    n_envs = int(entry.pop("n_envs", 1))
    env_kwargs = entry.pop("env_kwargs", None) or {}
    if not isinstance(env_kwargs, dict):
        raise ValueError(f"{path}: {env_id!r}: env_kwargs must be a mapping, got {env_kwargs!r}")
    for key in _ZOO_ONLY_KEYS:
        entry.pop(key, None)
    if isinstance(entry.get("policy_kwargs"), str):
        namespace = {"dict": dict, **policy_kwargs_namespace()}
        try:
            entry["policy_kwargs"] = eval(entry["policy_kwargs"], namespace)  # the zoo's convention
        except Exception as error:
            raise ValueError(f"{path}: {env_id!r}: cannot evaluate policy_kwargs {entry['policy_kwargs']!r}") from error
    return ZooEntry(n_timesteps, entry, dict(env_kwargs), n_envs)


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


def policy_kwargs_namespace() -> dict[str, Any]:
    """Names that ``policy_kwargs`` strings in ``dcqn.yml`` may use (the zoo evaluates those strings)."""
    from torch import nn

    import campusnav_env  # noqa: F401  (registers the CampusNav ids with gymnasium)
    from sb3_dcqn.fusion import EmbeddingFusionExtractor

    return {"EmbeddingFusionExtractor": EmbeddingFusionExtractor, "nn": nn}


def register_dcqn() -> None:
    """Add DCQN to the RL Zoo's algorithm, sampler and converter tables (idempotent)."""
    exp_manager, hyperparams_opt, utils = _import_zoo()
    # The zoo's modules import these dicts by name: mutating them in place reaches every user
    utils.ALGOS[ALGO_NAME] = DCQN
    hyperparams_opt.HYPERPARAMS_SAMPLER[ALGO_NAME] = sample_dcqn_params
    hyperparams_opt.HYPERPARAMS_CONVERTER[ALGO_NAME] = hyperparams_opt.convert_offpolicy_params
    # The experiment manager eval()s policy_kwargs strings in its own module globals
    vars(exp_manager).update(policy_kwargs_namespace())


def main(argv: list[str] | None = None) -> None:
    """Entry point of ``dcqn-zoo``: the zoo's ``train`` CLI with DCQN registered (and ``dcqn.yml`` as default conf)."""
    register_dcqn()
    from rl_zoo3.train import train

    args = list(sys.argv[1:] if argv is None else argv)
    if "-conf" not in args and "--conf-file" not in args:
        args += ["-conf", str(default_hyperparams_path())]
    sys.argv = [sys.argv[0] if sys.argv else "dcqn-zoo", *args]
    train()


if __name__ == "__main__":
    main()
