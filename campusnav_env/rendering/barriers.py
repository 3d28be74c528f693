"""
Closure barriers: what a closed road shows in the street views.

A closed road (``closed_roads`` of :meth:`~campusnav_env.rendering.street_view.StreetViewRenderer.render_node`) gets a
construction barrier at each end, :data:`BARRIER_OFFSET` along it from the intersection: red-and-white striped boards
on trestles across the asphalt, a "ROAD CLOSED" sign on top and two orange cones in front. The barrier is a vertical
plane, so its picture is one exact homography of a texture and its depth is exact per image column.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Sequence
from dataclasses import dataclass
from functools import partial

import cv2
import numpy as np

from campusnav_env.maps.geometry import points_along
from campusnav_env.rendering.camera import MAX_DISTANCE, View, fit_board
from campusnav_env.rendering.lighting import fog_amount
from campusnav_env.rendering.palette import BARRIER_LEG_RGB, BARRIER_RED_RGB, BARRIER_WHITE_RGB, CONE_ORANGE_RGB
from campusnav_env.rendering.scene import World

__all__ = [
    "BARRIER_NEAR",
    "BARRIER_OFFSET",
    "BARRIER_RAILS",
    "BARRIER_TEXELS_PER_M",
    "BARRIER_TOP",
    "BARRIER_VERSION",
    "Barrier",
    "ClosureBarriers",
    "draw_cone",
]

# Bump when the closure barriers' drawing changes: only views rendered with closed roads key on it.
BARRIER_VERSION = 1

# Where the closed road leaves the intersection: past the crossing road's asphalt (6 m), before the zebra crossing
BARRIER_OFFSET = 9.0  # distance along a closed road from each end to its barrier (m)
BARRIER_NEAR = 1.0  # barrier parts nearer to the camera than this are clipped (m)
BARRIER_TOP = 2.75  # top of the "ROAD CLOSED" sign above the road (m)
BARRIER_RAILS = ((0.4, 0.75), (0.9, 1.25), (1.4, 1.75))  # (bottom, top) of the striped boards (m)
BARRIER_TEXELS_PER_M = 64  # barrier texture resolution: sharp at 640x480 down to about 5 m away


@dataclass(frozen=True)
class Barrier:
    """A closed road's barrier: a vertical board across the road, facing the intersection it guards."""

    centre: np.ndarray  # ground point on the road's centreline (east, north)
    facing: np.ndarray  # horizontal unit vector along the road towards that intersection


