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

How a view is drawn (numpy + OpenCV, no display; about 15-30 ms for a 640x480 view on one core):

1. **Sky**: a vertical gradient whose colours follow the time of day.
2. **Ground**: roads (asphalt, verges, sidewalks, dashed centre lines, zebra crossings), fields with their lines and
   parks are drawn top-down into a texture around the intersection, once per node; the ground half of each view is the
   exact perspective image of that plane (a homography, ``cv2.warpPerspective``), so road surfaces and markings are
   projected correctly and clipped at the camera.
3. **Buildings**: walls are vertical and the camera has no pitch, so every image column is a ray in the ground plane.
   Each column's ray is intersected with the front-facing walls within range; walls nearer to the camera hide the
   lower part of farther ones (all buildings are taller than the eye), so a running minimum of the wall tops, nearest
   first, gives the visible wall of every pixel exactly: no painter's-order errors and no near-plane artefacts.
   Facades are textured per pixel (windows per storey and pitch, cornice, entrance), shaded by the sun direction,
   anti-aliased with distance and fogged. Landmark signs are warped onto their wall where it is visible.
4. **Trees, cars, monument signs, closure barriers**: billboards/boxes drawn far to near and depth-tested against the
   walls. A closed road (``closed_roads`` of :meth:`StreetViewRenderer.render_node`) gets a construction barrier at
   each end, :data:`BARRIER_OFFSET` along it from the intersection: red-and-white striped boards on trestles across
   the asphalt, a "ROAD CLOSED" sign on top and two orange cones in front. The barrier is a vertical plane, so its
   picture is one exact homography of a texture and its depth is exact per image column.

Appearance changes (``RenderSettings.time_of_day``, ``RenderSettings.cars``) draw their random part (cloud cover,
exposure, which windows are lit, where the cars are) from the ``rng`` passed to the render call, so they are
reproducible; without an ``rng`` they come from a generator seeded by the world seed and the node.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Collection
from dataclasses import dataclass, fields
from functools import partial

import cv2
import numpy as np

from campusnav_env.maps.compass import view_bearings
from campusnav_env.rendering.palette import (
    ASPHALT_RGB,
    BARRIER_LEG_RGB,
    BARRIER_RED_RGB,
    BARRIER_WHITE_RGB,
    CAR_PALETTE,
    CONE_ORANGE_RGB,
    GRASS_RGB,
    LIT_WINDOW_RGB,
    MARKING_RGB,
    SIDEWALK_RGB,
    TRUNK_RGB,
)
from campusnav_env.rendering.scene import World, footprint_walls
from campusnav_env.rendering.spatial_index import SpatialIndex

__all__ = [
    "BARRIER_OFFSET",
    "BARRIER_VERSION",
    "RENDERER_VERSION",
    "RenderSettings",
    "StreetViewRenderer",
    "view_bearings",  # moved to campusnav_env.maps.compass, still importable from here
]

# Bump when the drawing changes: feature caches key on RenderSettings.key().
# v2: each view looks along its slot's road (RoadGraph.slot_bearings) instead of the compass bearing.
RENDERER_VERSION = 2
# Bump when the closure barriers' drawing changes: only views rendered with closed roads key on it.
BARRIER_VERSION = 1

MAX_DISTANCE = 400.0  # objects farther than this are not drawn (m)
NEAR = 0.3  # near plane (m)
FOG_START = 40.0  # haze begins beyond this distance, so that nearby colours stay true (m)
FOG_DISTANCE = 900.0  # e-folding distance of the haze beyond FOG_START (m)
GROUND_RES = 0.3  # ground texture resolution (m per texel)
GROUND_RADIUS = 240.0  # the ground texture covers +-this around the intersection (m)
# Where the closed road leaves the intersection: past the crossing road's asphalt (6 m), before the zebra crossing
BARRIER_OFFSET = 9.0  # distance along a closed road from each end to its barrier (m)
BARRIER_NEAR = 1.0  # barrier parts nearer to the camera than this are clipped (m)
BARRIER_TOP = 2.75  # top of the "ROAD CLOSED" sign above the road (m)
BARRIER_RAILS = ((0.4, 0.75), (0.9, 1.25), (1.4, 1.75))  # (bottom, top) of the striped boards (m)
BARRIER_TEXELS_PER_M = 64  # barrier texture resolution: sharp at 640x480 down to about 5 m away


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


@dataclass(frozen=True)
class _Lighting:
    """Colours and light multipliers of one moment (all float32, colours on the 0..255 scale)."""

    sky_top: np.ndarray
    sky_horizon: np.ndarray
    haze: np.ndarray
    sun_dir: np.ndarray  # horizontal unit vector towards the sun (east, north)
    sun: np.ndarray  # direct light on a wall facing the sun, per channel
    ambient: np.ndarray  # light on a wall in shade, per channel
    ground: np.ndarray  # light on the ground, per channel
    lit_windows: float  # share of windows lit from inside
    window_sky: float  # how much the sky reflects in the glass


def _smoothstep(a: float, b: float, x: float) -> float:
    t = min(1.0, max(0.0, (x - a) / (b - a)))
    return t * t * (3.0 - 2.0 * t)


def _mix(a: tuple[float, ...] | np.ndarray, b: tuple[float, ...] | np.ndarray, t: float) -> np.ndarray:
    return np.asarray(a, dtype=np.float32) * (1.0 - t) + np.asarray(b, dtype=np.float32) * t


def _lighting(hour: float | None, rng: np.random.Generator | None) -> _Lighting:
    """Sun position and colours for ``hour`` (``None`` = fixed noon), with cloud and exposure jitter from ``rng``."""
    cloud, exposure = 0.15, 1.0
    if hour is None:
        hour = 12.0
    elif rng is not None:
        cloud = float(rng.uniform(0.0, 0.75))
        exposure = float(rng.uniform(0.9, 1.1))
    elevation = 62.0 * math.sin(math.pi * (hour - 6.0) / 12.0)
    azimuth = math.radians((90.0 + (hour - 6.0) * 15.0) % 360.0)
    day = _smoothstep(-8.0, 6.0, elevation)
    golden = 1.0 - _smoothstep(2.0, 22.0, elevation)
    top = _mix(_mix((8, 12, 30), (72, 92, 150), day), _mix((62, 118, 200), (88, 104, 160), golden), day)
    horizon = _mix(_mix((26, 32, 56), (236, 160, 104), day), _mix((184, 208, 232), (244, 176, 120), golden), day)
    grey = np.float32(0.72 * day + 0.12) * np.float32(230)
    top = _mix(top, (grey, grey, grey + 6), 0.8 * cloud)
    horizon = _mix(horizon, (grey + 8, grey + 8, grey + 10), 0.7 * cloud)
    sun_colour = _mix((1.0, 0.98, 0.94), (1.0, 0.72, 0.48), golden)
    direct = day * min(1.0, max(0.0, math.sin(math.radians(elevation)) * 2.5)) * (1.0 - 0.85 * cloud)
    ambient = _mix((0.16, 0.18, 0.28), (0.6, 0.62, 0.66), day) * np.float32(1.0 + 0.15 * cloud * day)
    sun = sun_colour * np.float32(0.5 * direct * math.cos(math.radians(max(elevation, 0.0))))
    ground = ambient * np.float32(0.85) + sun_colour * np.float32(
        0.45 * direct * max(0.2, math.sin(math.radians(elevation)))
    )
    scale = np.float32(exposure)
    return _Lighting(
        sky_top=top * scale,
        sky_horizon=horizon * scale,
        haze=horizon * scale,
        sun_dir=np.array([math.sin(azimuth), math.cos(azimuth)]),
        sun=sun * scale,
        ambient=ambient * scale,
        ground=ground * scale,
        lit_windows=0.4 * (1.0 - day),
        window_sky=0.25 * day,
    )


@dataclass(frozen=True)
class _Car:
    center: np.ndarray
    along: np.ndarray
    rgb: tuple[int, int, int]


@dataclass(frozen=True)
class _Barrier:
    """A closed road's barrier: a vertical board across the road, facing the intersection it guards."""

    centre: np.ndarray  # ground point on the road's centreline (east, north)
    facing: np.ndarray  # horizontal unit vector along the road towards that intersection


