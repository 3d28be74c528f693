"""
Street-view renderer: what a camera at an intersection sees in each of its four compass slots.

The camera is a horizontal pinhole camera standing at the intersection (``eye_height`` above the road) with a 90-degree
horizontal field of view, like a street-view car. View ``d`` of a node (``d`` = 0 N, 1 E, 2 S, 3 W, the node's compass
slots, :mod:`campusnav_env.maps.compass`) looks along the *view bearing* of that slot: the initial bearing of the road
in slot ``d`` (``RoadGraph.slot_bearings``), or the slot's compass bearing 0/90/180/270 where the slot is empty (see
:func:`~campusnav_env.maps.compass.view_bearings`). So the road seen straight ahead in view ``d`` is always the road
that the action pointing to slot ``d`` takes, even where a road sits far from its slot's compass bearing. One shared
:class:`~campusnav_env.rendering.world.World` supplies every view, so the same building seen from two intersections
looks related.

:class:`StreetViewRenderer` composes the parts of a view (numpy + OpenCV, no display; about 15-30 ms for a 640x480
view on one core), each drawing into the shared buffers of a :class:`~campusnav_env.rendering.camera.View`:

1. **Sky and ground** (:mod:`~campusnav_env.rendering.ground`): a gradient that follows the time of day; roads,
   markings, fields and parks as the exact perspective image of a top-down texture.
2. **Buildings** (:mod:`~campusnav_env.rendering.buildings`): walls found per image column by a ray cast, textured
   facades, landmark names on their walls.
3. **Trees, cars, monument signs, closure barriers** (:mod:`~campusnav_env.rendering.props`,
   :mod:`~campusnav_env.rendering.buildings`, :mod:`~campusnav_env.rendering.barriers`): billboards and boxes drawn
   far to near and depth-tested against the walls. A closed road (``closed_roads`` of
   :meth:`StreetViewRenderer.render_node`) gets a construction barrier at each end, :data:`BARRIER_OFFSET` along it.

Appearance changes (``RenderSettings.time_of_day``, ``RenderSettings.cars``) draw their random part (cloud cover,
exposure, which windows are lit, where the cars are) from the ``rng`` passed to the render call, so they are
reproducible; without an ``rng`` they come from a generator seeded by the world seed and the node. A :class:`Shot`
given to :meth:`StreetViewRenderer.render_view` replaces the settings' hour and cars for that one picture and turns the
camera a few degrees off the view bearing: a world whose pictures vary between visits
(:class:`~campusnav_env.rendering.variation.ViewVariation`) is drawn shot by shot.
"""

from __future__ import annotations

from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, fields
from typing import Any, TypeVar

import cv2
import numpy as np

from campusnav_env.maps.compass import view_bearings
from campusnav_env.rendering.barriers import BARRIER_OFFSET, BARRIER_VERSION, Barrier, ClosureBarriers
from campusnav_env.rendering.buildings import Buildings
from campusnav_env.rendering.camera import Camera, View
from campusnav_env.rendering.ground import Ground, Sky
from campusnav_env.rendering.lighting import Lighting, lighting_at
from campusnav_env.rendering.props import Car, Trees, cars_in_view, sample_cars
from campusnav_env.rendering.scene import World

__all__ = [
    "BARRIER_OFFSET",
    "BARRIER_VERSION",
    "RENDERER_VERSION",
    "RenderSettings",
    "Shot",
    "StreetViewRenderer",
    "settings_from_mapping",
    "view_bearings",  # moved to campusnav_env.maps.compass, still importable from here
]

# Bump when the drawing changes: feature caches key on RenderSettings.key().
# v2: each view looks along its slot's road (RoadGraph.slot_bearings) instead of the compass bearing.
RENDERER_VERSION = 2

Settings = TypeVar("Settings")


