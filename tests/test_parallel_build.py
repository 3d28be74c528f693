"""Specification of the parallel feature build (campusnav_env.features.parallel_build) and of rendering at the size
the encoder consumes (campusnav_env.features.view_source.settings_for_encoder)."""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import torch

import campusnav_env.features.feature_cache as feature_cache
import campusnav_env.features.view_source as view_source
from campusnav_env.features.encoders import PixelProjectionEncoder, ThumbnailEncoder, ViewEncoder
from campusnav_env.features.feature_cache import cache_path, encode_every_node
from campusnav_env.features.parallel_build import ViewBuildError, default_workers, encode_views_in_workers
from campusnav_env.features.view_source import ViewSource, settings_for_encoder
from campusnav_env.maps.campus import generate_campus
from campusnav_env.rendering.street_view import RenderSettings

N_NODES = 20  # three batches of 8 nodes: both workers get work
SMALL_VIEWS = RenderSettings(width=64, height=48)


class NoiseRenderer:
    """
    Picklable stand-in renderer (workers import it from this module): node n's views drawn from seed n.

    :param fail_at: The node whose rendering raises
    :param exit_at: The node whose rendering ends the worker process at once (as a crash or the OOM killer would)
    :param slow_from: Nodes from this one on take ``delay`` seconds each
    :param delay: See ``slow_from``
    :param chatty: Print each node to stdout, as a careless renderer might
    :param log: A file to which each rendered node is appended
    """

    def __init__(
        self,
        fail_at: int | None = None,
        exit_at: int | None = None,
        slow_from: int | None = None,
        delay: float = 0.0,
        chatty: bool = False,
        log: Path | None = None,
    ) -> None:
        self.fail_at, self.exit_at, self.slow_from, self.delay = fail_at, exit_at, slow_from, delay
        self.chatty, self.log = chatty, log

    def __call__(self) -> NoiseRenderer:  # its own factory: the worker calls it once
        return self

    def render_node(self, node: int) -> np.ndarray:
        if node == self.fail_at:
            raise RuntimeError("the renderer crashed")
        if node == self.exit_at:
            os._exit(3)
        if self.slow_from is not None and node >= self.slow_from:
            time.sleep(self.delay)
        if self.chatty:
            print(f"rendering node {node}", flush=True)
        if self.log is not None:
            with open(self.log, "a") as f:
                f.write(f"{node}\n")
        return np.random.default_rng(node).integers(0, 256, (4, 24, 32, 3), dtype=np.uint8)


class GatedRenderer(NoiseRenderer):
    """Node ``GATED_NODE`` renders only once the file ``gate`` exists (at most 60 s, then it fails saying so)."""

    def __init__(self, gate: Path) -> None:
        super().__init__()
        self.gate = gate

    def render_node(self, node: int) -> np.ndarray:
        if node == GATED_NODE:
            deadline = time.monotonic() + 60
            while not self.gate.exists():
                if time.monotonic() > deadline:
                    raise RuntimeError("the progress bar did not show the earlier batches before the last one ended")
                time.sleep(0.01)
        return super().render_node(node)


GATED_NODE = 16  # the first node of the last batch


class RecordingBar:
    """Stands in for tqdm: records each update, and opens the gate once a batch has been shown."""

    gate: Path
    updates: list[int]

    def __init__(self, *args: object, **kwargs: object) -> None:
        pass

    def __enter__(self) -> RecordingBar:
        return self

    def __exit__(self, *exc: object) -> None:
        pass

    def update(self, n: int) -> None:
        type(self).updates.append(n)
        self.gate.touch()


class SleepingFactory:
    """A renderer factory that says what it does on stderr, then never returns (a worker stuck starting)."""

    def __call__(self) -> NoiseRenderer:
        print("loading a very large world", file=sys.stderr, flush=True)
        time.sleep(3600)
        return NoiseRenderer()


def _refuse_to_load() -> PixelProjectionEncoder:
    raise RuntimeError("this encoder's weights are not on this machine")


class UnloadableEncoder(PixelProjectionEncoder):
    """Pickles in the parent; unpickling it (in a worker) fails."""

    def __reduce__(self) -> tuple[object, ...]:
        return _refuse_to_load, ()


class WhereEncoder(ViewEncoder):
    """Encodes each view as (process id, torch threads): where and how it was encoded."""

    name = "where"
    output_shape = (2,)
    dtype = np.dtype(np.int64)

    def encode(self, images: np.ndarray) -> np.ndarray:
        return np.tile([os.getpid(), torch.get_num_threads()], (len(images), 1))


class CNNSizedEncoder(PixelProjectionEncoder):
    """A pixel encoder that declares a CNN's 224 x 224 input size."""

    view_input_size = (224, 224)


