"""On-disk cache of per-node view encodings.

Rendering four 640x480 views per intersection and running a CNN over them takes seconds to minutes, so the result is
computed once per (world, renderer settings, encoder, number of nodes) and stored as
``<cache_dir>/views-<key[:24]>.npz``. The key is a sha256 over :data:`CACHE_FORMAT_VERSION`, the caller's key parts,
the encoder's name and output shape/dtype and the number of nodes; the file records the full key and a checksum of the
array, and a file that fails either check (or cannot be read) is reported with a warning and rebuilt. Files are
written to a temporary file in the same directory and moved into place with :func:`os.replace`, so readers never see a
partial file.

Processes that need the same missing file at the same time (parallel envs, jobs sharing ``$CAMPUSNAV_CACHE``) build it
once. The builder holds ``<cache file>.lock`` with the operating system's file lock (:class:`filelock.FileLock`:
``flock`` on POSIX, ``LockFileEx`` on Windows), which the OS releases when the process ends, however it ends (a
crash, ``kill -9``): a dead builder never blocks the next one. The others warn that they wait for it, naming the
builder's pid and host (from ``<cache file>.lock.owner``, which the builder writes while it holds the lock), and once
they hold the lock find the file valid and load it. The lock is released in a ``finally``, also on exceptions and
Ctrl-C; the empty lock file may stay behind (the lock is the OS's, not the file's existence). Waiting ends after
``lock_timeout`` seconds (default :data:`DEFAULT_LOCK_TIMEOUT`, or ``$CAMPUSNAV_CACHE_LOCK_TIMEOUT``) with a
:class:`TimeoutError` that names the lock file and its owner. Loading a valid file takes no lock, so a read-only cache
directory works.

A build resumes where a killed one stopped (Ctrl-C, the OOM killer, a lost node): :func:`cached_batched_features`
stores each batch of nodes as it finishes in ``<cache file>.shards/nodes-<start>-<stop>.npz`` (temp file, then
:func:`os.replace`; each shard records the cache key, its nodes and a checksum), and the next builder of the same
file loads the valid shards and builds only the other batches. A torn or foreign shard fails its checks and is built
again, never read. Once every batch is in, the cache file is written as before (readers see no change) and the shards
are removed.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
import shutil
import socket
import tempfile
import time
import warnings
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np
from filelock import FileLock, Timeout
from tqdm import tqdm

from campusnav_env.atomic_files import write_text_atomic
from campusnav_env.features.encoders import ViewEncoder

__all__ = [
    "CACHE_FORMAT_VERSION",
    "DEFAULT_LOCK_TIMEOUT",
    "LOCK_TIMEOUT_ENV",
    "BatchBuild",
    "cache_key",
    "cache_path",
    "cached_batched_features",
    "cached_features",
    "cached_view_features",
    "collect_batches",
    "default_cache_dir",
    "encode_batches",
    "encode_every_node",
    "encode_nodes",
    "lock_paths",
    "node_batches",
    "render_nodes",
    "shard_dir",
]

logger = logging.getLogger(__name__)

# A build that yields each finished batch of nodes with its encodings, given the batches to build (in any order)
BatchBuild = Callable[[Sequence[range]], Iterable[tuple[range, np.ndarray]]]

# Bump when the file layout or the meaning of cached arrays changes: old files then simply stop matching.
CACHE_FORMAT_VERSION = 1
VIEWS_PER_NODE = 4
# Views encoded per call: amortises CNN batching (32 views = 8 nodes) while bounding memory (~30 MB at 640x480).
VIEWS_PER_BATCH = 32

# Seconds to wait for another process building the same cache: a ResNet-50 pass over a large map on a CPU takes tens
# of minutes, so an hour only gives up on owners that hang or died on another host.
DEFAULT_LOCK_TIMEOUT = 3600.0
LOCK_TIMEOUT_ENV = "CAMPUSNAV_CACHE_LOCK_TIMEOUT"


def default_cache_dir() -> Path:
    """Return ``$CAMPUSNAV_CACHE`` if set, else ``~/.cache/campusnav``."""
    env = os.environ.get("CAMPUSNAV_CACHE")
    return Path(env).expanduser() if env else Path.home() / ".cache" / "campusnav"


def _check_key_parts(key_parts: Mapping[str, str]) -> dict[str, str]:
    if not isinstance(key_parts, Mapping):
        raise TypeError(f"key_parts must be a mapping of str to str, got {type(key_parts).__name__}")
    for k, v in key_parts.items():
        if not isinstance(k, str) or not isinstance(v, str):
            raise TypeError(f"key_parts must map str to str, got {k!r}: {v!r}")
    return dict(sorted(key_parts.items()))


def _check_n_nodes(n_nodes: int) -> int:
    if isinstance(n_nodes, bool) or not isinstance(n_nodes, (int, np.integer)) or n_nodes < 1:
        raise ValueError(f"n_nodes must be a positive integer, got {n_nodes!r}")
    return int(n_nodes)


def _key_document(key_parts: Mapping[str, str], n_nodes: int, encoder: ViewEncoder) -> dict[str, object]:
    return {
        "format_version": CACHE_FORMAT_VERSION,
        "key_parts": _check_key_parts(key_parts),
        "encoder": encoder.name,
        "output_shape": [int(d) for d in encoder.output_shape],
        "dtype": np.dtype(encoder.dtype).str,
        "n_nodes": _check_n_nodes(n_nodes),
    }


def cache_key(key_parts: Mapping[str, str], n_nodes: int, encoder: ViewEncoder) -> str:
    """Return the sha256 hex key of a cache entry (independent of the order of ``key_parts``)."""
    document = json.dumps(_key_document(key_parts, n_nodes, encoder), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(document.encode("utf-8")).hexdigest()


def cache_path(
    key_parts: Mapping[str, str], n_nodes: int, encoder: ViewEncoder, *, cache_dir: str | Path | None = None
) -> Path:
    """Return the file that :func:`cached_view_features` reads and writes for these arguments."""
    directory = default_cache_dir() if cache_dir is None else Path(cache_dir)
    return directory / f"views-{cache_key(key_parts, n_nodes, encoder)[:24]}.npz"


def _checksum(array: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(array).data).hexdigest()


def _load(path: Path, key: str, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    """Read and verify a cache file; raise ValueError saying what is wrong."""
    try:
        # Open the file ourselves: np.load leaks its handle when the archive is unreadable.
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as data:
            features = data["features"]
            meta = json.loads(str(data["meta"]))
    except Exception as e:  # truncated or foreign files fail in many ways (BadZipFile, EOFError, KeyError, ...)
        raise ValueError(f"unreadable ({type(e).__name__}: {e})") from e
    if not isinstance(meta, dict) or meta.get("key") != key:
        raise ValueError("key mismatch (written for other inputs)")
    if features.shape != shape or features.dtype != dtype:
        raise ValueError(f"array is {features.shape} {features.dtype}, expected {shape} {dtype}")
    if meta.get("checksum") != _checksum(features):
        raise ValueError("checksum mismatch (array damaged)")
    return features


def _ensure_writable_dir(directory: Path) -> None:
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise type(e)(e.errno, f"cannot create cache directory {directory}: {e.strerror or e}") from e
    if not os.access(directory, os.W_OK | os.X_OK):
        raise PermissionError(f"cache directory {directory} is not writable; set $CAMPUSNAV_CACHE or pass cache_dir")


def _save_atomic(path: Path, features: np.ndarray, meta: Mapping[str, object], *, durable: bool = True) -> None:
    """
    Write the npz to a temp file in the same directory, fsync it (where ``durable``), then rename it over ``path``.
    Shards skip the fsyncs: one lost or torn by a power cut fails its checksum and is built again.
    """
    tmp_name: str | None = None
    try:
        with tempfile.NamedTemporaryFile(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp", delete=False) as tmp:
            tmp_name = tmp.name
            # Saving to the open handle: given a file name, numpy would append ".npz" to it.
            np.savez(tmp, features=features, meta=np.array(json.dumps(meta, sort_keys=True)))
            tmp.flush()
            if durable:
                os.fsync(tmp.fileno())
        os.replace(tmp_name, path)
    except BaseException:
        if tmp_name is not None:
            with contextlib.suppress(OSError):
                os.unlink(tmp_name)
        raise
    if not durable:
        return
    # Make the rename itself durable where the platform allows fsync on a directory.
    with contextlib.suppress(OSError):
        fd = os.open(path.parent, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _check_views(views: object, node: int, first: tuple[int, ...] | None) -> np.ndarray:
    if not isinstance(views, np.ndarray):
        raise ValueError(f"render_node({node}) returned {type(views).__name__}, expected a numpy array (4, H, W, 3)")
    if views.ndim != 4 or views.shape[0] != VIEWS_PER_NODE or views.shape[3] != 3:
        raise ValueError(f"render_node({node}) returned shape {views.shape}, expected (4, H, W, 3) in N, E, S, W order")
    if views.dtype != np.uint8:
        raise ValueError(f"render_node({node}) returned dtype {views.dtype}, expected uint8 RGB")
    if first is not None and views.shape != first:
        raise ValueError(f"render_node({node}) returned shape {views.shape}, but earlier nodes gave {first}")
    return views


def render_nodes(
    nodes: Sequence[int], render_node: Callable[[int], np.ndarray], view_shape: tuple[int, ...] | None = None
) -> np.ndarray:
    """
    Render and check the four views of each node.

    :param nodes: The nodes, in order
    :param render_node: ``render_node(node)`` returns the node's views, ``(4, H, W, 3)`` uint8 RGB in N, E, S, W order
    :param view_shape: The ``(4, H, W, 3)`` shape earlier nodes gave (None: take the first node's)
    :return: ``(4 * len(nodes), H, W, 3)``, node after node
    :raises ValueError: if a node's views have the wrong type, shape or dtype
    """
    batch = []
    for node in nodes:
        views = _check_views(render_node(node), node, view_shape)
        view_shape = views.shape
        batch.append(views)
    return np.concatenate(batch)


def encode_nodes(views: np.ndarray, encoder: ViewEncoder) -> np.ndarray:
    """
    Encode the views of :func:`render_nodes` and check the encoder's output.

    :param views: ``(4 * n, H, W, 3)`` uint8 views, node after node
    :param encoder: The encoder
    :return: ``(n, 4, *encoder.output_shape)``
    :raises ValueError: if the encoder returned the wrong shape
    """
    n_nodes = len(views) // VIEWS_PER_NODE
    encoded = np.asarray(encoder.encode(views))
    want = (len(views), *encoder.output_shape)
    if encoded.shape != want:
        raise ValueError(f"encoder {encoder.name!r} returned shape {encoded.shape}, expected {want}")
    return encoded.reshape(n_nodes, VIEWS_PER_NODE, *encoder.output_shape)


def node_batches(n_nodes: int) -> list[range]:
    """The nodes ``0 .. n_nodes - 1`` in the batches that are rendered and then encoded in one call."""
    nodes_per_batch = max(1, VIEWS_PER_BATCH // VIEWS_PER_NODE)
    return [range(start, min(start + nodes_per_batch, n_nodes)) for start in range(0, n_nodes, nodes_per_batch)]


def encode_batches(
    batches: Sequence[range], render_node: Callable[[int], np.ndarray], encoder: ViewEncoder
) -> Iterator[tuple[range, np.ndarray]]:
    """
    Render and encode batches of nodes in this process (the serial build, a :data:`BatchBuild`).

    :param batches: The batches (of :func:`node_batches`)
    :param render_node: As for :func:`cached_view_features`
    :param encoder: Encoder applied to the views
    :return: Each batch with its ``(len(batch), 4, *encoder.output_shape)`` encodings, as it finishes
    """
    view_shape: tuple[int, ...] | None = None
    for nodes in batches:
        views = render_nodes(nodes, render_node, view_shape)
        view_shape = (VIEWS_PER_NODE, *views.shape[1:])
        yield nodes, encode_nodes(views, encoder)


def _progress_bar(n_nodes: int, encoder: ViewEncoder, progress: bool, initial: int = 0) -> tqdm:
    return tqdm(total=n_nodes, initial=initial, desc=progress_label(encoder), unit="node", disable=not progress)


def collect_batches(
    n_nodes: int, encoder: ViewEncoder, batches: Iterable[tuple[range, np.ndarray]], progress: bool
) -> np.ndarray:
    """
    Fill every node's encodings from a build's batches, advancing a progress bar as each one arrives.

    :param n_nodes: Number of nodes
    :param encoder: The encoder the batches come from (shape and dtype of the array)
    :param batches: ``(nodes, encodings)`` pairs covering nodes ``0 .. n_nodes - 1``
    :param progress: Show a tqdm progress bar
    :return: ``(n_nodes, 4, *encoder.output_shape)`` array of dtype ``encoder.dtype``
    """
    features = np.empty((n_nodes, VIEWS_PER_NODE, *encoder.output_shape), dtype=encoder.dtype)
    with _progress_bar(n_nodes, encoder, progress) as bar:
        for nodes, encoded in batches:
            features[nodes.start : nodes.stop] = encoded
            bar.update(len(nodes))
    return features


def encode_every_node(
    n_nodes: int, render_node: Callable[[int], np.ndarray], encoder: ViewEncoder, progress: bool
) -> np.ndarray:
    """
    Render and encode every node's views in this process, in batches of :func:`node_batches` (the serial build).

    :param n_nodes: Number of nodes; nodes ``0 .. n_nodes - 1`` are rendered
    :param render_node: As for :func:`cached_view_features`
    :param encoder: Encoder applied to the views
    :param progress: Show a tqdm progress bar
    :return: ``(n_nodes, 4, *encoder.output_shape)`` array of dtype ``encoder.dtype``
    """
    return collect_batches(n_nodes, encoder, encode_batches(node_batches(n_nodes), render_node, encoder), progress)


def progress_label(encoder: ViewEncoder) -> str:
    """The progress bar's description of a feature build."""
    return f"encoding views ({encoder.name})"


def _resolve_lock_timeout(lock_timeout: float | None) -> float:
    """Return the lock timeout in seconds: the argument, else ``$CAMPUSNAV_CACHE_LOCK_TIMEOUT``, else the default."""
    source: str = "lock_timeout"
    value: object = lock_timeout
    if lock_timeout is None:
        source = f"${LOCK_TIMEOUT_ENV}"
        value = os.environ.get(LOCK_TIMEOUT_ENV, "").strip() or DEFAULT_LOCK_TIMEOUT
    try:
        seconds = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        seconds = float("nan")
    if isinstance(value, bool) or not seconds >= 0:  # `not >=` also rejects NaN
        raise ValueError(f"{source} must be a number of seconds >= 0, got {value!r}")
    return seconds


def lock_paths(path: Path) -> tuple[Path, Path]:
    """The lock file of a cache file, and the file in which its builder records who it is."""
    return path.with_name(path.name + ".lock"), path.with_name(path.name + ".lock.owner")


def _read_owner(owner_file: Path) -> str:
    """Who holds the lock, as its owner file says (it may be missing for the instant after the lock is taken)."""
    try:
        record = json.loads(owner_file.read_text(encoding="utf-8"))
        started = time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(float(record["since"])))
        return f"pid {int(record['pid'])} on host {record['host']!r} since {started}"
    except (OSError, ValueError, KeyError, TypeError):
        return "a process that has not recorded itself yet"


