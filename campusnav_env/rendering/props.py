"""
Props of the street views: trees and passing cars, billboards and boxes depth-tested against the walls.

Trees are drawn in one vectorised pass (a trunk and a two-tone crown each, the nearest tree winning per pixel); cars
(``RenderSettings.cars``) are sampled on the roads around the camera from the render call's rng and drawn as a body and
a cabin box, far to near with the monument signs and closure barriers.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

import cv2
import numpy as np

from campusnav_env.maps.geometry import points_along
from campusnav_env.rendering.camera import MAX_DISTANCE, NEAR, View
from campusnav_env.rendering.lighting import fog_amount
from campusnav_env.rendering.palette import CAR_PALETTE, TRUNK_RGB
from campusnav_env.rendering.scene import World
from campusnav_env.rendering.spatial_index import SpatialIndex

__all__ = ["Car", "Trees", "cars_in_view", "draw_car", "sample_cars"]


class Trees:
    """
    Every tree of a world, as arrays indexed by position.

    :param world: The scene
    """

    def __init__(self, world: World) -> None:
        trees = world.trees
        self._pos = np.array([t.position for t in trees], dtype=np.float64).reshape(-1, 2)
        self._radius = np.array([t.radius for t in trees], dtype=np.float64)
        self._height = np.array([t.height for t in trees], dtype=np.float64)
        self._rgb = np.array([t.crown_rgb for t in trees], dtype=np.float32).reshape(-1, 3)
        self._index = SpatialIndex(self._pos, self._pos, cell=100.0)

    def draw(self, view: View) -> None:
        """Every visible tree in one vectorised pass: a trunk and a two-tone crown, per-pixel nearest tree wins."""
        camera = view.camera
        ids = self._index.query(view.cam, MAX_DISTANCE)
        if len(ids) == 0:
            return
        rel = self._pos[ids] - view.cam
        x, z = rel @ view.right, rel @ view.fwd
        radius = self._radius[ids]
        ok = (z > 1.5) & (z < MAX_DISTANCE) & (np.abs(x) - radius < z * (camera.cx / camera.fx))
        ok &= camera.fx * radius / np.maximum(z, 1.0) > 0.5
        ids, x, z, radius = ids[ok], x[ok], z[ok], radius[ok]
        if len(ids) == 0:
            return
        height = self._height[ids]
        f = camera.fy / z
        uc = (camera.cx + camera.fx * x / z).astype(np.float32)
        v_ground = camera.cy + f * camera.eye
        vc = (camera.cy + f * (camera.eye - (height - radius * 1.05))).astype(np.float32)
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
        x0, x1 = (np.clip(np.round(v), 0, camera.width).astype(np.int64) for v in boxes[:2])
        y0, y1 = (np.clip(np.round(v), 0, camera.height).astype(np.int64) for v in boxes[2:])
        bw, bh = np.maximum(x1 - x0, 0), np.maximum(y1 - y0, 0)
        n = bw * bh
        part = np.repeat(np.arange(2 * len(ids)), n)
        offset = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        cols = x0[part] + offset % np.maximum(bw[part], 1)
        rows = y0[part] + offset // np.maximum(bw[part], 1)
        tree = part % len(ids)
        is_trunk = part >= len(ids)
        flat = rows * camera.width + cols
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
        nearest = np.full(camera.width * camera.height, np.inf, dtype=np.float32)
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
        base = self._rgb[ids[tree]]
        tone = np.where(
            highlight[:, None], view.lighting.ambient + view.lighting.sun * 1.1, view.lighting.ambient * 0.8
        )
        leaf = base * tone * (0.8 + 0.4 * blotch).astype(np.float32)[:, None]
        bark = np.float32(TRUNK_RGB) * view.lighting.ambient
        colour = np.where(is_trunk[:, None], bark, leaf).astype(np.float32)
        fog = fog_amount(zt)[:, None]
        colour = colour * (1 - fog) + view.lighting.haze * fog
        flat_image = view.image.reshape(-1, 3)
        a = alpha[:, None]
        flat_image[flat] = flat_image[flat] * (1 - a) + colour * a
        solid = alpha > 0.5
        view.depth.reshape(-1)[flat[solid]] = zt[solid]


@dataclass(frozen=True)
class Car:
    """A passing car: its centre on the lane, the unit vector it drives along, and its colour."""

    center: np.ndarray
    along: np.ndarray
    rgb: tuple[int, int, int]


def sample_cars(
    roads: Sequence[np.ndarray], road_index: SpatialIndex, road_width: float, cam: np.ndarray, rng: np.random.Generator
) -> list[Car]:
    """
    Cars in the right-hand lane of the roads near the camera (about one per 45 m of road), none at the camera.

    :param roads: Every road's polyline
    :param road_index: The roads' bounding boxes
    :param road_width: Asphalt width (m); cars drive a quarter of it right of the centreline
    :param cam: The camera position (east, north)
    :param rng: Where the cars are and what colour
    :return: The cars within 14-180 m of the camera
    """
    cars: list[Car] = []
    lane = road_width / 4
    for road in road_index.query(cam, 180.0):
        g = roads[road]
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
        pts = points_along(g, cum, s)
        for p, a, side, colour in zip(pts, along, sides, colours, strict=True):
            direction = a if side == 0 else -a
            centre = p + np.array([direction[1], -direction[0]]) * lane  # right of the driving direction
            if np.linalg.norm(centre - cam) < 14.0 or np.linalg.norm(centre - cam) > 180.0:
                continue
            cars.append(Car(centre, direction, CAR_PALETTE[int(colour)]))
    return cars


def cars_in_view(view: View, cars: list[Car]) -> list[tuple[float, Callable[[], None]]]:
    """``(depth, draw)`` of every car that may show in the view, in the order of ``cars``."""
    tan_half = view.camera.tan_half
    parts: list[tuple[float, Callable[[], None]]] = []
    for car in cars:
        rel = car.center - view.cam
        z = float(rel @ view.fwd)
        if z > 2.0 and abs(float(rel @ view.right)) - 3.0 < z * tan_half:
            parts.append((z, partial(draw_car, view, car)))
    return parts


def draw_car(view: View, car: Car) -> None:
    """A car: a body box and a glass cabin box with their visible faces lit by the sun, and a soft shadow."""
    camera = view.camera
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
        lo_uv, lo_z = view.project(corners, np.full(4, bottom))
        hi_uv, _ = view.project(corners, np.full(4, top))
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
    shadow_uv, _ = view.project(
        np.array(
            [
                car.center - along * 2.4 - across * 1.0,
                car.center + along * 2.4 - across * 1.0,
                car.center + along * 2.4 + across * 1.0,
                car.center - along * 2.4 + across * 1.0,
            ]
        ),
        np.zeros(4),
    )
    everything = np.concatenate([f[0] for f in faces] + [shadow_uv])
    placed = camera.pixel_box(*everything.min(axis=0), *everything.max(axis=0))
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
    fog = float(fog_amount(np.array(z)))
    out[..., :3] = out[..., :3] * (1 - fog) + view.lighting.haze * fog
    out[..., 3] /= 255.0
    view.composite(box, out, z)
