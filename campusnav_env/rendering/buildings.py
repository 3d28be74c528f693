"""
Buildings and signs of the street views: walls with textured facades, landmark names on their walls, and the
free-standing monument signs of landmarks without a building.

Walls are vertical and the camera has no pitch, so every image column is a ray in the ground plane. Each column's ray
is intersected with the front-facing walls within range; walls nearer to the camera hide the lower part of farther
ones (all buildings are taller than the eye), so a running minimum of the wall tops, nearest first, gives the visible
wall of every pixel exactly: no painter's-order errors and no near-plane artefacts. Facades are textured per pixel
(windows per storey and pitch, cornice, entrance), shaded by the sun direction, anti-aliased with distance and fogged.
Landmark signs are warped onto their wall where it is visible.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from functools import partial

import cv2
import numpy as np

from campusnav_env.rendering.camera import MAX_DISTANCE, NEAR, View, fit_board
from campusnav_env.rendering.lighting import fog_amount
from campusnav_env.rendering.palette import FACADE_SIGN_INK_RGB, FACADE_SIGN_RGB, LIT_WINDOW_RGB
from campusnav_env.rendering.scene import Sign, World, footprint_walls
from campusnav_env.rendering.spatial_index import SpatialIndex

__all__ = ["Buildings"]


class Buildings:
    """
    The walls of every building of a world (indexed for the per-column ray cast) and its signs.

    :param world: The scene
    """

    def __init__(self, world: World) -> None:
        self.world = world
        buildings = world.buildings
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

    def draw_walls(self, view: View) -> np.ndarray:
        """
        Cast one ray per column through the walls; fill facade pixels, depth and wall ids.

        :return: Ids of the walls that some pixel shows
        """
        camera = view.camera
        ids = self._wall_index.query(view.cam, MAX_DISTANCE)
        if len(ids) == 0:
            return ids
        a, b = self._wall_a[ids] - view.cam, self._wall_b[ids] - view.cam
        xa, za = a @ view.right, a @ view.fwd
        xb, zb = b @ view.right, b @ view.fwd
        tan_half = camera.cx / camera.fx + 1e-6
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
        ua = camera.cx + camera.fx * (xa + ta * dx) / (za + ta * dz)
        ub = camera.cx + camera.fx * (xa + tb * dx) / (za + tb * dz)
        c0 = np.clip(np.ceil(np.minimum(ua, ub)), 0, camera.width).astype(np.int64)
        c1 = np.clip(np.floor(np.maximum(ua, ub)), -1, camera.width - 1).astype(np.int64)
        span = np.maximum(c1 - c0 + 1, 0)
        k = np.repeat(np.arange(len(ids)), span)
        col = np.repeat(c0, span) + (np.arange(span.sum()) - np.repeat(np.cumsum(span) - span, span))
        # Ray of column c: (x_c * z, z). Solve x_c * (za + t dz) = xa + t dx for t; then z = za + t dz.
        xc = camera.col_x[col]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (xc * za[k] - xa[k]) / (dx[k] - xc * dz[k])
        z = za[k] + t * dz[k]
        hit = (t >= -1e-9) & (t <= 1.0 + 1e-9) & (z > NEAR) & (z < MAX_DISTANCE)
        col, z, t, wall = col[hit], z[hit], np.clip(t[hit], 0.0, 1.0), ids[k[hit]]
        if len(col) == 0:
            return col
        height = self._b_height[self._wall_owner[wall]]
        top = camera.cy - camera.fy * (height - camera.eye) / z
        # Nearest first within each column; a hit is visible where its top rises above every nearer hit's top
        # (buildings are taller than the eye, so nearer walls hide the lower part of farther ones).
        order = np.lexsort((z, col))
        col, z, t, wall, top = col[order], z[order], t[order], wall[order], top[order]
        big = 4.0 * (camera.height + camera.fy * 100.0)  # exceeds the range of `top`: per-column running minimum
        running = np.minimum.accumulate(top - col * big) + col * big
        first = np.ones(len(col), dtype=bool)
        first[1:] = col[1:] != col[:-1]
        prev = np.empty_like(running)
        prev[0] = np.inf
        prev[1:] = running[:-1]
        visible = first | (top < prev)
        col, z, t, wall, top, prev, first = (x[visible] for x in (col, z, t, wall, top, prev, first))
        # Pixel rows of each visible hit: [top, top of the previous visible hit), the nearest down to its ground line.
        r0 = np.clip(np.ceil(top), 0, camera.height).astype(np.int64)
        r1 = np.where(first, np.floor(camera.cy + camera.fy * camera.eye / z) + 1, np.ceil(prev))
        r1 = np.clip(r1, 0, camera.height).astype(np.int64)
        n_rows = np.maximum(r1 - r0, 0)
        hit_of_px = np.repeat(np.arange(len(col)), n_rows)
        rows = np.repeat(r0, n_rows) + (np.arange(n_rows.sum()) - np.repeat(np.cumsum(n_rows) - n_rows, n_rows))
        flat = rows * camera.width + col[hit_of_px]
        view.depth.reshape(-1)[flat] = z[hit_of_px]
        view.wall_of_pixel.reshape(-1)[flat] = wall[hit_of_px]
        view.image.reshape(-1, 3)[flat] = self._facade_colours(rows, hit_of_px, z, t, wall, view)
        return np.unique(wall)

    def _facade_colours(
        self,
        rows: np.ndarray,
        hit: np.ndarray,
        z: np.ndarray,
        t: np.ndarray,
        wall: np.ndarray,
        view: View,
    ) -> np.ndarray:
        """
        Facade colour of every wall pixel (``rows``, ``hit`` index into the per-hit ``z``, ``t``, ``wall``).

        Everything constant along a column of one wall (where along the wall, shading, haze, distance fading) is
        computed per hit; per pixel remain the storey, the window test and a lookup in a small per-hit palette.
        """
        camera, lighting = view.camera, view.lighting
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
        alpha = np.clip((np.minimum(spacing, floor_h) * camera.fy / z - 3.0) / 4.0, 0.0, 1.0).astype(np.float32)[
            :, None
        ]
        fog = fog_amount(z)[:, None]
        palette = np.stack([facade, glass, lit, cornice, entrance], axis=1)  # (hits, 5, 3)
        palette = palette * alpha[:, None] + mean[:, None, :] * (1 - alpha[:, None])
        palette = palette * (1 - fog[:, None]) + lighting.haze * fog[:, None]
        amp = (0.2 * alpha[:, 0] * (1 - fog[:, 0])).astype(np.float32)
        # Storey coordinate of each pixel: height / floor_h = a - row * b.
        a = ((camera.eye + camera.cy * z / camera.fy) / floor_h).astype(np.float32)
        b = (z / (camera.fy * floor_h)).astype(np.float32)
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

    def draw_facade_signs(self, view: View, visible_walls: np.ndarray) -> None:
        """Landmark names on their walls, warped onto the wall and shown only on the pixels that wall covers."""
        camera = view.camera
        if not self._signs:
            return
        visible = set(visible_walls.tolist())
        for wall, text in self._signs:
            if wall not in visible:
                continue
            a, b = self._wall_a[wall], self._wall_b[wall]
            length = float(self._wall_len[wall])
            board = self._sign_image(text, FACADE_SIGN_RGB, FACADE_SIGN_INK_RGB)
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
            quad, z = view.project(pts, heights)
            if (z < NEAR).any():
                continue
            warped = camera.warp_board(fit_board(board, quad), quad)
            if warped is None:
                continue
            (x0, y0, x1, y1), rgb, alpha = warped
            alpha = alpha * (view.wall_of_pixel[y0:y1, x0:x1] == wall)
            normal = self._wall_normal[wall]
            shade = view.lighting.ambient + max(0.0, float(normal @ view.lighting.sun_dir)) * view.lighting.sun + 0.1
            fog = float(fog_amount(np.array(z.mean())))
            rgb = rgb * shade * (1 - fog) + view.lighting.haze * fog
            region = view.image[y0:y1, x0:x1]
            region[:] = region * (1 - alpha[..., None]) + rgb * alpha[..., None]

    def sign_posts_in_view(self, view: View) -> list[tuple[float, Callable[[], None]]]:
        """``(depth, draw)`` of every monument sign in the view's frustum, in the world's order."""
        tan_half = view.camera.tan_half
        parts: list[tuple[float, Callable[[], None]]] = []
        for sign in self.world.signs:
            rel = sign.position - view.cam
            z = float(rel @ view.fwd)
            if 1.0 < z < MAX_DISTANCE and abs(float(rel @ view.right)) - sign.width < z * tan_half:
                parts.append((z, partial(self._draw_sign_post, view, sign)))
        return parts

    def _draw_sign_post(self, view: View, sign: Sign) -> None:
        """A monument sign: its board on two posts, reading left to right from either side."""
        camera = view.camera
        rad = math.radians(sign.bearing)
        facing = np.array([math.sin(rad), math.cos(rad)])
        across = np.array([facing[1], -facing[0]])
        ends = np.array([sign.position - across * sign.width / 2, sign.position + across * sign.width / 2])
        uv_end, z_end = view.project(ends, np.full(2, sign.elevation))
        if (z_end < NEAR).any():
            return
        if uv_end[0, 0] > uv_end[1, 0]:  # read left to right from whichever side the camera is on
            ends = ends[::-1]
        board = self._sign_image(sign.text, sign.board_rgb, sign.text_rgb)
        top, bottom = sign.elevation + sign.height, sign.elevation
        pts = np.array([ends[0], ends[1], ends[1], ends[0]])
        quad, z = view.project(pts, np.array([top, top, bottom, bottom]))
        board = fit_board(board, quad)
        # Two posts from the ground to the board, at a fifth of its width from each end.
        feet = ends[0] + np.outer([0.2, 0.8], ends[1] - ends[0])
        post_top, _ = view.project(feet, np.full(2, bottom))
        post_foot, _ = view.project(feet, np.zeros(2))
        everything = np.concatenate([quad, post_foot])
        placed = camera.pixel_box(*everything.min(axis=0), *everything.max(axis=0))
        warped = camera.warp_board(board, quad)
        if placed is None or warped is None:
            return
        box, ox, oy = placed
        patch = np.zeros((box[3] - box[1], box[2] - box[0], 4), dtype=np.float32)
        post_w = max(1, round(camera.fx * 0.2 / float(z.mean())))
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
        fog = float(fog_amount(np.array(z.mean())))
        patch[..., :3] = patch[..., :3] * light * (1 - fog) + view.lighting.haze * fog
        view.composite(box, patch, float(z.mean()))
