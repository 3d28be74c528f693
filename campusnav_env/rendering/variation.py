"""A world whose pictures vary between visits: each view of each intersection rendered K times in other conditions.

Real streets never give the same picture twice: the light changes with the hour and the clouds, cars come and go, and
a street-view car never stops at exactly the same angle. :class:`ViewVariation` says how a varied world differs from
picture to picture: ``renders`` pictures (K) of every view, each at an hour drawn in ``hours`` (the renderer draws
cloud cover and exposure for it), with passing ``cars`` placed at random, and the camera turned by up to
``yaw_jitter_deg`` degrees off the view bearing. Render ``k`` of view ``d`` of intersection ``n`` is drawn from a
generator seeded with ``(seed, n, d, k)`` (:meth:`ViewVariation.shot`): the same picture on every machine and in every
build (this process, worker processes, Ray actors, a resumed build), whatever order they are built in.

:class:`VariedRenderer` draws them: its :meth:`~VariedRenderer.render_node` takes the index ``n * K + k`` of one
render of an intersection's four views, so that the K-fold build goes through the feature cache, the worker pool and
Ray exactly as the fixed views do (:class:`~campusnav_env.features.view_source.ViewSource`), K times the work.

The K-fold cost, measured on the campus (101 intersections, 640 x 480 views, built in one process on 2 shared cores;
``python benchmarks/view_variation.py``, ``benchmarks/results/view_variation.md``): with EfficientNet-Lite0, K = 8
takes 7.8x the fixed build's seconds (500 s against 64 s) and 8.0x its cache bytes (16.6 MB against 2.1 MB); with
pixel features 0.83 MB against 0.11 MB. A varied render costs about 1.3x a fixed one where cars pass (44.5 against
33.5 ms per 640 x 480 view, rendered alone), which the encoder's cost hides under a CNN; the env keeps the K renders'
features in memory too (K times the fixed views').
"""

from __future__ import annotations

from collections.abc import Collection, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from campusnav_env.maps.compass import COMPASS
from campusnav_env.rendering.scene import World
from campusnav_env.rendering.street_view import RenderSettings, Shot, StreetViewRenderer, settings_from_mapping

__all__ = ["VARIATION_VERSION", "VariedRenderer", "ViewVariation", "check_settings_vary"]

# Bump when what a render's seed draws changes: feature caches of varied worlds key on ViewVariation.key()
VARIATION_VERSION = 1
# At most this many degrees of yaw jitter: more would show another road than the one the action takes
MAX_YAW_JITTER_DEG = 15.0


