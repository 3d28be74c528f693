"""
The scene around a road graph: what a street-view camera can see besides the roads, as plain data.

A :class:`World` holds the road graph, the :class:`Building` footprints (landmarks first), the :class:`Tree` s, the
open :class:`Field` s and the free-standing monument :class:`Sign` s, and the road dimensions shared by the renderer
and the placement. :func:`~campusnav_env.rendering.world.build_world` fills it.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from campusnav_env.rendering.palette import CROWN_PALETTE, RGB

if TYPE_CHECKING:
    from campusnav_env.maps.road_graph import RoadGraph

__all__ = [
    "ROAD_WIDTH",
    "SIDEWALK_WIDTH",
    "VERGE_WIDTH",
    "WORLD_VERSION",
    "Building",
    "Field",
    "Sign",
    "Tree",
    "World",
    "footprint_walls",
]

# Bump when placement rules change: the world fingerprint (and so every feature cache key) depends on it.
WORLD_VERSION = 2

ROAD_WIDTH = 12.0  # asphalt, both lanes (m)
VERGE_WIDTH = 2.0  # grass strip with street trees between asphalt and sidewalk (m)
SIDEWALK_WIDTH = 2.5  # (m)


@dataclass(frozen=True, eq=False)
class Building:
    """
    An extruded footprint with a facade pattern.

    :param footprint: ``(k, 2)`` counter-clockwise polygon (metres); wall ``i`` runs from vertex ``i`` to ``i + 1``
    :param height: Roof height (m)
    :param facade_rgb: Wall colour
    :param window_rgb: Glass colour
    :param roof_rgb: Roof colour (top-down map and pictures)
    :param floor_height: Storey height (m); windows repeat with it vertically
    :param window_spacing: Horizontal window pitch along a wall (m)
    :param window_width: Share of the pitch that is glass (1.0 = ribbon windows)
    :param window_height: Share of the storey that is glass
    :param name: Landmark name shown as a sign, or ``None``
    :param node: The landmark's intersection, or ``None``
    :param sign_wall: Index of the wall carrying the sign (the one facing ``node``), or ``None``
    """

    footprint: np.ndarray
    height: float
    facade_rgb: RGB
    window_rgb: RGB
    roof_rgb: RGB
    floor_height: float = 3.5
    window_spacing: float = 3.0
    window_width: float = 0.5
    window_height: float = 0.55
    name: str | None = None
    node: int | None = None
    sign_wall: int | None = None


@dataclass(frozen=True, eq=False)
class Tree:
    """A street or park tree: a trunk and a round crown."""

    position: np.ndarray
    radius: float
    height: float
    crown_rgb: RGB = CROWN_PALETTE[0]


@dataclass(frozen=True, eq=False)
class Field:
    """An open ground area drawn on the ground plane: ``kind`` is ``"sports"`` (with white ``lines``) or ``"park"``."""

    polygon: np.ndarray
    rgb: RGB
    kind: str = "park"
    name: str | None = None
    lines: tuple[np.ndarray, ...] = ()


@dataclass(frozen=True, eq=False)
class Sign:
    """
    A free-standing monument sign: a board of ``width`` x ``height`` m whose bottom is ``elevation`` m up.

    The board stands at ``position`` across the direction ``bearing`` (degrees clockwise from north) that its face
    points to; the text reads correctly from either side.
    """

    position: np.ndarray
    text: str
    bearing: float
    width: float = 8.0
    height: float = 1.6
    elevation: float = 0.8
    board_rgb: RGB = (28, 52, 40)
    text_rgb: RGB = (245, 245, 235)


@dataclass(eq=False)
class World:
    """
    Everything around a road graph that the street-view renderer draws.

    :param graph: The road network (closures do not change the world)
    :param buildings: Building footprints, landmarks first
    :param trees: Street and park trees
    :param fields: Sports fields and parks (ground-level areas)
    :param signs: Monument signs of landmarks without a building
    :param road_width: Asphalt width of every road (m)
    :param verge_width: Grass strip between asphalt and sidewalk on each side (m)
    :param sidewalk_width: Sidewalk width on each side (m)
    :param seed: The placement seed
    """

    graph: RoadGraph
    buildings: tuple[Building, ...]
    trees: tuple[Tree, ...]
    fields: tuple[Field, ...]
    signs: tuple[Sign, ...] = ()
    road_width: float = ROAD_WIDTH
    verge_width: float = VERGE_WIDTH
    sidewalk_width: float = SIDEWALK_WIDTH
    seed: int = 0
    _fingerprint: str | None = field(default=None, repr=False)

    @property
    def clearance(self) -> float:
        """Distance from a road centreline that buildings never enter: half the road plus verge and sidewalk."""
        return self.road_width / 2 + self.verge_width + self.sidewalk_width

    def landmark_building(self, name: str) -> Building:
        """The building carrying landmark ``name``'s sign (``KeyError`` naming it if it has none)."""
        for building in self.buildings:
            if building.name == name:
                return building
        raise KeyError(f"no landmark building named {name!r} in this world")

    def fingerprint(self) -> str:
        """sha256 hex of the road graph's fingerprint, the placement parameters and every object in the world."""
        if self._fingerprint is None:
            digest = hashlib.sha256(f"campusnav-world-v{WORLD_VERSION}|{self.graph.fingerprint()}".encode())
            digest.update(repr((self.road_width, self.verge_width, self.sidewalk_width, self.seed)).encode())
            for b in self.buildings:
                digest.update(np.ascontiguousarray(b.footprint, dtype=np.float64).tobytes())
                digest.update(
                    repr(
                        (
                            b.height,
                            b.facade_rgb,
                            b.window_rgb,
                            b.roof_rgb,
                            b.floor_height,
                            b.window_spacing,
                            b.window_width,
                            b.window_height,
                            b.name,
                            b.node,
                            b.sign_wall,
                        )
                    ).encode()
                )
            for t in self.trees:
                digest.update(np.ascontiguousarray(t.position, dtype=np.float64).tobytes())
                digest.update(repr((t.radius, t.height, t.crown_rgb)).encode())
            for f in self.fields:
                digest.update(np.ascontiguousarray(f.polygon, dtype=np.float64).tobytes())
                digest.update(repr((f.rgb, f.kind, f.name, len(f.lines))).encode())
                for line in f.lines:
                    digest.update(np.ascontiguousarray(line, dtype=np.float64).tobytes())
            for s in self.signs:
                digest.update(np.ascontiguousarray(s.position, dtype=np.float64).tobytes())
                digest.update(repr((s.text, s.bearing, s.width, s.height, s.elevation, s.board_rgb)).encode())
            self._fingerprint = digest.hexdigest()
        return self._fingerprint


def footprint_walls(buildings: Sequence[Building]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every wall of every footprint as segments: starts ``(M, 2)``, ends ``(M, 2)`` and building ids ``(M,)``."""
    starts, ends, owner = [], [], []
    for i, b in enumerate(buildings):
        f = np.asarray(b.footprint, dtype=np.float64)
        starts.append(f)
        ends.append(np.roll(f, -1, axis=0))
        owner.append(np.full(len(f), i, dtype=np.int64))
    if not starts:
        return np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, dtype=np.int64)
    return np.concatenate(starts), np.concatenate(ends), np.concatenate(owner)
