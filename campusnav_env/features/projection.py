"""Projection of view features onto fewer dimensions: PCA fit on the map's own views.

A CNN's 1280 or 2048 features per view are far more than a map of a few hundred intersections needs to tell its views
apart: the 4N views of an N-node map span at most 4N dimensions, and most of their variance lies in a few dozen. The
critics' first layer reads 8 views per observation (current and goal), so its cost scales with the feature size;
projecting each view onto its leading principal axes makes that layer proportionally cheaper. Like the z-scoring the
env already does, the projection is fit on the map's own views (no labels, no map knowledge beyond what the camera
sees) and is deterministic: the sign of each axis is fixed so that its largest loading is positive.
"""

from __future__ import annotations

import numpy as np

__all__ = ["pca_project"]


def pca_project(views: np.ndarray, dim: int) -> np.ndarray:
    """
    Project every view's features onto the ``dim`` leading principal axes of all views, whitened.

    :param views: Features of shape ``(N, V, D)``: ``V`` views of ``N`` intersections
    :param dim: Number of axes to keep, ``1 <= dim <= min(N * V - 1, D)``
    :return: Shape ``(N, V, dim)`` float32; each output dimension has zero mean and unit variance over the views
    :raises ValueError: if ``dim`` is out of range
    """
    views = np.asarray(views, dtype=np.float64)
    if views.ndim != 3:
        raise ValueError(f"views must have shape (N, V, D), got {views.shape}")
    flat = views.reshape(-1, views.shape[-1])
    limit = min(flat.shape[0] - 1, flat.shape[1])
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or not 1 <= dim <= limit:
        raise ValueError(
            f"view_dim must be an int in [1, {limit}] for {flat.shape[0]} views of {flat.shape[1]} features, "
            f"got {dim!r}"
        )
    centred = flat - flat.mean(axis=0)
    # Thin SVD of the (views x features) matrix: rows of vt are the principal axes, s their spread
    _, s, vt = np.linalg.svd(centred, full_matrices=False)
    axes = vt[:dim]
    signs = np.sign(axes[np.arange(dim), np.abs(axes).argmax(axis=1)])
    axes = axes * signs[:, None]
    spread = s[:dim] / np.sqrt(max(flat.shape[0] - 1, 1))
    projected = (centred @ axes.T) / np.maximum(spread, 1e-12)
    return projected.reshape(*views.shape[:2], dim).astype(np.float32)
