"""
Every colour of the rendered world: ground and road surfaces, facades, windows, roofs, tree crowns, cars, closure
barriers, the landmark palette that the 3D views and the top-down map share (:func:`landmark_colour`), and the
top-down map's and the figures' own colours (roads, closures, routes, text).

Colours are RGB tuples on the 0..255 scale.
"""

from __future__ import annotations

import hashlib

import cv2
import numpy as np

__all__ = [
    "AGENT_RGB",
    "ASPHALT_RGB",
    "BACKGROUND_RGB",
    "BARRIER_LEG_RGB",
    "BARRIER_RED_RGB",
    "BARRIER_WHITE_RGB",
    "BORDER_RGB",
    "CAR_PALETTE",
    "CLOSED_RGB",
    "CONE_ORANGE_RGB",
    "CROWN_PALETTE",
    "FACADE_PALETTE",
    "FACADE_SIGN_INK_RGB",
    "FACADE_SIGN_RGB",
    "GOAL_RGB",
    "GRASS_RGB",
    "LANDMARK_COLOURS",
    "LEARNED_ROUTE_RGB",
    "LIT_WINDOW_RGB",
    "MARKING_RGB",
    "NODE_ID_RGB",
    "NODE_RGB",
    "PAGE_RGB",
    "PARK_GREEN",
    "PATH_RGB",
    "RECOVERED_RGB",
    "REROUTED_RGB",
    "RGB",
    "ROAD_RGB",
    "ROOF_PALETTE",
    "ROUTE_COLOURS",
    "SHORTEST_PATH_RGB",
    "SIDEWALK_RGB",
    "SPORTS_GREEN",
    "TEXT_RGB",
    "TRUNK_RGB",
    "WINDOW_PALETTE",
    "landmark_colour",
]

RGB = tuple[int, int, int]

# Distinctive facade colours of the named places (saturated, unlike the muted palette of ordinary buildings).
LANDMARK_COLOURS: dict[str, RGB] = {
    "Dreese Lab": (176, 28, 46),
    "Town house": (226, 122, 24),
    "Cinema": (118, 38, 156),
    "Library": (36, 78, 170),
    "Stadium": (24, 128, 116),
    "Student union": (214, 170, 20),
    "Hospital": (70, 170, 215),
    "Museum": (150, 96, 40),
    "Train station": (112, 120, 30),
    "Chapel": (200, 60, 130),
    "Bookstore": (40, 150, 60),
}
# Ordinary buildings (placement picks from these)
FACADE_PALETTE: tuple[RGB, ...] = (
    (150, 78, 62),  # red brick
    (132, 66, 52),  # dark brick
    (198, 184, 156),  # beige
    (176, 172, 162),  # concrete
    (150, 150, 148),  # grey
    (220, 216, 206),  # white render
    (190, 160, 118),  # sandstone
    (118, 96, 78),  # brown
    (168, 140, 110),  # tan
)
WINDOW_PALETTE: tuple[RGB, ...] = ((52, 64, 80), (70, 92, 112), (40, 48, 56), (96, 120, 136), (60, 80, 76))
ROOF_PALETTE: tuple[RGB, ...] = ((90, 90, 92), (110, 104, 98), (70, 72, 76))
# Landmark names on their walls
FACADE_SIGN_RGB: RGB = (240, 238, 228)
FACADE_SIGN_INK_RGB: RGB = (24, 24, 28)
# Tree crowns and open fields
CROWN_PALETTE: tuple[RGB, ...] = ((52, 96, 40), (64, 110, 46), (44, 84, 44), (78, 118, 52), (58, 92, 34))
SPORTS_GREEN: RGB = (76, 150, 60)
PARK_GREEN: RGB = (92, 136, 70)
# Ground, roads and markings
GRASS_RGB = (104, 138, 74)
ASPHALT_RGB = (82, 82, 86)
SIDEWALK_RGB = (178, 174, 166)
MARKING_RGB = (236, 236, 226)
# Props and closure barriers
TRUNK_RGB = (92, 70, 52)
LIT_WINDOW_RGB = (255, 212, 140)
BARRIER_RED_RGB = (206, 28, 34)
BARRIER_WHITE_RGB = (246, 246, 240)
CONE_ORANGE_RGB = (250, 96, 10)
BARRIER_LEG_RGB = (226, 226, 222)
CAR_PALETTE = (
    (235, 235, 235),
    (30, 30, 34),
    (170, 172, 176),
    (176, 30, 36),
    (36, 70, 150),
    (96, 100, 104),
    (40, 90, 60),
    (210, 170, 60),
)

# The top-down map (rendering/map_view.py) and the figures built on it (figures.py)
BACKGROUND_RGB = (246, 245, 240)
ROAD_RGB = (168, 168, 172)
NODE_RGB = (96, 96, 100)
CLOSED_RGB = (220, 30, 36)
PATH_RGB = (30, 100, 220)
AGENT_RGB = (0, 150, 80)
GOAL_RGB = (250, 196, 20)
TEXT_RGB = (30, 30, 34)
NODE_ID_RGB = (70, 70, 90)
PAGE_RGB = (255, 255, 255)
# Distinct colours of extra routes (matplotlib's tab10 without the path blue and the closure red).
ROUTE_COLOURS = (
    (255, 127, 14),
    (148, 103, 189),
    (44, 160, 44),
    (140, 86, 75),
    (227, 119, 194),
    (23, 190, 207),
    (188, 189, 34),
    (127, 127, 127),
)
# One meaning per colour in every route picture (evaluate, draw, routes.png): orange is the route the agent learned
# (the greedy policy's; before a closure in routes.png), purple the route after a closure, cyan the shortest path
LEARNED_ROUTE_RGB = ROUTE_COLOURS[0]
REROUTED_RGB = ROUTE_COLOURS[1]
SHORTEST_PATH_RGB = ROUTE_COLOURS[5]
RECOVERED_RGB = (20, 120, 60)
BORDER_RGB = (200, 200, 204)


def landmark_colour(name: str) -> RGB:
    """Facade colour of a landmark: fixed for the campus names, a saturated colour hashed from the name otherwise."""
    if name in LANDMARK_COLOURS:
        return LANDMARK_COLOURS[name]
    hue = int(hashlib.sha256(name.encode()).hexdigest()[:4], 16) % 180
    hsv = np.array([[[hue, 200, 190]]], dtype=np.uint8)
    r, g, b = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0]
    return (int(r), int(g), int(b))
