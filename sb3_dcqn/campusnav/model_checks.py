"""The model files named on the ``dcqn-campusnav`` command line: a readable model zip, and what was saved beside it.

Importing this module is cheap (no torch, no CampusNav): each check imports what it needs.
"""

from __future__ import annotations

import zipfile
from pathlib import Path
from typing import TYPE_CHECKING

from sb3_dcqn.campusnav.errors import CommandError

if TYPE_CHECKING:
    from sb3_dcqn.campusnav.model_files import SavedRun

__all__ = ["MODEL_FILES", "MODEL_NAME", "find_model", "saved_run"]

MODEL_NAME = "dcqn_campusnav"
MODEL_FILES = f"give a {MODEL_NAME}.zip saved by train, demo or readapt (or by DCQN.save)"


def find_model(path: str, flag: str = "") -> Path:
    """
    The model zip named on the command line: it exists and is a readable model file (``runs/x/dcqn_campusnav`` names
    ``runs/x/dcqn_campusnav.zip``, as ``DCQN.load`` reads it).
    """
    from sb3_dcqn.campusnav.model_files import model_paths

    given = Path(path)
    named = f"{flag} {path}" if flag else path
    model = given if given.is_file() else model_paths(given)[0]
    if given.is_dir():
        inside = given / f"{MODEL_NAME}.zip"
        hint = f" (it holds {inside}: give that)" if inside.is_file() else ""
        raise CommandError(f"{named}: is a folder, not a model file{hint}; {MODEL_FILES}")
    if not model.is_file():
        raise CommandError(f"model file not found: {named}")
    if model.suffix != ".zip" and not zipfile.is_zipfile(model):
        raise CommandError(f"{named}: not a model zip (a model is a .zip file written by DCQN.save); {MODEL_FILES}")
    try:
        with zipfile.ZipFile(model) as archive:
            problem = None if "data" in archive.namelist() else "no 'data' entry"
    except (zipfile.BadZipFile, OSError) as error:
        problem = str(error)
    if problem is not None:
        raise CommandError(f"{model}: not a readable model file ({problem}); {MODEL_FILES}")
    return model


def saved_run(model: Path) -> SavedRun:
    """What was saved next to a model: env settings, training envs, closures, levers (``SavedRun()`` if nothing)."""
    from sb3_dcqn.campusnav.model_files import read_saved_run

    try:
        return read_saved_run(model)
    except ValueError as error:
        raise CommandError(str(error)) from None