@contextlib.contextmanager
def _build_lock(path: Path, timeout: float) -> Iterator[None]:
    """
    Hold the lock of the cache file ``path`` (see the module docstring), waiting up to ``timeout`` seconds for it.

    :raises TimeoutError: if another process still holds it after ``timeout`` seconds
    """
    lock_file, owner_file = lock_paths(path)
    lock = FileLock(lock_file)
    try:
        lock.acquire(timeout=0)
    except Timeout:
        owner = _read_owner(owner_file)
        warnings.warn(
            f"waiting for another process ({owner}) that is building the same feature cache {path} "
            f"(lock file {lock_file}, timeout {timeout:g} s)",
            RuntimeWarning,
            stacklevel=4,  # the caller of cached_features, past contextlib's __enter__
        )
        try:
            lock.acquire(timeout=timeout)
        except Timeout:
            owner = _read_owner(owner_file)
            raise TimeoutError(
                f"gave up after {timeout:g} s waiting for the lock file {lock_file}, held by {owner}, "
                f"which is building the feature cache {path}. The lock is the operating system's and ends with that "
                f"process; to wait longer pass lock_timeout or set ${LOCK_TIMEOUT_ENV}"
            ) from None
    try:
        record = {"pid": os.getpid(), "host": socket.gethostname(), "since": time.time()}
        write_text_atomic(owner_file, json.dumps(record))
        yield
    finally:
        try:
            owner_file.unlink(missing_ok=True)
        finally:
            lock.release()


