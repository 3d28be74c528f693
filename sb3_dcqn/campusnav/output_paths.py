"""Where ``dcqn-campusnav`` writes: run folders and pictures that never replace earlier results, checked before any
work (a folder that cannot be made, a picture that is no PNG), and the feature cache's folder.

Importing this module is cheap (no torch, no CampusNav).
"""

from __future__ import annotations

import os
import re
import tempfile
from collections.abc import Callable
from pathlib import Path

from sb3_dcqn.campusnav.errors import CommandError, note
from sb3_dcqn.campusnav.model_checks import MODEL_NAME

__all__ = [
    "DEFAULT_OUT",
    "RESULT_NAMES",
    "check_cache",
    "check_folder",
    "free_folder",
    "free_picture",
    "holds_results",
    "moved_note",
]

# Each training subcommand's own output folder, so that one never replaces another's results
DEFAULT_OUT = {"demo": "runs/campusnav-demo", "train": "runs/campusnav-train"}
PICTURE_SUFFIXES = (".png",)  # what campusnav_env.figures.write_figure writes
# The files a run writes into its folder: a folder holding any of them holds an earlier run's results
RESULT_NAMES = (
    "summary.json",
    "summary.md",
    "tb",
    "routes.png",
    "curves.png",
    "checkpoints",
    f"{MODEL_NAME}.zip",
    f"{MODEL_NAME}.env.json",
    f"{MODEL_NAME}_replay_buffer.pkl",
)


def check_folder(folder: Path, flag: str, given: Path | None = None) -> None:
    """
    An output folder that can be made: no part of it is a file, and its nearest existing folder is writable.

    :param given: The path the flag gave, for the message (default: ``folder``; a file's path for its folder)
    """
    given = folder if given is None else given
    for part in (folder, *folder.parents):
        if part.exists() or part.is_symlink():
            if not part.is_dir():
                where = "is a file" if part == given else f"is inside {part}, a file"
                raise CommandError(f"{flag} {given}: {where}, not a folder")
            if not os.access(part, os.W_OK | os.X_OK):
                raise CommandError(f"{flag} {given}: cannot write in {part}")
            try:  # access() says yes to root everywhere, /proc included: try it
                os.rmdir(tempfile.mkdtemp(prefix=".dcqn-campusnav-", dir=part))
            except OSError as error:
                raise CommandError(f"{flag} {given}: cannot write in {part} ({error.strerror or error})") from None
            return


def holds_results(folder: Path) -> bool:
    """Whether a folder holds a run's results (any file a run writes: :data:`RESULT_NAMES`)."""
    return folder.is_dir() and any((folder / name).exists() for name in RESULT_NAMES)


def _numbered(path: Path, number: int) -> Path:
    """``runs/fixed`` -> ``runs/fixed_2``; ``map.png`` -> ``map_2.png``."""
    return path.with_name(f"{path.stem}_{number}{path.suffix}")


def _first_free(path: Path, taken: Callable[[Path], bool]) -> Path:
    """The first numbered path after ``path`` (``_2``, ``_3``, ...) that is not ``taken``."""
    number = 2
    while taken(_numbered(path, number)):
        number += 1
    return _numbered(path, number)


def free_folder(out: Path, force: bool, flag: str = "--out") -> Path:
    """
    The folder a run writes to: ``out``, or where it holds an earlier run's results the first free numbered folder
    next to it (``runs/fixed`` -> ``runs/fixed_2``, as the RL Zoo numbers its runs; :func:`moved_note` says so once
    the input is checked); ``--force`` writes into ``out`` all the same.
    """
    if force or not holds_results(out):
        check_folder(out, flag)
        return out
    out = Path(os.path.abspath(out)) if not out.name else out  # "." has no name to number
    numbered = re.fullmatch(r"(.+)_\d+", out.name)
    if numbered and out.with_name(numbered.group(1)).is_dir():  # runs/x_2 taken: runs/x_3, not runs/x_2_2
        out = out.with_name(numbered.group(1))
    free = _first_free(out, holds_results)
    check_folder(free, flag, given=free)
    return free


def moved_note(asked: Path, free: Path, flag: str = "--out") -> None:
    """Say where a run writes instead of a folder that holds an earlier run's results (:func:`free_folder`)."""
    if free != asked:
        note(f"{flag} {asked} holds an earlier run's results (kept): writing to {free} (--force: write into {asked})")


def free_picture(path: str | None, force: bool, flag: str = "--picture") -> Path | None:
    """
    A picture path that can be written (checked before anything is computed): where the picture or its route text
    (``map.png``: ``map.txt``) exists, the first free numbered name (``map_2.png``), unless ``--force``.
    """
    if path is None:
        return None
    picture = Path(path)
    if picture.is_dir():
        raise CommandError(f"{flag} {picture}: is a folder; give a file name such as {picture / 'map.png'}")
    if picture.suffix.lower() not in PICTURE_SUFFIXES:
        raise CommandError(
            f"{flag} {picture}: pictures are written as PNG; give a name ending in {', '.join(PICTURE_SUFFIXES)} "
            f"(e.g. {picture.with_suffix('.png')})"
        )
    check_folder(picture.parent, flag, given=picture)

    def taken(candidate: Path) -> bool:
        return candidate.exists() or candidate.with_suffix(".txt").exists()

    if force or not taken(picture):
        return picture
    return _first_free(picture, taken)


def check_cache() -> None:
    """The feature cache's folder (``$CAMPUSNAV_CACHE``) can be made and written, before any view is rendered."""
    from campusnav_env.features.feature_cache import default_cache_dir

    check_folder(default_cache_dir(), "$CAMPUSNAV_CACHE")
