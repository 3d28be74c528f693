"""
Sky, ground and roads of the street views.

The sky is a vertical gradient whose colours follow the time of day. The ground (roads with asphalt, verges,
sidewalks, dashed centre lines and zebra crossings; fields with their lines; parks) is drawn top-down into a texture
around the intersection, once per node; the ground half of each view is the exact perspective image of that plane (a
homography, ``cv2.warpPerspective``), so road surfaces and markings are projected correctly and clipped at the camera.
"""

from __future__ import annotations

import math
from collections import OrderedDict

import cv2
import numpy as np

from campusnav_env.maps.geometry import points_along
from campusnav_env.rendering.camera import View
from campusnav_env.rendering.lighting import fog_amount
from campusnav_env.rendering.palette import ASPHALT_RGB, GRASS_RGB, MARKING_RGB, SIDEWALK_RGB
from campusnav_env.rendering.scene import World
from campusnav_env.rendering.spatial_index import SpatialIndex

__all__ = ["GROUND_RADIUS", "GROUND_RES", "Ground", "Sky"]

GROUND_RES = 0.3  # ground texture resolution (m per texel)
GROUND_RADIUS = 240.0  # the ground texture covers +-this around the intersection (m)


class Sky:
    """The sky above the horizon: a gradient from the horizon colour to the zenith colour of the view's light."""

    def __init__(self) -> None:
        # The last gradient drawn: every view of one moment has the same sky
        self._cache: tuple[tuple[bytes, bytes], np.ndarray] | None = None

    def draw(self, view: View) -> None:
        """Fill the sky half of the view (above the horizon) with the gradient of its light."""
        camera, lighting = view.camera, view.lighting
        sky = view.image[: camera.horizon]
        n = sky.shape[0]
        if n == 0:
            return
        key = (lighting.sky_top.tobytes(), lighting.sky_horizon.tobytes())
        if self._cache is None or self._cache[0] != key:
            # Angle above the horizon of each row: the gradient is steepest near the horizon, as in real skies.
            elevation = (camera.cy - np.arange(n, dtype=np.float32)) / camera.fy
            t = (np.clip(np.arctan(elevation) / (math.pi / 3), 0.0, 1.0) ** 0.6)[:, None]
            rows = lighting.sky_horizon[None, :] * (1 - t) + lighting.sky_top[None, :] * t
            self._cache = (key, np.ascontiguousarray(np.broadcast_to(rows[:, None, :], sky.shape)))
        sky[:] = self._cache[1]


class Ground:
    """
    The ground plane around every intersection of a world: roads, markings, fields and parks, with a fixed grain.

    :param world: The scene; ``roads`` (its road polylines) and ``road_index`` (their boxes) serve the cars and
        closure barriers too
    """

    def __init__(self, world: World) -> None:
        self.world = world
        self.roads = [np.asarray(g, dtype=np.float64) for g in world.graph.geometries]
        if self.roads:
            lo = np.stack([g.min(axis=0) for g in self.roads])
            hi = np.stack([g.max(axis=0) for g in self.roads])
        else:
            lo = hi = np.zeros((0, 2))
        self.road_index = SpatialIndex(lo, hi, cell=200.0)
        # Dashed centre lines (3 m dash, 6 m gap), kept clear of the intersections.
        dashes = []
        for g in self.roads:
            seg = np.linalg.norm(np.diff(g, axis=0), axis=1)
            total = float(seg.sum())
            if total < 30.0:
                continue
            cum = np.concatenate([[0.0], np.cumsum(seg)])
            s0 = np.arange(12.0, total - 15.0, 9.0)
            starts, ends = points_along(g, cum, s0), points_along(g, cum, s0 + 3.0)
            dashes.append(np.stack([starts, ends], axis=1))
        self._dashes = np.concatenate(dashes) if dashes else np.zeros((0, 2, 2))
        self._dash_index = SpatialIndex(self._dashes.min(axis=1), self._dashes.max(axis=1), cell=100.0)
        # Zebra crossings on every road of intersections with three or more roads.
        stripes = []
        half = world.road_width / 2
        degree = np.zeros(world.graph.n_nodes, dtype=np.int64)
        for u, v in world.graph.roads:
            degree[u] += 1
            degree[v] += 1
        for (u, v), g in zip(world.graph.roads, self.roads, strict=True):
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
        self._cache: OrderedDict[int, tuple[np.ndarray, np.ndarray]] = OrderedDict()

    def _texture(self, node: int, cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Top-down texture of the ground around ``node`` (and its 4x smaller copy for distant rows), cached."""
        cached = self._cache.get(node)
        if cached is not None:
            self._cache.move_to_end(node)
            return cached
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
            f = self.world.fields[i]
            cv2.fillPoly(tex, [px(f.polygon)], f.rgb, cv2.LINE_AA, shift)
            if f.lines:
                thickness = max(1, round(0.15 / GROUND_RES))
                cv2.polylines(tex, [px(line) for line in f.lines], False, MARKING_RGB, thickness, cv2.LINE_AA, shift)
        roads = [px(self.roads[i]) for i in self.road_index.query(cam, reach)]
        if roads:
            rw = self.world.road_width
            for colour, width in (
                (SIDEWALK_RGB, rw + 2 * (self.world.verge_width + self.world.sidewalk_width)),
                (GRASS_RGB, rw + 2 * self.world.verge_width),
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
        self._cache[node] = (tex, small)
        while len(self._cache) > 2:
            self._cache.popitem(last=False)
        return tex, small

    def draw(self, view: View) -> None:
        """Fill the ground half of the view (below the horizon) with the perspective image of the ground texture."""
        camera = view.camera
        horizon = camera.horizon
        tex, small = self._texture(view.node, view.cam)
        h, w = camera.height, camera.width
        eye, fx, fy, cx, cy = camera.eye, camera.fx, camera.fy, camera.cx, camera.cy
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
        fog = fog_amount(z)[:, None, None]
        ground = view.image[horizon:]
        np.multiply(out, (view.lighting.ground * (1 - fog)).astype(np.float32), out=ground)
        ground += (view.lighting.haze * fog).astype(np.float32)
