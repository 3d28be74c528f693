"""Specification of the on-disk view-feature cache (campusnav_env.features.feature_cache)."""

from __future__ import annotations

import contextlib
import json
import multiprocessing
import os
import re
import socket
import subprocess
import sys
import time
import warnings
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from filelock import FileLock, Timeout

import campusnav_env.features.feature_cache as feature_cache
from campusnav_env.features.encoders import PixelProjectionEncoder, ThumbnailEncoder, ViewEncoder
from campusnav_env.features.feature_cache import (
    CACHE_FORMAT_VERSION,
    LOCK_TIMEOUT_ENV,
    cache_key,
    cache_path,
    cached_view_features,
    default_cache_dir,
    lock_paths,
)

N_NODES = 10
KEY = {"world": "world-fingerprint-abc", "render": "640x480-fov90-noon"}


class CountingRenderer:
    """Deterministic fake renderer: node n gives four small views drawn from seed n; counts calls."""

    def __init__(self, fail_at: int | None = None, error: type[BaseException] = RuntimeError) -> None:
        self.calls: list[int] = []
        self.fail_at = fail_at
        self.error = error

    def __call__(self, node: int) -> np.ndarray:
        if node == self.fail_at:
            raise self.error(f"renderer crashed at node {node}")
        self.calls.append(node)
        return np.random.default_rng(node).integers(0, 256, (4, 24, 32, 3), dtype=np.uint8)


def files_in(directory: Path) -> list[str]:
    """
    A cache directory's files besides lock files: ``filelock`` may leave a build's empty ``<cache file>.lock`` behind,
    as the lock is the OS's lock on the open file, not the file's existence (owner records and temp files count).
    """
    return sorted(name for name in os.listdir(directory) if not name.endswith(".lock"))


@pytest.fixture
def encoder() -> PixelProjectionEncoder:
    return PixelProjectionEncoder(dim=8)


def build(
    cache_dir: Path,
    encoder: ViewEncoder,
    render: Callable[[int], np.ndarray],
    key: dict[str, str] = KEY,
    n_nodes: int = N_NODES,
    lock_timeout: float | None = None,
) -> np.ndarray:
    return cached_view_features(
        key, n_nodes, render, encoder, cache_dir=cache_dir, progress=False, lock_timeout=lock_timeout
    )


def test_first_call_computes_every_node_second_call_loads(tmp_path: Path, encoder: PixelProjectionEncoder) -> None:
    render = CountingRenderer()
    features = build(tmp_path, encoder, render)
    assert sorted(render.calls) == list(range(N_NODES))
    assert features.shape == (N_NODES, 4, 8) and features.dtype == np.float32
    # The cache encodes 8 nodes per matrix product, the reference one node alone: float32 sums of 576 products then
    # run in a shape- and CPU-dependent order (6.6e-7 apart on AVX2; ~sqrt(576) * 6e-8 of the feature scale). 1e-4 of
    # the scale is far above such rounding and far below the distance between two nodes' features (~0.3 of it).
    atol = 1e-4 * np.abs(features).max()
    for node in (0, 7):
        np.testing.assert_allclose(features[node], encoder.encode(render(node)), rtol=0, atol=atol)

    again = CountingRenderer()
    np.testing.assert_array_equal(build(tmp_path, encoder, again), features)
    assert again.calls == []
    assert files_in(tmp_path) == [cache_path(KEY, N_NODES, encoder, cache_dir=tmp_path).name]


def test_cache_file_records_its_key_and_checksum(tmp_path: Path, encoder: PixelProjectionEncoder) -> None:
    build(tmp_path, encoder, CountingRenderer())
    path = cache_path(KEY, N_NODES, encoder, cache_dir=tmp_path)
    key = cache_key(KEY, N_NODES, encoder)
    assert path == tmp_path / f"views-{key[:24]}.npz"
    with np.load(path) as data:
        meta = json.loads(str(data["meta"]))
        assert data["features"].shape == (N_NODES, 4, 8)
    assert meta["key"] == key and len(meta["checksum"]) == 64
    assert meta["format_version"] == CACHE_FORMAT_VERSION and meta["encoder"] == encoder.name


