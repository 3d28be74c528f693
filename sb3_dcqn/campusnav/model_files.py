"""The files of a saved model: the zip, its replay buffer and its env settings (``<model>.env.json``), each written
atomically."""

from __future__ import annotations

import io
import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from campusnav_env.atomic_files import write_bytes_atomic, write_text_atomic
from sb3_dcqn.campusnav.buffer_files import dump_compact_buffer
from sb3_dcqn.campusnav.settings import EnvSettings
from sb3_dcqn.dcqn import DCQN

__all__ = ["SavedRun", "model_paths", "read_saved_run", "read_saved_settings", "save_model"]


def model_paths(model: Path) -> tuple[Path, Path, Path]:
    """The model zip and the files kept next to it: replay buffer and env settings."""
    stem = model.with_suffix("") if model.suffix == ".zip" else model
    return stem.with_suffix(".zip"), Path(f"{stem}_replay_buffer.pkl"), Path(f"{stem}.env.json")


@dataclass(frozen=True)
class SavedRun:
    """
    What ``<model>.env.json`` records of the run that saved a model.

    :param settings: The env it was trained on (``None``: no such file)
    :param n_envs: Its number of training envs
    :param closed_roads: The roads closed when it was saved (evaluate and readapt start from them)
    :param levers: The re-adaptation levers it was trained with (``None``: not recorded, an older file)
    :param callbacks: Its hyperparameter entry's ``callback`` specs, as :attr:`~sb3_dcqn.zoo_entry.ZooEntry.callbacks`
        (``None``: not recorded)
    """

    settings: EnvSettings | None = None
    n_envs: int = 1
    closed_roads: list[tuple[int, int]] = field(default_factory=list)
    levers: tuple[str, ...] | None = None
    callbacks: tuple[tuple[str, dict[str, Any]], ...] | None = None


def read_saved_run(model: Path) -> SavedRun:
    """
    What was saved next to a model (its env settings, closures, levers and callbacks).

    :param model: The model zip
    :return: the record (``SavedRun()`` without the file)
    :raises ValueError: if the file is not a model settings file, naming it
    """
    sidecar = model_paths(model)[2]
    if not sidecar.is_file():
        return SavedRun()
    try:
        document = json.loads(sidecar.read_text())
        levers, callbacks = document.get("levers"), document.get("callbacks")
        return SavedRun(
            settings=EnvSettings.from_json(document["settings"]),
            n_envs=int(document.get("n_envs", 1)),
            closed_roads=[(int(u), int(v)) for u, v in document.get("closed_roads_at_save") or []],
            levers=None if levers is None else tuple(str(name) for name in levers),
            callbacks=None if callbacks is None else tuple((str(path), dict(kw)) for path, kw in callbacks),
        )
    except (ValueError, KeyError, TypeError) as error:
        raise ValueError(f"{sidecar}: not a model settings file ({error!r})") from None


def read_saved_settings(model: Path) -> tuple[EnvSettings | None, int]:
    """
    The env settings and number of training envs saved next to a model.

    :param model: The model zip
    :return: the settings and the number of envs (``None, 1`` without the file)
    :raises ValueError: if the file is not a model settings file, naming it
    """
    saved = read_saved_run(model)
    return saved.settings, saved.n_envs


def save_model(
    model: DCQN,
    path: Path,
    settings: EnvSettings,
    closed_roads: Sequence[tuple[int, int]],
    replay_buffer: bool,
    levers: Sequence[str] = (),
    callbacks: Sequence[tuple[str, dict[str, Any]]] = (),
) -> list[Path]:
    """
    Save the model (and its replay buffer, as large as what it stores: :mod:`~sb3_dcqn.campusnav.buffer_files`, and
    its env settings), each file atomically; returns the paths.

    Every file is serialised before any is written, and the model zip is written last: a save that fails writes
    nothing, and a model zip is never left without the settings file that says which closures it was trained under.

    :param closed_roads: The roads closed now (``closed_roads_at_save``)
    :param levers: The re-adaptation levers it trains with (readapt's default)
    :param callbacks: Its entry's ``callback`` specs (readapt builds them anew)
    """
    zip_path, buffer_path, sidecar = model_paths(path)
    model_data = io.BytesIO()
    model.save(model_data)
    buffer_data = None
    if replay_buffer:
        buffer_data = io.BytesIO()
        dump_compact_buffer(model.replay_buffer, buffer_data)  # as large as what it stores; load_replay_buffer reads it
    document = {
        "settings": settings.to_json(),
        "num_timesteps": model.num_timesteps,
        "n_envs": model.n_envs,
        "closed_roads_at_save": [list(road) for road in closed_roads],
        "levers": list(levers),
        "callbacks": [[path, kwargs] for path, kwargs in callbacks],
    }
    zip_path.parent.mkdir(parents=True, exist_ok=True)
    written = [] if buffer_data is None else [write_bytes_atomic(buffer_path, buffer_data.getvalue())]
    written.append(write_text_atomic(sidecar, json.dumps(document, indent=2) + "\n"))
    written.insert(0, write_bytes_atomic(zip_path, model_data.getvalue()))
    return written