@dataclass(frozen=True)
class _View:
    """What the drawing steps of one rendered view share: the camera, the light and the buffers they fill in place."""

    node: int
    cam: np.ndarray  # camera position (east, north)
    fwd: np.ndarray  # horizontal unit vector the camera looks along
    right: np.ndarray  # horizontal unit vector to the camera's right
    lighting: _Lighting
    image: np.ndarray  # (height, width, 3) float32 colours
    depth: np.ndarray  # (height, width) float32 distance along ``fwd`` of what each pixel shows (inf: nothing yet)
    wall_of_pixel: np.ndarray  # (height, width) int32 id of the wall each pixel shows (-1: none)


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
        self.width, self.height = settings.width, settings.height
        self.fx = self.fy = (self.width / 2.0) / math.tan(math.radians(settings.fov_deg) / 2.0)
        self.cx, self.cy = (self.width - 1) / 2.0, (self.height - 1) / 2.0
        self.eye = float(settings.eye_height)
        self.positions = np.asarray(world.graph.positions, dtype=np.float64)
        # (N, 4) bearing each view looks along: the road in the slot, the compass bearing where the slot is empty
        self.view_bearings = view_bearings(world.graph)
        # Camera-space x/z of each column's ray (the ray direction is forward + x * right).
        self._col_x = (np.arange(self.width) - self.cx) / self.fx
        self._rows = np.arange(self.height, dtype=np.float32)
        self._prepare_walls()
        self._prepare_ground()
        self._prepare_sprites()
        self._ground_cache: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()
        self._sky_cache: tuple[tuple[bytes, bytes], np.ndarray] | None = None
        self._road_barriers: dict[int, tuple[_Barrier, _Barrier]] = {}
        self._barrier_image: np.ndarray | None = None

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
    ) -> np.ndarray:
        """
        The view from ``node`` in compass slot ``direction`` (0 N, 1 E, 2 S, 3 W), looking along
        :meth:`view_bearing` ``(node, direction)``: down the road that the action pointing to that slot takes.

        :param node: Intersection id
        :param direction: Compass slot
        :param closed_roads: Roads (node pairs, either order) that show a construction barrier at both ends
        :param rng: Source of the random appearance changes (only used when the settings ask for them)
        :return: ``(height, width, 3)`` uint8 RGB image
        :raises ValueError: if the node or the direction is out of range
        :raises TypeError: if the node is not an int
        :raises KeyError: if a closed road is not a road of the graph
        """
        node = self._check_node(node)
        direction = self._check_direction(direction)
        barriers = self._barriers(closed_roads)
        lighting, cars = self._moment(node, rng, salt=direction + 1)
        return self._render(node, direction, lighting, cars, barriers)

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
        barriers = self._barriers(closed_roads)
        lighting, cars = self._moment(node, rng, salt=0)
        return np.stack([self._render(node, d, lighting, cars, barriers) for d in range(4)])

    # ----------------------------------------------------------------------------------------------------------------
    # Set-up
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

    def _prepare_walls(self) -> None:
        buildings = self.world.buildings
        a, b, owner = footprint_walls(buildings)
        self._wall_a, self._wall_b, self._wall_owner = a, b, owner
        d = b - a
        self._wall_len = np.linalg.norm(d, axis=1)
        self._wall_normal = np.stack([d[:, 1], -d[:, 0]], axis=1) / np.maximum(self._wall_len, 1e-9)[:, None]
        self._wall_index = SpatialIndex(np.minimum(a, b), np.maximum(a, b), cell=100.0)
        n = len(buildings)
        self._b_height = np.array([x.height for x in buildings], dtype=np.float32).reshape(n)
        self._b_facade = np.array([x.facade_rgb for x in buildings], dtype=np.float32).reshape(n, 3)
        self._b_window = np.array([x.window_rgb for x in buildings], dtype=np.float32).reshape(n, 3)
        self._b_floor = np.array([x.floor_height for x in buildings], dtype=np.float32).reshape(n)
        self._b_spacing = np.array([x.window_spacing for x in buildings], dtype=np.float32).reshape(n)
        self._b_win_w = np.array([x.window_width for x in buildings], dtype=np.float32).reshape(n)
        self._b_win_h = np.array([x.window_height for x in buildings], dtype=np.float32).reshape(n)
        # The wall facing the landmark's intersection gets an entrance; it and every other long wall carry the name.
        first_wall = np.concatenate([[0], np.cumsum([len(x.footprint) for x in buildings])])[:-1].astype(np.int64)
        self._wall_door = np.zeros(len(a), dtype=bool)
        self._signs: list[tuple[int, str]] = []  # (wall id, text)
        for i, x in enumerate(buildings):
            if x.name is None:
                continue
            if x.sign_wall is not None:
                self._wall_door[int(first_wall[i] + x.sign_wall)] = True
            for k in range(len(x.footprint)):
                wall = int(first_wall[i] + k)
                if k == x.sign_wall or self._wall_len[wall] >= 20.0:
                    self._signs.append((wall, x.name))
        self._sign_images: dict[str, np.ndarray] = {}

    def _prepare_ground(self) -> None:
        world = self.world
        self._roads = [np.asarray(g, dtype=np.float64) for g in world.graph.geometries]
        if self._roads:
            lo = np.stack([g.min(axis=0) for g in self._roads])
            hi = np.stack([g.max(axis=0) for g in self._roads])
        else:
            lo = hi = np.zeros((0, 2))
        self._road_index = SpatialIndex(lo, hi, cell=200.0)
        # Dashed centre lines (3 m dash, 6 m gap), kept clear of the intersections.
        dashes = []
        for g in self._roads:
            seg = np.linalg.norm(np.diff(g, axis=0), axis=1)
            total = float(seg.sum())
            if total < 30.0:
                continue
            cum = np.concatenate([[0.0], np.cumsum(seg)])
            s0 = np.arange(12.0, total - 15.0, 9.0)
            starts, ends = self._along(g, cum, s0), self._along(g, cum, s0 + 3.0)
            dashes.append(np.stack([starts, ends], axis=1))
        self._dashes = np.concatenate(dashes) if dashes else np.zeros((0, 2, 2))
        self._dash_index = SpatialIndex(self._dashes.min(axis=1), self._dashes.max(axis=1), cell=100.0)
        # Zebra crossings on every road of intersections with three or more roads.
        stripes = []
        half = world.road_width / 2
        degree = np.zeros(len(self.positions), dtype=np.int64)
        for u, v in world.graph.roads:
            degree[u] += 1
            degree[v] += 1
        for (u, v), g in zip(world.graph.roads, self._roads, strict=True):
            for node, pts in ((u, g), (v, g[::-1])):
                if degree[node] < 3:
                    continue
                first = pts[1] - pts[0]
                length = float(np.linalg.norm(first))
                if length < 30.0:
                    continue
                along = first / length
                across = np.array([-along[1], along[0]])
                centre = pts[0] + along * 12.5
                offsets = np.arange(-half + 0.6, half - 0.3, 1.2)
                for o in offsets:
                    c = centre + across * o
                    stripes.append(
                        np.array(
                            [
                                c - along * 1.5 - across * 0.3,
                                c + along * 1.5 - across * 0.3,
                                c + along * 1.5 + across * 0.3,
                                c - along * 1.5 + across * 0.3,
                            ]
                        )
                    )
        self._stripes = np.stack(stripes) if stripes else np.zeros((0, 4, 2))
        self._stripe_index = SpatialIndex(self._stripes.min(axis=1), self._stripes.max(axis=1), cell=100.0)
        fields_ = world.fields
        self._field_index = SpatialIndex(
            np.array([f.polygon.min(axis=0) for f in fields_]).reshape(-1, 2),
            np.array([f.polygon.max(axis=0) for f in fields_]).reshape(-1, 2),
            cell=200.0,
        )
        # Fixed multiplicative grain (fine speckle + larger patches, 128 = 1.0) so that no surface is a flat colour.
        size = round(2 * GROUND_RADIUS / GROUND_RES)
        noise = np.random.default_rng(12345).normal(0.0, 1.0, (size, size)).astype(np.float32)
        grain = cv2.GaussianBlur(noise, (0, 0), 0.8) * 0.09 + cv2.GaussianBlur(noise, (0, 0), 8.0) * 1.2
        self._ground_base = np.empty((size, size, 3), dtype=np.uint8)
        self._ground_base[:, :] = np.asarray(GRASS_RGB, dtype=np.uint8)
        self._grain = np.repeat(np.clip(128.0 * (1.0 + grain), 0, 255).astype(np.uint8)[..., None], 3, axis=2)

    @staticmethod
    def _along(g: np.ndarray, cum: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Points at arc lengths ``s`` along polyline ``g`` with cumulative lengths ``cum``."""
        k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(g) - 2)
        t = (s - cum[k]) / np.maximum(cum[k + 1] - cum[k], 1e-9)
        return g[k] + t[:, None] * (g[k + 1] - g[k])

    def _prepare_sprites(self) -> None:
        trees = self.world.trees
        self._tree_pos = np.array([t.position for t in trees], dtype=np.float64).reshape(-1, 2)
        self._tree_radius = np.array([t.radius for t in trees], dtype=np.float64)
        self._tree_height = np.array([t.height for t in trees], dtype=np.float64)
        self._tree_rgb = np.array([t.crown_rgb for t in trees], dtype=np.float32).reshape(-1, 3)
        self._tree_index = SpatialIndex(self._tree_pos, self._tree_pos, cell=100.0)

    # ----------------------------------------------------------------------------------------------------------------
    # Random moment: light and cars
    # ----------------------------------------------------------------------------------------------------------------

    def _moment(self, node: int, rng: np.random.Generator | None, salt: int) -> tuple[_Lighting, list[_Car]]:
        settings = self.settings
        if settings.time_of_day is None and not settings.cars:
            return _lighting(None, None), []
        if rng is None:
            rng = np.random.default_rng([self.world.seed, node, salt, 0x5EED])
        lighting = _lighting(settings.time_of_day, rng if settings.time_of_day is not None else None)
        cars = self._sample_cars(node, rng) if settings.cars else []
        return lighting, cars

    def _sample_cars(self, node: int, rng: np.random.Generator) -> list[_Car]:
        """Cars in the right-hand lane of the roads near ``node`` (about one per 45 m of road), none at the camera."""
        cam = self.positions[node]
        cars: list[_Car] = []
        lane = self.world.road_width / 4
        for road in self._road_index.query(cam, 180.0):
            g = self._roads[road]
            seg = np.linalg.norm(np.diff(g, axis=0), axis=1)
            cum = np.concatenate([[0.0], np.cumsum(seg)])
            total = float(cum[-1])
            n = int(rng.poisson(total / 45.0))
            s = rng.uniform(8.0, max(total - 8.0, 8.5), size=n)
            sides = rng.integers(0, 2, size=n)
            colours = rng.integers(0, len(CAR_PALETTE), size=n)
            if n == 0:
                continue
            k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(g) - 2)
            along = (g[k + 1] - g[k]) / np.maximum(seg[k], 1e-9)[:, None]
            pts = self._along(g, cum, s)
            for p, a, side, colour in zip(pts, along, sides, colours, strict=True):
                direction = a if side == 0 else -a
                centre = p + np.array([direction[1], -direction[0]]) * lane  # right of the driving direction
                if np.linalg.norm(centre - cam) < 14.0 or np.linalg.norm(centre - cam) > 180.0:
                    continue
                cars.append(_Car(centre, direction, CAR_PALETTE[int(colour)]))
        return cars

    # ----------------------------------------------------------------------------------------------------------------
    # Drawing
    # ----------------------------------------------------------------------------------------------------------------

    def _render(
        self, node: int, direction: int, lighting: _Lighting, cars: list[_Car], barriers: list[_Barrier]
    ) -> np.ndarray:
        yaw = math.radians(self.view_bearings[node, direction])  # the road in this slot, or its compass bearing
        h, w = self.height, self.width
        view = _View(
            node=node,
            cam=self.positions[node],
            fwd=np.array([math.sin(yaw), math.cos(yaw)]),
            right=np.array([math.cos(yaw), -math.sin(yaw)]),
            lighting=lighting,
            image=np.empty((h, w, 3), dtype=np.float32),
            depth=np.full((h, w), np.inf, dtype=np.float32),
            wall_of_pixel=np.full((h, w), -1, dtype=np.int32),
        )
        horizon = math.floor(self.cy) + 1  # first ground row
        self._draw_sky(view.image[:horizon], lighting)
        self._draw_ground(view, horizon)
        visible_walls = self._draw_walls(view)
        self._draw_facade_signs(view, visible_walls)
        self._draw_sprites(view, cars, barriers)
        return cv2.convertScaleAbs(view.image)  # rounds and saturates to uint8 (all colours are >= 0)

    def _fog(self, z: np.ndarray) -> np.ndarray:
        beyond = np.maximum(np.asarray(z, dtype=np.float32) - np.float32(FOG_START), np.float32(0.0))
        return (1.0 - np.exp(-beyond / np.float32(FOG_DISTANCE))).astype(np.float32)

    def _draw_sky(self, sky: np.ndarray, lighting: _Lighting) -> None:
        n = sky.shape[0]
        if n == 0:
            return
        key = (lighting.sky_top.tobytes(), lighting.sky_horizon.tobytes())
        if self._sky_cache is None or self._sky_cache[0] != key:
            # Angle above the horizon of each row: the gradient is steepest near the horizon, as in real skies.
            elevation = (self.cy - np.arange(n, dtype=np.float32)) / self.fy
            t = (np.clip(np.arctan(elevation) / (math.pi / 3), 0.0, 1.0) ** 0.6)[:, None]
            rows = lighting.sky_horizon[None, :] * (1 - t) + lighting.sky_top[None, :] * t
            self._sky_cache = (key, np.ascontiguousarray(np.broadcast_to(rows[:, None, :], sky.shape)))
        sky[:] = self._sky_cache[1]

    def _ground_texture(self, node: int) -> tuple[np.ndarray, np.ndarray]:
        """Top-down texture of the ground around ``node`` (and its 4x smaller copy for distant rows), cached."""
        cached = self._ground_cache.get(node)
        if cached is not None:
            self._ground_cache.move_to_end(node)
            return cached
        world = self.world
        cam = self.positions[node]
        tex = self._ground_base.copy()
        origin = np.array([cam[0] - GROUND_RADIUS, cam[1] + GROUND_RADIUS])
        shift = 4
        scale = (1 << shift) / GROUND_RES

        def px(points: np.ndarray) -> np.ndarray:
            p = np.asarray(points, dtype=np.float64)
            out = np.empty(p.shape)
            out[..., 0] = (p[..., 0] - origin[0]) * scale - 0.5 * (1 << shift)
            out[..., 1] = (origin[1] - p[..., 1]) * scale - 0.5 * (1 << shift)
            return np.round(out).astype(np.int32)

        reach = GROUND_RADIUS * 1.5
        for i in self._field_index.query(cam, reach):
            f = world.fields[i]
            cv2.fillPoly(tex, [px(f.polygon)], f.rgb, cv2.LINE_AA, shift)
            if f.lines:
                thickness = max(1, round(0.15 / GROUND_RES))
                cv2.polylines(tex, [px(line) for line in f.lines], False, MARKING_RGB, thickness, cv2.LINE_AA, shift)
        roads = [px(self._roads[i]) for i in self._road_index.query(cam, reach)]
        if roads:
            rw = world.road_width
            for colour, width in (
                (SIDEWALK_RGB, rw + 2 * (world.verge_width + world.sidewalk_width)),
                (GRASS_RGB, rw + 2 * world.verge_width),
                (ASPHALT_RGB, rw),
            ):
                cv2.polylines(tex, roads, False, colour, max(1, round(width / GROUND_RES)), cv2.LINE_AA, shift)
        stripes = self._stripes[self._stripe_index.query(cam, reach)]
        if len(stripes):
            cv2.fillPoly(tex, list(px(stripes)), MARKING_RGB, cv2.LINE_AA, shift)
        dashes = self._dashes[self._dash_index.query(cam, reach)]
        if len(dashes):
            thickness = max(1, round(0.2 / GROUND_RES))
            cv2.polylines(tex, list(px(dashes)), False, MARKING_RGB, thickness, cv2.LINE_AA, shift)
        tex = cv2.multiply(tex, self._grain, scale=1.0 / 128.0)
        small = cv2.resize(tex, (tex.shape[1] // 4, tex.shape[0] // 4), interpolation=cv2.INTER_AREA)
        self._ground_cache[node] = (tex, small)
        while len(self._ground_cache) > 2:
            self._ground_cache.popitem(last=False)
        return tex, small

    def _draw_ground(self, view: _View, horizon: int) -> None:
        tex, small = self._ground_texture(view.node)
        h, w = self.height, self.width
        eye, fx, fy, cx, cy = self.eye, self.fx, self.fy, self.cx, self.cy
        cam, fwd, right = view.cam, view.fwd, view.right
        # Ground point of output pixel (u, v' = v - horizon), homogeneous: (X*W, Y*W, W) with W = (v - cy) / fy.
        g = np.array(
            [
                [eye * right[0] / fx, cam[0] / fy, cam[0] * (horizon - cy) / fy + eye * (fwd[0] - right[0] * cx / fx)],
                [eye * right[1] / fx, cam[1] / fy, cam[1] * (horizon - cy) / fy + eye * (fwd[1] - right[1] * cx / fx)],
                [0.0, 1.0 / fy, (horizon - cy) / fy],
            ]
        )
        x0, y0 = cam[0] - GROUND_RADIUS, cam[1] + GROUND_RADIUS
        out = np.empty((h - horizon, w, 3), dtype=np.uint8)
        # Distant rows sample the 4x smaller texture (a one-level mipmap) so that road markings do not alias.
        split = min(h, horizon + max(0, math.ceil(fy * eye / 45.0 - (horizon - cy))))
        for tex_, res, r0, r1 in ((small, GROUND_RES * 4, horizon, split), (tex, GROUND_RES, split, h)):
            if r1 <= r0:
                continue
            to_tex = np.array([[1.0 / res, 0.0, -x0 / res - 0.5], [0.0, -1.0 / res, y0 / res - 0.5], [0.0, 0.0, 1.0]])
            shift = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, r0 - horizon], [0.0, 0.0, 1.0]])
            m = to_tex @ g @ shift
            out[r0 - horizon : r1 - horizon] = cv2.warpPerspective(
                tex_,
                m,
                (w, r1 - r0),
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=GRASS_RGB,
            )
        z = fy * eye / (np.arange(horizon, h, dtype=np.float32) - np.float32(cy))
        fog = self._fog(z)[:, None, None]
        ground = view.image[horizon:]
        np.multiply(out, (view.lighting.ground * (1 - fog)).astype(np.float32), out=ground)
        ground += (view.lighting.haze * fog).astype(np.float32)

    def _draw_walls(self, view: _View) -> np.ndarray:
        """
        Cast one ray per column through the walls; fill facade pixels, depth and wall ids.

        :return: Ids of the walls that some pixel shows
        """
        ids = self._wall_index.query(view.cam, MAX_DISTANCE)
        if len(ids) == 0:
            return ids
        a, b = self._wall_a[ids] - view.cam, self._wall_b[ids] - view.cam
        xa, za = a @ view.right, a @ view.fwd
        xb, zb = b @ view.right, b @ view.fwd
        tan_half = self.cx / self.fx + 1e-6
        keep = (
            ((-a * self._wall_normal[ids]).sum(axis=1) > 1e-9)  # front-facing: the camera is on the outer side
            & ((za > NEAR) | (zb > NEAR))
            & ~((xa > za * tan_half) & (xb > zb * tan_half))  # both ends right of the frustum
            & ~((xa < -za * tan_half) & (xb < -zb * tan_half))  # both ends left of it
            & (np.minimum(za, zb) < MAX_DISTANCE)
        )
        ids, xa, za, xb, zb = ids[keep], xa[keep], za[keep], xb[keep], zb[keep]
        if len(ids) == 0:
            return ids
        # Columns each wall covers, after clipping it at the near plane.
        dx, dz = xb - xa, zb - za
        with np.errstate(divide="ignore", invalid="ignore"):
            ta = np.where(za < NEAR, (NEAR - za) / dz, 0.0)
            tb = np.where(zb < NEAR, (NEAR - za) / dz, 1.0)
        ua = self.cx + self.fx * (xa + ta * dx) / (za + ta * dz)
        ub = self.cx + self.fx * (xa + tb * dx) / (za + tb * dz)
        c0 = np.clip(np.ceil(np.minimum(ua, ub)), 0, self.width).astype(np.int64)
        c1 = np.clip(np.floor(np.maximum(ua, ub)), -1, self.width - 1).astype(np.int64)
        span = np.maximum(c1 - c0 + 1, 0)
        k = np.repeat(np.arange(len(ids)), span)
        col = np.repeat(c0, span) + (np.arange(span.sum()) - np.repeat(np.cumsum(span) - span, span))
        # Ray of column c: (x_c * z, z). Solve x_c * (za + t dz) = xa + t dx for t; then z = za + t dz.
        xc = self._col_x[col]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (xc * za[k] - xa[k]) / (dx[k] - xc * dz[k])
        z = za[k] + t * dz[k]
        hit = (t >= -1e-9) & (t <= 1.0 + 1e-9) & (z > NEAR) & (z < MAX_DISTANCE)
        col, z, t, wall = col[hit], z[hit], np.clip(t[hit], 0.0, 1.0), ids[k[hit]]
        if len(col) == 0:
            return col
        height = self._b_height[self._wall_owner[wall]]
        top = self.cy - self.fy * (height - self.eye) / z
        # Nearest first within each column; a hit is visible where its top rises above every nearer hit's top
        # (buildings are taller than the eye, so nearer walls hide the lower part of farther ones).
        order = np.lexsort((z, col))
        col, z, t, wall, top = col[order], z[order], t[order], wall[order], top[order]
        big = 4.0 * (self.height + self.fy * 100.0)  # exceeds the range of `top`: per-column running minimum
        running = np.minimum.accumulate(top - col * big) + col * big
        first = np.ones(len(col), dtype=bool)
        first[1:] = col[1:] != col[:-1]
        prev = np.empty_like(running)
        prev[0] = np.inf
        prev[1:] = running[:-1]
        visible = first | (top < prev)
        col, z, t, wall, top, prev, first = (x[visible] for x in (col, z, t, wall, top, prev, first))
        # Pixel rows of each visible hit: [top, top of the previous visible hit), the nearest down to its ground line.
        r0 = np.clip(np.ceil(top), 0, self.height).astype(np.int64)
        r1 = np.where(first, np.floor(self.cy + self.fy * self.eye / z) + 1, np.ceil(prev))
        r1 = np.clip(r1, 0, self.height).astype(np.int64)
        n_rows = np.maximum(r1 - r0, 0)
        hit_of_px = np.repeat(np.arange(len(col)), n_rows)
        rows = np.repeat(r0, n_rows) + (np.arange(n_rows.sum()) - np.repeat(np.cumsum(n_rows) - n_rows, n_rows))
        flat = rows * self.width + col[hit_of_px]
        view.depth.reshape(-1)[flat] = z[hit_of_px]
        view.wall_of_pixel.reshape(-1)[flat] = wall[hit_of_px]
        view.image.reshape(-1, 3)[flat] = self._facade_colours(rows, hit_of_px, z, t, wall, view.lighting)
        return np.unique(wall)

    def _facade_colours(
        self,
        rows: np.ndarray,
        hit: np.ndarray,
        z: np.ndarray,
        t: np.ndarray,
        wall: np.ndarray,
        lighting: _Lighting,
    ) -> np.ndarray:
        """
        Facade colour of every wall pixel (``rows``, ``hit`` index into the per-hit ``z``, ``t``, ``wall``).

        Everything constant along a column of one wall (where along the wall, shading, haze, distance fading) is
        computed per hit; per pixel remain the storey, the window test and a lookup in a small per-hit palette.
        """
        bld = self._wall_owner[wall]
        length = self._wall_len[wall]
        u = t * length
        floor_h, spacing = self._b_floor[bld], self._b_spacing[bld]
        roof, win_w, win_h = self._b_height[bld], self._b_win_w[bld], self._b_win_h[bld]
        # Whole windows only, centred on the wall with a margin at its ends.
        n_cols = np.floor((length - 1.0) / spacing)
        ku = (u - (length - n_cols * spacing) / 2.0) / spacing
        window_col = (ku >= 0) & (ku < n_cols) & (np.abs(ku - np.floor(ku) - 0.5) < win_w / 2)
        col_hash = (np.floor(ku).astype(np.int64) * 73856093) ^ (wall * 83492791)
        door = self._wall_door[wall] & (np.abs(u - length / 2) < 1.8)
        # Light on this wall, and haze and distance fading of the window grid (finer than a pixel: show its mean).
        normal = self._wall_normal[wall]
        facing = np.clip(normal @ lighting.sun_dir, 0.0, None)
        fill = 0.08 * (normal @ np.array([-0.6, 0.8]))  # fixed fill light: walls at right angles never look the same
        shade = (lighting.ambient[None, :] + facing[:, None] * lighting.sun[None, :] + fill[:, None]).astype(np.float32)
        facade = self._b_facade[bld] * shade
        glass = (
            self._b_window[bld] * (0.55 + 0.45 * shade) + np.float32(lighting.window_sky * 0.5) * lighting.sky_horizon
        )
        lit = np.broadcast_to(np.asarray(LIT_WINDOW_RGB, dtype=np.float32), glass.shape)
        cornice = facade * np.float32(0.72)
        entrance = shade * np.float32(22.0)
        cover = (win_w * win_h)[:, None]
        mean = facade * (1 - cover) + glass * cover
        alpha = np.clip((np.minimum(spacing, floor_h) * self.fy / z - 3.0) / 4.0, 0.0, 1.0).astype(np.float32)[:, None]
        fog = self._fog(z)[:, None]
        palette = np.stack([facade, glass, lit, cornice, entrance], axis=1)  # (hits, 5, 3)
        palette = palette * alpha[:, None] + mean[:, None, :] * (1 - alpha[:, None])
        palette = palette * (1 - fog[:, None]) + lighting.haze * fog[:, None]
        amp = (0.2 * alpha[:, 0] * (1 - fog[:, 0])).astype(np.float32)
        # Storey coordinate of each pixel: height / floor_h = a - row * b.
        a = ((self.eye + self.cy * z / self.fy) / floor_h).astype(np.float32)
        b = (z / (self.fy * floor_h)).astype(np.float32)
        fv = a[hit] - rows.astype(np.float32) * b[hit]
        storey = np.floor(fv)
        pv = fv - storey
        fh = floor_h[hit]
        window = window_col[hit] & (np.abs(pv - 0.55) < win_h[hit] / 2) & (fv * fh > 0.8) & (fv * fh < roof[hit] - 0.9)
        pixel_hash = storey.astype(np.int64) * 19349663 + col_hash[hit]
        pixel_hash ^= pixel_hash >> 15
        pixel_hash = (pixel_hash * 0x2C1B3C6D) & 0xFFFFFFFF
        pixel_hash = (pixel_hash ^ (pixel_hash >> 12)) & 1023
        lit_px = window & (pixel_hash < int(lighting.lit_windows * 1024))
        idx = np.where(window, np.where(lit_px, 2, 1), 0)
        idx = np.where(fv * fh > roof[hit] - 0.6, 3, idx)
        idx = np.where(door[hit] & (fv * fh < 3.2), 4, idx)
        colour = palette[hit, idx]
        variation = np.where(idx == 1, 1.0 + amp[hit] * (pixel_hash.astype(np.float32) / 511.5 - 1.0), 1.0)
        return colour * variation[:, None].astype(np.float32)

    def _sign_image(self, text: str, board: tuple[int, int, int], ink: tuple[int, int, int]) -> np.ndarray:
        """RGBA image of a name board (cached): light letters on a board, 48 px high."""
        key = f"{text}|{board}|{ink}"
        cached = self._sign_images.get(key)
        if cached is not None:
            return cached
        font, scale, thickness = cv2.FONT_HERSHEY_DUPLEX, 1.2, 2
        (tw, th), _ = cv2.getTextSize(text, font, scale, thickness)
        img = np.zeros((48, tw + 24, 4), dtype=np.uint8)
        img[...] = (*board, 255)
        cv2.putText(img, text, (12, (48 + th) // 2), font, scale, (*ink, 255), thickness, cv2.LINE_AA)
        self._sign_images[key] = img
        return img

    def _project(self, pts: np.ndarray, heights: np.ndarray, view: _View) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates ``(n, 2)`` and depths ``(n,)`` of 3D points (ground position + height)."""
        rel = pts - view.cam
        x, z = rel @ view.right, rel @ view.fwd
        zs = np.maximum(z, 1e-6)
        uv = np.stack([self.cx + self.fx * x / zs, self.cy + self.fy * (self.eye - heights) / zs], axis=1)
        return uv, z

    @staticmethod
    def _fit_board(board: np.ndarray, quad: np.ndarray) -> np.ndarray:
        """The board shrunk (area-averaged) towards its on-screen size, so that small signs do not alias."""
        scale = float(np.ptp(quad[:, 1])) / board.shape[0]
        if scale >= 0.7:
            return board
        height = max(4, round(board.shape[0] * scale * 1.4))
        width = max(4, round(board.shape[1] * height / board.shape[0]))
        return cv2.resize(board, (width, height), interpolation=cv2.INTER_AREA)

    def _warp_board(
        self, board: np.ndarray, quad: np.ndarray
    ) -> tuple[tuple[int, int, int, int], np.ndarray, np.ndarray] | None:
        """
        Warp an RGBA board onto an image quad (TL, TR, BR, BL).

        :return: The clipped box ``(x0, y0, x1, y1)``, colours and alpha, or ``None`` where under 2 pixels show
        """
        x0, y0 = np.floor(quad.min(axis=0)).astype(int)
        x1, y1 = np.ceil(quad.max(axis=0)).astype(int) + 1
        x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, self.width), min(y1, self.height)
        if x1 - x0 < 2 or y1 - y0 < 2:
            return None
        bh, bw = board.shape[:2]
        src = np.float32([[0, 0], [bw, 0], [bw, bh], [0, bh]]) - 0.5
        m = cv2.getPerspectiveTransform(src, (quad - [x0, y0]).astype(np.float32))
        warped = cv2.warpPerspective(board, m, (x1 - x0, y1 - y0), flags=cv2.INTER_LINEAR, borderValue=(0, 0, 0, 0))
        return (x0, y0, x1, y1), warped[..., :3].astype(np.float32), warped[..., 3].astype(np.float32) / 255.0

    def _draw_facade_signs(self, view: _View, visible_walls: np.ndarray) -> None:
        if not self._signs:
            return
        visible = set(visible_walls.tolist())
        for wall, text in self._signs:
            if wall not in visible:
                continue
            a, b = self._wall_a[wall], self._wall_b[wall]
            length = float(self._wall_len[wall])
            board = self._sign_image(text, (240, 238, 228), (24, 24, 28))
            # Letters about 1.6 m high (the board is 2.4 m), above the entrance, never wider than the wall allows.
            sign_h = 2.4
            sign_w = min(length * 0.9, sign_h * board.shape[1] / board.shape[0])
            sign_h = sign_w * board.shape[0] / board.shape[1]
            bottom = 3.8
            unit = (b - a) / length
            left = a + unit * (length - sign_w) / 2 + self._wall_normal[wall] * 0.05
            right_end = left + unit * sign_w
            pts = np.array([left, right_end, right_end, left])
            heights = np.array([bottom + sign_h, bottom + sign_h, bottom, bottom])
            quad, z = self._project(pts, heights, view)
            if (z < NEAR).any():
                continue
            warped = self._warp_board(self._fit_board(board, quad), quad)
            if warped is None:
                continue
            (x0, y0, x1, y1), rgb, alpha = warped
            alpha = alpha * (view.wall_of_pixel[y0:y1, x0:x1] == wall)
            normal = self._wall_normal[wall]
            shade = view.lighting.ambient + max(0.0, float(normal @ view.lighting.sun_dir)) * view.lighting.sun + 0.1
            fog = float(self._fog(np.array(z.mean())))
            rgb = rgb * shade * (1 - fog) + view.lighting.haze * fog
            region = view.image[y0:y1, x0:x1]
            region[:] = region * (1 - alpha[..., None]) + rgb * alpha[..., None]

    def _draw_sprites(self, view: _View, cars: list[_Car], barriers: list[_Barrier]) -> None:
        """
        Trees (all at once), then cars, monument signs and closure barriers far to near, each depth-tested against
        what is drawn.
        """
        self._draw_trees(view)
        tan_half = self.cx / self.fx
        # (depth, tie-break, draw): sorted on the first two only, cars >= 0, signs and barrier parts < 0
        items: list[tuple[float, int, Callable[[], None]]] = []
        for i, car in enumerate(cars):
            rel = car.center - view.cam
            z = float(rel @ view.fwd)
            if z > 2.0 and abs(float(rel @ view.right)) - 3.0 < z * tan_half:
                items.append((z, i, partial(self._draw_car, view, car)))
        for i, sign in enumerate(self.world.signs):
            rel = sign.position - view.cam
            z = float(rel @ view.fwd)
            if 1.0 < z < MAX_DISTANCE and abs(float(rel @ view.right)) - sign.width < z * tan_half:
                items.append((z, -1 - i, partial(self._draw_sign_post, view, i)))
        for k, (z, draw) in enumerate(self._barrier_parts(view, barriers)):
            items.append((z, -1 - len(self.world.signs) - k, draw))
        for _, _, draw in sorted(items, key=lambda item: item[:2], reverse=True):
            draw()

    def _draw_trees(self, view: _View) -> None:
        """Every visible tree in one vectorised pass: a trunk and a two-tone crown, per-pixel nearest tree wins."""
        ids = self._tree_index.query(view.cam, MAX_DISTANCE)
        if len(ids) == 0:
            return
        rel = self._tree_pos[ids] - view.cam
        x, z = rel @ view.right, rel @ view.fwd
        radius = self._tree_radius[ids]
        ok = (z > 1.5) & (z < MAX_DISTANCE) & (np.abs(x) - radius < z * (self.cx / self.fx))
        ok &= self.fx * radius / np.maximum(z, 1.0) > 0.5
        ids, x, z, radius = ids[ok], x[ok], z[ok], radius[ok]
        if len(ids) == 0:
            return
        height = self._tree_height[ids]
        f = self.fy / z
        uc = (self.cx + self.fx * x / z).astype(np.float32)
        v_ground = self.cy + f * self.eye
        vc = (self.cy + f * (self.eye - (height - radius * 1.05))).astype(np.float32)
        rx, ry = (f * radius).astype(np.float32), (f * radius * 1.08).astype(np.float32)
        trunk_w = np.maximum(0.5, f * 0.2)
        # Pixel boxes: the crown's, and the trunk's below it (kept apart: a shared box would be mostly empty).
        boxes = np.stack(
            [
                np.concatenate([uc - rx - 1, uc - trunk_w - 1]),
                np.concatenate([uc + rx + 1, uc + trunk_w + 1]),
                np.concatenate([vc - ry - 1, vc + 0.5 * ry]),
                np.concatenate([vc + ry + 1, v_ground + 1]),
            ]
        )
        x0, x1 = (np.clip(np.round(v), 0, self.width).astype(np.int64) for v in boxes[:2])
        y0, y1 = (np.clip(np.round(v), 0, self.height).astype(np.int64) for v in boxes[2:])
        bw, bh = np.maximum(x1 - x0, 0), np.maximum(y1 - y0, 0)
        n = bw * bh
        part = np.repeat(np.arange(2 * len(ids)), n)
        offset = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        cols = x0[part] + offset % np.maximum(bw[part], 1)
        rows = y0[part] + offset // np.maximum(bw[part], 1)
        tree = part % len(ids)
        is_trunk = part >= len(ids)
        flat = rows * self.width + cols
        # The trunk sits a hair behind its own crown, so that the crown wins where both cover a pixel.
        zt = (z[tree] + 0.01 * is_trunk).astype(np.float32)
        in_front = zt < view.depth.reshape(-1)[flat]
        tree, cols, rows, flat, zt, is_trunk = (a[in_front] for a in (tree, cols, rows, flat, zt, is_trunk))
        colsf, rowsf = cols.astype(np.float32), rows.astype(np.float32)
        du = (colsf - uc[tree]) / rx[tree]
        dv = (rowsf - vc[tree]) / ry[tree]
        dist = np.sqrt(du * du + dv * dv)
        crown = np.clip((1.0 - dist) * rx[tree] + 0.5, 0.0, 1.0) * ~is_trunk  # anti-aliased edge, ~1 pixel wide
        trunk = is_trunk & (np.abs(colsf - uc[tree]) < trunk_w[tree]) & (rowsf <= v_ground[tree])
        alpha = np.maximum(crown, trunk).astype(np.float32)
        keep = alpha > 0.02
        tree, flat, zt, du, dv, crown, alpha, is_trunk = (
            a[keep] for a in (tree, flat, zt, du, dv, crown, alpha, is_trunk)
        )
        # The nearest tree at each pixel wins (ties between trees at exactly one depth are harmless).
        nearest = np.full(self.width * self.height, np.inf, dtype=np.float32)
        np.minimum.at(nearest, flat, zt)
        win = zt == nearest[flat]
        tree, flat, zt, du, dv, alpha, is_trunk = (a[win] for a in (tree, flat, zt, du, dv, alpha, is_trunk))
        # Two-tone crown lit from the sun's side, blotchy leaves from a hash of the crown coordinates.
        side = float(view.lighting.sun_dir @ view.right)
        hx = 0.28 * (np.sign(side) if abs(side) > 0.2 else -1.0)
        highlight = ((du - hx) / 0.72) ** 2 + ((dv + 0.22) / 0.7) ** 2 < 1.0
        phase = (ids[tree] % 97).astype(np.float32)
        blotch = 0.5 + 0.25 * np.sin(du * 11.0 + phase) * np.sin(dv * 9.0 + 1.7 * phase)
        blotch += 0.25 * np.sin((du + dv) * 17.0 + 0.3 * phase) * np.sin((du - dv) * 13.0)
        base = self._tree_rgb[ids[tree]]
        tone = np.where(
            highlight[:, None], view.lighting.ambient + view.lighting.sun * 1.1, view.lighting.ambient * 0.8
        )
        leaf = base * tone * (0.8 + 0.4 * blotch).astype(np.float32)[:, None]
        bark = np.float32(TRUNK_RGB) * view.lighting.ambient
        colour = np.where(is_trunk[:, None], bark, leaf).astype(np.float32)
        fog = self._fog(zt)[:, None]
        colour = colour * (1 - fog) + view.lighting.haze * fog
        flat_image = view.image.reshape(-1, 3)
        a = alpha[:, None]
        flat_image[flat] = flat_image[flat] * (1 - a) + colour * a
        solid = alpha > 0.5
        view.depth.reshape(-1)[flat[solid]] = zt[solid]

    def _composite(self, view: _View, box: tuple[int, int, int, int], rgba: np.ndarray, z: float | np.ndarray) -> None:
        """
        Blend an RGBA patch (float colours, alpha 0..1) into the image where it is nearer than what is there.

        :param z: The patch's depth: one number, or an array broadcast against the patch (e.g. one per column)
        """
        x0, y0, x1, y1 = box
        zone = view.depth[y0:y1, x0:x1]
        alpha = rgba[..., 3] * (zone > z)
        region = view.image[y0:y1, x0:x1]
        region[:] = region * (1 - alpha[..., None]) + rgba[..., :3] * alpha[..., None]
        solid = alpha > 0.5
        zone[solid] = z if np.ndim(z) == 0 else np.broadcast_to(z, zone.shape)[solid]

    def _patch(self, x0: float, y0: float, x1: float, y1: float) -> tuple[tuple[int, int, int, int], int, int] | None:
        ix0, iy0 = max(math.floor(x0), 0), max(math.floor(y0), 0)
        ix1, iy1 = min(math.ceil(x1) + 1, self.width), min(math.ceil(y1) + 1, self.height)
        if ix1 <= ix0 or iy1 <= iy0:
            return None
        return (ix0, iy0, ix1, iy1), ix0, iy0

    def _draw_car(self, view: _View, car: _Car) -> None:
        along = car.along
        across = np.array([-along[1], along[0]])
        body = (car.center, 2.25, 0.9, 0.0, 0.95)  # centre, half length, half width, bottom, top
        cabin = (car.center - along * 0.25, 1.2, 0.78, 0.95, 1.45)
        colour = np.asarray(car.rgb, dtype=np.float32)
        glass = np.float32([40, 48, 58])
        faces: list[tuple[np.ndarray, np.ndarray]] = []  # (image polygon, rgb) in drawing order
        z_all = []
        for (centre, hl, hw, bottom, top), rgb in ((body, colour), (cabin, glass)):
            corners = np.array(
                [
                    centre - along * hl - across * hw,
                    centre + along * hl - across * hw,
                    centre + along * hl + across * hw,
                    centre - along * hl + across * hw,
                ]
            )
            lo_uv, lo_z = self._project(corners, np.full(4, bottom), view)
            hi_uv, _ = self._project(corners, np.full(4, top), view)
            if (lo_z < NEAR).any():
                return
            z_all.append(lo_z)
            for k in range(4):
                a, b = corners[k], corners[(k + 1) % 4]
                edge = b - a
                normal = np.array([edge[1], -edge[0]]) / max(float(np.linalg.norm(edge)), 1e-9)
                if float(normal @ (view.cam - (a + b) / 2)) <= 0:
                    continue
                light = view.lighting.ambient + max(0.0, float(normal @ view.lighting.sun_dir)) * view.lighting.sun
                poly = np.array([lo_uv[k], lo_uv[(k + 1) % 4], hi_uv[(k + 1) % 4], hi_uv[k]])
                faces.append((poly, rgb * light))
            faces.append((hi_uv, rgb * (view.lighting.ambient + view.lighting.sun * 0.9 + 0.1)))
        shadow_uv, _ = self._project(
            np.array(
                [
                    car.center - along * 2.4 - across * 1.0,
                    car.center + along * 2.4 - across * 1.0,
                    car.center + along * 2.4 + across * 1.0,
                    car.center - along * 2.4 + across * 1.0,
                ]
            ),
            np.zeros(4),
            view,
        )
        everything = np.concatenate([f[0] for f in faces] + [shadow_uv])
        placed = self._patch(*everything.min(axis=0), *everything.max(axis=0))
        if placed is None:
            return
        box, ox, oy = placed
        patch = np.zeros((box[3] - box[1], box[2] - box[0], 4), dtype=np.uint8)
        offset = np.array([ox, oy])
        cv2.fillPoly(patch, [np.round((shadow_uv - offset) * 16).astype(np.int32)], (20, 20, 22, 200), cv2.LINE_AA, 4)
        for poly, rgb in faces:
            rgba = (*map(int, np.clip(rgb, 0, 255)), 255)
            cv2.fillPoly(patch, [np.round((poly - offset) * 16).astype(np.int32)], rgba, cv2.LINE_AA, 4)
        z = float(np.concatenate(z_all).mean())
        out = patch.astype(np.float32)
        fog = float(self._fog(np.array(z)))
        out[..., :3] = out[..., :3] * (1 - fog) + view.lighting.haze * fog
        out[..., 3] /= 255.0
        self._composite(view, box, out, z)

    def _draw_sign_post(self, view: _View, i: int) -> None:
        sign = self.world.signs[i]
        rad = math.radians(sign.bearing)
        facing = np.array([math.sin(rad), math.cos(rad)])
        across = np.array([facing[1], -facing[0]])
        ends = np.array([sign.position - across * sign.width / 2, sign.position + across * sign.width / 2])
        uv_end, z_end = self._project(ends, np.full(2, sign.elevation), view)
        if (z_end < NEAR).any():
            return
        if uv_end[0, 0] > uv_end[1, 0]:  # read left to right from whichever side the camera is on
            ends = ends[::-1]
        board = self._sign_image(sign.text, sign.board_rgb, sign.text_rgb)
        top, bottom = sign.elevation + sign.height, sign.elevation
        pts = np.array([ends[0], ends[1], ends[1], ends[0]])
        quad, z = self._project(pts, np.array([top, top, bottom, bottom]), view)
        board = self._fit_board(board, quad)
        # Two posts from the ground to the board, at a fifth of its width from each end.
        feet = ends[0] + np.outer([0.2, 0.8], ends[1] - ends[0])
        post_top, _ = self._project(feet, np.full(2, bottom), view)
        post_foot, _ = self._project(feet, np.zeros(2), view)
        everything = np.concatenate([quad, post_foot])
        placed = self._patch(*everything.min(axis=0), *everything.max(axis=0))
        warped = self._warp_board(board, quad)
        if placed is None or warped is None:
            return
        box, ox, oy = placed
        patch = np.zeros((box[3] - box[1], box[2] - box[0], 4), dtype=np.float32)
        post_w = max(1, round(self.fx * 0.2 / float(z.mean())))
        offset = np.array([ox, oy])
        for top_pt, foot in zip(post_top, post_foot, strict=True):
            p0 = tuple(int(c) for c in np.round((top_pt - offset) * 16))
            p1 = tuple(int(c) for c in np.round((foot - offset) * 16))
            cv2.line(patch, p0, p1, (60.0, 60.0, 62.0, 1.0), post_w, cv2.LINE_AA, 4)
        (bx0, by0, bx1, by1), rgb, alpha = warped
        sub = patch[by0 - oy : by1 - oy, bx0 - ox : bx1 - ox]
        sub[..., :3] = sub[..., :3] * (1 - alpha[..., None]) + rgb * alpha[..., None]
        sub[..., 3] = np.maximum(sub[..., 3], alpha)
        light = view.lighting.ambient + view.lighting.sun * 0.5 + 0.15
        fog = float(self._fog(np.array(z.mean())))
        patch[..., :3] = patch[..., :3] * light * (1 - fog) + view.lighting.haze * fog
        self._composite(view, box, patch, float(z.mean()))

    # ----------------------------------------------------------------------------------------------------------------
    # Closure barriers
    # ----------------------------------------------------------------------------------------------------------------

    def _barriers(self, closed_roads: Collection[tuple[int, int]]) -> list[_Barrier]:
        """The barriers of the closed roads (two per road, placed once per road and kept)."""
        graph = self.world.graph
        barriers: list[_Barrier] = []
        for road in sorted({graph.road_id(int(u), int(v)) for u, v in closed_roads}):
            pair = self._road_barriers.get(road)
            if pair is None:
                pair = self._road_barriers[road] = self._place_barriers(road)
            barriers.extend(pair)
        return barriers

    def _place_barriers(self, road: int) -> tuple[_Barrier, _Barrier]:
        """One barrier :data:`BARRIER_OFFSET` along the road's polyline from each end (a third of short roads)."""
        g = self._roads[road]
        cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(g, axis=0), axis=1))])
        total = float(cum[-1])
        s = min(BARRIER_OFFSET, total / 3.0)
        # The road's direction over a metre around each barrier: robust to bends and degenerate segments
        at = np.array([s, total - s])
        centres = self._along(g, cum, at)
        ahead = self._along(g, cum, np.minimum(at + 0.5, total)) - self._along(g, cum, np.maximum(at - 0.5, 0.0))
        ahead /= np.maximum(np.linalg.norm(ahead, axis=1), 1e-9)[:, None]
        # The barrier near the first end faces back towards it, the one near the last end faces forward
        return _Barrier(centres[0], -ahead[0]), _Barrier(centres[1], ahead[1])

    def _barrier_parts(self, view: _View, barriers: list[_Barrier]) -> list[tuple[float, Callable[[], None]]]:
        """``(depth, draw)`` of every barrier board and cone in the view's frustum."""
        parts: list[tuple[float, Callable[[], None]]] = []
        tan_half = self.cx / self.fx
        half = self.world.road_width / 2
        for barrier in barriers:
            across = np.array([barrier.facing[1], -barrier.facing[0]])
            rel = barrier.centre + np.outer([-half, half], across) - view.cam
            x, z = rel @ view.right, rel @ view.fwd
            in_view = (
                (z > BARRIER_NEAR).any()
                and z.min() < MAX_DISTANCE
                and not (x > z * tan_half).all()  # both ends right of the frustum
                and not (x < -z * tan_half).all()  # both ends left of it
            )
            if in_view:
                parts.append((float(z.mean()), partial(self._draw_barrier, view, barrier)))
            # Two cones on the intersection's side of the board, in the lanes
            for offset in (-half + 2.0, half - 2.0):
                cone = barrier.centre + barrier.facing * 1.6 + across * offset
                x_cone, z_cone = (cone - view.cam) @ view.right, (cone - view.cam) @ view.fwd
                if BARRIER_NEAR < z_cone < MAX_DISTANCE and abs(x_cone) - 0.3 < z_cone * tan_half:
                    parts.append((float(z_cone), partial(self._draw_cone, view, cone)))
        return parts

    def _barrier_texture(self) -> np.ndarray:
        """
        RGBA picture of a barrier across the asphalt (built once): sections of three red-and-white striped boards on
        trestles, a "ROAD CLOSED" sign on top; rows top (:data:`BARRIER_TOP` m) to bottom (the ground).
        """
        if self._barrier_image is not None:
            return self._barrier_image
        width = self.world.road_width
        ppm = BARRIER_TEXELS_PER_M
        img = np.zeros((round(BARRIER_TOP * ppm), round(width * ppm), 4), dtype=np.uint8)
        n_rows, n_cols = img.shape[:2]

        def col(metres: float) -> int:
            return round(metres * ppm)

        def row(height: float) -> int:
            return round(n_rows - height * ppm)

        # Diagonal red and white bands, 0.25 m each: legible up close, a pink-red block from afar
        u, v = np.meshgrid(np.arange(n_cols) / ppm, (n_rows - np.arange(n_rows)) / ppm)
        red = ((u + v) / 0.5) % 1.0 < 0.5
        stripes = np.where(red[..., None], (*BARRIER_RED_RGB, 255), (*BARRIER_WHITE_RGB, 255)).astype(np.uint8)
        n_sections = max(1, round(width / 3.0))
        section = width / n_sections
        leg = (*BARRIER_LEG_RGB, 255)
        for k in range(n_sections):
            a, b = k * section + 0.06, (k + 1) * section - 0.06
            for x in (a + 0.15 * (b - a), b - 0.15 * (b - a)):
                cv2.rectangle(img, (col(x - 0.04), row(1.8)), (col(x + 0.04), row(0.0)), leg, -1)
                cv2.rectangle(img, (col(x - 0.3), row(0.06)), (col(x + 0.3), row(0.0)), (40, 40, 42, 255), -1)
            for bottom, top in BARRIER_RAILS:
                img[row(top) : row(bottom), col(a) : col(b)] = stripes[row(top) : row(bottom), col(a) : col(b)]
        # The sign: black letters on white with a black border, on two posts above the middle
        sign_w = min(3.0, 0.4 * width)
        left, right, bottom, top = (width - sign_w) / 2, (width + sign_w) / 2, 1.85, BARRIER_TOP - 0.02
        for x in (left + 0.2 * sign_w, right - 0.2 * sign_w):
            cv2.rectangle(img, (col(x - 0.04), row(bottom)), (col(x + 0.04), row(1.7)), leg, -1)
        cv2.rectangle(img, (col(left), row(top)), (col(right), row(bottom)), (*BARRIER_WHITE_RGB, 255), -1)
        cv2.rectangle(img, (col(left), row(top)), (col(right), row(bottom)), (20, 20, 22, 255), max(1, col(0.05)))
        text, font = "ROAD CLOSED", cv2.FONT_HERSHEY_DUPLEX
        (tw, th), _ = cv2.getTextSize(text, font, 1.0, 2)
        scale = min(0.86 * (col(right) - col(left)) / tw, 0.5 * (row(bottom) - row(top)) / th)
        (tw, th), _ = cv2.getTextSize(text, font, scale, max(1, round(2 * scale)))
        origin = ((n_cols - tw) // 2, (row(top) + row(bottom) + th) // 2)
        cv2.putText(img, text, origin, font, scale, (20, 20, 22, 255), max(1, round(2 * scale)), cv2.LINE_AA)
        self._barrier_image = img
        return img

    def _draw_barrier(self, view: _View, barrier: _Barrier) -> None:
        """The barrier board warped onto its plane (clipped at :data:`BARRIER_NEAR`), depth exact per column."""
        # Read from whichever side the camera is on: the texture's left end is the viewer's left
        looking = -barrier.facing if float((view.cam - barrier.centre) @ barrier.facing) > 0 else barrier.facing
        to_right = np.array([looking[1], -looking[0]])
        half = self.world.road_width / 2
        left, right = barrier.centre - to_right * half, barrier.centre + to_right * half
        texture = self._barrier_texture()
        z_ends = (np.array([left, right]) - view.cam) @ view.fwd
        # The texture columns in front of the near clip (a board seen from the side may reach behind the camera)
        t = np.array([0.0, 1.0])
        if z_ends[0] < BARRIER_NEAR:
            t[0] = (BARRIER_NEAR - z_ends[0]) / (z_ends[1] - z_ends[0])
        if z_ends[1] < BARRIER_NEAR:
            t[1] = (BARRIER_NEAR - z_ends[0]) / (z_ends[1] - z_ends[0])
        c0, c1 = math.floor(t[0] * texture.shape[1]), math.ceil(t[1] * texture.shape[1])
        if c1 - c0 < 2:
            return
        ends = left + np.outer(np.array([c0, c1]) / texture.shape[1], right - left)
        quad, _ = self._project(ends[[0, 1, 1, 0]], np.array([BARRIER_TOP, BARRIER_TOP, 0.0, 0.0]), view)
        board = texture[:, c0:c1]
        warped = self._warp_board(self._fit_board(board, quad), quad)
        if warped is None:
            return
        (x0, y0, x1, y1), rgb, alpha = warped
        # Depth of the board in each column: where the column's ray meets the board's ground line
        rel = ends - view.cam
        xa, za = rel[0] @ view.right, rel[0] @ view.fwd
        dx, dz = (rel[1] - rel[0]) @ view.right, (rel[1] - rel[0]) @ view.fwd
        xc = self._col_x[x0:x1]
        with np.errstate(divide="ignore", invalid="ignore"):
            along = (xc * za - xa) / (dx - xc * dz)
        along = np.clip(np.nan_to_num(along, nan=0.0), 0.0, 1.0)  # nan: a column that sees the board edge-on
        z = (za + along * dz).astype(np.float32)
        fog = self._fog(z)[None, :, None]
        light = view.lighting.ambient + view.lighting.sun * 0.5 + 0.15
        rgb = rgb * light * (1 - fog) + view.lighting.haze * fog
        self._composite(view, (x0, y0, x1, y1), np.concatenate([rgb, alpha[..., None]], axis=2), z[None, :])

    def _draw_cone(self, view: _View, position: np.ndarray) -> None:
        """A traffic cone (0.75 m, orange with a white band, on a dark base), seen from the side at any angle."""
        rel = position - view.cam
        x, z = float(rel @ view.right), float(rel @ view.fwd)
        f = self.fy / z
        u = self.cx + self.fx * x / z
        placed = self._patch(u - 0.25 * f, self.cy + f * (self.eye - 0.75), u + 0.25 * f, self.cy + f * self.eye)
        if placed is None:
            return
        box, ox, oy = placed
        patch = np.zeros((box[3] - box[1], box[2] - box[0], 4), dtype=np.uint8)
        light = view.lighting.ambient + view.lighting.sun * 0.5 + 0.15

        def outline(profile: list[tuple[float, float]]) -> np.ndarray:
            """Image polygon of a solid of revolution's profile, (height, half width) pairs from the bottom up."""
            heights = np.array([p[0] for p in profile] + [p[0] for p in profile[::-1]])
            widths = np.array([-p[1] for p in profile] + [p[1] for p in profile[::-1]])
            pts = np.stack([u + f * widths - ox, self.cy + f * (self.eye - heights) - oy], axis=1)
            return np.round(pts * 16).astype(np.int32)

        for profile, rgb in (
            ([(0.0, 0.22), (0.05, 0.22)], (36.0, 36.0, 38.0)),
            ([(0.05, 0.17), (0.75, 0.03)], CONE_ORANGE_RGB),
            ([(0.3, 0.124), (0.45, 0.094)], BARRIER_WHITE_RGB),
        ):
            colour = np.clip(np.asarray(rgb, dtype=np.float32) * light, 0, 255)
            cv2.fillPoly(patch, [outline(profile)], (*map(int, colour), 255), cv2.LINE_AA, 4)
        out = patch.astype(np.float32)
        fog = float(self._fog(np.array(z)))
        out[..., :3] = out[..., :3] * (1 - fog) + view.lighting.haze * fog
        out[..., 3] /= 255.0
        self._composite(view, box, out, z)