def test_uint8_encoders_are_cached_too(tmp_path: Path) -> None:
    thumbnails = build(tmp_path, ThumbnailEncoder(height=6, width=8), CountingRenderer())
    assert thumbnails.shape == (N_NODES, 4, 3, 6, 8) and thumbnails.dtype == np.uint8
    render = CountingRenderer()
    np.testing.assert_array_equal(build(tmp_path, ThumbnailEncoder(height=6, width=8), render), thumbnails)
    assert render.calls == []


def test_key_part_order_does_not_matter(encoder: PixelProjectionEncoder) -> None:
    reordered = dict(reversed(list(KEY.items())))
    assert cache_key(reordered, N_NODES, encoder) == cache_key(KEY, N_NODES, encoder)


@pytest.mark.parametrize(
    ("key", "encoder_kwargs", "n_nodes"),
    [
        ({**KEY, "world": "another-world"}, {"dim": 8}, N_NODES),
        ({**KEY, "render": "640x480-fov90-dusk"}, {"dim": 8}, N_NODES),
        ({**KEY, "cars": "on"}, {"dim": 8}, N_NODES),
        (KEY, {"dim": 8, "seed": 1}, N_NODES),
        (KEY, {"dim": 16}, N_NODES),
        (KEY, {"dim": 8}, N_NODES + 1),
    ],
    ids=["world", "render-settings", "extra-key-part", "encoder-seed", "encoder-dim", "n-nodes"],
)
def test_any_change_of_inputs_invalidates(
    tmp_path: Path, encoder: PixelProjectionEncoder, key: dict[str, str], encoder_kwargs: dict[str, int], n_nodes: int
) -> None:
    build(tmp_path, encoder, CountingRenderer())
    other = PixelProjectionEncoder(**encoder_kwargs)
    assert cache_path(key, n_nodes, other, cache_dir=tmp_path) != cache_path(KEY, N_NODES, encoder, cache_dir=tmp_path)
    render = CountingRenderer()
    build(tmp_path, other, render, key=key, n_nodes=n_nodes)
    assert sorted(render.calls) == list(range(n_nodes))
    assert len(files_in(tmp_path)) == 2


def corrupt_truncate(path: Path) -> None:
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])


def corrupt_garbage(path: Path) -> None:
    path.write_bytes(b"this is not an npz file" * 10)


def corrupt_flip_values(path: Path) -> None:
    """A well-formed file whose array no longer matches the recorded checksum."""
    with np.load(path) as data:
        features, meta = data["features"].copy(), data["meta"]
    features[3, 1, 0] += 1.0
    np.savez(path, features=features, meta=meta)


def corrupt_foreign_key(path: Path) -> None:
    """A well-formed file written for other inputs (e.g. copied by hand)."""
    with np.load(path) as data:
        features, meta = data["features"], json.loads(str(data["meta"]))
    meta["key"] = "0" * 64
    np.savez(path, features=features, meta=np.array(json.dumps(meta)))


@pytest.mark.parametrize(
    ("corrupt", "problem"),
    [
        (corrupt_truncate, "unreadable"),
        (corrupt_garbage, "unreadable"),
        (corrupt_flip_values, "checksum"),
        (corrupt_foreign_key, "key mismatch"),
    ],
    ids=["truncated", "garbage", "checksum", "foreign-key"],
)
def test_damaged_cache_file_is_reported_and_rebuilt(
    tmp_path: Path, encoder: PixelProjectionEncoder, corrupt: Callable[[Path], None], problem: str
) -> None:
    good = build(tmp_path, encoder, CountingRenderer())
    path = cache_path(KEY, N_NODES, encoder, cache_dir=tmp_path)
    corrupt(path)
    render = CountingRenderer()
    with pytest.warns(RuntimeWarning, match=rf"{path.name}.*{problem}"):
        rebuilt = build(tmp_path, encoder, render)
    assert sorted(render.calls) == list(range(N_NODES))
    np.testing.assert_array_equal(rebuilt, good)
    # The rebuilt file is valid again.
    again = CountingRenderer()
    build(tmp_path, encoder, again)
    assert again.calls == []
    assert files_in(tmp_path) == [path.name]


