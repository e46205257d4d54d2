"""Normalised median test and RANSAC affine consensus (track.outliers)."""

from __future__ import annotations

import numpy as np
import pytest

from track.errors import InputError
from track.outliers import normalized_median_test, ransac_affine


def smooth_field(x):
    return np.column_stack([0.05 * x[:, 0] + 2.0, np.sin(x[:, 1] / 20.0), 0.01 * x[:, 2] ** 1.5])


def test_median_test_flags_planted_outliers_and_keeps_smooth():
    rng = np.random.default_rng(0)
    x = rng.uniform(0, 100, (800, 3))
    u = smooth_field(x) + rng.normal(0, 0.02, x.shape)
    planted = rng.choice(800, 40, replace=False)
    u[planted] += rng.uniform(-5, 5, (40, 3)) + np.sign(rng.uniform(-1, 1, (40, 3))) * 1.0
    keep = normalized_median_test(x, u, n_neighbors=12, threshold=3.0, eps_um=0.05)
    assert not np.any(keep[planted])
    clean = np.setdiff1d(np.arange(800), planted)
    assert keep[clean].mean() >= 0.98


def test_median_test_small_sets_pass():
    assert normalized_median_test(np.eye(3), np.zeros((3, 3))).all()


@pytest.mark.parametrize(
    ("kwargs", "needle"),
    [
        ({"n_neighbors": 2}, "n_neighbors"),
        ({"threshold": 0}, "threshold"),
        ({"eps_um": -1}, "eps_um"),
    ],
)
def test_median_test_validates(kwargs, needle):
    x = np.random.default_rng(0).random((10, 3))
    with pytest.raises(InputError, match=needle):
        normalized_median_test(x, x, **kwargs)


def test_median_test_rejects_nan():
    x = np.random.default_rng(0).random((10, 3))
    u = x.copy()
    u[3, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        normalized_median_test(x, u)


def test_ransac_recovers_affine_with_most_candidates_wrong():
    rng = np.random.default_rng(1)
    a = rng.uniform(0, 100, (300, 3))
    f = np.array([[1.0, 0.0, 1.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]) @ np.diag([2.0, 0.7, 0.7])
    b = a @ f.T + [10.0, -5.0, 3.0] + rng.normal(0, 0.05, a.shape)
    wrong = rng.choice(300, 180, replace=False)
    b[wrong] = rng.uniform(-100, 300, (180, 3))
    out = ransac_affine(a, b, threshold_um=1.0, n_trials=2000, seed=0)
    assert out is not None
    aff, mask = out
    np.testing.assert_allclose(aff.matrix, f, atol=0.01)
    truth = np.ones(300, dtype=bool)
    truth[wrong] = False
    assert np.array_equal(mask, truth)


def test_ransac_gives_up_on_noise():
    rng = np.random.default_rng(2)
    assert (
        ransac_affine(rng.random((50, 3)) * 100, rng.random((50, 3)) * 100, 0.5, min_inliers=20)
        is None
    )
