"""The ``dcqn-campusnav`` checks of the hyperparameter entry: the zoo-format YAML entry an env trains with, its
``-params`` overrides, ``--device`` and the levers, looked at before any work.

Each check raises :class:`~sb3_dcqn.campusnav.errors.CommandError` with a message that names what is wrong (the file,
the entry, the key) and, where there is one, the fix. The other inputs have modules of their own: output folders and
pictures (:mod:`~sb3_dcqn.campusnav.output_paths`), the env (:mod:`~sb3_dcqn.campusnav.env_checks`), the map, goals and
start (:mod:`~sb3_dcqn.campusnav.map_checks`), roads and closures (:mod:`~sb3_dcqn.campusnav.closure_checks`), model
files (:mod:`~sb3_dcqn.campusnav.model_checks`). Importing this module is cheap (no torch, no CampusNav): each check
imports what it needs.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_dcqn.campusnav.errors import CommandError, note
from sb3_dcqn.campusnav.levers import LEVERS
from sb3_dcqn.campusnav.requests import Request

if TYPE_CHECKING:
    from sb3_dcqn.zoo_files import ZooEntry

__all__ = ["check_device", "parse_params", "training_entry", "with_params", "zoo_entry"]


# ------------------------------------------------------------------------------------------------ hyperparameters
def zoo_entry(conf: str | None, env_id: str) -> ZooEntry:
    from sb3_dcqn.zoo_files import default_hyperparams_path, load_zoo_entry

    path = default_hyperparams_path() if conf is None else Path(conf)
    try:
        return load_zoo_entry(path, env_id)
    except (FileNotFoundError, ValueError) as error:
        raise CommandError(f"--conf: {error}") from None
    except KeyError as error:
        raise CommandError(f"--conf: {error.args[0]} (choose another --env or --conf)") from None


def parse_params(params: Sequence[str]) -> dict[str, Any]:
    """
    ``-params key:value ...`` as a dict: values as YAML reads them, then as the zoo reads an entry's
    (:func:`sb3_dcqn.zoo_files.preprocess_hyperparams`: ``lin_`` schedules, ``policy_kwargs`` evaluated), or an error
    naming the bad one.
    """
    import yaml

    from sb3_dcqn.zoo_files import preprocess_hyperparams

    parsed: dict[str, Any] = {}
    for item in params:
        key, colon, text = item.partition(":")
        if not colon or not key.strip():
            raise CommandError(f"-params {item}: expected key:value (e.g. learning_rate:0.001 buffer_size:10000)")
        try:
            parsed[key.strip()] = yaml.safe_load(text.strip())
        except yaml.YAMLError:
            parsed[key.strip()] = text.strip()
    try:
        return preprocess_hyperparams(parsed, "-params")
    except ValueError as error:
        raise CommandError(str(error)) from None


def with_params(entry: ZooEntry, params: Sequence[str]) -> ZooEntry:
    """
    An entry with ``-params`` overrides, checked as the YAML's keys are (``n_timesteps`` and ``n_envs`` as counts).
    """
    from dataclasses import replace

    from sb3_dcqn.dcqn import DCQN
    from sb3_dcqn.zoo_files import check_hyperparams

    overrides = parse_params(params)
    if not overrides:
        return entry
    counts = {key: overrides.pop(key) for key in ("n_timesteps", "n_envs") if key in overrides}
    for key, value in counts.items():
        if isinstance(value, bool) or not isinstance(value, int | float) or value != int(value) or value < 1:
            raise CommandError(f"-params {key}: expected a positive integer, got {value!r}")
    try:
        check_hyperparams({**entry.hyperparams, **overrides}, DCQN, "-params")
    except ValueError as error:
        raise CommandError(str(error)) from None
    return replace(
        entry,
        hyperparams={**entry.hyperparams, **overrides},
        n_timesteps=int(counts.get("n_timesteps", entry.n_timesteps)),
        n_envs=int(counts.get("n_envs", entry.n_envs)),
    )


def check_device(device: str | None) -> None:
    """``--device``: a torch device name, checked as the YAML's ``device`` key is."""
    if device is None:
        return
    from sb3_dcqn.dcqn import DCQN
    from sb3_dcqn.zoo_files import check_values

    try:
        check_values({"device": device}, DCQN, "--device")
    except ValueError as error:
        raise CommandError(str(error).replace("--device: device: ", "--device: ")) from None


def training_entry(request: Request, env_id: str) -> tuple[ZooEntry, tuple[str, ...]]:
    """
    The hyperparameter entry to train with (``-params`` and levers applied), its keys checked against DCQN's before
    any work, and the levers used: those given, or the subcommand's default levers that can run with the entry's
    replay buffer (:func:`~sb3_dcqn.campusnav.levers.usable_levers`; a note names those left out).
    """
    from sb3_dcqn.campusnav.levers import check_levers, usable_levers, with_levers
    from sb3_dcqn.dcqn import DCQN
    from sb3_dcqn.zoo_files import check_hyperparams, default_hyperparams_path

    entry = zoo_entry(request.conf, env_id)
    path = default_hyperparams_path() if request.conf is None else Path(request.conf)
    try:
        check_hyperparams(entry.hyperparams, DCQN, f"{path}: entry {env_id!r}")
    except ValueError as error:
        raise CommandError(f"--conf: {error}") from None
    entry = with_params(entry, request.params)
    if request.levers is None:
        levers, left_out = usable_levers(request.default_levers, entry.hyperparams)
        for name, why in left_out.items():
            note(f"note: default lever {name!r} ({LEVERS[name].name}) left out: {why}")
    else:
        levers = request.levers
        try:
            check_levers(levers, entry.hyperparams)
        except ValueError as error:
            raise CommandError(f"--levers: {error} (entry {env_id!r} of {path})") from None
    return with_levers(entry, levers), tuple(levers)
