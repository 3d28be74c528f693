"""Projection of view features onto fewer dimensions: PCA fit on the map's own views.

A CNN's 1280 or 2048 features per view are far more than a map of a few hundred intersections needs to tell its views
apart: the 4N views of an N-node map span at most 4N dimensions, and most of their variance lies in a few dozen. The
critics' first layer reads 8 views per observation (current and goal), so its cost scales with the feature size;
projecting each view onto its leading principal axes makes that layer proportionally cheaper. Like the z-scoring the
env already does, the projection is fit on the map's own views (no labels, no map knowledge beyond what the camera
sees) and is deterministic: the sign of each axis is fixed so that its largest loading is positive.

The fit is kept (:class:`ViewProjection`), so that views rendered later (a closed road's barrier, see the env's
``visible_closures``) go through exactly the transform the original views went through.

``V`` views span at most ``V - 1`` axes (one is spent on their mean), and no more than their features: a small map
cannot fill a large ``view_dim``. :class:`ViewProjection` refuses such a request; the env's :class:`FeatureTransform`
fits it to the limit (:func:`fit_view_dim`) with one warning, since the axes beyond it would carry no variance.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

__all__ = ["FeatureTransform", "ViewProjection", "fit_view_dim", "pca_project"]


@dataclass(frozen=True)
class ViewProjection:
    """
    A whitened PCA of view features: fit once on a map's views (:meth:`fit`), applied to any views (:meth:`transform`).

    :param mean: ``(D,)`` mean of the views it was fit on
    :param axes: ``(dim, D)`` leading principal axes, each signed so that its largest loading is positive
    :param spread: ``(dim,)`` standard deviation of the fitted views along each axis
    """

    mean: np.ndarray
    axes: np.ndarray
    spread: np.ndarray

    @classmethod
    def fit(cls, views: np.ndarray, dim: int) -> ViewProjection:
        """
        The ``dim`` leading principal axes of all views.

        :param views: Features of shape ``(N, V, D)``: ``V`` views of ``N`` intersections
        :param dim: Number of axes to keep, ``1 <= dim <= min(N * V - 1, D)``
        :return: the projection
        :raises ValueError: if ``views`` is not 3-D or ``dim`` is out of range
        """
        views = np.asarray(views)
        if views.ndim != 3:
            raise ValueError(f"views must have shape (N, V, D), got {views.shape}")
        flat = views.reshape(-1, views.shape[-1])
        limit = min(flat.shape[0] - 1, flat.shape[1])
        if not _is_int(dim) or not 1 <= dim <= limit:
            raise ValueError(
                f"view_dim must be an int in [1, {limit}] for {flat.shape[0]} views of {flat.shape[1]} features "
                f"(they span at most one axis fewer than there are views), got {dim!r}"
            )
        n_rows, n_features = flat.shape
        if flat.size >= _SCATTER_MIN_VALUES and n_rows >= _SCATTER_ROWS_PER_FEATURE * n_features:
            mean, s, vt = _scatter_axes(flat, dim)
        else:
            mean, s, vt = _svd_axes(flat)
        axes = vt[:dim]
        signs = np.sign(axes[np.arange(dim), np.abs(axes).argmax(axis=1)])
        spread = np.maximum(s[:dim] / np.sqrt(max(flat.shape[0] - 1, 1)), 1e-12)
        parts = (mean, axes * signs[:, None], spread)
        for part in parts:
            part.flags.writeable = False
        return cls(*parts)

    @property
    def dim(self) -> int:
        """Number of output dimensions."""
        return int(self.axes.shape[0])

    def transform(self, views: np.ndarray) -> np.ndarray:
        """
        Project views onto the fitted axes, whitened (the views it was fit on get zero mean and unit variance).

        :param views: Features of shape ``(..., D)``
        :return: Shape ``(..., dim)`` float32
        :raises ValueError: if the feature size is not the fitted one
        """
        views = np.asarray(views)
        if views.ndim == 0 or views.shape[-1] != self.mean.shape[0]:
            raise ValueError(f"views must have {self.mean.shape[0]} features in their last axis, got {views.shape}")
        flat = views.reshape(-1, views.shape[-1])
        projected = np.empty((flat.shape[0], self.dim), dtype=np.float32)
        # A chunk of rows at a time, so that the float64 copies stay small on large maps (one chunk up to 1024 nodes)
        for start in range(0, flat.shape[0], _CHUNK_ROWS):
            chunk = flat[start : start + _CHUNK_ROWS].astype(np.float64)
            projected[start : start + _CHUNK_ROWS] = ((chunk - self.mean) @ self.axes.T) / self.spread
        return projected.reshape(*views.shape[:-1], self.dim)


# Large fits (from 820 intersections of 1280-d CNN views: 4M values, at least 2 views per feature) take the principal
# axes from the features' scatter matrix instead of a thin SVD of all views: the SVD's time and its (views x features)
# float64 copies grow with the map (10,000 intersections, 40,000 views of 1280 features: 18 s and 2.5 GB above the
# input, 2.5 s and 0.4 GB now; benchmarks/results/scale.md); the scatter matrix is 1280 x 1280 whatever the map.
# Smaller fits keep the SVD: the shipped maps' features stay bit for bit what they were.
_SCATTER_MIN_VALUES = 1 << 22
_SCATTER_ROWS_PER_FEATURE = 2
_CHUNK_ROWS = 4096  # rows converted to float64 at a time (40 MB at 1280 features)


def _svd_axes(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, singular values and principal axes (rows) of ``(views, features)`` by a thin SVD, in float64."""
    flat = np.asarray(flat, dtype=np.float64)
    mean = flat.mean(axis=0)
    _, s, vt = np.linalg.svd(flat - mean, full_matrices=False)
    return mean, s, vt