def test_the_parallel_build_equals_the_serial_build() -> None:
    encoder = PixelProjectionEncoder(dim=16)
    serial = encode_every_node(N_NODES, NoiseRenderer().render_node, encoder, progress=False)
    parallel = encode_views_in_workers(N_NODES, NoiseRenderer(), encoder, workers=2, progress=False)
    assert parallel.shape == serial.shape == (N_NODES, 4, 16)
    np.testing.assert_allclose(parallel, serial, rtol=1e-5, atol=1e-6)


def test_workers_are_other_processes_with_one_torch_thread_each() -> None:
    where = encode_views_in_workers(N_NODES, NoiseRenderer(), WhereEncoder(), workers=2, progress=False)
    pids = set(where[..., 0].ravel().tolist())
    assert os.getpid() not in pids
    assert 1 <= len(pids) <= 2
    assert set(where[..., 1].ravel().tolist()) == {1}


def test_a_failing_node_is_named() -> None:
    message = r"node 13: rendering its views failed: RuntimeError: the renderer crashed"
    with pytest.raises(ViewBuildError, match=message) as failure:
        encode_views_in_workers(N_NODES, NoiseRenderer(fail_at=13), PixelProjectionEncoder(), workers=1)
    assert failure.value.nodes == (13,)
    assert "Traceback" in str(failure.value.__cause__)  # the worker's traceback


def test_a_failing_node_stops_the_build_at_once(tmp_path: Path) -> None:
    log = tmp_path / "rendered.log"
    # Node 0 fails at once; the other batches (nodes 8-19) take 0.5 s a node, 6 s in all on two workers
    renderer = NoiseRenderer(fail_at=0, slow_from=8, delay=0.5, log=log)
    with pytest.raises(ViewBuildError, match="node 0: rendering its views failed"):
        encode_views_in_workers(N_NODES, renderer, PixelProjectionEncoder(), workers=2, progress=False)
    rendered = log.read_text().split() if log.exists() else []
    assert len(rendered) < N_NODES - 8  # the workers were stopped before the other batches were done


def test_the_progress_bar_advances_as_each_batch_finishes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # The last batch cannot finish before the bar has shown an earlier one: a bar updated only at the end would fail
    monkeypatch.setattr(RecordingBar, "gate", tmp_path / "gate", raising=False)
    monkeypatch.setattr(RecordingBar, "updates", [], raising=False)
    monkeypatch.setattr(feature_cache, "tqdm", RecordingBar)
    encode_views_in_workers(N_NODES, GatedRenderer(tmp_path / "gate"), PixelProjectionEncoder(), workers=2)
    assert sorted(RecordingBar.updates) == [4, 8, 8]  # one update per batch of 8 nodes (the last one has 4)


def test_a_worker_that_dies_is_reported_with_its_nodes() -> None:
    with pytest.raises(ViewBuildError, match=r"worker died while building nodes from 8 on .*exited with status 3"):
        encode_views_in_workers(N_NODES, NoiseRenderer(exit_at=13), PixelProjectionEncoder(), workers=1)


class KilledRenderer(NoiseRenderer):
    """Node 13's rendering kills its worker with SIGKILL, as the OOM killer does."""

    def render_node(self, node: int) -> np.ndarray:
        if node == 13:
            os.kill(os.getpid(), signal.SIGKILL)
        return super().render_node(node)


def test_a_worker_killed_by_a_signal_is_reported_with_the_signal() -> None:
    with pytest.raises(
        ViewBuildError, match=r"worker died while building nodes from 8 on .*killed by signal 9 \(SIGKILL\)"
    ):
        encode_views_in_workers(N_NODES, KilledRenderer(), PixelProjectionEncoder(), workers=1)


def test_a_worker_that_cannot_start_says_why() -> None:
    with pytest.raises(
        ViewBuildError,
        match=r"worker could not start: pid \d+: RuntimeError: this encoder's weights are not on this machine",
    ) as failure:
        encode_views_in_workers(N_NODES, NoiseRenderer(), UnloadableEncoder(), workers=1)
    assert failure.value.nodes == tuple(range(N_NODES))


def test_a_worker_that_does_not_start_in_time_is_stopped_and_its_stderr_shown(
    capfd: pytest.CaptureFixture[str],
) -> None:
    start = time.monotonic()
    with pytest.raises(ViewBuildError, match=r"view-build workers did not start within 20 s \(no batch finished"):
        encode_views_in_workers(N_NODES, SleepingFactory(), PixelProjectionEncoder(), workers=1, start_timeout=20)
    assert time.monotonic() - start < 60  # 20 s, then the worker is killed
    assert "loading a very large world" in capfd.readouterr().err  # the workers' stderr is the parent's


def test_objects_of_the_running_script_are_refused() -> None:
    for script in ("__main__", "__mp_main__"):  # the script run, or re-imported by multiprocessing's spawn
        script_encoder = type("ScriptEncoder", (PixelProjectionEncoder,), {"__module__": script})
        with pytest.raises(TypeError, match=rf"ScriptEncoder is defined in the script being run \({script}\)"):
            encode_views_in_workers(N_NODES, NoiseRenderer(), script_encoder(), workers=1)
    with pytest.raises(TypeError, match="must be picklable"):
        encode_views_in_workers(N_NODES, lambda: NoiseRenderer(), PixelProjectionEncoder(), workers=1)


