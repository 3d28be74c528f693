"""PCA projection of view features (the env's ``view_dim`` option): fit once, applied to any views."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from campusnav_env.features.projection import FeatureTransform, ViewProjection, fit_view_dim, pca_project


def _views(seed: int = 0, n: int = 30, d: int = 50) -> np.ndarray:
    rng = np.random.default_rng(seed)
    # Low-rank structure plus noise, like CNN features of a small map
    return (rng.normal(size=(n * 4, 6)) @ rng.normal(size=(6, d)) + 0.1 * rng.normal(size=(n * 4, d))).reshape(n, 4, d)


def test_projection_is_whitened_and_keeps_the_leading_subspace() -> None:
    views = _views()
    projected = pca_project(views, 6)
    assert projected.shape == (30, 4, 6) and projected.dtype == np.float32
    flat = projected.reshape(-1, 6).astype(np.float64)
    np.testing.assert_allclose(flat.mean(axis=0), 0.0, atol=1e-5)
    # Whitened: unit variance, uncorrelated axes
    np.testing.assert_allclose(np.cov(flat, rowvar=False), np.eye(6), atol=1e-4)
    # Six axes hold the rank-6 signal: the views' pairwise distances are kept up to the noise and the whitening
    original = views.reshape(-1, 50)
    residual = (original - original.mean(axis=0)) - (
        flat @ np.linalg.lstsq(flat, original - original.mean(axis=0), rcond=None)[0]
    )
    assert np.linalg.norm(residual) / np.linalg.norm(original - original.mean(axis=0)) < 0.1


def test_projection_is_deterministic_up_to_the_axis_sign_rule() -> None:
    views = _views(1)
    first = pca_project(views, 4)
    # The same views in another row order give the same projection of each view (signs fixed by the loadings)
    order = np.random.default_rng(2).permutation(views.shape[0])
    again = pca_project(views[order], 4)
    np.testing.assert_allclose(again, first[order], atol=1e-4)


@pytest.mark.parametrize("dim", [0, 51, 2.5, True])
def test_projection_rejects_a_bad_dimension(dim: object) -> None:
    with pytest.raises(ValueError, match="view_dim must be an int"):
        pca_project(_views(), dim)  # type: ignore[arg-type]


def test_the_refusal_says_why_the_dimension_is_too_large() -> None:
    views = _views(n=5)  # 20 views of 50 features: 19 axes
    n_views = views.shape[0] * views.shape[1]
    with pytest.raises(ValueError, match=rf"in \[1, {n_views - 1}\] .* \(they span at most one axis fewer than there"):
        pca_project(views, n_views)


def test_the_env_s_view_dim_is_fitted_to_what_the_views_span_and_said() -> None:
    views = _views(n=5)  # 20 views of 50 features span 19 axes
    n_views, n_features = views.shape[0] * views.shape[1], views.shape[2]
    limit = min(n_views - 1, n_features)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # within the limit: kept, without a word
        assert fit_view_dim(limit, views) == limit
    with pytest.warns(UserWarning, match=rf"view_dim 64 is more than this map's {n_views} views of {n_features} "):
        assert fit_view_dim(64, views) == limit
    with pytest.warns(UserWarning, match=rf"using view_dim {limit}"):
        transform = FeatureTransform.fit(views, "features", True, 64)
    assert transform.projection is not None and transform.projection.dim == limit
    for bad in (0, 2.5, True):
        with pytest.raises(ValueError, match="view_dim must be an int of at least 1"):
            fit_view_dim(bad, views)  # type: ignore[arg-type]


def test_a_fitted_projection_applies_the_same_transform_to_new_views() -> None:
    views = _views(3)
    projection = ViewProjection.fit(views, 5)
    assert projection.dim == 5
    np.testing.assert_array_equal(projection.transform(views), pca_project(views, 5))
    # A few views on their own (e.g. one node re-rendered) get the rows they get among all views
    np.testing.assert_allclose(projection.transform(views[7:9]), pca_project(views, 5)[7:9], atol=1e-5)
    np.testing.assert_allclose(projection.transform(views[7, 2]), pca_project(views, 5)[7, 2], atol=1e-5)
    # New views are not refit: an affine map, the fitted mean goes to zero
    new = _views(4)[:3]
    np.testing.assert_allclose(
        projection.transform(new) - projection.transform(np.zeros_like(new)),
        (new.astype(np.float64) @ projection.axes.T) / projection.spread,
        atol=1e-4,
    )
    np.testing.assert_allclose(projection.transform(projection.mean), 0.0, atol=1e-6)
    with pytest.raises(ValueError, match="read-only"):
        projection.axes[0, 0] = 1.0
    with pytest.raises(ValueError, match="50 features"):
        projection.transform(np.zeros((2, 4, 49)))
    with pytest.raises(ValueError, match=r"shape \(N, V, D\)"):
        ViewProjection.fit(np.zeros((4, 50)), 2)