def shard_dir(path: Path) -> Path:
    """The directory in which a build of the cache file ``path`` keeps its finished batches until it is done."""
    return path.with_name(path.name + ".shards")


_SHARD_NAME = re.compile(r"nodes-(\d+)-(\d+)\.npz")


class _Shards:
    """
    A build's finished batches on disk (see the module docstring): each stored as it finishes, loaded by the next
    builder where the build was killed.

    :param path: The cache file being built
    :param key: Its key
    :param encoder: The encoder (shape and dtype of each shard)
    """

    def __init__(self, path: Path, key: str, encoder: ViewEncoder) -> None:
        self.directory = shard_dir(path)
        self.key = key
        self.encoding = (VIEWS_PER_NODE, *encoder.output_shape)
        self.dtype = np.dtype(encoder.dtype)

    def _path(self, nodes: range) -> Path:
        return self.directory / f"nodes-{nodes.start}-{nodes.stop}.npz"

    def _key(self, nodes: range) -> str:
        return f"{self.key}|nodes={nodes.start}-{nodes.stop}"

    def load(self, batches: Sequence[range]) -> dict[range, np.ndarray]:
        """The valid shards of ``batches``; torn, damaged or foreign ones are left to be built again."""
        wanted = set(batches)
        found: dict[range, np.ndarray] = {}
        with contextlib.suppress(FileNotFoundError):
            for entry in os.scandir(self.directory):
                match = _SHARD_NAME.fullmatch(entry.name)  # temp files of a killed writer do not match
                nodes = range(int(match[1]), int(match[2])) if match else None
                if nodes not in wanted:
                    continue
                shape = (len(nodes), *self.encoding)
                try:
                    found[nodes] = _load(Path(entry.path), self._key(nodes), shape, self.dtype)
                except ValueError as e:
                    logger.info("feature cache shard %s is invalid (%s): building its nodes again", entry.path, e)
        return found

    def save(self, nodes: range, encoded: np.ndarray) -> None:
        """Store one finished batch (temp file, then rename: a torn shard never has a shard's name)."""
        self.directory.mkdir(exist_ok=True)
        meta = {"key": self._key(nodes), "checksum": _checksum(encoded)}
        _save_atomic(self._path(nodes), encoded, meta, durable=False)

    def remove(self, *, only_if_empty: bool = False) -> None:
        """Delete the shards (the cache file holds them all), or only an empty directory (a build that failed)."""
        if only_if_empty:
            with contextlib.suppress(OSError):
                self.directory.rmdir()
        else:
            shutil.rmtree(self.directory, ignore_errors=True)