@dataclass(frozen=True)
class RenderSettings:
    """
    Camera and appearance settings of the street views.

    :param width: Image width (pixels)
    :param height: Image height (pixels)
    :param fov_deg: Horizontal field of view (degrees)
    :param eye_height: Camera height above the road (m); 2.5 m is a street-view car's camera mast
    :param time_of_day: Hour in [0, 24] that sets sun, sky and lit windows, with random cloud cover and exposure drawn
        from the render call's rng; ``None`` = fixed noon without variation
    :param cars: Draw passing cars on the roads near the camera (positions and colours from the rng)
    :raises ValueError: if a setting is out of range
    """

    width: int = 640
    height: int = 480
    fov_deg: float = 90.0
    eye_height: float = 2.5
    time_of_day: float | None = None
    cars: bool = False

    def __post_init__(self) -> None:
        if not (isinstance(self.width, int) and isinstance(self.height, int)) or self.width < 16 or self.height < 16:
            raise ValueError(f"width and height must be ints >= 16, got {self.width}x{self.height}")
        if not 10.0 <= float(self.fov_deg) <= 150.0:
            raise ValueError(f"fov_deg must be in [10, 150], got {self.fov_deg}")
        if not 0.5 <= float(self.eye_height) <= 5.5:
            raise ValueError(f"eye_height must be in [0.5, 5.5] m (below the lowest building), got {self.eye_height}")
        if self.time_of_day is not None and not 0.0 <= float(self.time_of_day) <= 24.0:
            raise ValueError(f"time_of_day must be an hour in [0, 24] or None, got {self.time_of_day}")

    def key(self) -> str:
        """Stable string of the renderer version and every field, for cache keys."""
        parts = [f"streetview-v{RENDERER_VERSION}"]
        for f in fields(self):
            value = getattr(self, f.name)
            parts.append(f"{f.name}={value!r}" if not isinstance(value, float) else f"{f.name}={value:.6g}")
        return "|".join(parts)


def settings_from_mapping(cls: type[Settings], value: Mapping[str, Any], what: str) -> Settings:
    """
    A settings dataclass (:class:`RenderSettings`, a view variation, a view build) from a mapping of its fields, e.g. a
    YAML entry's ``env_kwargs``.

    :param cls: The dataclass
    :param value: Its fields by name
    :param what: The argument's name, for the message (e.g. ``"view_variation"``)
    :return: ``cls(**value)``
    :raises TypeError: naming the unknown fields and the fields there are
    """
    known = [f.name for f in fields(cls)]  # type: ignore[arg-type]
    unknown = sorted(str(key) for key in value if key not in known)
    if unknown:
        raise TypeError(f"{what}: unknown field(s) {unknown}; the fields are {known}")
    return cls(**value)


@dataclass(frozen=True)
class Shot:
    """
    The conditions of one picture where they change from picture to picture (a varied world, see
    :class:`~campusnav_env.rendering.variation.ViewVariation`): they replace the settings' ``time_of_day`` and
    ``cars`` for that picture, and the camera is turned ``yaw_offset_deg`` off the view bearing (a street-view car
    never stops at exactly the same angle).

    :param time_of_day: Hour in [0, 24] (random cloud cover and exposure drawn from the render call's rng), or
        ``None`` for the fixed noon
    :param cars: Draw passing cars (positions and colours from the render call's rng)
    :param yaw_offset_deg: Degrees clockwise added to the view bearing, in [-45, 45]
    :raises ValueError: if a field is out of range
    """

    time_of_day: float | None = None
    cars: bool = False
    yaw_offset_deg: float = 0.0

    def __post_init__(self) -> None:
        if self.time_of_day is not None and not 0.0 <= float(self.time_of_day) <= 24.0:
            raise ValueError(f"Shot.time_of_day must be an hour in [0, 24] or None, got {self.time_of_day}")
        if not -45.0 <= float(self.yaw_offset_deg) <= 45.0:
            raise ValueError(f"Shot.yaw_offset_deg must be in [-45, 45] degrees, got {self.yaw_offset_deg}")


