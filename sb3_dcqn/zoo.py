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
from importlib import resources
from pathlib import Path
from typing import Any

from sb3_dcqn.dcqn import DCQN

ALGO_NAME = "dcqn"


def default_hyperparams_path() -> Path:
    """Path of the ``dcqn.yml`` hyperparameter file shipped with the package."""
    return Path(str(resources.files("sb3_dcqn") / "hyperparams" / "dcqn.yml"))


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
    import campusnav_env  # noqa: F401  (registers the CampusNav ids with gymnasium)
    from sb3_dcqn.fusion import EmbeddingFusionExtractor

    return {"EmbeddingFusionExtractor": EmbeddingFusionExtractor}


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
