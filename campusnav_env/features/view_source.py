"""Where the env's view encodings come from: the on-disk cache, or the 3D world rendered and encoded now.

:class:`ViewSource` hands out every node's four views of the open map and, for visible closures, one node's views with
construction barriers on its closed roads (each a one-node cache entry). The 3D world and the renderer are built only
on a cache miss.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from campusnav_env.features.encoders import ViewEncoder, make_encoder
from campusnav_env.features.feature_cache import cached_view_features
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.barriers import BARRIER_VERSION
from campusnav_env.rendering.scene import WORLD_VERSION
from campusnav_env.rendering.street_view import RenderSettings, StreetViewRenderer
from campusnav_env.rendering.world import build_world

__all__ = ["IMAGE_MODE_VIEW", "ViewSource"]

IMAGE_MODE_VIEW = (48, 64)  # (height, width) of each view in image mode


class ViewSource:
    """
    Per-node encodings of the four compass views, from the on-disk cache or rendered and encoded now: the open map's
    (every node) and one node's with closure barriers. The 3D world and the renderer are built only on a cache miss.
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
    ) -> None:
        if observation_mode == "image":
            height, width = IMAGE_MODE_VIEW
            encoder = make_encoder("thumbnail", height=height, width=width)
            # Thumbnails are downscaled from renders 4x their size, which keeps signs and windows legible
            render_settings = render_settings or RenderSettings(width=4 * width, height=4 * height)
        elif isinstance(encoder, str):
            encoder = make_encoder(encoder, **dict(encoder_kwargs or {}))
        self.graph = graph
        self.encoder = encoder
        self.settings = render_settings or RenderSettings()
        self.world_seed = world_seed
        self.cache_dir = cache_dir
        self.progress = progress
        self._renderer: StreetViewRenderer | None = None
        # Keyed without building the world: its inputs (graph, seed, generator version) determine it
        self.key_parts = {
            "graph": graph.fingerprint(),
            "world": f"v{WORLD_VERSION}-seed{world_seed}",
            "render": self.settings.key(),
        }

    @property
    def renderer(self) -> StreetViewRenderer:
        if self._renderer is None:
            self._renderer = StreetViewRenderer(build_world(self.graph, seed=self.world_seed), self.settings)
        return self._renderer

    def open_views(self) -> np.ndarray:
        """``(N, 4, *encoding)``: every node's views of the open map."""
        return cached_view_features(
            self.key_parts,
            self.graph.n_nodes,
            lambda node: self.renderer.render_node(node),
            self.encoder,
            cache_dir=self.cache_dir,
            progress=self.progress,
        )

    def views_with(self, node: int, closed_roads: frozenset[tuple[int, int]]) -> np.ndarray:
        """``(4, *encoding)``: one node's views with barriers on ``closed_roads`` (a one-node cache entry)."""
        roads = ",".join(f"{u}-{v}" for u, v in sorted(closed_roads))
        key_parts = {**self.key_parts, "closures": f"barrier-v{BARRIER_VERSION}|node={node}|closed={roads}"}

        def render(_: int) -> np.ndarray:  # the entry's only node, 0, is this node
            return self.renderer.render_node(node, closed_roads=closed_roads)

        return cached_view_features(key_parts, 1, render, self.encoder, cache_dir=self.cache_dir, progress=False)[0]