def _check_batch(nodes: range, encoded: object, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
    want = (len(nodes), *shape[1:])
    if not isinstance(encoded, np.ndarray) or encoded.shape != want or encoded.dtype != dtype:
        got = f"{encoded.shape} {encoded.dtype}" if isinstance(encoded, np.ndarray) else type(encoded).__name__
        raise ValueError(f"the feature build returned {got} for nodes {nodes.start}-{nodes.stop - 1}, expected {want}")
    return encoded


def cached_view_features(
    key_parts: Mapping[str, str],
    n_nodes: int,
    render_node: Callable[[int], np.ndarray],
    encoder: ViewEncoder,
    *,
    cache_dir: str | Path | None = None,
    progress: bool = True,
    lock_timeout: float | None = None,
) -> np.ndarray:
    """
    Return the encodings of every node's four views, computing and caching them on first use (resuming a build
    that was killed, see the module docstring).

    :param key_parts: Everything besides the encoder that determines the views, as strings (e.g.
        ``{"world": world.fingerprint(), "render": settings.key()}``); order does not matter
    :param n_nodes: Number of nodes; nodes ``0 .. n_nodes - 1`` are rendered
    :param render_node: ``render_node(node)`` returns the node's views, ``(4, H, W, 3)`` uint8 RGB in N, E, S, W order
    :param encoder: Encoder applied to the views
    :param cache_dir: Cache directory; None uses :func:`default_cache_dir`
    :param progress: Show a tqdm progress bar while computing
    :param lock_timeout: Seconds to wait while another process builds the same file (see the module docstring); None
        reads ``$CAMPUSNAV_CACHE_LOCK_TIMEOUT``, else :data:`DEFAULT_LOCK_TIMEOUT`
    :return: ``(n_nodes, 4, *encoder.output_shape)`` array of dtype ``encoder.dtype``
    :raises ValueError: if ``render_node`` or the encoder returned arrays of the wrong shape or dtype, ``n_nodes`` < 1
        or the lock timeout is not a number >= 0
    :raises PermissionError: if the cache directory is not writable (other ``OSError`` if it cannot be created)
    :raises TimeoutError: if another process still holds the file's lock after ``lock_timeout`` seconds
    """
    return cached_batched_features(
        key_parts,
        n_nodes,
        encoder,
        lambda batches: encode_batches(batches, render_node, encoder),
        cache_dir=cache_dir,
        progress=progress,
        lock_timeout=lock_timeout,
    )


def cached_batched_features(
    key_parts: Mapping[str, str],
    n_nodes: int,
    encoder: ViewEncoder,
    build: BatchBuild,
    *,
    cache_dir: str | Path | None = None,
    progress: bool = True,
    lock_timeout: float | None = None,
) -> np.ndarray:
    """
    :func:`cached_view_features` with the build given as a :data:`BatchBuild`: ``build(batches)`` yields each of
    ``batches`` (of :func:`node_batches`) with its encodings as it finishes, in this process, in worker processes
    (:mod:`campusnav_env.features.parallel_build`) or on a Ray cluster (:mod:`campusnav_env.features.ray_build`).
    Called only on a cache miss, under the file's lock, with the batches that a killed build left undone; each batch
    is checked and stored as a shard as it arrives, then the whole array is stored atomically.

    :param key_parts: As for :func:`cached_view_features`
    :param n_nodes: Number of nodes
    :param encoder: The encoder the build uses (its name, shape and dtype key the file)
    :param build: The build
    :param cache_dir: Cache directory; None uses :func:`default_cache_dir`
    :param progress: Show a tqdm progress bar while building (starting at the nodes already built)
    :param lock_timeout: As for :func:`cached_view_features`
    :return: The cached or computed array
    :raises ValueError: if the build returned another shape or dtype, or left batches out (and as
        :func:`cached_view_features`)
    """

    def compute(path: Path, key: str, shape: tuple[int, ...], dtype: np.dtype) -> np.ndarray:
        shards = _Shards(path, key, encoder)
        batches = node_batches(shape[0])
        done = shards.load(batches)
        todo = [nodes for nodes in batches if nodes not in done]
        features = np.empty(shape, dtype=dtype)
        for nodes, encoded in done.items():
            features[nodes.start : nodes.stop] = encoded
        if done:
            logger.info(
                "resuming the feature build of %s: %d of %d batches already built", path, len(done), len(batches)
            )
        try:
            with _progress_bar(shape[0], encoder, progress, initial=sum(map(len, done))) as bar:
                for nodes, encoded in build(todo) if todo else ():
                    if nodes not in todo or nodes in done:
                        raise ValueError(f"the feature build returned nodes {nodes.start}-{nodes.stop - 1} unasked")
                    shards.save(nodes, _check_batch(nodes, encoded, shape, dtype))
                    features[nodes.start : nodes.stop] = encoded
                    done[nodes] = encoded
                    bar.update(len(nodes))
        except BaseException:
            shards.remove(only_if_empty=True)
            raise
        missing = [nodes for nodes in todo if nodes not in done]
        if missing:
            raise ValueError(f"the feature build left {len(missing)} batches out, from node {missing[0].start} on")
        return features

    return _cached(key_parts, n_nodes, encoder, compute, cache_dir=cache_dir, lock_timeout=lock_timeout, shards=True)


def cached_features(
    key_parts: Mapping[str, str],
    n_nodes: int,
    encoder: ViewEncoder,
    compute: Callable[[], np.ndarray],
    *,
    cache_dir: str | Path | None = None,
    lock_timeout: float | None = None,
) -> np.ndarray:
    """
    :func:`cached_view_features` with the computation given whole: ``compute()`` returns every node's encodings. It is
    called only on a cache miss, under the file's lock; its result is checked and stored atomically. It does not
    resume (:func:`cached_batched_features` does).

    :param key_parts: As for :func:`cached_view_features`
    :param n_nodes: Number of nodes
    :param encoder: The encoder ``compute`` uses (its name, shape and dtype key the file)
    :param compute: Returns the ``(n_nodes, 4, *encoder.output_shape)`` array of dtype ``encoder.dtype``
    :param cache_dir: Cache directory; None uses :func:`default_cache_dir`
    :param lock_timeout: As for :func:`cached_view_features`
    :return: The cached or computed array
    :raises ValueError: if ``compute`` returned another shape or dtype (and as :func:`cached_view_features`)
    """
    return _cached(key_parts, n_nodes, encoder, lambda *_: compute(), cache_dir=cache_dir, lock_timeout=lock_timeout)


def _cached(
    key_parts: Mapping[str, str],
    n_nodes: int,
    encoder: ViewEncoder,
    compute: Callable[[Path, str, tuple[int, ...], np.dtype], np.ndarray],
    *,
    cache_dir: str | Path | None,
    lock_timeout: float | None,
    shards: bool = False,
) -> np.ndarray:
    """Load the cache file, or build it under its lock with ``compute(path, key, shape, dtype)`` and store it."""
    n_nodes = _check_n_nodes(n_nodes)
    timeout = _resolve_lock_timeout(lock_timeout)
    document = _key_document(key_parts, n_nodes, encoder)
    key = cache_key(key_parts, n_nodes, encoder)
    path = cache_path(key_parts, n_nodes, encoder, cache_dir=cache_dir)
    shape = (n_nodes, VIEWS_PER_NODE, *encoder.output_shape)
    dtype = np.dtype(encoder.dtype)

    if path.exists():
        with contextlib.suppress(ValueError):  # an invalid file is reported and rebuilt below, under the lock
            return _load(path, key, shape, dtype)

    # Fail before waiting or spending minutes on rendering if the result could not be stored.
    _ensure_writable_dir(path.parent)
    with _build_lock(path, timeout):
        # Another process may have built the file while this one waited for the lock.
        if path.exists():
            try:
                return _load(path, key, shape, dtype)
            except ValueError as e:
                warnings.warn(f"feature cache {path} is invalid: {e}; rebuilding it", RuntimeWarning, stacklevel=3)
        features = compute(path, key, shape, dtype)
        if not isinstance(features, np.ndarray) or features.shape != shape or features.dtype != dtype:
            got = f"{features.shape} {features.dtype}" if isinstance(features, np.ndarray) else type(features).__name__
            raise ValueError(f"the feature build returned {got}, expected {shape} {dtype}")
        _save_atomic(path, features, {**document, "key": key, "checksum": _checksum(features)})
        if shards:
            _Shards(path, key, encoder).remove()
        return features