def test_failed_render_leaves_the_old_file_and_no_partial_file(tmp_path: Path, encoder: PixelProjectionEncoder) -> None:
    path = cache_path(KEY, N_NODES, encoder, cache_dir=tmp_path)
    build(tmp_path, encoder, CountingRenderer())
    corrupt_garbage(path)  # an existing (invalid) file that a rebuild would replace
    before = path.read_bytes()
    with pytest.warns(RuntimeWarning), pytest.raises(RuntimeError, match="crashed at node 6"):
        build(tmp_path, encoder, CountingRenderer(fail_at=6))
    assert path.read_bytes() == before
    assert files_in(tmp_path) == [path.name]


def test_failure_while_writing_leaves_the_old_file_and_no_temp_file(
    tmp_path: Path, encoder: PixelProjectionEncoder, monkeypatch: pytest.MonkeyPatch
) -> None:
    path = cache_path(KEY, N_NODES, encoder, cache_dir=tmp_path)
    build(tmp_path, encoder, CountingRenderer())
    corrupt_truncate(path)
    before = path.read_bytes()

    def savez_then_fail(file: object, **arrays: np.ndarray) -> None:
        file.write(b"PK\x03\x04 half an archive")  # type: ignore[attr-defined]
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(feature_cache.np, "savez", savez_then_fail)
    with pytest.warns(RuntimeWarning), pytest.raises(OSError, match="No space left"):
        build(tmp_path, encoder, CountingRenderer())
    assert path.read_bytes() == before
    assert files_in(tmp_path) == [path.name]


@pytest.mark.parametrize(
    ("views", "message"),
    [
        (np.zeros((3, 24, 32, 3), np.uint8), r"render_node\(0\) returned shape \(3, 24, 32, 3\)"),
        (np.zeros((4, 24, 32), np.uint8), r"render_node\(0\) returned shape \(4, 24, 32\)"),
        (np.zeros((4, 24, 32, 3), np.float32), r"render_node\(0\) returned dtype float32"),
        ([[0]], r"render_node\(0\) returned list"),
    ],
    ids=["three-views", "grey", "float", "not-an-array"],
)
def test_bad_render_output_is_a_clear_error(
    tmp_path: Path, encoder: PixelProjectionEncoder, views: object, message: str
) -> None:
    with pytest.raises(ValueError, match=message):
        build(tmp_path, encoder, lambda node: views)  # type: ignore[arg-type,return-value]
    assert files_in(tmp_path) == []


def test_views_must_keep_one_size_across_nodes(tmp_path: Path, encoder: PixelProjectionEncoder) -> None:
    def render(node: int) -> np.ndarray:
        return np.zeros((4, 24, 32 if node < 4 else 30, 3), np.uint8)

    with pytest.raises(ValueError, match=r"render_node\(4\).*earlier nodes"):
        build(tmp_path, encoder, render)


def test_encoder_returning_the_wrong_shape_is_a_clear_error(tmp_path: Path) -> None:
    class BrokenEncoder(PixelProjectionEncoder):
        def encode(self, images: np.ndarray) -> np.ndarray:
            return super().encode(images)[:, :4]

    with pytest.raises(ValueError, match=r"encoder 'pixels.*' returned shape"):
        build(tmp_path, BrokenEncoder(dim=8), CountingRenderer())


def test_bad_arguments_are_rejected(tmp_path: Path, encoder: PixelProjectionEncoder) -> None:
    with pytest.raises(ValueError, match="n_nodes"):
        build(tmp_path, encoder, CountingRenderer(), n_nodes=0)
    with pytest.raises(TypeError, match="key_parts"):
        build(tmp_path, encoder, CountingRenderer(), key={"seed": 3})  # type: ignore[dict-item]


