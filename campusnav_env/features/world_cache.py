"""
The 3D world of a big map, kept in the feature cache folder so that a resumed view build does not place it again.

Placing a map's buildings, trees and parks (:func:`~campusnav_env.rendering.world.build_world`) is what comes before
the first view of a cold build, and it is redone whenever the world is needed again: a build interrupted and resumed,
or visible closures' barrier views on a map whose open views are cached. Its time grows with the map (about 22 s at
3,000 intersections on one core of a 2-core EPYC, 84 s at 10,000, minutes at 56,000), while reading it back takes a
second or a few. So on maps of at least :data:`MIN_NODES_FOR_WORLD_CACHE` intersections the world is written next to
the view caches the first time it is placed (``world-<key>.pkl``, a few kB per intersection; atomically: a temporary
file, then a rename) and read from there afterwards. The key is the road graph's fingerprint, the placement seed and
the world generator's version, so a changed map, seed or generator never reads another world.

The file is a pickle of the user's own cache folder, trusted as that folder's view caches are. One that cannot be
read, or that holds another map's world, is rebuilt (with a warning) and replaced; deleting it only costs the next
build the placement.
"""

from __future__ import annotations

import hashlib
import pickle
import warnings
from pathlib import Path

from campusnav_env.atomic_files import write_bytes_atomic
from campusnav_env.features.feature_cache import default_cache_dir
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.scene import WORLD_VERSION, World
from campusnav_env.rendering.world import build_world

__all__ = ["MIN_NODES_FOR_WORLD_CACHE", "cached_world", "world_cache_path"]

# Below this the placement takes seconds at most (7-13 s at 1,000 intersections), about what the file saves
MIN_NODES_FOR_WORLD_CACHE = 2_000


def world_cache_path(graph: RoadGraph, seed: int, cache_dir: str | Path | None = None) -> Path:
    """The file that :func:`cached_world` reads and writes for ``graph`` and ``seed``."""
    key = hashlib.sha256(f"campusnav-world-v{WORLD_VERSION}|{graph.fingerprint()}|seed{int(seed)}".encode())
    directory = default_cache_dir() if cache_dir is None else Path(cache_dir)
    return directory / f"world-{key.hexdigest()[:24]}.pkl"


def _read(path: Path, graph: RoadGraph, seed: int) -> World | None:
    """The world stored at ``path`` if it is this map's and seed's; None (with a warning) if it is not readable."""
    try:
        with path.open("rb") as file:
            world = pickle.load(file)
    except (FileNotFoundError, NotADirectoryError):  # not placed yet (or no folder to hold it)
        return None
    except Exception as error:  # a truncated or foreign file: any unpickling error means "build it again"
        warnings.warn(f"world cache {path} could not be read ({error!r}); placing the world again", stacklevel=4)
        return None
    if not isinstance(world, World) or world.graph.fingerprint() != graph.fingerprint() or world.seed != int(seed):
        warnings.warn(f"world cache {path} holds another map's world; placing the world again", stacklevel=4)
        return None
    return world


def cached_world(graph: RoadGraph, seed: int, cache_dir: str | Path | None = None) -> World:
    """
    The 3D world of ``graph`` and ``seed``: read from the cache folder where it was placed before, else placed now
    and, on maps of at least :data:`MIN_NODES_FOR_WORLD_CACHE` intersections, written there.

    :param graph: The road network
    :param seed: Placement seed (:func:`~campusnav_env.rendering.world.build_world`)
    :param cache_dir: The feature cache folder (None: ``$CAMPUSNAV_CACHE`` or ``~/.cache/campusnav``)
    :return: The world, equal to ``build_world(graph, seed=seed)``
    """
    if graph.n_nodes < MIN_NODES_FOR_WORLD_CACHE:
        return build_world(graph, seed=seed)
    path = world_cache_path(graph, seed, cache_dir)
    world = _read(path, graph, seed)
    if world is not None:
        return world
    world = build_world(graph, seed=seed)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, pickle.dumps(world, protocol=pickle.HIGHEST_PROTOCOL))
    except OSError as error:  # a full or read-only disk costs the next build the placement, nothing else
        warnings.warn(f"the world could not be kept at {path} ({error}); a resumed build places it again", stacklevel=3)
    return world
