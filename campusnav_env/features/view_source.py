"""Where the env's view encodings come from: the on-disk cache, or the 3D world rendered and encoded now.

:class:`ViewSource` hands out every node's four views of the open map and, for visible closures, one node's views with
construction barriers on its closed roads (each a one-node cache entry). The 3D world and the renderer are built only
on a cache miss; a big map's open views are rendered and encoded by worker processes
(:mod:`campusnav_env.features.parallel_build`).

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
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from campusnav_env.features.encoders import ViewEncoder, make_encoder
from campusnav_env.features.feature_cache import cached_features, cached_view_features, encode_every_node
from campusnav_env.features.parallel_build import default_workers, encode_views_in_workers, pickle_for_workers
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.barriers import BARRIER_VERSION
from campusnav_env.rendering.scene import WORLD_VERSION, World
from campusnav_env.rendering.street_view import RenderSettings, StreetViewRenderer
from campusnav_env.rendering.world import build_world

__all__ = ["IMAGE_MODE_VIEW", "MIN_NODES_FOR_WORKERS", "ViewSource", "settings_for_encoder"]

IMAGE_MODE_VIEW = (48, 64)  # (height, width) of each view in image mode
# Maps smaller than this are built in this process unless workers are asked for: starting a worker (torch, the encoder,
# the renderer) costs seconds, more than a small map's build saves
MIN_NODES_FOR_WORKERS = 256


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
        (:func:`~campusnav_env.features.parallel_build.default_workers`) on maps of at least
        :data:`MIN_NODES_FOR_WORKERS` nodes, else this process; 1: this process
    :param fit_views_to_encoder: Render at the size the encoder consumes (:func:`settings_for_encoder`); False renders
        at ``render_settings``' size, as before (the features of the caches made then)
    :param world: The 3D world of ``graph`` and ``world_seed``, where the caller has built it; None: built on a cache
        miss
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
        fit_views_to_encoder: bool = True,
        world: World | None = None,
    ) -> None:
        if observation_mode == "image":
            height, width = IMAGE_MODE_VIEW
            encoder = make_encoder("thumbnail", height=height, width=width)
            # Thumbnails are downscaled from renders 4x their size, which keeps signs and windows legible
            render_settings = render_settings or RenderSettings(width=4 * width, height=4 * height)
        elif isinstance(encoder, str):
            encoder = make_encoder(encoder, **dict(encoder_kwargs or {}))
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise ValueError(f"workers must be an int >= 1 or None, got {workers!r}")
        self.graph = graph
        self.encoder = encoder
        self.requested_settings = render_settings or RenderSettings()
        # What is rendered (and keys the cache)
        self.settings = (
            settings_for_encoder(self.requested_settings, encoder) if fit_views_to_encoder else self.requested_settings
        )
        self.world_seed = world_seed
        self.cache_dir = cache_dir
        self.progress = progress
        self.workers = workers
        self._world = world
        self._renderer: StreetViewRenderer | None = None
        # Keyed without building the world: its inputs (graph, seed, generator version) determine it
        self.key_parts = {
            "graph": graph.fingerprint(),
            "world": f"v{WORLD_VERSION}-seed{world_seed}",
            "render": self.settings.key(),
        }

    @property
    def world(self) -> World:
        """The 3D world, built on first use (once: the workers get a copy)."""
        if self._world is None:
            self._world = build_world(self.graph, seed=self.world_seed)
        return self._world

    @property
    def renderer(self) -> StreetViewRenderer:
        if self._renderer is None:
            self._renderer = StreetViewRenderer(self.world, self.settings)
        return self._renderer

    def build_workers(self) -> int:
        """The number of processes that build the open map's views (1: this process)."""
        if self.workers is not None:
            return self.workers
        return default_workers() if self.graph.n_nodes >= MIN_NODES_FOR_WORKERS else 1

    def open_views(self) -> np.ndarray:
        """``(N, 4, *encoding)``: every node's views of the open map."""
        return cached_features(
            self.key_parts, self.graph.n_nodes, self.encoder, self._build_open_views, cache_dir=self.cache_dir
        )

    def _build_open_views(self) -> np.ndarray:
        """Render and encode every node's open views, in worker processes where :meth:`build_workers` says so."""
        workers = self.build_workers()
        if workers > 1 and self.workers is None and not _picklable(self.encoder):
            warnings.warn(
                f"encoder {self.encoder.name!r} cannot be pickled for worker processes; building in this process",
                RuntimeWarning,
                stacklevel=3,
            )
            workers = 1
        if workers > 1:
            return encode_views_in_workers(
                self.graph.n_nodes,
                functools.partial(StreetViewRenderer, self.world, self.settings),
                self.encoder,
                workers=workers,
                progress=self.progress,
            )
        return encode_every_node(
            self.graph.n_nodes, lambda node: self.renderer.render_node(node), self.encoder, self.progress
        )

    def views_with(self, node: int, closed_roads: frozenset[tuple[int, int]]) -> np.ndarray:
        """``(4, *encoding)``: one node's views with barriers on ``closed_roads`` (a one-node cache entry)."""
        roads = ",".join(f"{u}-{v}" for u, v in sorted(closed_roads))
        key_parts = {**self.key_parts, "closures": f"barrier-v{BARRIER_VERSION}|node={node}|closed={roads}"}

        def render(_: int) -> np.ndarray:  # the entry's only node, 0, is this node
            return self.renderer.render_node(node, closed_roads=closed_roads)

        return cached_view_features(key_parts, 1, render, self.encoder, cache_dir=self.cache_dir, progress=False)[0]