class ClosureBarriers:
    """
    The barriers of a world's closed roads: placed on demand, kept per road, drawn from one texture.

    :param world: The scene
    :param roads: Every road's polyline, in road id order
    """

    def __init__(self, world: World, roads: Sequence[np.ndarray]) -> None:
        self.world = world
        self._roads = roads
        self._placed: dict[int, tuple[Barrier, Barrier]] = {}
        self._image: np.ndarray | None = None

    def on_roads(self, closed_roads: Collection[tuple[int, int]]) -> list[Barrier]:
        """
        The barriers of the closed roads (two per road, placed once per road and kept).

        :param closed_roads: Roads as node pairs, either order
        :return: Two barriers per road, roads in id order
        :raises KeyError: if a closed road is not a road of the graph
        """
        graph = self.world.graph
        barriers: list[Barrier] = []
        for road in sorted({graph.road_id(int(u), int(v)) for u, v in closed_roads}):
            pair = self._placed.get(road)
            if pair is None:
                pair = self._placed[road] = self._place(road)
            barriers.extend(pair)
        return barriers

    def _place(self, road: int) -> tuple[Barrier, Barrier]:
        """One barrier :data:`BARRIER_OFFSET` along the road's polyline from each end (a third of short roads)."""
        g = self._roads[road]
        cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(g, axis=0), axis=1))])
        total = float(cum[-1])
        s = min(BARRIER_OFFSET, total / 3.0)
        # The road's direction over a metre around each barrier: robust to bends and degenerate segments
        at = np.array([s, total - s])
        centres = points_along(g, cum, at)
        ahead = points_along(g, cum, np.minimum(at + 0.5, total)) - points_along(g, cum, np.maximum(at - 0.5, 0.0))
        ahead /= np.maximum(np.linalg.norm(ahead, axis=1), 1e-9)[:, None]
        # The barrier near the first end faces back towards it, the one near the last end faces forward
        return Barrier(centres[0], -ahead[0]), Barrier(centres[1], ahead[1])

    def in_view(self, view: View, barriers: list[Barrier]) -> list[tuple[float, Callable[[], None]]]:
        """``(depth, draw)`` of every barrier board and cone in the view's frustum."""
        parts: list[tuple[float, Callable[[], None]]] = []
        tan_half = view.camera.tan_half
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
                parts.append((float(z.mean()), partial(self._draw_board, view, barrier)))
            # Two cones on the intersection's side of the board, in the lanes
            for offset in (-half + 2.0, half - 2.0):
                cone = barrier.centre + barrier.facing * 1.6 + across * offset
                x_cone, z_cone = (cone - view.cam) @ view.right, (cone - view.cam) @ view.fwd
                if BARRIER_NEAR < z_cone < MAX_DISTANCE and abs(x_cone) - 0.3 < z_cone * tan_half:
                    parts.append((float(z_cone), partial(draw_cone, view, cone)))
        return parts

    def _texture(self) -> np.ndarray:
        """
        RGBA picture of a barrier across the asphalt (built once): sections of three red-and-white striped boards on
        trestles, a "ROAD CLOSED" sign on top; rows top (:data:`BARRIER_TOP` m) to bottom (the ground).
        """
        if self._image is not None:
            return self._image
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
        self._image = img
        return img

    def _draw_board(self, view: View, barrier: Barrier) -> None:
        """The barrier board warped onto its plane (clipped at :data:`BARRIER_NEAR`), depth exact per column."""
        camera = view.camera
        # Read from whichever side the camera is on: the texture's left end is the viewer's left
        looking = -barrier.facing if float((view.cam - barrier.centre) @ barrier.facing) > 0 else barrier.facing
        to_right = np.array([looking[1], -looking[0]])
        half = self.world.road_width / 2
        left, right = barrier.centre - to_right * half, barrier.centre + to_right * half
        texture = self._texture()
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
        quad, _ = view.project(ends[[0, 1, 1, 0]], np.array([BARRIER_TOP, BARRIER_TOP, 0.0, 0.0]))
        board = texture[:, c0:c1]
        warped = camera.warp_board(fit_board(board, quad), quad)
        if warped is None:
            return
        (x0, y0, x1, y1), rgb, alpha = warped
        # Depth of the board in each column: where the column's ray meets the board's ground line
        rel = ends - view.cam
        xa, za = rel[0] @ view.right, rel[0] @ view.fwd
        dx, dz = (rel[1] - rel[0]) @ view.right, (rel[1] - rel[0]) @ view.fwd
        xc = camera.col_x[x0:x1]
        with np.errstate(divide="ignore", invalid="ignore"):
            along = (xc * za - xa) / (dx - xc * dz)
        along = np.clip(np.nan_to_num(along, nan=0.0), 0.0, 1.0)  # nan: a column that sees the board edge-on
        z = (za + along * dz).astype(np.float32)
        fog = fog_amount(z)[None, :, None]
        light = view.lighting.ambient + view.lighting.sun * 0.5 + 0.15
        rgb = rgb * light * (1 - fog) + view.lighting.haze * fog
        view.composite((x0, y0, x1, y1), np.concatenate([rgb, alpha[..., None]], axis=2), z[None, :])


def draw_cone(view: View, position: np.ndarray) -> None:
    """A traffic cone (0.75 m, orange with a white band, on a dark base), seen from the side at any angle."""
    camera = view.camera
    rel = position - view.cam
    x, z = float(rel @ view.right), float(rel @ view.fwd)
    f = camera.fy / z
    u = camera.cx + camera.fx * x / z
    placed = camera.pixel_box(
        u - 0.25 * f, camera.cy + f * (camera.eye - 0.75), u + 0.25 * f, camera.cy + f * camera.eye
    )
    if placed is None:
        return
    box, ox, oy = placed
    patch = np.zeros((box[3] - box[1], box[2] - box[0], 4), dtype=np.uint8)
    light = view.lighting.ambient + view.lighting.sun * 0.5 + 0.15

    def outline(profile: list[tuple[float, float]]) -> np.ndarray:
        """Image polygon of a solid of revolution's profile, (height, half width) pairs from the bottom up."""
        heights = np.array([p[0] for p in profile] + [p[0] for p in profile[::-1]])
        widths = np.array([-p[1] for p in profile] + [p[1] for p in profile[::-1]])
        pts = np.stack([u + f * widths - ox, camera.cy + f * (camera.eye - heights) - oy], axis=1)
        return np.round(pts * 16).astype(np.int32)

    for profile, rgb in (
        ([(0.0, 0.22), (0.05, 0.22)], (36.0, 36.0, 38.0)),
        ([(0.05, 0.17), (0.75, 0.03)], CONE_ORANGE_RGB),
        ([(0.3, 0.124), (0.45, 0.094)], BARRIER_WHITE_RGB),
    ):
        colour = np.clip(np.asarray(rgb, dtype=np.float32) * light, 0, 255)
        cv2.fillPoly(patch, [outline(profile)], (*map(int, colour), 255), cv2.LINE_AA, 4)
    out = patch.astype(np.float32)
    fog = float(fog_amount(np.array(z)))
    out[..., :3] = out[..., :3] * (1 - fog) + view.lighting.haze * fog
    out[..., 3] /= 255.0
    view.composite(box, out, z)