@dataclass(frozen=True)
class ViewVariation:
    """
    How the pictures of a varied world differ between visits (see the module docstring).

    :param renders: Pictures rendered of every view (K >= 1); every visit sees one of them per view
    :param hours: ``(first, last)`` hour of the window each render's time of day is drawn in, uniformly, within
        [0, 24] (``first == last``: always that hour, clouds and exposure still drawn)
    :param cars: Passing cars placed at random in every render
    :param yaw_jitter_deg: Each render's camera is turned by an angle drawn uniformly in ``[-j, j]`` degrees off the
        view bearing, ``0 <= j <=`` :data:`MAX_YAW_JITTER_DEG`
    :param seed: Seed of the renders' conditions (render ``k`` of view ``d`` of node ``n`` from ``(seed, n, d, k)``)
    :raises ValueError: naming the field that is out of range
    :raises TypeError: naming the field that has the wrong type
    """

    renders: int = 8
    hours: tuple[float, float] = (9.0, 17.0)
    cars: bool = True
    yaw_jitter_deg: float = 3.0
    seed: int = 0

    def __post_init__(self) -> None:
        if isinstance(self.renders, bool) or not isinstance(self.renders, (int, np.integer)) or self.renders < 1:
            raise ValueError(f"ViewVariation.renders must be an int >= 1 (renders per view), got {self.renders!r}")
        try:
            first, last = (float(hour) for hour in self.hours)
        except (TypeError, ValueError):
            raise TypeError(f"ViewVariation.hours must be a pair of hours (first, last), got {self.hours!r}") from None
        if not 0.0 <= first <= last <= 24.0:
            raise ValueError(
                f"ViewVariation.hours must be a window (first, last) with 0 <= first <= last <= 24, got {self.hours!r}"
            )
        if not isinstance(self.cars, (bool, np.bool_)):
            raise TypeError(f"ViewVariation.cars must be True or False, got {self.cars!r}")
        if isinstance(self.yaw_jitter_deg, bool) or not isinstance(self.yaw_jitter_deg, (int, float, np.number)):
            raise TypeError(f"ViewVariation.yaw_jitter_deg must be a number of degrees, got {self.yaw_jitter_deg!r}")
        if not 0.0 <= float(self.yaw_jitter_deg) <= MAX_YAW_JITTER_DEG:
            raise ValueError(
                f"ViewVariation.yaw_jitter_deg must be in [0, {MAX_YAW_JITTER_DEG:g}] degrees (a few degrees of camera "
                f"yaw; more would look down another road), got {self.yaw_jitter_deg!r}"
            )
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise ValueError(f"ViewVariation.seed must be an int >= 0, got {self.seed!r}")
        # Normalised: a YAML list of hours and numpy scalars compare and key like the plain values
        object.__setattr__(self, "renders", int(self.renders))
        object.__setattr__(self, "hours", (first, last))
        object.__setattr__(self, "cars", bool(self.cars))
        object.__setattr__(self, "yaw_jitter_deg", float(self.yaw_jitter_deg))
        object.__setattr__(self, "seed", int(self.seed))

    @classmethod
    def of(cls, value: ViewVariation | int | Mapping[str, Any] | None) -> ViewVariation | None:
        """
        The variation an env's ``view_variation`` argument asks for.

        :param value: ``None`` (fixed views), an int K (``ViewVariation(renders=K)``), a mapping of fields (e.g. a YAML
            ``{renders: 8, hours: [9, 17]}``) or a ``ViewVariation``
        :return: the variation, or ``None`` for fixed views
        :raises TypeError: for another type, or an unknown field (naming it and the fields there are)
        :raises ValueError: as the constructor
        """
        if value is None or isinstance(value, ViewVariation):
            return value
        if isinstance(value, (int, np.integer)) and not isinstance(value, bool):
            return cls(renders=int(value))
        if isinstance(value, Mapping):
            return settings_from_mapping(cls, value, "view_variation")
        raise TypeError(
            f"view_variation must be None, an int (renders per view), a mapping of ViewVariation fields or a "
            f"ViewVariation, got {type(value).__name__} {value!r}"
        )

    def key(self) -> str:
        """Stable string of the variation's version and every field, for cache keys."""
        first, last = self.hours
        return (
            f"variation-v{VARIATION_VERSION}|renders={self.renders}|hours={first:.6g}-{last:.6g}|cars={self.cars}"
            f"|yaw_jitter_deg={self.yaw_jitter_deg:.6g}|seed={self.seed}"
        )

    def shot(self, node: int, view: int, render: int) -> tuple[Shot, np.random.Generator]:
        """
        Render ``render`` of view ``view`` (compass slot) of ``node``: its conditions, and the generator the renderer
        draws the rest of its random parts from (cloud cover, exposure, where the cars are).

        :param node: Intersection id
        :param view: Compass slot (0 N, 1 E, 2 S, 3 W)
        :param render: Render index in ``[0, renders)``
        :return: ``(shot, rng)``, the same for the same arguments on every machine
        :raises ValueError: if ``render`` is out of range
        """
        if not 0 <= render < self.renders:
            raise ValueError(f"render {render} out of range [0, {self.renders})")
        rng = np.random.default_rng([self.seed, int(node), int(view), int(render)])
        first, last = self.hours
        hour = float(rng.uniform(first, last)) if last > first else first
        yaw = float(rng.uniform(-self.yaw_jitter_deg, self.yaw_jitter_deg)) if self.yaw_jitter_deg > 0 else 0.0
        return Shot(time_of_day=hour, cars=self.cars, yaw_offset_deg=yaw), rng


class VariedRenderer:
    """
    Draws the K renders of every intersection's four views (see the module docstring): render ``k`` of node ``n`` is
    entry ``n * K + k`` of :meth:`render_node`, so that the feature cache, the worker pool and Ray build a varied world
    as they build fixed views (a ``NodeRenderer``; picklable, the 3D world is copied, not rebuilt).

    :param world: The scene (see :func:`~campusnav_env.rendering.world.build_world`)
    :param settings: Camera settings; their ``time_of_day`` and ``cars`` must be unset (each render draws its own)
    :param variation: How the renders vary
    :raises ValueError: if the settings fix a time of day or cars
    """

    def __init__(self, world: World, settings: RenderSettings | None, variation: ViewVariation) -> None:
        settings = RenderSettings() if settings is None else settings
        check_settings_vary(settings)
        self.variation = variation
        self.renderer = StreetViewRenderer(world, settings)

    def render(self, node: int, render: int, *, closed_roads: Collection[tuple[int, int]] = ()) -> np.ndarray:
        """
        Render ``render`` of the four views of ``node`` (N, E, S, W), each view in its own conditions.

        :param node: Intersection id
        :param render: Render index in ``[0, K)``
        :param closed_roads: Roads that show a construction barrier at both ends (same conditions as without them)
        :return: ``(4, height, width, 3)`` uint8 RGB images
        """
        views = []
        for view in range(len(COMPASS)):
            shot, rng = self.variation.shot(node, view, render)
            views.append(self.renderer.render_view(node, view, closed_roads=closed_roads, rng=rng, shot=shot))
        return np.stack(views)

    def render_node(self, entry: int) -> np.ndarray:
        """``(4, height, width, 3)``: render ``entry % K`` of node ``entry // K`` (the cache's entry ``entry``)."""
        node, render = divmod(int(entry), self.variation.renders)
        return self.render(node, render)


def check_settings_vary(settings: RenderSettings) -> None:
    """
    Refuse render settings that fix what a varied world draws per render (they would be silently ignored).

    :raises ValueError: naming the setting
    """
    if settings.time_of_day is not None or settings.cars:
        raise ValueError(
            "view_variation draws each render's hour and cars: leave render_settings' time_of_day at None and cars at "
            f"False (got time_of_day={settings.time_of_day!r}, cars={settings.cars!r}); the hour window is "
            "ViewVariation.hours"
        )