def _scatter_axes(flat: np.ndarray, dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """
    Mean, the ``dim`` largest singular values and their principal axes (rows) of ``(views, features)``, from the
    eigenvectors of the centred scatter matrix ``X^T X``, accumulated in float64 a chunk of rows at a time.
    """
    n_rows, n_features = flat.shape
    mean = np.zeros(n_features)
    for start in range(0, n_rows, _CHUNK_ROWS):
        mean += flat[start : start + _CHUNK_ROWS].sum(axis=0, dtype=np.float64)
    mean /= n_rows
    scatter = np.zeros((n_features, n_features))
    for start in range(0, n_rows, _CHUNK_ROWS):
        centred = flat[start : start + _CHUNK_ROWS].astype(np.float64) - mean
        scatter += centred.T @ centred
    eigenvalues, eigenvectors = np.linalg.eigh(scatter)  # ascending
    top = np.arange(n_features - 1, n_features - 1 - dim, -1)
    # The scatter's eigenvalues are the squared singular values; rounding can make a null direction slightly negative
    return mean, np.sqrt(np.maximum(eigenvalues[top], 0.0)), eigenvectors[:, top].T


def _is_int(value: object) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool)


def fit_view_dim(view_dim: int, views: np.ndarray) -> int:
    """
    ``view_dim``, or the most axes the views span when it asks for more (with a ``UserWarning`` naming both).

    :param view_dim: The number of axes asked for
    :param views: Features of shape ``(N, V, D)``
    :return: ``min(view_dim, N * V - 1, D)``
    :raises ValueError: if ``view_dim`` is not an int of at least 1
    """
    if not _is_int(view_dim) or view_dim < 1:
        raise ValueError(f"view_dim must be an int of at least 1, got {view_dim!r}")
    n_views, n_features = int(np.prod(views.shape[:-1])), int(views.shape[-1])
    limit = min(n_views - 1, n_features)
    if view_dim <= limit:
        return int(view_dim)
    warnings.warn(
        f"view_dim {view_dim} is more than this map's {n_views} views of {n_features} features span (at most "
        f"{limit} axes): using view_dim {limit}, which keeps all their variance",
        UserWarning,
        stacklevel=2,
    )
    return limit


def pca_project(views: np.ndarray, dim: int) -> np.ndarray:
    """
    Project every view's features onto the ``dim`` leading principal axes of all views, whitened.

    :param views: Features of shape ``(N, V, D)``: ``V`` views of ``N`` intersections
    :param dim: Number of axes to keep, ``1 <= dim <= min(N * V - 1, D)``
    :return: Shape ``(N, V, dim)`` float32; each output dimension has zero mean and unit variance over the views
    :raises ValueError: if ``dim`` is out of range
    """
    return ViewProjection.fit(views, dim).transform(views)


@dataclass(frozen=True)
class FeatureTransform:
    """
    What turns encoded views into observation rows: fit once on the open map's views, then applied to any views of
    that map (re-rendered with closure barriers), so that both are comparable.

    :param mode: The observation mode: ``"image"`` keeps the thumbnails as they are
    :param mean: Per-feature mean of the fitted views (standardisation), or None
    :param scale: Per-feature standard deviation (plus 1e-6) of the fitted views, or None
    :param projection: PCA projection fit on the standardised views (``view_dim``), or None
    """

    mode: str
    mean: np.ndarray | None = None
    scale: np.ndarray | None = None
    projection: ViewProjection | None = None

    @classmethod
    def fit(cls, node_views: np.ndarray, mode: str, normalize_features: bool, view_dim: int | None) -> FeatureTransform:
        if mode != "features":
            return cls(mode)
        views = node_views.astype(np.float32)
        mean = scale = projection = None
        if normalize_features:
            flat = views.reshape(-1, views.shape[-1])
            mean, scale = flat.mean(axis=0), flat.std(axis=0) + 1e-6
            # In place (views is this function's copy): no more full-size temporaries on large maps
            views -= mean
            views /= scale
        if view_dim is not None:
            projection = ViewProjection.fit(views, fit_view_dim(view_dim, views))
        return cls(mode, mean, scale, projection)

    def transform(self, node_views: np.ndarray) -> np.ndarray:
        """
        :param node_views: ``(n, 4, *encoding)`` encoded views of ``n`` nodes
        :return: features mode: ``(n, 4 * D)`` float32 rows (N, E, S, W blocks of D: SB3's extractors expect 1-D
            vectors); image mode: ``(n, 4, 3, h, w)`` uint8 thumbnails in compass order
        """
        if self.mode != "features":
            return np.ascontiguousarray(node_views, dtype=np.uint8)
        views = node_views.astype(np.float32)
        if self.mean is not None:
            views -= self.mean  # in place on this function's copy
            views /= self.scale
        if self.projection is not None:
            views = self.projection.transform(views)
        return views.reshape(views.shape[0], -1).astype(np.float32)
