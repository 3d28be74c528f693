"""The hyperparameter entry a ``dcqn-campusnav`` command reads, through the one schema (:mod:`sb3_dcqn.zoo_entry`).

``--conf``'s entry (default: the shipped ``dcqn.yml``) is read once, ``-params`` applied first as the zoo applies them,
and checked before any work; a bad setting is a :class:`~sb3_dcqn.campusnav.errors.CommandError` naming the file, the
entry and the key (or ``-params`` and the key). Keys only the zoo's env building applies (``normalize``,
``frame_stack``, wrappers, ``monitor_kwargs``) and keys the command line sets itself (``seed``, ``verbose``,
``tensorboard_log``) are refused with why, never silently ignored. Importing this module is cheap (no torch, no
CampusNav).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from sb3_dcqn.campusnav.errors import CommandError, note
from sb3_dcqn.campusnav.levers import LEVERS
from sb3_dcqn.campusnav.requests import Request

if TYPE_CHECKING:
    from sb3_dcqn.zoo_entry import EntryError, ZooEntry

__all__ = [
    "NOT_APPLIED",
    "check_device",
    "checked_params",
    "conf_entry",
    "parse_params",
    "training_budget",
    "training_entry",
]

# Entry keys dcqn-campusnav does not apply, why, and the fix: each is refused, naming the file, the entry and the key
_VEC_ENV = "the route evaluation, the route memory and evaluate read the env's own observations, not a VecEnv wrapper's"
_ZOO_APPLIES = "remove it, or train with dcqn-zoo, which applies it"
NOT_APPLIED = {
    "normalize": f"VecNormalize: {_VEC_ENV}; {_ZOO_APPLIES}",
    "vec_env_wrapper": f"{_VEC_ENV}; {_ZOO_APPLIES}",
    "frame_stack": "the route evaluation gives the model one observation at a time (CampusNav's carries its heading: "
    f"nothing to stack); {_ZOO_APPLIES}",
    "env_wrapper": f"evaluate, readapt and the route evaluation build the env as registered, unwrapped; {_ZOO_APPLIES}",
    "monitor_kwargs": f"no Monitor log is kept (the summary and TensorBoard record the episodes); {_ZOO_APPLIES}",
    "seed": "--seed sets it; remove it",
    "verbose": "--verbose sets it; remove it",
    "tensorboard_log": "each run logs to tb/ in its own folder; remove it",
}


def conf_entry(conf: str | None, env_id: str, params: Sequence[str] = ()) -> ZooEntry:
    """
    The entry for ``env_id`` of ``--conf`` (default: the shipped ``dcqn.yml``), with ``-params`` applied, checked.

    :raises CommandError: naming the file, the entry and the key (``-params`` and the key for an override); for a
        key dcqn-campusnav does not apply (:data:`NOT_APPLIED`), why
    """
    from sb3_dcqn.zoo_entry import EntryError, load_zoo_entry
    from sb3_dcqn.zoo_files import default_hyperparams_path

    path = default_hyperparams_path() if conf is None else Path(conf)
    try:
        entry = load_zoo_entry(path, env_id, parse_params(params))
    except EntryError as error:
        raise _command_error(error) from None
    # One check for every key this command line does not apply: the zoo's env keys and those its flags set
    for key in (key for key in NOT_APPLIED if key in entry.zoo_settings or key in entry.hyperparams):
        raise _command_error(entry.error(key, f"not applied by dcqn-campusnav ({NOT_APPLIED[key]})"))
    return entry


def training_entry(request: Request, env_id: str) -> tuple[ZooEntry, tuple[str, ...]]:
    """
    The entry to train with (``--conf``'s, ``-params`` and levers applied) and the levers used: those given, or the
    subcommand's default levers that can run with the entry's replay buffer
    (:func:`~sb3_dcqn.campusnav.levers.usable_levers`; a note names those left out).
    """
    from sb3_dcqn.campusnav.levers import check_levers, usable_levers, with_levers

    entry = conf_entry(request.conf, env_id, request.params)
    if request.levers is None:
        levers, left_out = usable_levers(request.default_levers, entry.hyperparams)
        for name, why in left_out.items():
            note(f"note: default lever {name!r} ({LEVERS[name].name}) left out: {why}")
    else:
        levers = request.levers
        try:
            check_levers(levers, entry.hyperparams)
        except ValueError as error:
            raise CommandError(f"--levers: {error} ({entry.source})") from None
    return with_levers(entry, levers), tuple(levers)


def training_budget(entry: ZooEntry, timesteps: int | None) -> int:
    """The steps to train: ``--timesteps`` where given, else the entry's ``n_timesteps`` (refused below 1)."""
    from sb3_dcqn.zoo_entry import EntryError

    try:
        return entry.budget(timesteps)
    except EntryError as error:
        raise _command_error(error) from None


def parse_params(params: Sequence[str]) -> dict[str, Any]:
    """``-params key:value ...`` as a dict, read as ``dcqn-zoo`` reads them (:func:`sb3_dcqn.zoo_entry.read_params`:
    Python as the zoo reads it, else YAML); the entry's reading does the rest."""
    from sb3_dcqn.zoo_entry import EntryError, read_params

    try:
        return read_params(params)
    except EntryError as error:
        raise _command_error(error) from None


def checked_params(params: dict[str, Any]) -> dict[str, Any]:
    """``-params`` given without an entry (a loaded model's), checked as an entry's keys are; DCQN's arguments."""
    from sb3_dcqn.zoo_entry import EntryError, check_params

    try:
        return check_params(params)
    except EntryError as error:
        raise _command_error(error) from None


def check_device(device: str | None) -> None:
    """
    ``--device``: a torch device name, checked as an entry's ``device`` is, and one this machine has (SB3 falls back
    to the CPU without a word where CUDA or MPS is missing: a run asked for the GPU must not quietly run without it).
    """
    from sb3_dcqn.zoo_entry import value_problem

    problem = None if device is None else value_problem("device", device)
    if problem is not None:
        raise CommandError(f"--device: {problem}")
    if device is None or device in ("auto", "cpu"):
        return
    import torch as th

    kind, _, index = device.partition(":")
    if kind == "cuda":
        count = th.cuda.device_count() if th.cuda.is_available() else 0
        if count == 0:
            build = f"torch {th.__version__}, " + ("built without CUDA" if th.version.cuda is None else "no GPU found")
            raise CommandError(f"--device {device}: CUDA is not available on this machine ({build}); pass --device cpu")
        if index and int(index) >= count:
            raise CommandError(f"--device {device}: this machine has {count} CUDA device(s), cuda:0..cuda:{count - 1}")
    elif kind == "mps" and not th.backends.mps.is_available():
        raise CommandError(f"--device {device}: MPS is not available on this machine; pass --device cpu")


def _command_error(error: EntryError) -> CommandError:
    """An entry's error in the command line's words: the flag that gave the setting first."""
    return CommandError(str(error) if error.from_params else f"--conf: {error}")
