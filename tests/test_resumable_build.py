"""Specification of a view build that resumes (campusnav_env.features.feature_cache.cached_batched_features): the cache
is written in shards as batches finish, a killed build redoes at most one batch per worker, a torn shard is never
read, and the finished cache file is the one readers always read."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from campusnav_env.features.encoders import PixelProjectionEncoder
from campusnav_env.features.feature_cache import (
    cache_path,
    cached_batched_features,
    cached_view_features,
    encode_batches,
    node_batches,
    shard_dir,
)
from campusnav_env.features.parallel_build import encode_batches_in_workers

N_NODES = 48  # six batches of 8 nodes
KEY = {"world": "resume-test", "render": "24x32"}
NODES_PER_BATCH = 8


class SlowRenderer:
    """
    Picklable renderer (workers import it from this module): node n's views drawn from seed n, each node taking
    ``delay`` seconds; each rendered node is appended to ``log``.
    """

    def __init__(self, delay: float = 0.0, log: Path | None = None) -> None:
        self.delay, self.log = delay, log

    def __call__(self) -> SlowRenderer:  # its own factory
        return self

    def render_node(self, node: int) -> np.ndarray:
        time.sleep(self.delay)
        if self.log is not None:
            with open(self.log, "a") as f:
                f.write(f"{node}\n")
        return np.random.default_rng(node).integers(0, 256, (4, 24, 32, 3), dtype=np.uint8)


class Untouchable:
    """A renderer for a build that must not render anything."""

    def __call__(self, node: int) -> np.ndarray:
        raise AssertionError(f"node {node} rendered again")


def encoder() -> PixelProjectionEncoder:
    return PixelProjectionEncoder(dim=8)


def build(cache_dir: Path, workers: int, renderer: SlowRenderer) -> np.ndarray:
    """The build as a killed one ran it: in this process (workers=1) or in a pool, through the sharded cache."""

    def batches(todo: list[range]):
        if workers == 1:
            return encode_batches(todo, renderer.render_node, encoder())
        return encode_batches_in_workers(todo, renderer, encoder(), workers=workers)

    return cached_batched_features(KEY, N_NODES, encoder(), batches, cache_dir=cache_dir, progress=False)


KILLED_BUILD = """
import sys
from pathlib import Path
sys.path.insert(0, {tests!r})
from test_resumable_build import SlowRenderer, build
build(Path({cache_dir!r}), {workers}, SlowRenderer(delay={delay}, log=Path({log!r})))
"""


def batches_in(log: Path) -> set[int]:
    """The batches (by index) of which the log records a rendered node."""
    return {int(line) // NODES_PER_BATCH for line in log.read_text().split()} if log.exists() else set()


def uninterrupted() -> np.ndarray:
    return cached_view_features(KEY, N_NODES, SlowRenderer().render_node, encoder(), cache_dir=None, progress=False)


@pytest.fixture(autouse=True)
def _no_default_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("CAMPUSNAV_CACHE", str(tmp_path / "default-cache"))


@pytest.mark.parametrize("workers", [1, 2], ids=["in-process", "two-workers"])
def test_a_killed_build_resumes_redoing_at_most_one_batch_per_worker(tmp_path: Path, workers: int) -> None:
    cache_dir, first_log, second_log = tmp_path / "cache", tmp_path / "first.log", tmp_path / "second.log"
    shards = shard_dir(cache_path(KEY, N_NODES, encoder(), cache_dir=cache_dir))
    code = KILLED_BUILD.format(
        tests=str(Path(__file__).parent), cache_dir=str(cache_dir), workers=workers, delay=0.15, log=str(first_log)
    )
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    # A new session: SIGKILL goes to the builder and its workers at once, as a lost node or the OOM killer would
    builder = subprocess.Popen([sys.executable, "-c", code], env=env, start_new_session=True)
    try:
        deadline = time.monotonic() + 120
        while len(list(shards.glob("nodes-*.npz"))) < 2:
            assert builder.poll() is None, f"the build exited with status {builder.returncode} before being killed"
            assert time.monotonic() < deadline, "the build wrote no two shards within 120 s"
            time.sleep(0.02)
    finally:
        os.killpg(builder.pid, signal.SIGKILL)
        builder.wait()
    kept = {int(path.name.split("-")[1]) // NODES_PER_BATCH for path in shards.glob("nodes-*.npz")}
    assert 2 <= len(kept) < len(node_batches(N_NODES))  # killed half way

    resumed = build(cache_dir, workers, SlowRenderer(log=second_log))
    np.testing.assert_allclose(resumed, uninterrupted(), rtol=1e-5, atol=1e-6)
    rebuilt = batches_in(second_log)
    assert rebuilt == set(range(len(node_batches(N_NODES)))) - kept  # every shard reused, every other batch built
    redone = rebuilt & batches_in(first_log)  # rendered by the killed build, lost with it
    assert len(redone) <= workers
    assert not shards.exists()  # the cache file holds them all now
    # The finished file is the one every reader reads: loaded, nothing rendered
    np.testing.assert_array_equal(
        cached_view_features(KEY, N_NODES, Untouchable(), encoder(), cache_dir=cache_dir, progress=False), resumed
    )


def test_a_torn_or_foreign_shard_is_never_read(tmp_path: Path) -> None:
    cache_dir = tmp_path / "cache"
    path = cache_path(KEY, N_NODES, encoder(), cache_dir=cache_dir)
    shards = shard_dir(path)
    # Shards of batches 0 and 1 from a first build that stopped there (the build raised at node 16)
    with pytest.raises(RuntimeError, match="stopped at node 16"):

        def stop_at_16(node: int) -> np.ndarray:
            if node == 16:
                raise RuntimeError("stopped at node 16")
            return SlowRenderer().render_node(node)

        cached_view_features(KEY, N_NODES, stop_at_16, encoder(), cache_dir=cache_dir, progress=False)
    assert sorted(p.name for p in shards.iterdir()) == ["nodes-0-8.npz", "nodes-8-16.npz"]
    # Batch 0's shard torn (half written), batch 1's replaced by one of another cache entry (another key), a
    # writer's temp file left behind, and a shard of batch 2 that holds garbage
    shard_0 = shards / "nodes-0-8.npz"
    shard_0.write_bytes(shard_0.read_bytes()[:200])
    other = tmp_path / "other"
    other_key = {**KEY, "world": "another world"}
    with pytest.raises(RuntimeError, match="stopped at node 16"):
        cached_view_features(other_key, N_NODES, stop_at_16, encoder(), cache_dir=other, progress=False)
    foreign = shard_dir(cache_path(other_key, N_NODES, encoder(), cache_dir=other)) / "nodes-8-16.npz"
    os.replace(foreign, shards / "nodes-8-16.npz")
    (shards / ".nodes-16-24.npz.abc.tmp").write_bytes(b"PK\x03\x04 half")
    (shards / "nodes-16-24.npz").write_bytes(b"not a shard")

    rendered: list[int] = []

    def render(node: int) -> np.ndarray:
        rendered.append(node)
        return SlowRenderer().render_node(node)

    features = cached_view_features(KEY, N_NODES, render, encoder(), cache_dir=cache_dir, progress=False)
    assert sorted(rendered) == list(range(N_NODES))  # none of those shards was read: every batch built again
    np.testing.assert_allclose(features, uninterrupted(), rtol=1e-5, atol=1e-6)
    assert not shards.exists()
    assert sorted(p.name for p in cache_dir.iterdir() if not p.name.endswith(".lock")) == [path.name]


def test_a_valid_shard_is_read_and_its_nodes_not_rendered_again(tmp_path: Path) -> None:
    cache_dir = tmp_path / "cache"

    def stop_at_40(node: int) -> np.ndarray:
        if node == 40:
            raise RuntimeError("stopped at node 40")
        return SlowRenderer().render_node(node)

    with pytest.raises(RuntimeError, match="stopped at node 40"):
        cached_view_features(KEY, N_NODES, stop_at_40, encoder(), cache_dir=cache_dir, progress=False)
    rendered: list[int] = []

    def render(node: int) -> np.ndarray:
        rendered.append(node)
        return SlowRenderer().render_node(node)

    features = cached_view_features(KEY, N_NODES, render, encoder(), cache_dir=cache_dir, progress=False)
    assert rendered == list(range(40, N_NODES))  # the last batch only
    np.testing.assert_allclose(features, uninterrupted(), rtol=1e-5, atol=1e-6)


def test_a_build_that_returns_the_wrong_batches_is_refused(tmp_path: Path) -> None:
    def wrong(todo: list[range]):
        yield range(0, 3), np.zeros((3, 4, 8), np.float32)

    with pytest.raises(ValueError, match="returned nodes 0-2 unasked"):
        cached_batched_features(KEY, N_NODES, encoder(), wrong, cache_dir=tmp_path, progress=False)

    def short(todo: list[range]):
        yield todo[0], np.zeros((len(todo[0]), 4, 7), np.float32)

    with pytest.raises(ValueError, match=r"returned \(8, 4, 7\) float32 for nodes 0-7, expected \(8, 4, 8\)"):
        cached_batched_features(KEY, N_NODES, encoder(), short, cache_dir=tmp_path, progress=False)

    def partial(todo: list[range]):
        yield todo[0], np.zeros((len(todo[0]), 4, 8), np.float32)

    with pytest.raises(ValueError, match="left 5 batches out, from node 8 on"):
        cached_batched_features(KEY, N_NODES, encoder(), partial, cache_dir=tmp_path, progress=False)