def test_unusable_cache_dir_is_a_clear_error(tmp_path: Path, encoder: PixelProjectionEncoder) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    render = CountingRenderer()
    with pytest.raises(OSError, match=r"cannot create cache directory .*a-file"):
        build(blocker / "cache", encoder, render)
    assert render.calls == []  # failed before spending time on rendering


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="needs POSIX permissions and a non-root user")
def test_read_only_cache_dir_is_a_permission_error(tmp_path: Path, encoder: PixelProjectionEncoder) -> None:
    read_only = tmp_path / "ro"
    read_only.mkdir()
    read_only.chmod(0o500)
    try:
        with pytest.raises(PermissionError, match=r"ro is not writable"):
            build(read_only, encoder, CountingRenderer())
    finally:
        read_only.chmod(0o700)


def test_default_cache_dir_honours_the_environment(
    tmp_path: Path, encoder: PixelProjectionEncoder, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CAMPUSNAV_CACHE", str(tmp_path / "features"))
    assert default_cache_dir() == tmp_path / "features"
    cached_view_features(KEY, N_NODES, CountingRenderer(), encoder, progress=False)
    assert cache_path(KEY, N_NODES, encoder).is_file()
    assert cache_path(KEY, N_NODES, encoder).parent == tmp_path / "features"

    monkeypatch.delenv("CAMPUSNAV_CACHE")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert default_cache_dir() == tmp_path / "home" / ".cache" / "campusnav"


def test_progress_bar_reports_nodes(
    tmp_path: Path, encoder: PixelProjectionEncoder, capsys: pytest.CaptureFixture[str]
) -> None:
    cached_view_features(KEY, N_NODES, CountingRenderer(), encoder, cache_dir=tmp_path, progress=True)
    assert f"{N_NODES}/{N_NODES}" in capsys.readouterr().err


def test_unwritable_cache_dir_fails_before_rendering(
    tmp_path: Path, encoder: PixelProjectionEncoder, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Same as above where the tests run as root: simulate the missing write permission."""
    monkeypatch.setattr(feature_cache.os, "access", lambda path, mode: False)
    render = CountingRenderer()
    with pytest.raises(PermissionError, match=rf"{tmp_path.name} is not writable"):
        build(tmp_path, encoder, render)
    assert render.calls == []


# --- one build at a time: the lock file ----------------------------------------------------------------------------


def lock_and_owner(cache_dir: Path, encoder: ViewEncoder) -> tuple[Path, Path]:
    """The lock of a cache file is ``<cache file>.lock``; its holder records itself in ``<cache file>.lock.owner``."""
    path = cache_path(KEY, N_NODES, encoder, cache_dir=cache_dir)
    assert lock_paths(path) == (path.with_name(path.name + ".lock"), path.with_name(path.name + ".lock.owner"))
    return lock_paths(path)


@contextlib.contextmanager
def held_lock(cache_dir: Path, encoder: ViewEncoder, *, record: bool = True) -> Iterator[FileLock]:
    """Hold a cache file's lock as another builder would (another open file: it excludes this process's builds too)."""
    lock_file, owner_file = lock_and_owner(cache_dir, encoder)
    cache_dir.mkdir(parents=True, exist_ok=True)
    lock = FileLock(lock_file)
    with lock.acquire(timeout=0):
        if record:
            owner_file.write_text(json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "since": time.time()}))
        yield lock
    owner_file.unlink(missing_ok=True)


def lock_is_free(lock_file: Path) -> bool:
    try:
        FileLock(lock_file).acquire(timeout=0).lock.release()
    except Timeout:
        return False
    return True


class LoggingRenderer(CountingRenderer):
    """A slow CountingRenderer that logs ``<pid> <node>`` per call to a file shared between processes."""

    def __init__(self, log: Path, delay: float = 0.0) -> None:
        super().__init__()
        self.log = log
        self.delay = delay

    def __call__(self, node: int) -> np.ndarray:
        time.sleep(self.delay)
        with open(self.log, "a") as f:
            f.write(f"{os.getpid()} {node}\n")
        return super().__call__(node)


def build_in_this_process(cache_dir: Path, log: Path, delay: float) -> np.ndarray:
    """Entry point of the other process: build the cache with a slow logging renderer."""
    return build(cache_dir, PixelProjectionEncoder(dim=8), LoggingRenderer(log, delay), lock_timeout=60)


def wait_for(condition: Callable[[], bool], what: str, timeout: float = 60.0) -> None:
    """Poll ``condition``: another Python process imports torch first, seconds on a busy machine."""
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, f"gave up after {timeout:g} s waiting until {what}"
        time.sleep(0.005)


def test_concurrent_builds_compute_once_and_share_the_file(tmp_path: Path, encoder: PixelProjectionEncoder) -> None:
    cache_dir, log = tmp_path / "cache", tmp_path / "render-calls.log"
    _, owner_file = lock_and_owner(cache_dir, encoder)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        # The other process renders 10 nodes at 50 ms each, so it holds the lock for half a second.
        other = pool.submit(build_in_this_process, cache_dir, log, 0.05)
        wait_for(lambda: owner_file.exists() or other.done(), "the other process holds the lock")
        assert not other.done(), f"the other process finished without holding the lock: {other.exception()}"
        waiting = r"waiting for another process \(pid \d+ on host .*\) that is building the same feature cache"
        with pytest.warns(RuntimeWarning, match=waiting):
            mine = build(cache_dir, encoder, LoggingRenderer(log), lock_timeout=60)  # fail, not hang, if broken
        theirs = other.result()

    calls = [line.split() for line in log.read_text().splitlines()]
    assert sorted(int(node) for _, node in calls) == list(range(N_NODES))  # every node rendered once in total
    assert str(os.getpid()) not in {pid for pid, _ in calls}  # ... all by the other process
    np.testing.assert_array_equal(mine, theirs)  # this process loaded the very file the other one stored
    assert files_in(cache_dir) == [cache_path(KEY, N_NODES, encoder, cache_dir=cache_dir).name]


def test_the_builder_holds_the_lock_and_records_its_pid_and_host(
    tmp_path: Path, encoder: PixelProjectionEncoder
) -> None:
    lock_file, owner_file = lock_and_owner(tmp_path, encoder)
    seen: list[tuple[dict[str, object], bool]] = []

    def render(node: int) -> np.ndarray:
        seen.append((json.loads(owner_file.read_text()), lock_is_free(lock_file)))
        return CountingRenderer()(node)

    features = build(tmp_path, encoder, render)
    record, free = seen[0]
    assert record["pid"] == os.getpid() and record["host"] == socket.gethostname()
    assert not free
    assert lock_is_free(lock_file) and not owner_file.exists()
    # Loading a valid file takes no lock (so read-only cache dirs work): it succeeds while another builder holds it.
    with held_lock(tmp_path, encoder):
        np.testing.assert_array_equal(build(tmp_path, encoder, CountingRenderer(), lock_timeout=0), features)


HOLD_THE_LOCK = """
import sys, time
from campusnav_env.features.encoders import PixelProjectionEncoder
from campusnav_env.features.feature_cache import cached_view_features

def render(node):
    time.sleep(3600)  # a build that is killed half way

cached_view_features({key!r}, {n_nodes}, render, PixelProjectionEncoder(dim=8), cache_dir={cache_dir!r}, progress=False)
"""


def test_a_killed_builder_does_not_block_the_next(tmp_path: Path, encoder: PixelProjectionEncoder) -> None:
    lock_file, owner_file = lock_and_owner(tmp_path, encoder)
    code = HOLD_THE_LOCK.format(key=KEY, n_nodes=N_NODES, cache_dir=str(tmp_path))
    # This checkout's package, whatever the venv has installed
    env = {**os.environ, "PYTHONPATH": str(Path(feature_cache.__file__).resolve().parents[2])}
    builder = subprocess.Popen([sys.executable, "-c", code], env=env)
    try:
        wait_for(lambda: owner_file.exists() or builder.poll() is not None, "the other process holds the lock")
        assert builder.poll() is None, f"the other process exited with status {builder.returncode}"
        assert not lock_is_free(lock_file)
    finally:
        builder.kill()  # SIGKILL: no finally of its own runs, its owner record stays behind
        builder.wait()
    assert json.loads(owner_file.read_text())["pid"] == builder.pid
    render = CountingRenderer()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # neither waits nor warns: the OS released the dead builder's lock
        build(tmp_path, encoder, render, lock_timeout=0)
    assert sorted(render.calls) == list(range(N_NODES))
    assert files_in(tmp_path) == [cache_path(KEY, N_NODES, encoder, cache_dir=tmp_path).name]  # its record is gone


@pytest.mark.parametrize(
    ("record", "owner"),
    [(True, rf"pid {os.getpid()} on host '{re.escape(socket.gethostname())}' since [-\d]+ [:\d]+"), (False, None)],
    ids=["recorded-owner", "owner-not-recorded-yet"],
)
def test_waiting_for_a_live_lock_times_out_with_a_clear_error(
    tmp_path: Path, encoder: PixelProjectionEncoder, record: bool, owner: str | None
) -> None:
    lock_file, _ = lock_and_owner(tmp_path, encoder)
    owner = owner or "a process that has not recorded itself yet"
    render = CountingRenderer()
    with held_lock(tmp_path, encoder, record=record):
        start = time.monotonic()
        with (
            pytest.warns(
                RuntimeWarning, match=rf"waiting for another process \({owner}\) .*{re.escape(lock_file.name)}"
            ),
            pytest.raises(
                TimeoutError,
                match=rf"after 0.3 s waiting for the lock file {re.escape(str(lock_file))}, held by {owner}",
            ),
        ):
            build(tmp_path, encoder, render, lock_timeout=0.3)
        assert 0.3 <= time.monotonic() - start < 5
        assert not lock_is_free(lock_file)  # another builder's lock is left alone
    assert render.calls == []


def test_lock_timeout_comes_from_the_argument_or_the_environment(
    tmp_path: Path, encoder: PixelProjectionEncoder, monkeypatch: pytest.MonkeyPatch
) -> None:
    with held_lock(tmp_path, encoder):
        monkeypatch.setenv(LOCK_TIMEOUT_ENV, "0.1")
        with pytest.warns(RuntimeWarning, match="waiting"), pytest.raises(TimeoutError, match=r"after 0.1 s"):
            build(tmp_path, encoder, CountingRenderer())
        with pytest.warns(RuntimeWarning, match="waiting"), pytest.raises(TimeoutError, match=r"after 0 s"):
            build(tmp_path, encoder, CountingRenderer(), lock_timeout=0)  # the argument wins

    for bad in ("soon", "-1", "nan"):
        monkeypatch.setenv(LOCK_TIMEOUT_ENV, bad)
        with pytest.raises(ValueError, match=rf"\${LOCK_TIMEOUT_ENV} must be a number of seconds >= 0, got '{bad}'"):
            build(tmp_path, encoder, CountingRenderer())
    with pytest.raises(ValueError, match=r"lock_timeout must be a number of seconds >= 0, got -1"):
        build(tmp_path, encoder, CountingRenderer(), lock_timeout=-1)


@pytest.mark.parametrize("error", [RuntimeError, KeyboardInterrupt])
def test_the_lock_is_released_when_building_fails(
    tmp_path: Path, encoder: PixelProjectionEncoder, error: type[BaseException]
) -> None:
    with pytest.raises(error, match="crashed at node 6"):
        build(tmp_path, encoder, CountingRenderer(fail_at=6, error=error))
    assert files_in(tmp_path) == []
    assert lock_is_free(lock_and_owner(tmp_path, encoder)[0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the next build does not wait
        build(tmp_path, encoder, CountingRenderer(), lock_timeout=0)
