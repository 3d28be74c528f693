"""The files of a saved model: the zip, its replay buffer and its env settings (``<model>.env.json``), each written
atomically."""

from __future__ import annotations

import io
import json
from collections.abc import Sequence
from pathlib import Path

from campusnav_env.atomic_files import write_bytes_atomic, write_text_atomic
from sb3_dcqn.campusnav.settings import EnvSettings
from sb3_dcqn.dcqn import DCQN

__all__ = ["model_paths", "read_saved_settings", "save_model"]


def model_paths(model: Path) -> tuple[Path, Path, Path]:
    """The model zip and the files kept next to it: replay buffer and env settings."""
    stem = model.with_suffix("") if model.suffix == ".zip" else model
    return stem.with_suffix(".zip"), Path(f"{stem}_replay_buffer.pkl"), Path(f"{stem}.env.json")


def read_saved_settings(model: Path) -> tuple[EnvSettings | None, int]:
    """
    The env settings and number of training envs saved next to a model.

    :param model: The model zip
    :return: the settings and the number of envs (``None, 1`` without the file)
    :raises ValueError: if the file is not a model settings file, naming it
    """
    sidecar = model_paths(model)[2]
    if not sidecar.is_file():
        return None, 1
    try:
        document = json.loads(sidecar.read_text())
        return EnvSettings.from_json(document["settings"]), int(document.get("n_envs", 1))
    except (ValueError, KeyError, TypeError) as error:
        raise ValueError(f"{sidecar}: not a model settings file ({error})") from None


def save_model(
    model: DCQN, path: Path, settings: EnvSettings, closed_roads: Sequence[tuple[int, int]], replay_buffer: bool
) -> list[Path]:
    """Save the model (and its replay buffer and env settings), each file atomically; returns the paths."""
    zip_path, buffer_path, sidecar = model_paths(path)
    zip_path.parent.mkdir(parents=True, exist_ok=True)
    data = io.BytesIO()
    model.save(data)
    written = [write_bytes_atomic(zip_path, data.getvalue())]
    if replay_buffer:
        data = io.BytesIO()
        model.save_replay_buffer(data)
        written.append(write_bytes_atomic(buffer_path, data.getvalue()))
    document = {
        "settings": settings.to_json(),
        "num_timesteps": model.num_timesteps,
        "n_envs": model.n_envs,
        "closed_roads_at_save": [list(road) for road in closed_roads],
    }
    written.append(write_text_atomic(sidecar, json.dumps(document, indent=2) + "\n"))
    return written