class StreetViewRenderer:
    """
    Draws the four views at every intersection of a :class:`~campusnav_env.rendering.world.World`, view ``d``
    looking along the road in compass slot ``d`` (``view_bearings[node, d]``, see
    :func:`~campusnav_env.maps.compass.view_bearings`).

    :param world: The scene (see :func:`~campusnav_env.rendering.world.build_world`)
    :param settings: Camera and appearance settings; ``None`` = defaults
    :raises TypeError: if ``world`` is not a ``World`` or ``settings`` not a ``RenderSettings``
    """

    def __init__(self, world: World, settings: RenderSettings | None = None) -> None:
        if not isinstance(world, World):
            raise TypeError(f"world must be a campusnav_env.rendering.world.World, got {type(world).__name__}")
        settings = RenderSettings() if settings is None else settings
        if not isinstance(settings, RenderSettings):
            raise TypeError(f"settings must be a RenderSettings, got {type(settings).__name__}")
        self.world = world
        self.settings = settings
        self.camera = Camera(settings.width, settings.height, settings.fov_deg, settings.eye_height)
        # The camera's intrinsics, as before the renderer came in parts
        self.width, self.height = self.camera.width, self.camera.height
        self.fx, self.fy, self.cx, self.cy, self.eye = (
            self.camera.fx,
            self.camera.fy,
            self.camera.cx,
            self.camera.cy,
            self.camera.eye,
        )
        self.positions = np.asarray(world.graph.positions, dtype=np.float64)
        # (N, 4) bearing each view looks along: the road in the slot, the compass bearing where the slot is empty
        self.view_bearings = view_bearings(world.graph)
        self._sky = Sky()
        self._ground = Ground(world)
        self._buildings = Buildings(world)
        self._trees = Trees(world)
        self._barriers = ClosureBarriers(world, self._ground.roads)

    # ----------------------------------------------------------------------------------------------------------------
    # Public API
    # ----------------------------------------------------------------------------------------------------------------

    def view_bearing(self, node: int, direction: int) -> float:
        """
        The bearing that view ``direction`` of ``node`` looks along: the initial bearing of the road in that compass
        slot, or the slot's compass bearing ``90 * direction`` where it is empty.

        :param node: Intersection id
        :param direction: Compass slot (0 N, 1 E, 2 S, 3 W)
        :return: Degrees clockwise from north, in ``[0, 360)``
        :raises ValueError: if the node or the direction is out of range
        :raises TypeError: if the node is not an int
        """
        node = self._check_node(node)
        return float(self.view_bearings[node, self._check_direction(direction)])

    def render_view(
        self,
        node: int,
        direction: int,
        *,
        closed_roads: Collection[tuple[int, int]] = (),
        rng: np.random.Generator | None = None,
        shot: Shot | None = None,
    ) -> np.ndarray:
        """
        The view from ``node`` in compass slot ``direction`` (0 N, 1 E, 2 S, 3 W), looking along
        :meth:`view_bearing` ``(node, direction)``: down the road that the action pointing to that slot takes.

        :param node: Intersection id
        :param direction: Compass slot
        :param closed_roads: Roads (node pairs, either order) that show a construction barrier at both ends
        :param rng: Source of the random appearance changes (only used when the settings or the shot ask for them)
        :param shot: This picture's hour, cars and camera yaw offset, in place of the settings' hour and cars
            (``None``: the settings')
        :return: ``(height, width, 3)`` uint8 RGB image
        :raises ValueError: if the node or the direction is out of range
        :raises TypeError: if the node is not an int
        :raises KeyError: if a closed road is not a road of the graph
        """
        node = self._check_node(node)
        direction = self._check_direction(direction)
        barriers = self._barriers.on_roads(closed_roads)
        lighting, cars = self._moment(node, rng, salt=direction + 1, shot=shot)
        yaw_offset_deg = 0.0 if shot is None else float(shot.yaw_offset_deg)
        return self._render(node, direction, lighting, cars, barriers, yaw_offset_deg=yaw_offset_deg)

    def render_node(
        self, node: int, *, closed_roads: Collection[tuple[int, int]] = (), rng: np.random.Generator | None = None
    ) -> np.ndarray:
        """
        The four views at ``node`` in slot order N, E, S, W (each along its :meth:`view_bearing`), taken at one
        moment (same light, same cars).

        :param node: Intersection id
        :param closed_roads: Roads (node pairs, either order) that show a construction barrier at both ends,
            :data:`BARRIER_OFFSET` along the road from each intersection: a closed road of ``node`` is seen blocked
            straight ahead in the view of its slot. Without closed roads the views are exactly the open map's.
        :param rng: Source of the random appearance changes (only used when the settings ask for them)
        :return: ``(4, height, width, 3)`` uint8 RGB images
        :raises ValueError: if the node is out of range
        :raises TypeError: if the node is not an int
        :raises KeyError: if a closed road is not a road of the graph
        """
        node = self._check_node(node)
        barriers = self._barriers.on_roads(closed_roads)
        lighting, cars = self._moment(node, rng, salt=0)
        return np.stack([self._render(node, d, lighting, cars, barriers) for d in range(4)])

    # ----------------------------------------------------------------------------------------------------------------
    # Checks, the moment, drawing
    # ----------------------------------------------------------------------------------------------------------------

    def _check_node(self, node: int) -> int:
        if isinstance(node, bool) or not isinstance(node, (int, np.integer)):
            raise TypeError(f"node must be an int, got {node!r}")
        if not 0 <= int(node) < len(self.positions):
            raise ValueError(f"node {node} out of range for a graph of {len(self.positions)} intersections")
        return int(node)

    @staticmethod
    def _check_direction(direction: int) -> int:
        if isinstance(direction, bool) or direction not in (0, 1, 2, 3):
            raise ValueError(f"direction must be 0 (N), 1 (E), 2 (S) or 3 (W), got {direction!r}")
        return int(direction)

    def _moment(
        self, node: int, rng: np.random.Generator | None, salt: int, shot: Shot | None = None
    ) -> tuple[Lighting, list[Car]]:
        """
        The light and the cars of one moment at ``node`` (``salt`` tells apart the render calls without an rng): the
        settings' hour and cars, or the shot's where one is given.
        """
        conditions = self.settings if shot is None else shot
        hour, with_cars = conditions.time_of_day, conditions.cars
        if hour is None and not with_cars:
            return lighting_at(None, None), []
        if rng is None:
            rng = np.random.default_rng([self.world.seed, node, salt, 0x5EED])
        lighting = lighting_at(hour, rng if hour is not None else None)
        cars = (
            sample_cars(self._ground.roads, self._ground.road_index, self.world.road_width, self.positions[node], rng)
            if with_cars
            else []
        )
        return lighting, cars

    def _render(
        self,
        node: int,
        direction: int,
        lighting: Lighting,
        cars: list[Car],
        barriers: list[Barrier],
        *,
        yaw_offset_deg: float = 0.0,
    ) -> np.ndarray:
        # The road in this slot, or its compass bearing (turned by a shot's yaw offset)
        bearing = self.view_bearings[node, direction] + yaw_offset_deg
        view = View.looking(self.camera, node, self.positions[node], bearing, lighting)
        self._sky.draw(view)
        self._ground.draw(view)
        visible_walls = self._buildings.draw_walls(view)
        self._buildings.draw_facade_signs(view, visible_walls)
        self._draw_props(view, cars, barriers)
        return cv2.convertScaleAbs(view.image)  # rounds and saturates to uint8 (all colours are >= 0)

    def _draw_props(self, view: View, cars: list[Car], barriers: list[Barrier]) -> None:
        """
        Trees (all at once), then cars, monument signs and closure barriers far to near, each depth-tested against
        what is drawn.
        """
        self._trees.draw(view)
        # (depth, tie-break, draw): sorted on the first two only, cars >= 0, signs then barrier parts < 0
        items: list[tuple[float, int, Callable[[], None]]] = [
            (z, i, draw) for i, (z, draw) in enumerate(cars_in_view(view, cars))
        ]
        others = self._buildings.sign_posts_in_view(view) + self._barriers.in_view(view, barriers)
        items += [(z, -1 - k, draw) for k, (z, draw) in enumerate(others)]
        for _, _, draw in sorted(items, key=lambda item: item[:2], reverse=True):
            draw()
