"""How an env builds its views: the machinery behind the observations, gathered in one settings object.

An env's constructor keeps what a user chooses about the task (world, goals, observation mode, encoder, ``view_dim``,
``view_variation``, rewards, ...) and takes everything about *how* the views are made, cached and standardised as one
:class:`ViewBuild` (``view_build=``), the way the renderer takes its :class:`~campusnav_env.rendering.street_view.
RenderSettings`: the encoder's arguments, the render settings, the 3D world's seed, the cache folder, the progress bar,
the build's workers, backend and Ray address, views rendered at the encoder's size, and the standardisation of the
features. The goal and city envs pass it on as it is. A mapping works too (a YAML entry's
``env_kwargs: {view_build: {cache_dir: ..., workers: 4}}``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from campusnav_env.features.encoders import ViewEncoder
from campusnav_env.features.parallel_build import check_workers
from campusnav_env.features.view_source import BUILD_BACKENDS, ViewSource
from campusnav_env.maps.road_graph import RoadGraph
from campusnav_env.rendering.street_view import RenderSettings, settings_from_mapping
from campusnav_env.rendering.variation import ViewVariation

__all__ = ["ViewBuild", "with_view_build"]


@dataclass(frozen=True)
class ViewBuild:
    """
    How an env's street views are built, cached and turned into features.

    :param encoder_kwargs: Arguments of a named encoder (e.g. ``{"weights_path": "resnet50.pth"}``)
    :param render_settings: Camera and appearance of the views (a :class:`RenderSettings` or a mapping of its fields);
        None: the defaults (640 x 480; image mode: views 4x the thumbnails)
    :param world_seed: Seed of the buildings, trees and fields placed around the roads
    :param cache_dir: Where view features are cached (None: ``$CAMPUSNAV_CACHE`` or ``~/.cache/campusnav``)
    :param progress: Show a progress bar while a cold cache is built
    :param workers: Processes that render and encode a cold cache's views (None: one per core on maps of 256
        intersections and more, see :class:`~campusnav_env.features.view_source.ViewSource`); Ray actors with
        ``backend="ray"``
    :param backend: Where a cold cache's views are built: ``"local"`` (this machine) or ``"ray"`` (a Ray cluster,
        ``pip install "sb3-dcqn[ray]"``); either resumes a killed build
    :param ray_address: The Ray cluster (``"auto"``, ``"ray://<head>:10001"``; None: ``$RAY_ADDRESS`` or a local Ray);
        only with ``backend="ray"``
    :param fit_views_to_encoder: Render the views at the size the CNN consumes (about 1.8x less work per view for
        EfficientNet-Lite0, features of cosine similarity 0.98 to full-size ones, cached under their own key); None:
        the env's choice (off for :class:`~campusnav_env.env.CampusNavEnv`, so that the built-in campus keeps its
        features; on for :class:`~campusnav_env.city_env.CampusNavCityEnv`)
    :param normalize_features: Standardise each feature over all views of the map (all their renders on a varied
        world) before any projection
    :raises ValueError: naming the field that is out of range
    :raises TypeError: naming the field that has the wrong type
    """

    encoder_kwargs: Mapping[str, Any] = field(default_factory=dict)
    render_settings: RenderSettings | None = None
    world_seed: int = 0
    cache_dir: str | Path | None = None
    progress: bool = True
    workers: int | None = None
    backend: str = "local"
    ray_address: str | None = None
    fit_views_to_encoder: bool | None = None
    normalize_features: bool = True

    def __post_init__(self) -> None:
        if self.encoder_kwargs is None:  # None reads as "no arguments", as the constructors took it
            object.__setattr__(self, "encoder_kwargs", {})
        if not isinstance(self.encoder_kwargs, Mapping):
            raise TypeError(f"ViewBuild.encoder_kwargs must be a mapping, got {self.encoder_kwargs!r}")
        object.__setattr__(self, "encoder_kwargs", dict(self.encoder_kwargs))
        if isinstance(self.render_settings, Mapping):  # from YAML
            object.__setattr__(
                self, "render_settings", settings_from_mapping(RenderSettings, self.render_settings, "render_settings")
            )
        if self.render_settings is not None and not isinstance(self.render_settings, RenderSettings):
            raise TypeError(f"ViewBuild.render_settings must be a RenderSettings or None, got {self.render_settings!r}")
        if isinstance(self.world_seed, bool) or not isinstance(self.world_seed, int):
            raise TypeError(f"ViewBuild.world_seed must be an int, got {self.world_seed!r}")
        if self.cache_dir is not None and not isinstance(self.cache_dir, (str, Path)):
            raise TypeError(f"ViewBuild.cache_dir must be a path or None, got {self.cache_dir!r}")
        for name in ("progress", "normalize_features"):
            if not isinstance(getattr(self, name), bool):
                raise TypeError(f"ViewBuild.{name} must be True or False, got {getattr(self, name)!r}")
        if self.fit_views_to_encoder is not None and not isinstance(self.fit_views_to_encoder, bool):
            raise TypeError(
                f"ViewBuild.fit_views_to_encoder must be True, False or None, got {self.fit_views_to_encoder!r}"
            )
        try:
            check_workers(self.workers, allow_none=True)
        except ValueError as e:
            raise ValueError(f"ViewBuild.{e}") from None
        if self.backend not in BUILD_BACKENDS:
            raise ValueError(
                f"ViewBuild.backend must be one of {', '.join(map(repr, BUILD_BACKENDS))}, got {self.backend!r}"
            )
        if self.ray_address is not None and self.backend != "ray":
            raise ValueError(
                f"ViewBuild.ray_address={self.ray_address!r} is for backend='ray', but the backend is {self.backend!r}"
            )

    @classmethod
    def of(cls, value: ViewBuild | Mapping[str, Any] | None, **changes: Any) -> ViewBuild:
        """
        The build an env's ``view_build`` argument asks for, with ``changes`` (e.g. a caller's ``progress=False`` over
        a YAML entry's ``view_build``).

        :param value: A ``ViewBuild``, a mapping of its fields (e.g. from YAML) or None (the defaults)
        :param changes: Fields to set over ``value``'s
        :return: the build settings
        :raises TypeError: for another type, or an unknown field (naming it and the fields there are)
        :raises ValueError: as the constructor
        """
        if value is None:
            value = {}
        if isinstance(value, ViewBuild):
            return dataclasses.replace(value, **changes) if changes else value
        if isinstance(value, Mapping):
            return settings_from_mapping(cls, {**value, **changes}, "view_build")
        raise TypeError(f"view_build must be a ViewBuild, a mapping of its fields or None, got {type(value).__name__}")

    def source(
        self,
        graph: RoadGraph,
        observation_mode: str,
        encoder: str | ViewEncoder,
        *,
        variation: ViewVariation | None = None,
        fit_views_to_encoder: bool = False,
    ) -> ViewSource:
        """
        The view source of a map built these ways.

        :param graph: The road graph
        :param observation_mode: ``"features"`` or ``"image"``
        :param encoder: An encoder or its name (made with :attr:`encoder_kwargs`)
        :param variation: Render every view K times (None: fixed views)
        :param fit_views_to_encoder: The env's choice where :attr:`fit_views_to_encoder` is None
        :return: the source (nothing is built before it is asked for views)
        """
        return ViewSource(
            graph,
            observation_mode,
            encoder,
            self.encoder_kwargs,
            self.render_settings,
            self.world_seed,
            self.cache_dir,
            self.progress,
            workers=self.workers,
            backend=self.backend,
            ray_address=self.ray_address,
            fit_views_to_encoder=fit_views_to_encoder
            if self.fit_views_to_encoder is None
            else self.fit_views_to_encoder,
            variation=variation,
        )


def with_view_build(env_kwargs: Mapping[str, Any], **changes: Any) -> dict[str, Any]:
    """
    An env's keyword arguments with ``changes`` made to their ``view_build`` (e.g. a benchmark's cache folder and no
    progress bar over a YAML entry's ``env_kwargs``).

    :param env_kwargs: Keyword arguments of an env (``view_build`` among them or not)
    :param changes: :class:`ViewBuild` fields to set
    :return: a new dict whose ``view_build`` is a :class:`ViewBuild`
    """
    return {**env_kwargs, "view_build": ViewBuild.of(env_kwargs.get("view_build"), **changes)}
