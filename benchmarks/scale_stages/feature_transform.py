"""Scale, feature transform: the time and memory of the env's feature transform (standardise, PCA to 64 per view)
on 1280-d features of every view of a map, per size.

Every env construction fits it on all 4N views, so its cost is paid by every process that builds an env (each
SubprocVecEnv worker, each evaluation env). Synthetic features with a CNN-like spectrum stand in for EfficientNet's
(the transform's cost depends on the shape, not on the values). Run by ``scale.py`` (stage ``fit``); alone::

    python benchmarks/scale_feature_transform.py --sizes 101 1000 10000 --runs-file /tmp/fit.jsonl --out /tmp/fit.md
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from benchmarks.report import markdown_table
from benchmarks.scale_common import EFFNET_DIM, MB, VIEW_DIM, Plan, peak_memory

STAGE = "fit"
# The fix of the PCA fit (large fits from the scatter matrix, chunked transform) and the run that measured the code
# before it: that run's records hold ``before_*`` figures, from a copy of FeatureTransform.fit/transform at 7faab86
FIX_COMMIT = "2c92cf1"
BEFORE_RUN_COMMIT = "6fc1f2b"


def synthetic_cnn_features(n_nodes: int, dim: int = EFFNET_DIM, seed: int = 0) -> np.ndarray:
    """``(n, 4, dim)`` float32 features with a CNN-like decaying spectrum (well separated leading axes)."""
    rng = np.random.default_rng(seed)
    rank = 96
    latent = rng.standard_normal((4 * n_nodes, rank), dtype=np.float32) * (0.93 ** np.arange(rank, dtype=np.float32))
    mixing = rng.standard_normal((rank, dim), dtype=np.float32)
    features = latent @ mixing
    features += 0.05 * rng.standard_normal(features.shape, dtype=np.float32)
    return np.maximum(features, 0.0).reshape(n_nodes, 4, dim)  # non-negative, like pooled activations


def measure_fit(n_nodes: int, plan: Plan) -> dict[str, Any]:
    """
    The env's feature transform, fit and applied on 1280-d features of ``n_nodes`` intersections.

    :param n_nodes: Intersections (4 views each)
    :param plan: The run (the stage measures the same whatever the plan)
    :return: the stage's record for this size (``after_*``: the transform as it is since the fix)
    """
    from campusnav_env.features.projection import FeatureTransform

    features = synthetic_cnn_features(n_nodes)
    record: dict[str, Any] = {"stage": STAGE, "size": n_nodes, "views": 4 * n_nodes, "features": EFFNET_DIM}
    with peak_memory() as peak:
        begin = time.perf_counter()
        FeatureTransform.fit(features, "features", True, VIEW_DIM).transform(features)
        record["after_seconds"] = time.perf_counter() - begin
    record |= {"after_extra_mb": peak.extra_mb, "input_mb": features.nbytes / MB, "memory_method": peak.method}
    return record


def fit_table(fits: dict[int, dict[str, Any]]) -> list[str]:
    """The feature transform at 1280-d per size; before the fix too where the records have it."""
    with_before = any("before_seconds" in fit for fit in fits.values())
    header = ["intersections (views x features)"]
    if with_before:
        header += ["before: fit + transform (s)", "before: peak memory (MB)"]
    header += ["after: fit + transform (s)", "after: peak memory (MB)"]
    if with_before:
        header += ["features before vs after"]
    rows = []
    for size in sorted(fits):
        fit = fits[size]
        row = [f"{size:,} ({fit['views']:,} x {fit['features']})"]
        if with_before:
            row += [f"{fit['before_seconds']:.2f}", f"{fit['before_extra_mb']:,.0f}"]
        row += [f"{fit['after_seconds']:.2f}", f"{fit['after_extra_mb']:,.0f}"]
        if with_before:
            row += ["identical" if fit["identical"] else f"max difference {fit['max_difference']:.1e}"]
        rows.append(row)
    return markdown_table(header, rows)


def feature_transform_section(fits: dict[int, dict[str, Any]]) -> list[str]:
    """The results section: the fix, where the figures come from, and the table."""
    with_before = any("before_seconds" in fit for fit in fits.values())
    source = (
        f"Before: measured in the same processes by `scale.py` at commit {BEFORE_RUN_COMMIT}, with a copy of "
        "`FeatureTransform.fit` and `transform` as they were at commit 7faab86 (the copy is in git history, not in "
        "the benchmark: a new run measures the shipped transform only)."
        if with_before
        else f"Before the fix (commit {FIX_COMMIT}): `git show {BEFORE_RUN_COMMIT}:benchmarks/results/scale.md`."
    )
    return [
        "### Fixed: the feature transform's PCA fit (campusnav_env/features/projection.py)",
        "",
        "Every env construction fits the feature transform on all 4N views (standardise, then PCA to 64 per "
        "view, the shipped `view_dim`): a thin SVD of the (4N x 1280) matrix in float64, with full-size float64 "
        "and float32 temporaries in the fit and again in the transform. Its time and memory grew with the map, "
        "in every process that builds an env (each SubprocVecEnv worker, each evaluation env). Now "
        "`ViewProjection.fit` takes large fits (from 4M values and 2 views per feature: 820+ intersections of "
        "1280-d views) from the 1280 x 1280 scatter matrix, accumulated a chunk of rows at a time; "
        "`ViewProjection.transform` works a chunk of 4,096 rows at a time; `FeatureTransform.fit/transform` "
        "standardise in place on their own copy. Smaller maps keep the exact SVD (the built-in campus's features "
        "are bit for bit unchanged). Synthetic 1280-d features with a CNN-like spectrum; peak memory: above the "
        f"input, per process (`VmHWM`). {source}",
        "",
        *fit_table(fits),
    ]
