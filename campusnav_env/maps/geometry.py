"""Plane geometry of road maps, vectorised: distances between points, segments and polygons (shapes broadcast)."""

from __future__ import annotations

import numpy as np

__all__ = ["point_segment_distances", "points_along", "polygon_segment_distances", "segment_segment_distances"]


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def point_segment_distances(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points ``p`` to segments ``a``-``b`` (all ``(..., 2)``, broadcast)."""
    ab = b - a
    denom = np.maximum((ab * ab).sum(-1), 1e-12)
    t = np.clip(((p - a) * ab).sum(-1) / denom, 0.0, 1.0)
    return np.linalg.norm(a + t[..., None] * ab - p, axis=-1)


def segment_segment_distances(p1: np.ndarray, p2: np.ndarray, q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Distance between segments ``p1-p2`` and ``q1-q2`` (0 where they cross); inputs ``(..., 2)``, broadcast."""
    d = np.minimum(
        np.minimum(point_segment_distances(p1, q1, q2), point_segment_distances(p2, q1, q2)),
        np.minimum(point_segment_distances(q1, p1, p2), point_segment_distances(q2, p1, p2)),
    )
    o1 = _cross(p2 - p1, q1 - p1)
    o2 = _cross(p2 - p1, q2 - p1)
    o3 = _cross(q2 - q1, p1 - q1)
    o4 = _cross(q2 - q1, p2 - q1)
    crossing = (o1 * o2 < 0) & (o3 * o4 < 0)
    return np.where(crossing, 0.0, d)


def polygon_segment_distances(polygons: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """
    Distance from each polygon to the segment paired with it (0 if the segment enters it).

    :param polygons: ``(P, k, 2)`` closed polygons (the last vertex connects to the first)
    :param a: ``(P, 2)`` segment starts
    :param b: ``(P, 2)`` segment ends
    :return: ``(P,)`` distances
    """
    v1 = polygons
    v2 = np.roll(polygons, -1, axis=1)
    dist = segment_segment_distances(v1, v2, a[:, None, :], b[:, None, :]).min(axis=1)
    # A segment wholly inside the polygon crosses no edge: test its start point (even-odd ray casting).
    py, px = a[:, None, 1], a[:, None, 0]
    y1, y2 = v1[..., 1], v2[..., 1]
    straddle = (y1 > py) != (y2 > py)
    x_at = v1[..., 0] + (py - y1) * (v2[..., 0] - v1[..., 0]) / np.where(y2 == y1, 1.0, y2 - y1)
    inside = (straddle & (px < x_at)).sum(axis=1) % 2 == 1
    return np.where(inside, 0.0, dist)


def points_along(polyline: np.ndarray, cumulative: np.ndarray, s: np.ndarray) -> np.ndarray:
    """
    Points at arc lengths ``s`` along a polyline (clamped to its first and last segment beyond its ends).

    :param polyline: ``(k, 2)`` vertices, ``k >= 2``
    :param cumulative: ``(k,)`` arc length at each vertex (0 first)
    :param s: ``(n,)`` arc lengths
    :return: ``(n, 2)`` points
    """
    k = np.clip(np.searchsorted(cumulative, s, side="right") - 1, 0, len(polyline) - 2)
    t = (s - cumulative[k]) / np.maximum(cumulative[k + 1] - cumulative[k], 1e-9)
    return polyline[k] + t[:, None] * (polyline[k + 1] - polyline[k])
