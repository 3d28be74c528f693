"""
The street-view camera and the buffers of one view: projection, clipping and depth-tested compositing.

The camera is a horizontal pinhole camera (no pitch, no roll) standing ``eye`` metres above the road. A
:class:`Camera` holds what all views share (image size, focal lengths, principal point); a :class:`View` is one
picture being drawn: where the camera stands and looks, the light of the moment, and the colour, depth and wall-id
buffers that the drawing steps fill in place.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from campusnav_env.rendering.lighting import Lighting

__all__ = ["MAX_DISTANCE", "NEAR", "Camera", "View", "fit_board"]

MAX_DISTANCE = 400.0  # objects farther than this are not drawn (m)
NEAR = 0.3  # near plane (m)


class Camera:
    """
    The pinhole camera shared by every view.

    :param width: Image width (pixels)
    :param height: Image height (pixels)
    :param fov_deg: Horizontal field of view (degrees)
    :param eye: Camera height above the road (m)
    """

    def __init__(self, width: int, height: int, fov_deg: float, eye: float) -> None:
        self.width, self.height = width, height
        self.fx = self.fy = (width / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
        self.cx, self.cy = (width - 1) / 2.0, (height - 1) / 2.0
        self.eye = float(eye)
        # Camera-space x/z of each column's ray (the ray direction is forward + x * right).
        self.col_x = (np.arange(width) - self.cx) / self.fx
        self.horizon = math.floor(self.cy) + 1  # first ground row

    @property
    def tan_half(self) -> float:
        """Tangent of half the horizontal field of view: a point is in view where ``|x| < z * tan_half``."""
        return self.cx / self.fx

    def pixel_box(
        self, x0: float, y0: float, x1: float, y1: float
    ) -> tuple[tuple[int, int, int, int], int, int] | None:
        """
        Integer pixel box covering ``[x0, x1] x [y0, y1]``, clipped to the image.

        :return: ``((x0, y0, x1, y1), x0, y0)`` (end exclusive), or ``None`` where nothing is left
        """
        ix0, iy0 = max(math.floor(x0), 0), max(math.floor(y0), 0)
        ix1, iy1 = min(math.ceil(x1) + 1, self.width), min(math.ceil(y1) + 1, self.height)
        if ix1 <= ix0 or iy1 <= iy0:
            return None
        return (ix0, iy0, ix1, iy1), ix0, iy0

    def warp_board(
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


def fit_board(board: np.ndarray, quad: np.ndarray) -> np.ndarray:
    """The board shrunk (area-averaged) towards its on-screen size, so that small signs do not alias."""
    scale = float(np.ptp(quad[:, 1])) / board.shape[0]
    if scale >= 0.7:
        return board
    height = max(4, round(board.shape[0] * scale * 1.4))
    width = max(4, round(board.shape[1] * height / board.shape[0]))
    return cv2.resize(board, (width, height), interpolation=cv2.INTER_AREA)


@dataclass(frozen=True)
class View:
    """What the drawing steps of one rendered view share: the camera, the light and the buffers they fill in place."""

    camera: Camera
    node: int
    cam: np.ndarray  # camera position (east, north)
    fwd: np.ndarray  # horizontal unit vector the camera looks along
    right: np.ndarray  # horizontal unit vector to the camera's right
    lighting: Lighting
    image: np.ndarray  # (height, width, 3) float32 colours
    depth: np.ndarray  # (height, width) float32 distance along ``fwd`` of what each pixel shows (inf: nothing yet)
    wall_of_pixel: np.ndarray  # (height, width) int32 id of the wall each pixel shows (-1: none)

    @classmethod
    def looking(cls, camera: Camera, node: int, position: np.ndarray, bearing: float, lighting: Lighting) -> View:
        """
        An empty view from ``position`` (intersection ``node``) along ``bearing`` (degrees clockwise from north).
        """
        yaw = math.radians(bearing)
        h, w = camera.height, camera.width
        return cls(
            camera=camera,
            node=node,
            cam=position,
            fwd=np.array([math.sin(yaw), math.cos(yaw)]),
            right=np.array([math.cos(yaw), -math.sin(yaw)]),
            lighting=lighting,
            image=np.empty((h, w, 3), dtype=np.float32),
            depth=np.full((h, w), np.inf, dtype=np.float32),
            wall_of_pixel=np.full((h, w), -1, dtype=np.int32),
        )

    def project(self, pts: np.ndarray, heights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Image coordinates ``(n, 2)`` and depths ``(n,)`` of 3D points (ground position + height)."""
        camera = self.camera
        rel = pts - self.cam
        x, z = rel @ self.right, rel @ self.fwd
        zs = np.maximum(z, 1e-6)
        uv = np.stack([camera.cx + camera.fx * x / zs, camera.cy + camera.fy * (camera.eye - heights) / zs], axis=1)
        return uv, z

    def composite(self, box: tuple[int, int, int, int], rgba: np.ndarray, z: float | np.ndarray) -> None:
        """
        Blend an RGBA patch (float colours, alpha 0..1) into the image where it is nearer than what is there.

        :param box: The patch's pixel box ``(x0, y0, x1, y1)``, end exclusive
        :param rgba: ``(y1 - y0, x1 - x0, 4)`` float colours and alpha
        :param z: The patch's depth: one number, or an array broadcast against the patch (e.g. one per column)
        """
        x0, y0, x1, y1 = box
        zone = self.depth[y0:y1, x0:x1]
        alpha = rgba[..., 3] * (zone > z)
        region = self.image[y0:y1, x0:x1]
        region[:] = region * (1 - alpha[..., None]) + rgba[..., :3] * alpha[..., None]
        solid = alpha > 0.5
        zone[solid] = z if np.ndim(z) == 0 else np.broadcast_to(z, zone.shape)[solid]
