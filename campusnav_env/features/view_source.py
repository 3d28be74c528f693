"""Where the env's view encodings come from: the on-disk cache, or the 3D world rendered and encoded now.

:class:`ViewSource` hands out every node's four views of the open map and, for visible closures, one node's views with
construction barriers on its closed roads (each a one-node cache entry). On a varied world
(:class:`~campusnav_env.rendering.variation.ViewVariation`) each of them comes K times, render after render: the
cache's entries are then the ``N * K`` renders of the nodes (entry ``n * K + k``, keyed by the variation's key as
well), built by the same pieces, K times the work; without a variation the keys and entries are exactly the fixed
views' ones. The 3D world and the renderer are built only
on a cache miss; a big map's open views are rendered and encoded by worker processes
(:mod:`campusnav_env.features.parallel_build`) or on a Ray cluster (:mod:`campusnav_env.features.ray_build`), stored
batch by batch so that a killed build resumes (:func:`~campusnav_env.features.feature_cache.cached_batched_features`).

Views are rendered at the size the encoder consumes (:func:`settings_for_encoder`): a CNN that resizes every view to
224 x 224 gets it rendered at 299 x 224 instead of 640 x 480 (same camera and field of view, so the same picture up
to resampling, at a fifth of the pixels). The settings actually rendered key the cache, so caches of full-size renders
are never mixed up with these.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import warnings
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from campusnav_env.features.encoders import ViewEncoder, make_encoder
from campusnav_env.features.feature_cache import cached_batched_features, cached_view_features, encode_batches
from campusnav_env.features.parallel_build import check_workers, encode_batches_in_workers
from campusnav_env.features.ray_build import encode_batches_on_ray
from campusnav_env.features.view_worker import default_workers, pickle_for_workers
from campusnav_env.features.world_cache import MIN_NODES_FOR_WORLD_CACHE, cached_world
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.barriers import BARRIER_VERSION
from campusnav_env.rendering.scene import WORLD_VERSION, World
from campusnav_env.rendering.street_view import RenderSettings, StreetViewRenderer
from campusnav_env.rendering.variation import VariedRenderer, ViewVariation, check_settings_vary

__all__ = ["BUILD_BACKENDS", "IMAGE_MODE_VIEW", "MIN_NODES_FOR_WORKERS", "ViewSource", "settings_for_encoder"]

IMAGE_MODE_VIEW = (48, 64)  # (height, width) of each view in image mode
# Maps smaller than this are built in this process unless workers are asked for: starting a worker (torch, the encoder,
# the renderer) costs seconds, more than a small map's build saves
MIN_NODES_FOR_WORKERS = 256
# Where a cold cache's open views are built: this machine (this process or a local pool), or a Ray cluster
BUILD_BACKENDS = ("local", "ray")


def settings_for_encoder(settings: RenderSettings, encoder: ViewEncoder) -> RenderSettings:
    """
    The settings to render at for ``encoder``: ``settings`` scaled down, aspect ratio and field of view kept, to the
    smallest size that covers the encoder's :attr:`~campusnav_env.features.encoders.ViewEncoder.view_input_size` in
    both directions (each side rounded up). The encoder then resizes these views as it resized the big ones: the same
    picture, less resampling. Unchanged where the encoder has no input size or the views are no bigger.

    :param settings: The requested settings (e.g. the default 640 x 480)
    :param encoder: The encoder
    :return: The settings to render with (640 x 480 for a 224 x 224 CNN: 299 x 224)
    """
    size = encoder.view_input_size
    if size is None:
        return settings
    height, width = size
    scale = max(width / settings.width, height / settings.height)
    if scale >= 1.0:
        return settings
    # Rounding up, and not past the requested side by float error (480 * 224 / 480 is 224)
    fit_width = max(width, math.ceil(round(settings.width * scale, 6)))
    fit_height = max(height, math.ceil(round(settings.height * scale, 6)))
    return dataclasses.replace(settings, width=fit_width, height=fit_height)


def _picklable(obj: object) -> bool:
    """Whether ``obj`` can reach the worker processes (picklable, and not defined in ``__main__``, which they lack)."""
    try:
        pickle_for_workers(obj)
    except TypeError:
        return False
    return True


class ViewSource:
    """
    Per-node encodings of the four compass views, from the on-disk cache or rendered and encoded now: the open map's
    (every node) and one node's with closure barriers. The 3D world and the renderer are built only on a cache miss.

    :param graph: The road graph
    :param observation_mode: ``"features"`` or ``"image"`` (thumbnails of views rendered 4x their size)
    :param encoder: An encoder or its name (:func:`~campusnav_env.features.encoders.make_encoder`)
    :param encoder_kwargs: Arguments of the named encoder
    :param render_settings: The views' settings; None: :class:`RenderSettings` defaults
    :param world_seed: Seed of the 3D world
    :param cache_dir: Feature cache directory; None: the default
    :param progress: Show a progress bar while building
    :param workers: Processes that render and encode the open map's views; None: one per available core
        (:func:`~campusnav_env.features.view_worker.default_workers`) on maps of at least
        :data:`MIN_NODES_FOR_WORKERS` nodes (counting each of a variation's K renders as one), else this process; 1:
        this process. With ``backend="ray"``: the number of Ray actors (None: :mod:`~campusnav_env.features.ray_build`'s
        plan, one per GPU or per CPU but one)
    :param backend: ``"local"`` (this machine) or ``"ray"`` (a Ray cluster, ``pip install "sb3-dcqn[ray]"``)
    :param ray_address: The Ray cluster (``"auto"``, ``"ray://<head>:10001"``; None: ``$RAY_ADDRESS`` or a local Ray),
        where Ray is not initialised in this process yet; only with ``backend="ray"``
    :param fit_views_to_encoder: Render at the size the encoder consumes (:func:`settings_for_encoder`); False renders
        at ``render_settings``' size, as before (the features of the caches made then)
    :param world: The 3D world of ``graph`` and ``world_seed``, where the caller has built it; None: built on a cache
        miss
    :param variation: Render every view K times in varied conditions (the render settings' ``time_of_day`` and
        ``cars`` unset); None: the fixed views
    :raises ValueError: if the backend is unknown, ``ray_address`` is given without Ray, or the render settings fix
        what the variation draws
    """

    def __init__(
        self,
        graph: RoadGraph,
        observation_mode: str,
        encoder: str | ViewEncoder,
        encoder_kwargs: Mapping[str, Any] | None,
        render_settings: RenderSettings | None,
        world_seed: int,
        cache_dir: str | Path | None,
        progress: bool,
        *,
        workers: int | None = None,
        backend: str = "local",
        ray_address: str | None = None,
        fit_views_to_encoder: bool = True,
        world: World | None = None,
        variation: ViewVariation | None = None,
    ) -> None:
        if observation_mode == "image":
            height, width = IMAGE_MODE_VIEW
            encoder = make_encoder("thumbnail", height=height, width=width)
            # Thumbnails are downscaled from renders 4x their size, which keeps signs and windows legible
            render_settings = render_settings or RenderSettings(width=4 * width, height=4 * height)
        elif isinstance(encoder, str):
            encoder = make_encoder(encoder, **dict(encoder_kwargs or {}))
        check_workers(workers, allow_none=True)
        if backend not in BUILD_BACKENDS:
            raise ValueError(f"build backend must be one of {', '.join(map(repr, BUILD_BACKENDS))}, got {backend!r}")
        if ray_address is not None and backend != "ray":
            raise ValueError(f"ray_address={ray_address!r} is for backend='ray', but the backend is {backend!r}")
        self.graph = graph
        self.encoder = encoder
        self.requested_settings = render_settings or RenderSettings()
        # What is rendered (and keys the cache)
        self.settings = (
            settings_for_encoder(self.requested_settings, encoder) if fit_views_to_encoder else self.requested_settings
        )
        if variation is not None:
            check_settings_vary(self.settings)
        self.variation = variation
        self.world_seed = world_seed
        self.cache_dir = cache_dir
        self.progress = progress
        self.workers = workers
        self.backend = backend
        self.ray_address = ray_address
        self._world = world
        self._renderer: StreetViewRenderer | VariedRenderer | None = None
        # Keyed without building the world: its inputs (graph, seed, generator version) determine it
        self.key_parts = {
            "graph": graph.fingerprint(),
            "world": f"v{WORLD_VERSION}-seed{world_seed}",
            "render": self.settings.key(),
        }
        if variation is not None:  # fixed views keep the keys they always had
            self.key_parts["variation"] = variation.key()

    @property
    def renders(self) -> int:
        """Renders of every view: the variation's K, 1 for fixed views."""
        return 1 if self.variation is None else self.variation.renders

    @property
    def world(self) -> World:
        """The 3D world, built on first use (once: the workers get a copy; a big map's is kept in the cache folder,
        so that a resumed build reads it instead of placing it again: :mod:`~campusnav_env.features.world_cache`)."""
        if self._world is None:
            self._world = cached_world(self.graph, self.world_seed, self.cache_dir)
        return self._world

    @property
    def renderer(self) -> StreetViewRenderer | VariedRenderer:
        """What draws the cache's entries (built once): the street views, or on a varied world their K renders."""
        if self._renderer is None:
            self._renderer = self._renderer_factory()()
        return self._renderer

    def _renderer_factory(self) -> functools.partial[StreetViewRenderer | VariedRenderer]:
        """The picklable factory of :attr:`renderer` that the worker processes and Ray actors are sent."""
        if self.variation is None:
            return functools.partial(StreetViewRenderer, self.world, self.settings)
        return functools.partial(VariedRenderer, self.world, self.settings, self.variation)

    def build_workers(self) -> int:
        """The number of processes that build the open map's views on this machine (1: this process)."""
        if self.workers is not None:
            return self.workers
        # A varied world's K renders are K nodes' worth of work each
        return default_workers() if self.graph.n_nodes * self.renders >= MIN_NODES_FOR_WORKERS else 1

    def open_renders(self) -> np.ndarray:
        """``(N, K, 4, *encoding)``: every node's K renders of its views of the open map (K = 1: the fixed views)."""
        entries = cached_batched_features(
            self.key_parts,
            self.graph.n_nodes * self.renders,
            self.encoder,
            self._build_open_views,
            cache_dir=self.cache_dir,
            progress=self.progress,
        )
        return entries.reshape(self.graph.n_nodes, self.renders, *entries.shape[1:])

    def open_views(self) -> np.ndarray:
        """``(N, 4, *encoding)``: every node's views of the open map (its first render on a varied world)."""
        return self.open_renders()[:, 0]

    def _build_open_views(self, batches: Sequence[range]) -> Iterable[tuple[range, np.ndarray]]:
        """Render and encode batches of open views: on Ray, in worker processes where :meth:`build_workers` says so."""
        make_renderer = self._renderer_factory()
        if self.backend == "ray":
            return encode_batches_on_ray(
                batches, make_renderer, self.encoder, address=self.ray_address, actors=self.workers
            )
        workers = self.build_workers()
        if workers > 1 and self.workers is None and not _picklable(self.encoder):
            warnings.warn(
                f"encoder {self.encoder.name!r} cannot be pickled for worker processes; building in this process",
                RuntimeWarning,
                stacklevel=4,
            )
            workers = 1
        if workers > 1:
            built = encode_batches_in_workers(batches, make_renderer, self.encoder, workers=workers)
            self._release_world()  # the workers have their copy
            return built
        return encode_batches(batches, lambda node: self.renderer.render_node(node), self.encoder)

    def _release_world(self) -> None:
        """Free this process's copy of a big map's world (gigabytes at 56,000 intersections) once the workers have
        theirs: it is in the cache folder, read back if barrier views need it."""
        if self.graph.n_nodes >= MIN_NODES_FOR_WORLD_CACHE:
            self._world = self._renderer = None

    def renders_with(self, node: int, closed_roads: frozenset[tuple[int, int]]) -> np.ndarray:
        """
        ``(K, 4, *encoding)``: one node's K renders of its views with barriers on ``closed_roads``, each render in the
        conditions of the open map's (a cache entry of K renders; K = 1: the fixed views).
        """
        roads = ",".join(f"{u}-{v}" for u, v in sorted(closed_roads))
        key_parts = {**self.key_parts, "closures": f"barrier-v{BARRIER_VERSION}|node={node}|closed={roads}"}
        renderer = self.renderer

        def render(entry: int) -> np.ndarray:  # the entry's renders are this node's
            if isinstance(renderer, VariedRenderer):
                return renderer.render(node, entry, closed_roads=closed_roads)
            return renderer.render_node(node, closed_roads=closed_roads)

        return cached_view_features(
            key_parts, self.renders, render, self.encoder, cache_dir=self.cache_dir, progress=False
        )