def test_output_of_the_renderer_does_not_disturb_the_workers(capfd: pytest.CaptureFixture[str]) -> None:
    encoder = PixelProjectionEncoder(dim=16)
    chatty = encode_views_in_workers(N_NODES, NoiseRenderer(chatty=True), encoder, workers=2, progress=False)
    np.testing.assert_allclose(
        chatty, encode_every_node(N_NODES, NoiseRenderer().render_node, encoder, False), atol=1e-6
    )
    captured = capfd.readouterr()
    assert "rendering node 19" in captured.out + captured.err  # printed, and the build is undisturbed


def test_the_worker_count_is_checked() -> None:
    with pytest.raises(ValueError, match="workers must be an int >= 1"):
        encode_views_in_workers(N_NODES, NoiseRenderer(), PixelProjectionEncoder(), workers=0)
    graph = generate_campus(16, seed=1)
    with pytest.raises(ValueError, match="workers must be an int >= 1 or None"):
        ViewSource(graph, "features", "pixels", None, SMALL_VIEWS, 0, None, False, workers=0)


def test_workers_default_to_the_available_cores_on_big_maps(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0, 1, 2}, raising=False)
    assert default_workers() == 3
    graph = generate_campus(16, seed=1)

    def source(**kwargs: object) -> ViewSource:
        return ViewSource(graph, "features", "pixels", None, SMALL_VIEWS, 0, None, False, **kwargs)

    assert source().build_workers() == 1  # a small map: starting workers would cost more than they save
    assert source(workers=2).build_workers() == 2
    monkeypatch.setattr(view_source, "MIN_NODES_FOR_WORKERS", 16)
    assert source().build_workers() == 3
    assert source(workers=1).build_workers() == 1


def test_view_source_builds_in_workers_and_reuses_the_cache(tmp_path: Path) -> None:
    graph = generate_campus(16, seed=1)

    def source(cache_dir: Path, workers: int) -> ViewSource:
        return ViewSource(graph, "features", "pixels", None, SMALL_VIEWS, 0, cache_dir, False, workers=workers)

    serial = source(tmp_path / "serial", 1).open_views()
    builder = source(tmp_path / "parallel", 2)
    parallel = builder.open_views()
    np.testing.assert_allclose(parallel, serial, rtol=1e-5, atol=1e-6)
    # The workers' result went through the cache: the same file as the serial build's, read without building anything
    path = cache_path(builder.key_parts, graph.n_nodes, builder.encoder, cache_dir=tmp_path / "parallel")
    assert path.name == cache_path(builder.key_parts, graph.n_nodes, builder.encoder, cache_dir=tmp_path).name
    assert path.is_file()
    again = source(tmp_path / "parallel", 2)
    np.testing.assert_array_equal(again.open_views(), parallel)
    assert again._world is None  # nothing rendered


def test_views_are_rendered_at_the_size_the_encoder_consumes() -> None:
    default = RenderSettings()
    fitted = settings_for_encoder(default, CNNSizedEncoder())
    # 640 x 480 -> 299 x 224: the smallest size covering 224 x 224 with the aspect ratio kept (rounded up)
    assert (fitted.width, fitted.height) == (299, 224)
    assert (fitted.fov_deg, fitted.eye_height, fitted.time_of_day, fitted.cars) == (90.0, 2.5, None, False)
    assert fitted.key() != default.key()  # another cache entry than the full-size renders
    dusk = RenderSettings(width=800, height=450, time_of_day=19.0, cars=True)
    assert settings_for_encoder(dusk, CNNSizedEncoder()) == RenderSettings(399, 224, time_of_day=19.0, cars=True)
    # Encoders that shrink big renders to thumbnails, and views no bigger than the input, are left alone
    assert settings_for_encoder(default, PixelProjectionEncoder()) == default
    assert settings_for_encoder(default, ThumbnailEncoder()) == default
    assert settings_for_encoder(RenderSettings(224, 168), CNNSizedEncoder()) == RenderSettings(224, 168)


def test_view_source_keys_the_cache_on_the_settings_it_renders() -> None:
    graph = generate_campus(16, seed=1)
    fitted = ViewSource(graph, "features", CNNSizedEncoder(), None, None, 0, None, False)
    assert fitted.requested_settings == RenderSettings()
    assert (fitted.settings.width, fitted.settings.height) == (299, 224)
    assert fitted.key_parts["render"] == fitted.settings.key()
    as_asked = ViewSource(graph, "features", CNNSizedEncoder(), None, None, 0, None, False, fit_views_to_encoder=False)
    assert as_asked.settings == RenderSettings()
    assert as_asked.key_parts["render"] == RenderSettings().key()
