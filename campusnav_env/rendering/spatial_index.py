"""A uniform-grid index of axis-aligned boxes: which items may lie within a radius of a point."""

from __future__ import annotations

import numpy as np

__all__ = ["SpatialIndex"]


class SpatialIndex:
    """
    Uniform-grid lookup of axis-aligned boxes: which items may lie within a radius of a point.

    :param lo: ``(n, 2)`` lower corners of the items' bounding boxes
    :param hi: ``(n, 2)`` upper corners
    :param cell: Grid cell size (m)
    """

    def __init__(self, lo: np.ndarray, hi: np.ndarray, cell: float = 100.0) -> None:
        lo = np.asarray(lo, dtype=np.float64).reshape(-1, 2)
        hi = np.asarray(hi, dtype=np.float64).reshape(-1, 2)
        self.cell = float(cell)
        self.n = len(lo)
        if self.n == 0:
            self._keys = np.zeros(0, dtype=np.int64)
            self._items = np.zeros(0, dtype=np.int64)
            return
        i0 = np.floor(lo / self.cell).astype(np.int64)
        i1 = np.floor(hi / self.cell).astype(np.int64)
        counts = (i1 - i0 + 1).prod(axis=1)
        items = np.repeat(np.arange(self.n), counts)
        # Enumerate the cells under each box: offset within the box, row-major.
        start = np.repeat(np.cumsum(counts) - counts, counts)
        k = np.arange(counts.sum()) - start
        nx = (i1 - i0 + 1)[items, 0]
        cx = i0[items, 0] + k % nx
        cy = i0[items, 1] + k // nx
        keys = self._key(cx, cy)
        order = np.argsort(keys, kind="stable")
        self._keys = keys[order]
        self._items = items[order]

    @staticmethod
    def _key(cx: np.ndarray, cy: np.ndarray) -> np.ndarray:
        return (cx + (1 << 20)) * (1 << 21) + (cy + (1 << 20))

    def query(self, center: np.ndarray, radius: float) -> np.ndarray:
        """Sorted unique ids of items whose box overlaps the square of half-side ``radius`` around ``center``."""
        if self.n == 0:
            return np.zeros(0, dtype=np.int64)
        c0 = np.floor((np.asarray(center) - radius) / self.cell).astype(np.int64)
        c1 = np.floor((np.asarray(center) + radius) / self.cell).astype(np.int64)
        gx, gy = np.meshgrid(np.arange(c0[0], c1[0] + 1), np.arange(c0[1], c1[1] + 1), indexing="ij")
        keys = self._key(gx.ravel(), gy.ravel())
        left = np.searchsorted(self._keys, keys, side="left")
        right = np.searchsorted(self._keys, keys, side="right")
        if (right - left).sum() == 0:
            return np.zeros(0, dtype=np.int64)
        idx = np.concatenate([self._items[lo:hi] for lo, hi in zip(left, right, strict=True) if hi > lo])
        return np.unique(idx)

    def pairs(self, points: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """
        Candidate (point id, item id) pairs: every point within ``radius`` (at most one cell) of an item's box.

        Candidates come from the 3x3 cells around each point, so some pairs are farther apart; callers measure.

        :param points: ``(n, 2)`` query points
        :param radius: Search radius (m), at most one grid cell
        :return: ``(point_ids, item_ids)``, equally long int64 arrays
        :raises ValueError: if ``radius`` exceeds the grid cell
        """
        points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if self.n == 0 or len(points) == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        if radius > self.cell:
            raise ValueError(f"radius {radius} exceeds the grid cell {self.cell}")
        base = np.floor(points / self.cell).astype(np.int64)
        point_ids, item_ids = [], []
        for dx in (-1, 0, 1):
            for dy in (-1, 0, 1):
                keys = self._key(base[:, 0] + dx, base[:, 1] + dy)
                left = np.searchsorted(self._keys, keys, side="left")
                right = np.searchsorted(self._keys, keys, side="right")
                counts = right - left
                pid = np.repeat(np.arange(len(points)), counts)
                offset = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
                point_ids.append(pid)
                item_ids.append(self._items[np.repeat(left, counts) + offset])
        pid = np.concatenate(point_ids)
        iid = np.concatenate(item_ids)
        # A box spanning several neighbouring cells yields the same pair more than once.
        key = np.unique(pid * self.n + iid)
        return key // self.n, key % self.n
