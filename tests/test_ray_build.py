"""Specification of the view build on a Ray cluster (campusnav_env.features.ray_build), on a local two-CPU cluster.

The tests that need Ray are marked ``ray`` and skipped, saying so, where it is not installed (``pip install
"sb3-dcqn[ray]"``).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from campusnav_env.features.encoders import PixelProjectionEncoder
from campusnav_env.features.feature_cache import (
    cache_path,
    cached_batched_features,
    cached_view_features,
    encode_every_node,
    node_batches,
)
from campusnav_env.features.ray_build import _actor_options, encode_batches_on_ray, import_ray
from campusnav_env.features.view_source import ViewSource
from campusnav_env.features.view_worker import ViewBuildError
from campusnav_env.maps.campus import generate_campus
from campusnav_env.rendering.street_view import RenderSettings

N_NODES = 20
SMALL_VIEWS = RenderSettings(width=64, height=48)


def _ray_installed() -> bool:
    try:
        return importlib.util.find_spec("ray") is not None
    except (ImportError, ValueError):  # an import hook that refuses it, or sys.modules["ray"] set to None
        return False


needs_ray = pytest.mark.skipif(not _ray_installed(), reason='Ray is not installed (pip install "sb3-dcqn[ray]")')


class NoiseRenderer:
    """
    Picklable renderer (actors import it from this module): node n's views drawn from seed n.

    :param fail_at: The node whose rendering raises
    :param exit_once_at: The node whose first rendering ends the actor's process (the file ``marker`` then exists)
    :param marker: See ``exit_once_at``
    :param log: A file to which each rendered node is appended
    """

    def __init__(
        self,
        fail_at: int | None = None,
        exit_once_at: int | None = None,
        marker: Path | None = None,
        log: Path | None = None,
    ) -> None:
        self.fail_at, self.exit_once_at, self.marker, self.log = fail_at, exit_once_at, marker, log

    def __call__(self) -> NoiseRenderer:
        return self

    def render_node(self, node: int) -> np.ndarray:
        if node == self.fail_at:
            raise RuntimeError("the renderer crashed")
        if node == self.exit_once_at and self.marker is not None and not self.marker.exists():
            self.marker.touch()
            os._exit(1)  # the actor's process dies, as under the OOM killer or with its node
        if self.log is not None:
            with open(self.log, "a") as f:
                f.write(f"{node}\n")
        return np.random.default_rng(node).integers(0, 256, (4, 24, 32, 3), dtype=np.uint8)


@pytest.fixture(scope="module")
def ray_cluster() -> Iterator[Any]:
    """A local Ray instance of two CPUs whose workers import this module (as a cluster's nodes import the package)."""
    ray = import_ray()
    path = os.pathsep.join([str(Path(__file__).parent), str(Path(__file__).resolve().parents[1]), *sys.path])
    # Its session (logs, sockets) in a short temp dir of its own, removed after: sockets' paths have a length limit
    session = tempfile.mkdtemp(prefix="ray-")
    try:
        ray.init(
            num_cpus=2,
            include_dashboard=False,
            logging_level="ERROR",
            runtime_env={"env_vars": {"PYTHONPATH": path, "OMP_NUM_THREADS": "1"}},
            _temp_dir=session,
        )
        yield ray
    finally:
        ray.shutdown()
        shutil.rmtree(session, ignore_errors=True)


def on_ray(renderer: NoiseRenderer, encoder: PixelProjectionEncoder, actors: int | None = 2) -> np.ndarray:
    features = np.empty((N_NODES, 4, *encoder.output_shape), encoder.dtype)
    for nodes, encoded in encode_batches_on_ray(node_batches(N_NODES), renderer, encoder, actors=actors):
        features[nodes.start : nodes.stop] = encoded
    return features


def test_without_ray_the_error_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray then raises ImportError
    with pytest.raises(
        ImportError, match=r'view_build backend="ray" needs Ray, which is not installed: pip install "sb3-dcqn\[ray\]"'
    ):
        encode_batches_on_ray(node_batches(N_NODES), NoiseRenderer(), PixelProjectionEncoder())
    graph = generate_campus(16, seed=1)
    with pytest.raises(ValueError, match="build backend must be one of 'local', 'ray', got 'dask'"):
        ViewSource(graph, "features", "pixels", None, SMALL_VIEWS, 0, None, False, backend="dask")
    with pytest.raises(ValueError, match="ray_address='auto' is for backend='ray'"):
        ViewSource(graph, "features", "pixels", None, SMALL_VIEWS, 0, None, False, ray_address="auto")


@needs_ray
@pytest.mark.ray
def test_actors_build_the_features_of_the_local_build(ray_cluster: Any) -> None:
    encoder = PixelProjectionEncoder(dim=16)
    serial = encode_every_node(N_NODES, NoiseRenderer().render_node, encoder, progress=False)
    np.testing.assert_allclose(on_ray(NoiseRenderer(), encoder), serial, rtol=1e-5, atol=1e-6)


@needs_ray
@pytest.mark.ray
def test_the_view_source_on_ray_fills_the_local_builds_cache_file(ray_cluster: Any, tmp_path: Path) -> None:
    graph = generate_campus(16, seed=1)

    def source(cache_dir: Path, **kwargs: Any) -> ViewSource:
        return ViewSource(graph, "features", "pixels", None, SMALL_VIEWS, 0, cache_dir, False, **kwargs)

    local = source(tmp_path / "local", workers=1).open_views()
    on_cluster = source(tmp_path / "ray", backend="ray")
    np.testing.assert_allclose(on_cluster.open_views(), local, rtol=1e-5, atol=1e-6)
    local_file = cache_path(on_cluster.key_parts, graph.n_nodes, on_cluster.encoder, cache_dir=tmp_path / "local")
    ray_file = cache_path(on_cluster.key_parts, graph.n_nodes, on_cluster.encoder, cache_dir=tmp_path / "ray")
    assert ray_file.name == local_file.name and ray_file.is_file()  # same key, same file
    again = source(tmp_path / "ray", workers=1)  # read by a local build: nothing rendered
    np.testing.assert_allclose(again.open_views(), local, rtol=1e-5, atol=1e-6)
    assert again._world is None


@needs_ray
@pytest.mark.ray
def test_an_actor_killed_mid_build_has_its_batches_retried_on_another(ray_cluster: Any, tmp_path: Path) -> None:
    encoder = PixelProjectionEncoder(dim=16)
    marker = tmp_path / "died-once"
    features = on_ray(NoiseRenderer(exit_once_at=11, marker=marker), encoder)
    assert marker.exists()  # an actor did die at node 11
    serial = encode_every_node(N_NODES, NoiseRenderer().render_node, encoder, progress=False)
    np.testing.assert_allclose(features, serial, rtol=1e-5, atol=1e-6)


@needs_ray
@pytest.mark.ray
def test_a_failing_node_is_named_and_the_actors_leave_the_driver_a_cpu(ray_cluster: Any) -> None:
    with pytest.raises(
        ViewBuildError, match=r"node 13: rendering its views failed: RuntimeError: the renderer crashed"
    ) as failure:
        on_ray(NoiseRenderer(fail_at=13), PixelProjectionEncoder())
    assert failure.value.nodes == (13,)
    assert len(_actor_options(ray_cluster, None)) == 1  # two CPUs on the driver's node: one for the actors
    assert len(_actor_options(ray_cluster, 3)) == 3


@needs_ray
@pytest.mark.ray
def test_a_build_killed_locally_resumes_on_ray_building_only_the_rest(ray_cluster: Any, tmp_path: Path) -> None:
    encoder, key = PixelProjectionEncoder(dim=16), {"world": "resumed on ray"}

    def stop_at_16(node: int) -> np.ndarray:
        if node == 16:
            raise KeyboardInterrupt  # Ctrl-C after two batches
        return NoiseRenderer().render_node(node)

    with pytest.raises(KeyboardInterrupt):
        cached_view_features(key, N_NODES, stop_at_16, encoder, cache_dir=tmp_path, progress=False)
    log = tmp_path / "rendered.log"
    renderer = NoiseRenderer(log=log)
    features = cached_batched_features(
        key,
        N_NODES,
        encoder,
        lambda batches: encode_batches_on_ray(batches, renderer, encoder, actors=2),
        cache_dir=tmp_path,
        progress=False,
    )
    assert sorted(int(node) for node in log.read_text().split()) == list(range(16, N_NODES))  # the rest only
    serial = encode_every_node(N_NODES, NoiseRenderer().render_node, encoder, progress=False)
    np.testing.assert_allclose(features, serial, rtol=1e-5, atol=1e-6)


class FakeRay:
    """What the actor plan reads of Ray: the nodes and their resources, and the driver's node."""

    def __init__(self, nodes: list[dict[str, Any]], driver: str) -> None:
        self._nodes, self._driver = nodes, driver

    def nodes(self) -> list[dict[str, Any]]:
        return self._nodes

    def get_runtime_context(self) -> Any:
        driver = self._driver
        return type("Context", (), {"get_node_id": lambda self: driver})()


@needs_ray
def test_the_plan_is_one_actor_per_gpu_else_every_cpu_but_one_of_the_drivers_node() -> None:
    head, other, lost = "a1" * 28, "b2" * 28, "c3" * 28  # Ray's node ids: 28 bytes in hex
    cpus = [
        {"NodeID": head, "Alive": True, "Resources": {"CPU": 4.0}},
        {"NodeID": other, "Alive": True, "Resources": {"CPU": 8.0}},
        {"NodeID": lost, "Alive": False, "Resources": {"CPU": 8.0}},
    ]
    plan = _actor_options(FakeRay(cpus, head), None)  # type: ignore[arg-type]
    assert len(plan) == 3 + 8  # the head keeps a CPU for the driver; the lost node counts for nothing
    assert {option["num_cpus"] for option in plan} == {1}
    assert [option["scheduling_strategy"].node_id for option in plan].count(head) == 3
    gpus = [{**cpus[0], "Resources": {"CPU": 4.0, "GPU": 2.0}}, {**cpus[1], "Resources": {"CPU": 8.0, "GPU": 1.0}}]
    plan = _actor_options(FakeRay(gpus, head), None)  # type: ignore[arg-type]
    assert plan == [{"num_cpus": 1, "num_gpus": 1}] * 3
