"""The view projection on large maps: the scatter-matrix fit and the chunked transform give what the SVD gives.

Large fits (from about 820 intersections of CNN features) take the principal axes from the features' scatter matrix
and transform a chunk of rows at a time, so that their cost no longer grows with (views x features) float64 copies
(``benchmarks/scale.py``). These tests pin the behaviour, not the speed: same projection as the thin SVD, small maps
bit for bit unchanged, callers' arrays untouched.
"""

from __future__ import annotations

import numpy as np
import pytest

from campusnav_env.features import projection
from campusnav_env.features.projection import FeatureTransform, ViewProjection


def _views(n: int, d: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    # Low-rank structure plus noise, with distinct spreads along the leading axes (CNN features of a map)
    signal = rng.normal(size=(n * 4, 8)) * np.linspace(4.0, 1.0, 8)
    return (signal @ rng.normal(size=(8, d)) + 0.1 * rng.normal(size=(n * 4, d))).astype(np.float32).reshape(n, 4, d)


def _svd_reference(views: np.ndarray, dim: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fit as it was before the large-map path: a thin SVD of all views in float64 (mean, axes, spread)."""
    flat = np.asarray(views, dtype=np.float64).reshape(-1, views.shape[-1])
    mean = flat.mean(axis=0)
    _, s, vt = np.linalg.svd(flat - mean, full_matrices=False)
    axes = vt[:dim]
    signs = np.sign(axes[np.arange(dim), np.abs(axes).argmax(axis=1)])
    spread = np.maximum(s[:dim] / np.sqrt(max(flat.shape[0] - 1, 1)), 1e-12)
    return mean, axes * signs[:, None], spread


def test_small_fits_keep_the_exact_svd() -> None:
    # 120 nodes of 64 features: below the large-fit size, so the shipped maps' features do not change by a bit
    views = _views(120, 64)
    fitted = ViewProjection.fit(views, 16)
    for got, want in zip((fitted.mean, fitted.axes, fitted.spread), _svd_reference(views, 16), strict=True):
        np.testing.assert_array_equal(got, want)


def test_large_fits_give_the_svd_projection(monkeypatch: pytest.MonkeyPatch) -> None:
    views = _views(150, 40)  # 600 views of 40 features
    monkeypatch.setattr(projection, "_SCATTER_MIN_VALUES", 1)  # take the large-map path at this size
    monkeypatch.setattr(projection, "_CHUNK_ROWS", 64)  # several chunks
    fitted = ViewProjection.fit(views, 8)
    mean, axes, spread = _svd_reference(views, 8)
    np.testing.assert_allclose(fitted.mean, mean, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fitted.axes, axes, rtol=0, atol=1e-9)  # same axes, same signs
    np.testing.assert_allclose(fitted.spread, spread, rtol=1e-9)
    flat = views.reshape(-1, 40).astype(np.float64)
    np.testing.assert_allclose(fitted.transform(views), ((flat - mean) @ axes.T / spread).reshape(150, 4, 8), atol=1e-5)


def test_fewer_views_than_twice_the_features_keep_the_svd(monkeypatch: pytest.MonkeyPatch) -> None:
    views = _views(10, 40)  # 40 views of 40 features: the scatter matrix would be no cheaper
    monkeypatch.setattr(projection, "_SCATTER_MIN_VALUES", 1)
    fitted = ViewProjection.fit(views, 5)
    np.testing.assert_array_equal(fitted.axes, _svd_reference(views, 5)[1])


def test_the_chunked_transform_gives_the_rows_of_the_one_shot_transform(monkeypatch: pytest.MonkeyPatch) -> None:
    views = _views(50, 24, seed=1)
    fitted = ViewProjection.fit(views, 6)
    whole = fitted.transform(views)
    monkeypatch.setattr(projection, "_CHUNK_ROWS", 7)  # 200 rows: 28 full chunks and a partial one
    chunked = fitted.transform(views)
    assert chunked.shape == whole.shape == (50, 4, 6) and chunked.dtype == np.float32
    np.testing.assert_allclose(chunked, whole, atol=1e-6)
    assert fitted.transform(views[:0]).shape == (0, 4, 6)


@pytest.mark.parametrize("view_dim", [None, 6])
def test_the_feature_transform_leaves_the_callers_views_alone(view_dim: int | None) -> None:
    # Standardising works in place on the transform's own copy, never on the encoder's (or the cache's) array
    views = _views(40, 24, seed=2)
    before = views.copy()
    transform = FeatureTransform.fit(views, "features", True, view_dim)
    rows = transform.transform(views)
    np.testing.assert_array_equal(views, before)
    assert rows.shape == (40, 4 * (view_dim or 24)) and rows.dtype == np.float32
    flat = rows.reshape(160, -1).astype(np.float64)
    np.testing.assert_allclose(flat.mean(axis=0), 0.0, atol=1e-4)  # standardised (and whitened) over the map's views
    np.testing.assert_allclose(flat.std(axis=0), 1.0, atol=5e-3)  # whitening divides by the n - 1 spread
